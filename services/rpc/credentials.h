// Transport security for Prism's gRPC servers and channels. Without certificate paths both sides
// use plaintext (loopback, a trusted cluster network); with them the server presents its
// certificate chain and private key (PEM files) and clients verify it against a CA bundle.
// Bad or missing files are reported before anything listens or connects.
#pragma once

#include <grpcpp/security/credentials.h>
#include <grpcpp/security/server_credentials.h>
#include <grpcpp/support/channel_arguments.h>

#include <filesystem>
#include <memory>

#include "absl/status/statusor.h"

namespace prism::rpc {

struct ServerTls {
  std::filesystem::path cert_chain;   // PEM; empty: plaintext
  std::filesystem::path private_key;  // PEM; required with cert_chain
};

struct ClientTls {
  std::filesystem::path ca_bundle;  // PEM roots to verify the server; empty: plaintext
};

absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> server_credentials(const ServerTls& tls);
absl::StatusOr<std::shared_ptr<grpc::ChannelCredentials>> channel_credentials(const ClientTls& tls);

// Channel arguments every Prism client uses: reconnect attempts at most 3 s apart. gRPC's
// default backoff grows to 120 s, so workers (and `prism watch`) came back up to a minute after
// a coordinator that had been down a few minutes was listening again.
grpc::ChannelArguments client_channel_arguments();

}  // namespace prism::rpc
