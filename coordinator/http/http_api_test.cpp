// The HTTP/JSON API against the OpenAPI document it is generated with: every JSON body a test
// receives is validated against the document's schema for its route (or the ApiError schema),
// the committed docs/api/openapi.json must be the generated document, and the flows a curl user
// follows (upload, submit, watch, outputs, cancel) give the same bytes as the gRPC API.
#include "coordinator/http/http_api.h"

#include <arpa/inet.h>
#include <httplib.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <fstream>
#include <future>
#include <regex>
#include <sstream>
#include <thread>

#include "coordinator/farm_server_fixture.h"
#include "coordinator/http/api_routes.h"
#include "nlohmann/json.hpp"

namespace prism::coordinator::farm_server_testing {
namespace {

using nlohmann::json;

// The first place `value` breaks `schema` (an OpenAPI 3.0 schema of the subset the generated
// document uses: $ref, object with properties, required and additionalProperties, array with
// items, string with enum and the int64/uint64 formats, integer with minimum, number, boolean),
// as "where: what"; empty when it conforms.
std::string schema_error(const json& value, const json& schema, const json& doc,
                         const std::string& where) {
  if (schema.contains("$ref")) {
    const std::string ref = schema["$ref"];
    const std::string prefix = "#/components/schemas/";
    if (ref.rfind(prefix, 0) != 0) return where + ": unsupported $ref " + ref;
    const json& schemas = doc["components"]["schemas"];
    const std::string name = ref.substr(prefix.size());
    if (!schemas.contains(name)) return where + ": dangling $ref " + ref;
    return schema_error(value, schemas[name], doc, where);
  }
  const std::string type = schema.value("type", "");
  if (type == "object") {
    if (!value.is_object()) return where + ": not an object";
    if (schema.contains("required")) {
      for (const json& required : schema["required"]) {
        const std::string key = required;
        if (!value.contains(key)) return where + ": missing required " + key;
      }
    }
    const json properties = schema.value("properties", json::object());
    for (const auto& [key, item] : value.items()) {
      if (!properties.contains(key)) {
        if (schema.value("additionalProperties", true) == false)
          return where + ": property " + key + " is not in the document";
        continue;
      }
      std::string error = schema_error(item, properties[key], doc, where + "." + key);
      if (!error.empty()) return error;
    }
    return "";
  }
  if (type == "array") {
    if (!value.is_array()) return where + ": not an array";
    for (std::size_t i = 0; i < value.size(); ++i) {
      std::string error =
          schema_error(value[i], schema["items"], doc, where + "[" + std::to_string(i) + "]");
      if (!error.empty()) return error;
    }
    return "";
  }
  if (type == "string") {
    if (!value.is_string()) return where + ": not a string";
    const std::string s = value;
    const std::string format = schema.value("format", "");
    if (format == "int64" && !std::regex_match(s, std::regex("-?[0-9]+")))
      return where + ": not an int64 string: " + s;
    if (format == "uint64" && !std::regex_match(s, std::regex("[0-9]+")))
      return where + ": not a uint64 string: " + s;
    if (schema.contains("enum")) {
      for (const json& allowed : schema["enum"])
        if (allowed == s) return "";
      return where + ": " + s + " is not one of the enum's names";
    }
    return "";
  }
  if (type == "integer") {
    if (!value.is_number_integer()) return where + ": not an integer";
    if (schema.contains("minimum") && value.get<double>() < schema["minimum"].get<double>())
      return where + ": below the minimum";
    return "";
  }
  if (type == "number") return value.is_number() ? "" : where + ": not a number";
  if (type == "boolean") return value.is_boolean() ? "" : where + ": not a boolean";
  return where + ": unsupported schema type '" + type + "'";
}

const http::Route& route(const std::string& id) {
  for (const http::Route& r : http::api_routes())
    if (r.id == id) return r;
  ADD_FAILURE() << "no route " << id;
  return http::api_routes().front();
}

class HttpApiTest : public FarmServerTest {
 protected:
  void SetUp() override {
    FarmServerTest::SetUp();
    http::HttpConfig config;
    config.api_token = kToken;
    auto api =
        http::HttpApi::start(farm_->farm(), config, std::make_shared<spdlog::logger>("http-test"));
    ASSERT_TRUE(api.ok()) << api.status();
    api_ = *std::move(api);
    http_ = std::make_unique<httplib::Client>("127.0.0.1", api_->port());
    http_->set_read_timeout(60, 0);
    doc_ = http::openapi_document();
  }
  void TearDown() override {
    api_.reset();  // before the farm it serves
    FarmServerTest::TearDown();
  }

  // A plain TCP connection to the API (for what httplib's client would not send); -1 on failure.
  int connect_raw() {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0) return -1;
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(static_cast<std::uint16_t>(api_->port()));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
      ::close(fd);
      return -1;
    }
    return fd;
  }

  httplib::Headers auth(const std::string& token = kToken) {
    return {{"Authorization", "Bearer " + token}};
  }

  // The response's JSON body, checked: the status, a JSON content type, and the body against the
  // document (the route's 200 schema on success, ApiError otherwise).
  json checked(const std::string& route_id, const httplib::Result& result, int status) {
    EXPECT_TRUE(result) << route_id << ": " << httplib::to_string(result.error());
    if (!result) return json();
    EXPECT_EQ(result->status, status) << route_id << ": " << result->body;
    EXPECT_EQ(result->get_header_value("Content-Type"), "application/json") << route_id;
    json body = json::parse(result->body, nullptr, false);
    EXPECT_FALSE(body.is_discarded()) << route_id << ": not JSON: " << result->body;
    const http::Route& r = route(route_id);
    const json& op = doc_["paths"][r.path][r.method];
    const json& schema = result->status == 200
                             ? op["responses"]["200"]["content"]["application/json"]["schema"]
                             : op["responses"]["default"]["content"]["application/json"]["schema"];
    EXPECT_EQ(schema_error(body, schema, doc_, route_id), "");
    return body;
  }

  std::string error_code(const json& body) { return body.value("code", ""); }

  std::unique_ptr<http::HttpApi> api_;
  std::unique_ptr<httplib::Client> http_;
  json doc_;
};

TEST(OpenApiDocumentTest, TheCommittedDocumentIsTheGeneratedOne) {
  std::ifstream in(fs::path(PRISM_SOURCE_DIR) / "docs/api/openapi.json");
  ASSERT_TRUE(in) << "docs/api/openapi.json is missing";
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_EQ(text.str(), http::openapi_document().dump(2) + "\n")
      << "regenerate it: build/coordinator/prism-openapi > docs/api/openapi.json";
}

TEST(OpenApiDocumentTest, EveryRouteIsDocumentedOnceWithSchemasThatResolve) {
  const json doc = http::openapi_document();
  std::set<std::string> ids;
  for (const http::Route& r : http::api_routes()) {
    EXPECT_TRUE(ids.insert(r.id).second) << "duplicate operationId " << r.id;
    ASSERT_TRUE(doc["paths"].contains(r.path)) << r.path;
    EXPECT_EQ(doc["paths"][r.path][r.method]["operationId"], r.id);
  }
  // Every $ref anywhere in the document names a schema it has.
  std::function<void(const json&)> walk = [&](const json& node) {
    if (node.is_object()) {
      if (node.contains("$ref")) {
        const std::string ref = node["$ref"];
        EXPECT_TRUE(doc["components"]["schemas"].contains(ref.substr(ref.rfind('/') + 1))) << ref;
      }
      for (const auto& [key, item] : node.items()) walk(item);
    } else if (node.is_array()) {
      for (const json& item : node) walk(item);
    }
  };
  walk(doc);
  // The mapping the schemas promise: lowerCamelCase names, 64-bit integers as strings.
  const json& progress = doc["components"]["schemas"]["prism.v1.JobProgress"]["properties"];
  EXPECT_EQ(progress["tasksTotal"]["type"], "string");
  EXPECT_EQ(progress["tilesTotal"]["type"], "integer");
}

// `curl --data-binary @scene.bundle` (the README's upload) sends
// application/x-www-form-urlencoded, which cpp-httplib's own body reading caps at 8 KiB with an
// empty 413: a real scene's bundle was refused. Read by the API, any content type carries it.
TEST_F(HttpApiTest, BundlesUploadWhateverTheirContentType) {
  const std::string big =
      packed_bundle(root_ / "big", std::string(kScene) + "\n# " + std::string(20000, 'x') + "\n");
  ASSERT_GT(big.size(), 20000u);
  for (const char* type :
       {"application/x-www-form-urlencoded", "application/octet-stream", "text/plain"}) {
    json uploaded = checked("uploadBundle", http_->Post("/api/v1/bundles", auth(), big, type), 200);
    EXPECT_EQ(uploaded.value("bundleHash", "").size(), 64u) << type;
  }
}

// The dashboard at /dashboard/, and at / and /dashboard by a redirect (the second was a 404).
TEST_F(HttpApiTest, TheDashboardIsFoundWithOrWithoutItsSlash) {
  for (const char* path : {"/", "/dashboard"}) {
    httplib::Result r = http_->Get(path);
    ASSERT_TRUE(r) << path;
    EXPECT_EQ(r->status, 302) << path;
    EXPECT_EQ(r->get_header_value("Location"), "/dashboard/") << path;
  }
  httplib::Result page = http_->Get("/dashboard/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->body.find("<html"), std::string::npos);
}

// `curl -X PUT URL` sends no Content-Length; on a route that does not exist cpp-httplib's own
// body reading answered it with an empty 400. The answer is the JSON 404 of any unknown route.
TEST_F(HttpApiTest, UnknownRoutesWithoutABodyGetTheJsonNotFound) {
  for (const char* method : {"PUT", "PATCH", "POST", "DELETE"}) {
    const int fd = connect_raw();
    ASSERT_GE(fd, 0);
    const std::string request =
        std::string(method) + " /api/v1/nothing HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n";
    ASSERT_EQ(::send(fd, request.data(), request.size(), 0), ssize_t(request.size()));
    std::string reply;
    char buffer[4096];
    for (ssize_t n; (n = ::recv(fd, buffer, sizeof(buffer), 0)) > 0;) reply.append(buffer, n);
    ::close(fd);
    EXPECT_TRUE(reply.starts_with("HTTP/1.1 404")) << method << ": " << reply;
    EXPECT_NE(reply.find("no route " + std::string(method) + " /api/v1/nothing"), std::string::npos)
        << reply;
  }
}

// A body over --max-bundle-bytes sent with a Content-Length (curl --data-binary, as the README
// uploads) was answered "the request body (the bundle) is empty": cpp-httplib did not read it.
// It is refused for its size, as a chunked one is.
TEST_F(HttpApiTest, ABodyOverTheLimitIsRefusedForItsSize) {
  const std::string big(100 << 10, 'x');  // the fixture's limit is 64 KiB
  // Without the token: 401 first, not the limit.
  httplib::Result anonymous = http_->Post("/api/v1/bundles", big, "application/octet-stream");
  ASSERT_TRUE(anonymous);
  EXPECT_EQ(anonymous->status, 401) << anonymous->body;
  httplib::Result r = http_->Post("/api/v1/bundles", auth(), big, "application/octet-stream");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 413) << r->body;  // permanent: not 429, which clients retry
  EXPECT_NE(r->body.find("is over 65536 bytes, the coordinator's --max-bundle-bytes"),
            std::string::npos)
      << r->body;
}

// The scheme of the Authorization header in any case (RFC 9110): "bearer" was refused.
TEST_F(HttpApiTest, TheBearerSchemeIsCaseInsensitive) {
  httplib::Result r =
      http_->Get("/api/v1/jobs", {{"Authorization", std::string("bearer ") + kToken}});
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200) << r->body;
}

// Idle connections that send nothing (each holds a server thread until its read timeout) do not
// hold up the API: with 16 threads, 16 of them made every request wait 5 s.
TEST_F(HttpApiTest, IdleConnectionsDoNotHoldUpRequests) {
  std::vector<int> idle;
  for (int i = 0; i < 24; ++i) {
    const int fd = connect_raw();
    ASSERT_GE(fd, 0);
    idle.push_back(fd);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // each taken by a thread
  // Answered while the idle connections still hold their threads (their timeout is 5 s).
  httplib::Client quick("127.0.0.1", api_->port());
  quick.set_read_timeout(2, 0);
  httplib::Result r = quick.Get("/api/v1/jobs", auth());
  for (int fd : idle) ::close(fd);
  ASSERT_TRUE(r) << httplib::to_string(r.error());
  EXPECT_EQ(r->status, 200);
}

// A route asked for with a method it does not take (DELETE on a job) was the 404 of a route
// that does not exist; it is a 405 naming the methods the path takes, in the Allow header too.
TEST_F(HttpApiTest, AKnownPathWithAnotherMethodIsMethodNotAllowed) {
  // Without the token: 401, telling nothing of the path's methods.
  httplib::Result anonymous = http_->Delete("/api/v1/jobs/j-000001");
  ASSERT_TRUE(anonymous);
  EXPECT_EQ(anonymous->status, 401);
  EXPECT_FALSE(anonymous->has_header("Allow"));
  httplib::Result r = http_->Delete("/api/v1/jobs/j-000001", auth());
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 405);
  EXPECT_EQ(r->get_header_value("Allow"), "GET");
  const json body = json::parse(r->body);
  EXPECT_EQ(body["code"], "METHOD_NOT_ALLOWED");
  EXPECT_NE(body["message"].get<std::string>().find("not DELETE"), std::string::npos) << r->body;
  httplib::Result put = http_->Put("/api/v1/jobs", auth(), "{}", "application/json");
  ASSERT_TRUE(put);
  EXPECT_EQ(put->status, 405);
  const std::string allow = put->get_header_value("Allow");
  EXPECT_NE(allow.find("GET"), std::string::npos) << allow;
  EXPECT_NE(allow.find("POST"), std::string::npos) << allow;
}

TEST_F(HttpApiTest, UploadSubmitWatchFetchAndCancelAsCurlWould) {
  // Upload the bundle as raw bytes, and ask for it by hash.
  const std::string bundle = packed_bundle(root_ / "scene", kScene);
  scene_root_ = root_ / "scene";
  json uploaded =
      checked("uploadBundle",
              http_->Post("/api/v1/bundles", auth(), bundle, "application/octet-stream"), 200);
  const std::string hash = uploaded.value("bundleHash", "");
  ASSERT_EQ(hash.size(), 64u);
  EXPECT_TRUE(checked("hasBundle", http_->Get("/api/v1/bundles/" + hash, auth()), 200)["present"]);
  EXPECT_FALSE(checked("hasBundle", http_->Get("/api/v1/bundles/" + std::string(64, 'a'), auth()),
                       200)["present"]);
  // A malformed hash is the caller's error, not an absent bundle.
  EXPECT_EQ(error_code(checked("hasBundle", http_->Get("/api/v1/bundles/abc", auth()), 400)),
            "INVALID_ARGUMENT");

  // Submit the request `prism pack` would print: the spec as JSON.
  v1::SubmitJobRequest request;
  *request.mutable_spec() = small_spec(hash);
  request.set_client_token("http-1");
  std::string body;
  ASSERT_TRUE(google::protobuf::util::MessageToJsonString(request, &body).ok());
  json submitted =
      checked("submitJob", http_->Post("/api/v1/jobs", auth(), body, "application/json"), 200);
  const std::string job_id = submitted["job"].value("jobId", "");
  ASSERT_FALSE(job_id.empty());
  EXPECT_TRUE(submitted["job"]["state"] == "JOB_STATE_QUEUED" ||
              submitted["job"]["state"] == "JOB_STATE_RENDERING")
      << submitted.dump();
  // The same client token is the same job.
  EXPECT_EQ(checked("submitJob", http_->Post("/api/v1/jobs", auth(), body, "application/json"),
                    200)["job"]["jobId"],
            job_id);

  // Watch while a worker renders: events until the job is done, each a JobInfo.
  auto watch = std::async(std::launch::async, [&] {
    httplib::Client client("127.0.0.1", api_->port());
    client.set_read_timeout(60, 0);
    std::string stream;
    auto result = client.Get("/api/v1/jobs/" + job_id + ":watch", auth(),
                             [&](const char* data, std::size_t n) {
                               stream.append(data, n);
                               return true;
                             });
    EXPECT_TRUE(result);
    if (result) {
      EXPECT_EQ(result->status, 200);
      EXPECT_EQ(result->get_header_value("Content-Type"), "text/event-stream");
    }
    return stream;
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  const std::string worker = register_worker();
  run_worker(worker);
  EXPECT_EQ(wait_done(job_id).state(), v1::JOB_STATE_DONE);
  const std::string stream = watch.get();
  std::vector<json> events;
  std::size_t at = 0;
  while (at < stream.size()) {
    const std::size_t end = stream.find("\n\n", at);
    ASSERT_NE(end, std::string::npos) << "an unterminated event: " << stream.substr(at);
    const std::string event = stream.substr(at, end - at);
    at = end + 2;
    ASSERT_EQ(event.rfind("event: job\ndata: ", 0), 0u) << event;
    events.push_back(json::parse(event.substr(17)));
    EXPECT_EQ(schema_error(events.back(), {{"$ref", "#/components/schemas/prism.v1.JobInfo"}}, doc_,
                           "event"),
              "");
  }
  ASSERT_GE(events.size(), 2u);
  EXPECT_EQ(events.back()["state"], "JOB_STATE_DONE");
  for (std::size_t i = 1; i < events.size(); ++i) {
    EXPECT_LE(std::stoull(events[i - 1]["progress"]["tasksDone"].get<std::string>()),
              std::stoull(events[i]["progress"]["tasksDone"].get<std::string>()));
  }

  // The job, the list and the outputs; the spectral EXR is the gRPC API's bytes.
  json job = checked("getJob", http_->Get("/api/v1/jobs/" + job_id, auth()), 200);
  EXPECT_EQ(job["state"], "JOB_STATE_DONE");
  EXPECT_FALSE(job.value("reportJson", "").empty());
  json listed = checked("listJobs", http_->Get("/api/v1/jobs?state=done&limit=5", auth()), 200);
  ASSERT_EQ(listed["jobs"].size(), 1u);
  EXPECT_EQ(listed["jobs"][0]["jobId"], job_id);
  EXPECT_TRUE(checked("listJobs", http_->Get("/api/v1/jobs?state=JOB_STATE_QUEUED", auth()), 200)
                  .value("jobs", json::array())
                  .empty());
  // One point per accepted final-pass result (9 tiles x 2 sample ranges), ending at every sample.
  json convergence =
      checked("getConvergence", http_->Get("/api/v1/jobs/" + job_id + "/convergence", auth()), 200);
  ASSERT_EQ(convergence["points"].size(), 18u);
  const json& last = convergence["points"].back();
  EXPECT_EQ(last["samples"], job["progress"]["samplesTotal"]);
  EXPECT_GT(last["relativeError"].get<double>(), 0.0);
  EXPECT_LT(last["relativeError"].get<double>(), 1.0);
  json tiles = checked("getTiles", http_->Get("/api/v1/jobs/" + job_id + "/tiles", auth()), 200);
  EXPECT_EQ(tiles["tilesX"], 3);  // 12x10 in 4 px tiles
  EXPECT_EQ(tiles["tilesY"], 3);
  EXPECT_EQ(tiles["states"], std::string(9, 'd'));
  json outputs =
      checked("listResults", http_->Get("/api/v1/jobs/" + job_id + "/outputs", auth()), 200);
  std::string exr_name;
  for (const json& f : outputs["files"])
    if (f["kind"] == "OUTPUT_KIND_SPECTRAL_EXR") exr_name = f["fileName"];
  ASSERT_FALSE(exr_name.empty()) << outputs.dump();
  auto exr = http_->Get("/api/v1/jobs/" + job_id + "/outputs/" + exr_name, auth());
  ASSERT_TRUE(exr);
  EXPECT_EQ(exr->status, 200);
  EXPECT_EQ(exr->body, fetch_spectral_exr(job_id));
  EXPECT_EQ(exr->get_header_value("Content-Disposition"),
            "attachment; filename=\"" + exr_name + "\"");
  auto preview = http_->Get("/api/v1/jobs/" + job_id + "/preview.png?exposure=1", auth());
  ASSERT_TRUE(preview);
  EXPECT_EQ(preview->status, 200);
  EXPECT_EQ(preview->get_header_value("Content-Type"), "image/png");
  EXPECT_EQ(preview->body.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));

  // A finished job cannot be cancelled; a queued one can, and again (idempotent).
  EXPECT_EQ(error_code(checked("cancelJob",
                               http_->Post("/api/v1/jobs/" + job_id + ":cancel", auth()), 409)),
            "FAILED_PRECONDITION");
  request.set_client_token("http-2");
  body.clear();
  ASSERT_TRUE(google::protobuf::util::MessageToJsonString(request, &body).ok());
  const std::string second =
      checked("submitJob", http_->Post("/api/v1/jobs", auth(), body, "application/json"),
              200)["job"]["jobId"];
  // No worker takes the second job before it is cancelled: none of its tiles was done, and
  // they show as cancelled (they showed as queued, as if it would go on).
  for (int i = 0; i < 2; ++i) {
    json cancelled =
        checked("cancelJob", http_->Post("/api/v1/jobs/" + second + ":cancel", auth()), 200);
    EXPECT_EQ(cancelled["state"], "JOB_STATE_CANCELLED");
  }
  EXPECT_EQ(
      checked("getTiles", http_->Get("/api/v1/jobs/" + second + "/tiles", auth()), 200)["states"],
      std::string(9, 'c'));
  // The workers list shows the fake worker with its completed tasks.
  json workers = checked("listWorkers", http_->Get("/api/v1/workers", auth()), 200);
  ASSERT_EQ(workers["workers"].size(), 1u);
  EXPECT_EQ(workers["workers"][0]["workerId"], worker);
  EXPECT_NE(workers["workers"][0]["tasksCompleted"], "0");
  EXPECT_EQ(workers["workers"][0]["samplesCompleted"], job["progress"]["samplesTotal"])
      << "the one worker rendered every sample of the job";

  // /metrics counts what happened.
  auto metrics = http_->Get("/metrics", auth());
  ASSERT_TRUE(metrics);
  EXPECT_EQ(metrics->status, 200);
  const int tasks = std::stoi(job["progress"]["tasksTotal"].get<std::string>());
  EXPECT_NE(metrics->body.find("prism_results_total{outcome=\"accepted\"} " +
                               std::to_string(tasks) + "\n"),
            std::string::npos)
      << metrics->body;
  EXPECT_NE(metrics->body.find("prism_jobs{state=\"done\"} 1\n"), std::string::npos);
  EXPECT_NE(metrics->body.find("prism_jobs{state=\"cancelled\"} 1\n"), std::string::npos);
  EXPECT_NE(metrics->body.find("prism_task_latency_seconds_count " + std::to_string(tasks) + "\n"),
            std::string::npos);
}

TEST_F(HttpApiTest, RefusesWithoutTheTokenExceptTheDocument) {
  for (const http::Route& r : http::api_routes()) {
    if (!r.authenticated) continue;
    std::string path = std::regex_replace(r.path, std::regex("\\{[a-z_]+\\}"), "x");
    for (const std::string& token : {std::string(), std::string("wrong")}) {
      httplib::Headers headers;
      if (!token.empty()) headers = auth(token);
      httplib::Result result = r.method == "get"    ? http_->Get(path, headers)
                               : r.method == "post" ? http_->Post(path, headers, "", "text/plain")
                                                    : http_->Put(path, headers, "", "text/plain");
      json body = checked(r.id, result, 401);
      EXPECT_EQ(error_code(body), "UNAUTHENTICATED") << r.id;
      EXPECT_EQ(result->get_header_value("WWW-Authenticate"), "Bearer");
    }
  }
  auto doc = http_->Get("/api/v1/openapi.json");
  ASSERT_TRUE(doc);
  EXPECT_EQ(doc->status, 200);
  EXPECT_EQ(json::parse(doc->body), doc_);
}

TEST_F(HttpApiTest, BadInputGetsAnErrorThatSaysWhat) {
  const std::string hash = upload_scene();
  struct Case {
    std::string route, method, path, body;
    int status;
    std::string code, says;
  };
  const std::vector<Case> cases = {
      {"submitJob", "post", "/api/v1/jobs", "{not json", 400, "INVALID_ARGUMENT",
       "request body is not a SubmitJobRequest"},
      {"submitJob", "post", "/api/v1/jobs", R"({"spec":{"bundleHash":"x"},"colour":1})", 400,
       "INVALID_ARGUMENT", "colour"},
      {"submitJob", "post", "/api/v1/jobs", R"({"spec":{"integrator":"INTEGRATOR_NONE"}})", 400,
       "INVALID_ARGUMENT", "INTEGRATOR_NONE"},
      {"submitJob", "post", "/api/v1/jobs",
       R"({"spec":{"bundleHash":")" + hash +
           R"(","scenePath":"scene.pbrt","spp":4,"bins":100000}})",
       400, "INVALID_ARGUMENT", "bins"},
      {"submitJob", "post", "/api/v1/jobs",
       R"({"spec":{"bundleHash":")" + std::string(64, 'b') + R"(","scenePath":"scene.pbrt"}})", 409,
       "FAILED_PRECONDITION", "upload it first"},
      {"getJob", "get", "/api/v1/jobs/j-999999", "", 404, "NOT_FOUND", "j-999999"},
      {"cancelJob", "post", "/api/v1/jobs/j-999999:cancel", "", 404, "NOT_FOUND", "j-999999"},
      {"watchJob", "get", "/api/v1/jobs/j-999999:watch", "", 404, "NOT_FOUND", "j-999999"},
      {"listResults", "get", "/api/v1/jobs/j-999999/outputs", "", 404, "NOT_FOUND", "j-999999"},
      {"getPreview", "get", "/api/v1/jobs/j-1/preview.png?exposure=bright", "", 400,
       "INVALID_ARGUMENT", "exposure=bright"},
      {"listJobs", "get", "/api/v1/jobs?state=sleeping", "", 400, "INVALID_ARGUMENT",
       "state=sleeping"},
      {"listJobs", "get", "/api/v1/jobs?limit=-3", "", 400, "INVALID_ARGUMENT", "limit"},
      {"uploadBundle", "post", "/api/v1/bundles", "", 400, "INVALID_ARGUMENT", "empty"},
      {"uploadBundle", "post", "/api/v1/bundles", "not a bundle", 400, "INVALID_ARGUMENT",
       "bundle"},
      {"listJobs", "get", "/api/v1/nothing-here", "", 404, "NOT_FOUND", "no route GET"},
  };
  for (const Case& c : cases) {
    httplib::Result result = c.method == "get"
                                 ? http_->Get(c.path, auth())
                                 : http_->Post(c.path, auth(), c.body, "application/json");
    json body = checked(c.route, result, c.status);
    EXPECT_EQ(error_code(body), c.code) << c.path << " " << c.body;
    EXPECT_NE(body.value("message", "").find(c.says), std::string::npos)
        << c.path << " " << c.body << ": " << body.dump();
  }
  // A job not yet done has no outputs; its preview waits for a first tile.
  json job =
      checked("submitJob",
              http_->Post("/api/v1/jobs", auth(),
                          R"({"spec":{"bundleHash":")" + hash +
                              R"(","scenePath":"scene.pbrt","spp":4,"width":12,"height":10}})",
                          "application/json"),
              200);
  const std::string id = job["job"]["jobId"];
  EXPECT_EQ(error_code(
                checked("listResults", http_->Get("/api/v1/jobs/" + id + "/outputs", auth()), 409)),
            "FAILED_PRECONDITION");
  EXPECT_EQ(error_code(checked("getPreview",
                               http_->Get("/api/v1/jobs/" + id + "/preview.png", auth()), 409)),
            "FAILED_PRECONDITION");
  EXPECT_EQ(error_code(checked("getResult",
                               http_->Get("/api/v1/jobs/" + id + "/outputs/x.exr", auth()), 409)),
            "FAILED_PRECONDITION");
}

}  // namespace
}  // namespace prism::coordinator::farm_server_testing
