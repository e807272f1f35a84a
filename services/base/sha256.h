// SHA-256 content hashes (OpenSSL EVP). Prism names scene bundles, blobs and task results by the
// lowercase hex SHA-256 of their bytes, so equal content has one name everywhere.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace prism::base {

// Incremental hasher: update() any number of times, then hex() or digest() once.
class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;

  void update(std::string_view bytes);
  std::array<std::uint8_t, 32> digest();
  std::string hex();

 private:
  void* ctx_;  // EVP_MD_CTX, kept opaque so OpenSSL headers stay out of ours.
  bool finished_ = false;
};

// Lowercase hex SHA-256 of bytes.
std::string sha256_hex(std::string_view bytes);

// True when text is 64 lowercase hex digits (a well-formed hash from an untrusted peer).
// Lowercase hex of a digest (Sha256::digest).
std::string sha256_hex_of(const std::array<std::uint8_t, 32>& digest);

// The 32 bytes of a lowercase hex SHA-256 (is_sha256_hex); nullopt for anything else.
std::optional<std::array<std::uint8_t, 32>> sha256_digest_of_hex(std::string_view text);

bool is_sha256_hex(std::string_view text);

}  // namespace prism::base
