#include "services/rpc/status_mapping.h"

#include <gtest/gtest.h>

namespace prism::rpc {
namespace {

TEST(StatusMappingTest, CodesAndMessagesSurviveBothWays) {
  struct Case {
    absl::Status status;
    grpc::StatusCode code;
  };
  const Case cases[] = {
      {absl::InvalidArgumentError("scene.pbrt:3:7: unknown shape"), grpc::INVALID_ARGUMENT},
      {absl::NotFoundError("no job 42"), grpc::NOT_FOUND},
      {absl::FailedPreconditionError("job is finished"), grpc::FAILED_PRECONDITION},
      {absl::ResourceExhaustedError("bundle over 1 GiB"), grpc::RESOURCE_EXHAUSTED},
      {absl::UnavailableError("draining"), grpc::UNAVAILABLE},
      {absl::UnauthenticatedError("bad token"), grpc::UNAUTHENTICATED},
      {absl::DataLossError("corrupt"), grpc::DATA_LOSS},
  };
  for (const auto& c : cases) {
    grpc::Status wire = to_grpc(c.status);
    EXPECT_EQ(wire.error_code(), c.code);
    EXPECT_EQ(wire.error_message(), std::string(c.status.message()));
    EXPECT_EQ(from_grpc(wire), c.status);
  }
  EXPECT_TRUE(to_grpc(absl::OkStatus()).ok());
  EXPECT_TRUE(from_grpc(grpc::Status::OK).ok());
}

}  // namespace
}  // namespace prism::rpc
