#include "services/rpc/credentials.h"

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>

#include <filesystem>
#include <fstream>

#include "prism/v1/farm.grpc.pb.h"

namespace prism::rpc {
namespace {

namespace fs = std::filesystem;

// Writes a fresh self-signed certificate for "localhost" (key and certificate PEM files).
void make_self_signed(const fs::path& cert_path, const fs::path& key_path) {
  EVP_PKEY* key = EVP_EC_gen("P-256");
  ASSERT_NE(key, nullptr);
  X509* cert = X509_new();
  ASSERT_NE(cert, nullptr);
  X509_set_version(cert, 2);
  ASN1_INTEGER_set(X509_get_serialNumber(cert), 1);
  X509_gmtime_adj(X509_getm_notBefore(cert), -60);
  X509_gmtime_adj(X509_getm_notAfter(cert), 3600);
  X509_set_pubkey(cert, key);
  X509_NAME* name = X509_get_subject_name(cert);
  X509_NAME_add_entry_by_txt(name, "CN", MBSTRING_ASC,
                             reinterpret_cast<const unsigned char*>("localhost"), -1, -1, 0);
  X509_set_issuer_name(cert, name);
  X509V3_CTX ctx;
  X509V3_set_ctx_nodb(&ctx);
  X509V3_set_ctx(&ctx, cert, cert, nullptr, nullptr, 0);
  X509_EXTENSION* san =
      X509V3_EXT_conf_nid(nullptr, &ctx, NID_subject_alt_name, "DNS:localhost,IP:127.0.0.1");
  ASSERT_NE(san, nullptr);
  X509_add_ext(cert, san, -1);
  X509_EXTENSION_free(san);
  X509_EXTENSION* bc = X509V3_EXT_conf_nid(nullptr, &ctx, NID_basic_constraints, "critical,CA:TRUE");
  X509_add_ext(cert, bc, -1);
  X509_EXTENSION_free(bc);
  ASSERT_GT(X509_sign(cert, key, EVP_sha256()), 0);
  FILE* f = std::fopen(cert_path.c_str(), "w");
  PEM_write_X509(f, cert);
  std::fclose(f);
  f = std::fopen(key_path.c_str(), "w");
  PEM_write_PrivateKey(f, key, nullptr, nullptr, 0, nullptr, nullptr);
  std::fclose(f);
  X509_free(cert);
  EVP_PKEY_free(key);
}

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
