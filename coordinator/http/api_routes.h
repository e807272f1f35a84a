// The coordinator's HTTP/JSON API, described once: every route with its method, path, parameters
// and bodies. The server (http_api.h) registers exactly these routes, and the OpenAPI document
// (openapi_document(), committed as docs/api/openapi.json) is generated from them and from the
// protobuf descriptors of the messages the bodies are, so neither the routes nor the schemas
// are written twice by hand. JSON bodies use protobuf's JSON mapping (lowerCamelCase names,
// enum names as strings, 64-bit integers as strings, every scalar field present).
#pragma once

#include <string>
#include <vector>

#include "google/protobuf/descriptor.h"
#include "nlohmann/json.hpp"

namespace prism::coordinator::http {

// What a route's successful response carries.
enum class Body {
  kMessage,      // a protobuf message as JSON (`message`)
  kEventStream,  // text/event-stream; each event's data is `message` as JSON
  kPng,          // image/png
  kFile,         // application/octet-stream (an output file)
  kMetrics,      // text/plain in the Prometheus exposition format
  kOpenApi,      // this document
};

struct Parameter {
  std::string name;
  std::string in;    // "path" or "query"
  std::string type;  // "string", "integer" or "number"
  bool required = false;
  std::string description;
  bool repeated = false;  // a query parameter that may be given several times
};

struct Route {
  std::string id;      // operationId: the handler's name in http_api.cpp
  std::string method;  // "get", "post", "put"
  std::string path;    // OpenAPI path template, e.g. /api/v1/jobs/{job_id}
  std::string summary;
  std::vector<Parameter> parameters;
  const google::protobuf::Descriptor* request = nullptr;  // JSON request body, if any
  bool binary_request = false;                            // raw bytes request body
  Body body = Body::kMessage;
  const google::protobuf::Descriptor* response = nullptr;  // kMessage and kEventStream
  bool authenticated = true;
};

// Every route, in the order the document lists them.
const std::vector<Route>& api_routes();

// The OpenAPI 3.0 document of api_routes(): paths, parameters, bodies, the error body, bearer
// authentication and a schema per protobuf message reachable from the bodies.
nlohmann::json openapi_document();

// The JSON Schema (OpenAPI 3.0 subset) of one message in protobuf's JSON mapping, with
// references to other messages as #/components/schemas/<full name>.
nlohmann::json message_schema(const google::protobuf::Descriptor& message);

}  // namespace prism::coordinator::http
