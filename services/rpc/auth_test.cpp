#include "services/rpc/auth.h"

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <memory>

#include "prism/v1/farm.grpc.pb.h"
#include "services/rpc/status_mapping.h"

namespace prism::rpc {
namespace {

// A FarmService with one method, guarded like the real adapters: check, then answer.
class GuardedFarm final : public prism::v1::FarmService::Service {
 public:
  explicit GuardedFarm(std::string token) : token_(std::move(token)) {}
  grpc::Status HasBundle(grpc::ServerContext* context, const prism::v1::HasBundleRequest*,
                         prism::v1::HasBundleResponse* response) override {
    if (auto status = check_bearer(*context, token_); !status.ok()) return to_grpc(status);
    response->set_present(true);
    return grpc::Status::OK;
  }

 private:
  std::string token_;
};

class AuthTest : public ::testing::Test {
 protected:
  void SetUp() override {
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
    builder.RegisterService(&service_);
    server_ = builder.BuildAndStart();
    ASSERT_TRUE(server_);
    ASSERT_GT(port, 0);
    auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(port),
                                       grpc::InsecureChannelCredentials());
    stub_ = prism::v1::FarmService::NewStub(channel);
  }
  void TearDown() override { server_->Shutdown(); }

  grpc::Status call(const std::string& authorization) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    if (!authorization.empty()) context.AddMetadata("authorization", authorization);
    prism::v1::HasBundleRequest request;
    prism::v1::HasBundleResponse response;
    return stub_->HasBundle(&context, request, &response);
  }

  GuardedFarm service_{"s3cret-token"};
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<prism::v1::FarmService::Stub> stub_;
};

TEST_F(AuthTest, AcceptsTheTokenAndRefusesEverythingElse) {
  EXPECT_TRUE(call("Bearer s3cret-token").ok());
  // The scheme in any case, as RFC 9110 has it (the token itself stays exact).
  EXPECT_TRUE(call("bearer s3cret-token").ok());
  EXPECT_TRUE(call("BEARER s3cret-token").ok());
  struct Case {
    std::string header;
    std::string message;
  };
  for (const Case& c :
       {Case{"", "missing authorization (want 'Bearer <token>')"},
        Case{"s3cret-token", "authorization is not a 'Bearer <token>'"},
        Case{"Bearer s3cret-tokeN", "invalid token"}, Case{"Bearer s3cret-token ", "invalid token"},
        Case{"Bearer ", "invalid token"}}) {
    grpc::Status status = call(c.header);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED) << c.header;
    EXPECT_EQ(status.error_message(), c.message) << c.header;
  }
}

TEST_F(AuthTest, ClientHelperSendsTheToken) {
  grpc::ClientContext context;
  add_bearer(context, "s3cret-token");
  prism::v1::HasBundleRequest request;
  prism::v1::HasBundleResponse response;
  EXPECT_TRUE(stub_->HasBundle(&context, request, &response).ok());
  EXPECT_TRUE(response.present());
}

TEST(AuthOpenTest, EmptyConfiguredTokenIsOpen) {
  grpc::ServerContext context;
  EXPECT_TRUE(check_bearer(context, "").ok());
  EXPECT_EQ(check_bearer(context, "x").code(), absl::StatusCode::kUnauthenticated);
}

}  // namespace
}  // namespace prism::rpc
