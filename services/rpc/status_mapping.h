// The one place where Prism's error values meet gRPC's. Domain code returns absl::Status
// (INVALID_ARGUMENT for a bad scene or spec, NOT_FOUND, FAILED_PRECONDITION for a wrong state,
// RESOURCE_EXHAUSTED for limits, UNAVAILABLE while draining, UNAUTHENTICATED); the gRPC
// adapters convert with these two functions so code and message cross the wire unchanged.
#pragma once

#include <grpcpp/support/status.h>

#include "absl/status/status.h"

namespace prism::rpc {

grpc::Status to_grpc(const absl::Status& status);
absl::Status from_grpc(const grpc::Status& status);

}  // namespace prism::rpc
