#include "services/rpc/credentials.h"

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/status.h"

namespace prism::rpc {
namespace {

constexpr std::uint64_t kMaxPemBytes = std::uint64_t{1} << 20;

absl::StatusOr<std::string> read_pem(const std::filesystem::path& path, const char* what) {
  auto text = base::read_file(path, kMaxPemBytes);
  if (!text.ok()) {
    return absl::Status(text.status().code(),
                        absl::StrCat("TLS ", what, ": ", text.status().message()));
  }
  if (text->find("-----BEGIN ") == std::string::npos) {
    return absl::InvalidArgumentError(
        absl::StrCat("TLS ", what, " ", path.string(), " is not a PEM file"));
  }
  return text;
}

}  // namespace

absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> server_credentials(const ServerTls& tls) {
  if (tls.cert_chain.empty() && tls.private_key.empty()) return grpc::InsecureServerCredentials();
  if (tls.cert_chain.empty() || tls.private_key.empty()) {
    return absl::InvalidArgumentError("TLS needs both a certificate chain and a private key");
  }
  PRISM_ASSIGN_OR_RETURN(std::string cert, read_pem(tls.cert_chain, "certificate chain"));
  PRISM_ASSIGN_OR_RETURN(std::string key, read_pem(tls.private_key, "private key"));
  grpc::SslServerCredentialsOptions options;
  options.pem_key_cert_pairs.push_back({key, cert});
  return grpc::SslServerCredentials(options);
}

absl::StatusOr<std::shared_ptr<grpc::ChannelCredentials>> channel_credentials(
    const ClientTls& tls) {
  if (tls.ca_bundle.empty()) return grpc::InsecureChannelCredentials();
  PRISM_ASSIGN_OR_RETURN(std::string roots, read_pem(tls.ca_bundle, "CA bundle"));
  grpc::SslCredentialsOptions options;
  options.pem_root_certs = roots;
  return grpc::SslCredentials(options);
}

grpc::ChannelArguments client_channel_arguments() {
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 1000);
  args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, 1000);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 3000);
  return args;
}

}  // namespace prism::rpc
