#include "services/base/sha256.h"

#include <gtest/gtest.h>

namespace prism::base {
namespace {

// Test vectors from FIPS 180-2 appendix B.
TEST(Sha256Test, KnownVectors) {
  EXPECT_EQ(sha256_hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
}

TEST(Sha256Test, IncrementalEqualsOneShot) {
  Sha256 hasher;
  hasher.update("ab");
  hasher.update("c");
  EXPECT_EQ(hasher.hex(), sha256_hex("abc"));
}

TEST(Sha256Test, RecognisesWellFormedHex) {
  EXPECT_TRUE(is_sha256_hex(sha256_hex("x")));
  EXPECT_FALSE(is_sha256_hex("abc"));
  EXPECT_FALSE(is_sha256_hex(std::string(64, 'G')));
  EXPECT_FALSE(is_sha256_hex(std::string(63, 'a') + "/"));
}

TEST(Sha256Test, HexGivesBackTheDigestsBytes) {
  for (const char* text : {"", "x", "a tile result"}) {
    Sha256 hasher;
    hasher.update(text);
    EXPECT_EQ(sha256_digest_of_hex(sha256_hex(text)), hasher.digest()) << text;
  }
  EXPECT_FALSE(sha256_digest_of_hex("abc").has_value());
  EXPECT_FALSE(sha256_digest_of_hex(std::string(64, 'A')).has_value());  // hex is lowercase
}

}  // namespace
}  // namespace prism::base
