#include "services/rpc/auth.h"

#include <openssl/crypto.h>

#include <string>

#include "absl/strings/match.h"

namespace prism::rpc {
namespace {

constexpr std::string_view kScheme = "Bearer ";

bool equal_constant_time(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  return CRYPTO_memcmp(a.data(), b.data(), a.size()) == 0;
}

}  // namespace

absl::Status check_bearer(const grpc::ServerContext& context, std::string_view expected) {
  if (expected.empty()) return absl::OkStatus();
  const auto& metadata = context.client_metadata();
  auto range = metadata.equal_range(
      grpc::string_ref(kAuthorizationHeader.data(), kAuthorizationHeader.size()));
  if (range.first == range.second) {
    return absl::UnauthenticatedError("missing authorization (want 'Bearer <token>')");
  }
  return check_bearer_value(
      std::string_view(range.first->second.data(), range.first->second.size()), expected);
}

absl::Status check_bearer_value(std::optional<std::string_view> value, std::string_view expected) {
  if (expected.empty()) return absl::OkStatus();
  if (!value.has_value()) {
    return absl::UnauthenticatedError("missing authorization (want 'Bearer <token>')");
  }
  // The scheme's name is case-insensitive (RFC 9110 11.1): "bearer x" is "Bearer x".
  if (value->size() < kScheme.size() ||
      !absl::EqualsIgnoreCase(absl::string_view(value->data(), kScheme.size()),
                              absl::string_view(kScheme.data(), kScheme.size()))) {
    return absl::UnauthenticatedError("authorization is not a 'Bearer <token>'");
  }
  if (!equal_constant_time(value->substr(kScheme.size()), expected)) {
    return absl::UnauthenticatedError("invalid token");
  }
  return absl::OkStatus();
}

void add_bearer(grpc::ClientContext& context, std::string_view token) {
  if (token.empty()) return;
  context.AddMetadata(std::string(kAuthorizationHeader), std::string(kScheme) + std::string(token));
}

}  // namespace prism::rpc
