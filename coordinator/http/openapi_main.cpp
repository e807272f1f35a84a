// prism-openapi: writes the coordinator's OpenAPI document (api_routes.h) to stdout, as
// committed in docs/api/openapi.json: `prism-openapi > docs/api/openapi.json`.
#include <iostream>

#include "coordinator/http/api_routes.h"

int main() {
  std::cout << prism::coordinator::http::openapi_document().dump(2) << "\n";
  return 0;
}
