#include "services/base/sha256.h"

#include <openssl/evp.h>

#include "services/base/check.h"

namespace prism::base {

Sha256::Sha256() : ctx_(EVP_MD_CTX_new()) {
  PRISM_CHECK(ctx_ != nullptr);
  PRISM_CHECK(EVP_DigestInit_ex(static_cast<EVP_MD_CTX*>(ctx_), EVP_sha256(), nullptr) == 1);
}

Sha256::~Sha256() {
  EVP_MD_CTX_free(static_cast<EVP_MD_CTX*>(ctx_));
}

void Sha256::update(std::string_view bytes) {
  PRISM_CHECK(!finished_);
  PRISM_CHECK(EVP_DigestUpdate(static_cast<EVP_MD_CTX*>(ctx_), bytes.data(), bytes.size()) == 1);
}

std::array<std::uint8_t, 32> Sha256::digest() {
  PRISM_CHECK(!finished_);
  finished_ = true;
  std::array<std::uint8_t, 32> out{};
  unsigned int length = 0;
  PRISM_CHECK(EVP_DigestFinal_ex(static_cast<EVP_MD_CTX*>(ctx_), out.data(), &length) == 1);
  PRISM_CHECK(length == out.size());
  return out;
}

std::string Sha256::hex() {
  return sha256_hex_of(digest());
}

std::string sha256_hex_of(const std::array<std::uint8_t, 32>& digest) {
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string text;
  text.reserve(64);
  for (std::uint8_t byte : digest) {
    text.push_back(kDigits[byte >> 4]);
    text.push_back(kDigits[byte & 15]);
  }
  return text;
}

std::string sha256_hex(std::string_view bytes) {
  Sha256 hasher;
  hasher.update(bytes);
  return hasher.hex();
}

std::optional<std::array<std::uint8_t, 32>> sha256_digest_of_hex(std::string_view text) {
  if (!is_sha256_hex(text)) return std::nullopt;
  auto nibble = [](char c) { return std::uint8_t(c <= '9' ? c - '0' : c - 'a' + 10); };
  std::array<std::uint8_t, 32> out{};
  for (std::size_t i = 0; i < out.size(); ++i) {
    out[i] = std::uint8_t(nibble(text[2 * i]) << 4 | nibble(text[2 * i + 1]));
  }
  return out;
}

bool is_sha256_hex(std::string_view text) {
  if (text.size() != 64) return false;
  for (char c : text) {
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  }
  return true;
}

}  // namespace prism::base
