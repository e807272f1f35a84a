#include "services/rpc/chunks.h"

#include <gtest/gtest.h>

#include <string>

namespace prism::rpc {
namespace {

std::string bytes_of(std::size_t n) {
  std::string s(n, '\0');
  for (std::size_t i = 0; i < n; ++i) s[i] = char(i * 131 + 7);
  return s;
}

TEST(ChunksTest, SplitAndAssembleRoundTrip) {
  for (std::size_t n : {std::size_t{0}, std::size_t{1}, std::size_t{999}, std::size_t{1000},
                        std::size_t{2501}}) {
    std::string data = bytes_of(n);
    auto chunks = split_chunks(data, 1000);
    EXPECT_EQ(chunks.size(), std::max<std::size_t>(1, (n + 999) / 1000));
    ChunkAssembler assembler(1 << 20);
    std::uint64_t offset = 0;
    for (auto c : chunks) {
      ASSERT_TRUE(assembler.add(offset, c, n).ok());
      offset += c.size();
    }
    auto out = assembler.finish(base::sha256_hex(data));
    ASSERT_TRUE(out.ok()) << out.status();
    EXPECT_EQ(*out, data);
  }
}

TEST(ChunksTest, RefusesGapsOversizeAndWrongHash) {
  std::string data = bytes_of(3000);
  {
    ChunkAssembler a(1 << 20);
    ASSERT_TRUE(a.add(0, std::string_view(data).substr(0, 1000)).ok());
    auto gap = a.add(2000, std::string_view(data).substr(2000, 1000));
    EXPECT_EQ(gap.code(), absl::StatusCode::kInvalidArgument);
    EXPECT_EQ(gap.message(), "chunk at offset 2000 but 1000 bytes received");
  }
  {
    ChunkAssembler a(2000);
    EXPECT_EQ(a.add(0, "", 3000).code(), absl::StatusCode::kResourceExhausted);
    ChunkAssembler b(2000);
    ASSERT_TRUE(b.add(0, std::string_view(data).substr(0, 1500)).ok());
    EXPECT_EQ(b.add(1500, std::string_view(data).substr(1500, 1000)).code(),
              absl::StatusCode::kResourceExhausted);
  }
  {
    ChunkAssembler a(1 << 20);
    ASSERT_TRUE(a.add(0, data, 3000).ok());
    EXPECT_EQ(a.finish(base::sha256_hex("other")).status().code(), absl::StatusCode::kDataLoss);
  }
  {
    ChunkAssembler a(1 << 20);
    ASSERT_TRUE(a.add(0, std::string_view(data).substr(0, 100), 3000).ok());
    EXPECT_EQ(a.finish(base::sha256_hex(data)).status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_EQ(a.add(100, std::string_view(data).substr(100, 10), 2999).code(),
              absl::StatusCode::kInvalidArgument);
  }
}

}  // namespace
}  // namespace prism::rpc
