// Bearer-token authentication for Prism's gRPC services (and the coordinator's HTTP API). Clients
// send `authorization: Bearer <token>` metadata; a server configured with a token refuses any call
// without the exact token with UNAUTHENTICATED (compared in constant time, so the check leaks
// nothing about the token). Workers use the worker secret, clients the API token; an empty
// configured token means the service is open (local development, tests).
#pragma once

#include <grpcpp/client_context.h>
#include <grpcpp/server_context.h>

#include <optional>
#include <string>
#include <string_view>

#include "absl/status/status.h"

namespace prism::rpc {

inline constexpr std::string_view kAuthorizationHeader = "authorization";

// OK when `expected` is empty or the call carries `Bearer <expected>`; UNAUTHENTICATED with a
// message naming what was wrong (missing, malformed, wrong token) otherwise.
absl::Status check_bearer(const grpc::ServerContext& context, std::string_view expected);
// The same check on the value of an `authorization` header (HTTP; nullopt: no such header).
absl::Status check_bearer_value(std::optional<std::string_view> value, std::string_view expected);

// Adds the bearer token to an outgoing call (nothing when token is empty).
void add_bearer(grpc::ClientContext& context, std::string_view token);

}  // namespace prism::rpc
