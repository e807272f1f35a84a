#include "services/rpc/credentials.h"

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "prism/v1/farm.grpc.pb.h"
#include "tests/testing/tls_cert.h"

namespace prism::rpc {
namespace {

namespace fs = std::filesystem;

using testing::make_self_signed;

class Present final : public prism::v1::FarmService::Service {
  grpc::Status HasBundle(grpc::ServerContext*, const prism::v1::HasBundleRequest*,
                         prism::v1::HasBundleResponse* response) override {
    response->set_present(true);
    return grpc::Status::OK;
  }
};

class CredentialsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("prism_tls_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    make_self_signed(dir_ / "cert.pem", dir_ / "key.pem");
  }
  void TearDown() override { fs::remove_all(dir_); }

  grpc::Status call(int port, std::shared_ptr<grpc::ChannelCredentials> credentials) {
    auto stub = prism::v1::FarmService::NewStub(
        grpc::CreateChannel("localhost:" + std::to_string(port), credentials));
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
    prism::v1::HasBundleRequest request;
    prism::v1::HasBundleResponse response;
    return stub->HasBundle(&context, request, &response);
  }

  fs::path dir_;
};

TEST_F(CredentialsTest, TlsServerIsReachableOnlyWithTheRightRoots) {
  auto server_creds = server_credentials({dir_ / "cert.pem", dir_ / "key.pem"});
  ASSERT_TRUE(server_creds.ok()) << server_creds.status();
  Present service;
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort("127.0.0.1:0", *server_creds, &port);
  builder.RegisterService(&service);
  auto server = builder.BuildAndStart();
  ASSERT_TRUE(server);
  auto good = channel_credentials({dir_ / "cert.pem"});
  ASSERT_TRUE(good.ok()) << good.status();
  EXPECT_TRUE(call(port, *good).ok());
  EXPECT_FALSE(call(port, grpc::InsecureChannelCredentials()).ok());
  // A different self-signed certificate is not a trusted root for this server.
  make_self_signed(dir_ / "other.pem", dir_ / "other-key.pem");
  EXPECT_FALSE(call(port, *channel_credentials({dir_ / "other.pem"})).ok());
  server->Shutdown();
}

TEST_F(CredentialsTest, BadFilesAreReportedBeforeListening) {
  EXPECT_TRUE(server_credentials({}).ok());
  EXPECT_TRUE(channel_credentials({}).ok());
  EXPECT_EQ(server_credentials({dir_ / "cert.pem", ""}).status().code(),
            absl::StatusCode::kInvalidArgument);
  auto missing = server_credentials({dir_ / "cert.pem", dir_ / "nope.pem"});
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("private key"), std::string::npos);
  { std::ofstream(dir_ / "junk.pem") << "not a certificate"; }
  EXPECT_EQ(channel_credentials({dir_ / "junk.pem"}).status().code(),
            absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace prism::rpc
