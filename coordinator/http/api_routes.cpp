#include "coordinator/http/api_routes.h"

#include <map>

#include "absl/strings/match.h"
#include "prism/v1/farm.pb.h"

namespace prism::coordinator::http {
namespace {

namespace pb = google::protobuf;
using nlohmann::json;

std::string ref(const pb::Descriptor& message) {
  return "#/components/schemas/" + message.full_name();
}

json field_type_schema(const pb::FieldDescriptor& field) {
  switch (field.type()) {
    case pb::FieldDescriptor::TYPE_INT32:
    case pb::FieldDescriptor::TYPE_SINT32:
    case pb::FieldDescriptor::TYPE_SFIXED32:
      return {{"type", "integer"}, {"format", "int32"}};
    case pb::FieldDescriptor::TYPE_UINT32:
    case pb::FieldDescriptor::TYPE_FIXED32:
      return {{"type", "integer"}, {"format", "int32"}, {"minimum", 0}};
    // The JSON mapping writes 64-bit integers as decimal strings (JavaScript's numbers cannot
    // hold them); it reads both.
    case pb::FieldDescriptor::TYPE_INT64:
    case pb::FieldDescriptor::TYPE_SINT64:
    case pb::FieldDescriptor::TYPE_SFIXED64:
      return {{"type", "string"}, {"format", "int64"}};
    case pb::FieldDescriptor::TYPE_UINT64:
    case pb::FieldDescriptor::TYPE_FIXED64:
      return {{"type", "string"}, {"format", "uint64"}};
    case pb::FieldDescriptor::TYPE_FLOAT:
      return {{"type", "number"}, {"format", "float"}};
    case pb::FieldDescriptor::TYPE_DOUBLE:
      return {{"type", "number"}, {"format", "double"}};
    case pb::FieldDescriptor::TYPE_BOOL:
      return {{"type", "boolean"}};
    case pb::FieldDescriptor::TYPE_STRING:
      return {{"type", "string"}};
    case pb::FieldDescriptor::TYPE_BYTES:
      return {{"type", "string"}, {"format", "byte"}};
    case pb::FieldDescriptor::TYPE_ENUM: {
      json names = json::array();
      for (int i = 0; i < field.enum_type()->value_count(); ++i)
        names.push_back(field.enum_type()->value(i)->name());
      return {{"type", "string"}, {"enum", names}};
    }
    case pb::FieldDescriptor::TYPE_MESSAGE:
    case pb::FieldDescriptor::TYPE_GROUP:
      return {{"$ref", ref(*field.message_type())}};
  }
  return json::object();
}

// The messages reachable from `message` (itself included), by full name.
void collect(const pb::Descriptor& message, std::map<std::string, const pb::Descriptor*>& into) {
  if (!into.emplace(message.full_name(), &message).second) return;
  for (int i = 0; i < message.field_count(); ++i) {
    const pb::FieldDescriptor& field = *message.field(i);
    if (field.message_type() != nullptr) collect(*field.message_type(), into);
  }
}

json schema_content(const std::string& media_type, json schema) {
  json content = json::object();
  content[media_type] = json{{"schema", std::move(schema)}};
  return content;
}

json json_content(const pb::Descriptor& message) {
  return schema_content("application/json", json{{"$ref", ref(message)}});
}

json binary_content(const std::string& media_type) {
  return schema_content(media_type, json{{"type", "string"}, {"format", "binary"}});
}

Parameter job_id() {
  return {.name = "job_id",
          .in = "path",
          .type = "string",
          .required = true,
          .description = "a job's id, as SubmitJob returned it"};
}

}  // namespace

json message_schema(const pb::Descriptor& message) {
  json properties = json::object();
  json required = json::array();
  for (int i = 0; i < message.field_count(); ++i) {
    const pb::FieldDescriptor& field = *message.field(i);
    json schema = field_type_schema(field);
    if (field.is_repeated()) schema = {{"type", "array"}, {"items", schema}};
    properties[field.json_name()] = schema;
    // Printed with every primitive field: plain scalars are always there; messages, lists,
    // proto3 `optional` fields and oneof members may be absent. A request may leave any field
    // out (its default: an empty clientToken submits a new job each time).
    if (field.message_type() == nullptr && !field.is_repeated() && !field.has_presence() &&
        !absl::EndsWith(message.name(), "Request"))
      required.push_back(field.json_name());
  }
  json schema = {{"type", "object"}, {"properties", properties}, {"additionalProperties", false}};
  if (!required.empty()) schema["required"] = required;
  return schema;
}

// Routes leave out the fields they do not need (designated initialisers; every field has a
// default), which GCC's -Wextra reports as missing initialisers.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
const std::vector<Route>& api_routes() {
  namespace v1 = prism::v1;
  static const std::vector<Route> routes = {
      {.id = "listJobs",
       .method = "get",
       .path = "/api/v1/jobs",
       .summary = "The jobs, newest first",
       .parameters = {{.name = "limit",
                       .in = "query",
                       .type = "integer",
                       .description = "at most this many (0 or absent: all)"},
                      {.name = "state",
                       .in = "query",
                       .type = "string",
                       .description = "only jobs in these states (JobState names, e.g. "
                                      "JOB_STATE_RENDERING); may be repeated",
                       .repeated = true}},
       .response = v1::ListJobsResponse::descriptor()},
      {.id = "submitJob",
       .method = "post",
       .path = "/api/v1/jobs",
       .summary = "Submit a job for a scene bundle already uploaded (POST /api/v1/bundles or "
                  "`prism submit`); `prism pack` prints this body. The same clientToken returns "
                  "the same job",
       .request = v1::SubmitJobRequest::descriptor(),
       .response = v1::SubmitJobResponse::descriptor()},
      {.id = "getJob",
       .method = "get",
       .path = "/api/v1/jobs/{job_id}",
       .summary = "One job: its spec, state, progress and, once done, its report",
       .parameters = {job_id()},
       .response = v1::JobInfo::descriptor()},
      {.id = "cancelJob",
       .method = "post",
       .path = "/api/v1/jobs/{job_id}:cancel",
       .summary = "Cancel a job (idempotent for a cancelled job)",
       .parameters = {job_id()},
       .response = v1::JobInfo::descriptor()},
      {.id = "watchJob",
       .method = "get",
       .path = "/api/v1/jobs/{job_id}:watch",
       .summary = "Server-sent events mirroring WatchJob: an event `job` with the job at once and "
                  "on every change of its state or counts; the stream ends when the job is over",
       .parameters = {job_id()},
       .body = Body::kEventStream,
       .response = v1::JobInfo::descriptor()},
      {.id = "getPreview",
       .method = "get",
       .path = "/api/v1/jobs/{job_id}/preview.png",
       .summary = "An 8-bit PNG of the image as far as it is finalised",
       .parameters = {job_id(),
                      {.name = "exposure",
                       .in = "query",
                       .type = "number",
                       .description = "exposure in stops (default 0)"}},
       .body = Body::kPng},
      {.id = "getTiles",
       .method = "get",
       .path = "/api/v1/jobs/{job_id}/tiles",
       .summary = "The job's final-pass tiles as they stand: queued, leased, done, failed or "
                  "cancelled",
       .parameters = {job_id()},
       .response = v1::TileMap::descriptor()},
      {.id = "getConvergence",
       .method = "get",
       .path = "/api/v1/jobs/{job_id}/convergence",
       .summary = "The job's error estimate against time: the relative standard error of the "
                  "image's mean after each accepted final-pass result",
       .parameters = {job_id()},
       .response = v1::Convergence::descriptor()},
      {.id = "listResults",
       .method = "get",
       .path = "/api/v1/jobs/{job_id}/outputs",
       .summary = "A finished job's output files",
       .parameters = {job_id()},
       .response = v1::ListResultsResponse::descriptor()},
      {.id = "getResult",
       .method = "get",
       .path = "/api/v1/jobs/{job_id}/outputs/{file_name}",
       .summary = "One output file of a finished job, by the name listResults gives",
       .parameters = {job_id(),
                      {.name = "file_name",
                       .in = "path",
                       .type = "string",
                       .required = true,
                       .description = "an output's fileName"}},
       .body = Body::kFile},
      {.id = "listWorkers",
       .method = "get",
       .path = "/api/v1/workers",
       .summary = "The registered workers with their state, heartbeat and current task",
       .response = v1::ListWorkersResponse::descriptor()},
      {.id = "hasBundle",
       .method = "get",
       .path = "/api/v1/bundles/{bundle_hash}",
       .summary = "Whether the coordinator has a scene bundle",
       .parameters = {{.name = "bundle_hash",
                       .in = "path",
                       .type = "string",
                       .required = true,
                       .description = "the bundle's SHA-256, 64 lowercase hex digits"}},
       .response = v1::HasBundleResponse::descriptor()},
      {.id = "uploadBundle",
       .method = "post",
       .path = "/api/v1/bundles",
       .summary = "Upload a packed scene bundle (the file `prism pack --bundle` writes); the scene "
                  "must load. Returns its content hash",
       .binary_request = true,
       .response = v1::UploadBundleResponse::descriptor()},
      {.id = "metrics",
       .method = "get",
       .path = "/metrics",
       .summary = "Prometheus metrics (text exposition format 0.0.4)",
       .body = Body::kMetrics},
      {.id = "openapi",
       .method = "get",
       .path = "/api/v1/openapi.json",
       .summary = "This document",
       .body = Body::kOpenApi,
       .authenticated = false},
  };
  return routes;
}
#pragma GCC diagnostic pop

json openapi_document() {
  std::map<std::string, const pb::Descriptor*> messages;
  collect(*prism::v1::ApiError::descriptor(), messages);
  json paths = json::object();
  for (const Route& route : api_routes()) {
    json op = {{"operationId", route.id}, {"summary", route.summary}};
    json parameters = json::array();
    for (const Parameter& p : route.parameters) {
      json schema = {{"type", p.type}};
      if (p.repeated) schema = {{"type", "array"}, {"items", {{"type", p.type}}}};
      json parameter = {{"name", p.name},
                        {"in", p.in},
                        {"required", p.required},
                        {"description", p.description},
                        {"schema", schema}};
      if (p.repeated) {
        parameter["style"] = "form";
        parameter["explode"] = true;
      }
      parameters.push_back(parameter);
    }
    if (!parameters.empty()) op["parameters"] = parameters;
    if (route.request != nullptr) {
      collect(*route.request, messages);
      op["requestBody"] = {{"required", true}, {"content", json_content(*route.request)}};
    } else if (route.binary_request) {
      op["requestBody"] =
          json{{"required", true}, {"content", binary_content("application/octet-stream")}};
    }
    json ok = {{"description", "OK"}};
    switch (route.body) {
      case Body::kMessage:
        collect(*route.response, messages);
        ok["content"] = json_content(*route.response);
        break;
      case Body::kEventStream:
        collect(*route.response, messages);
        ok["description"] =
            "OK: events `job`, each data line a " + route.response->name() + " as JSON";
        ok["content"] = schema_content("text/event-stream", json{{"type", "string"}});
        ok["content"]["text/event-stream"]["x-event-data"] = json{{"$ref", ref(*route.response)}};
        break;
      case Body::kPng:
        ok["content"] = binary_content("image/png");
        break;
      case Body::kFile:
        ok["content"] = binary_content("*/*");
        break;
      case Body::kMetrics:
        ok["content"] = schema_content("text/plain", json{{"type", "string"}});
        break;
      case Body::kOpenApi:
        ok["content"] = schema_content("application/json", json{{"type", "object"}});
        break;
    }
    json error = {{"description", "An error: the status code's name and a message"},
                  {"content", json_content(*prism::v1::ApiError::descriptor())}};
    op["responses"] = {{"200", ok}, {"default", error}};
    if (!route.authenticated) op["security"] = json::array();
    paths[route.path][route.method] = op;
  }
  json schemas = json::object();
  for (const auto& [name, message] : messages) schemas[name] = message_schema(*message);
  return {
      {"openapi", "3.0.3"},
      {"info",
       {{"title", "Prism coordinator HTTP/JSON API"},
        {"version", "v1"},
        {"description",
         "Jobs, workers, previews, outputs and metrics of a Prism render farm's coordinator "
         "(`prism-coordinator --http-listen ADDR`). Bodies are the gRPC API's protobuf messages "
         "(proto/prism/v1/) in protobuf's JSON mapping. Errors map the canonical status codes "
         "to HTTP (INVALID_ARGUMENT and OUT_OF_RANGE 400, UNAUTHENTICATED 401, "
         "PERMISSION_DENIED 403, NOT_FOUND 404, ALREADY_EXISTS, ABORTED and "
         "FAILED_PRECONDITION 409, RESOURCE_EXHAUSTED 429 when waiting may help (a full queue, "
         "a busy farm) and 413 when it cannot (a body or a job over the coordinator's limits), "
         "CANCELLED 499, UNIMPLEMENTED 501, "
         "UNAVAILABLE 503, DEADLINE_EXCEEDED 504, others 500); a path asked for with a method "
         "it does not take is "
         "405 METHOD_NOT_ALLOWED with an Allow header, an unknown path 404. Generated from "
         "coordinator/http/api_routes.cpp."}}},
      {"paths", paths},
      {"components",
       {{"schemas", schemas},
        {"securitySchemes", {{"bearer", {{"type", "http"}, {"scheme", "bearer"}}}}}}},
      {"security", json::array({{{"bearer", json::array()}}})},
  };
}

}  // namespace prism::coordinator::http
