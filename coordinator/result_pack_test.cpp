#include "coordinator/result_pack.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/base/sha256.h"
#include "tests/testing/test_dir.h"

namespace prism::coordinator {
namespace {

std::string result_of(int thread, int i) {
  // Distinct bytes of distinct lengths.
  return std::string(std::size_t(100 + 37 * i + thread),
                     static_cast<char>('a' + (i + thread) % 26)) +
         absl::StrCat(thread, "/", i);
}

TEST(ResultPackTest, ResultsFromManyThreadsGetTheirOwnRangesAndReadBackAfterAReopen) {
  const std::filesystem::path dir = prism::testing::fresh_dir("result_pack");
  const std::filesystem::path path = dir / "results.pack";
  struct Written {
    std::uint64_t offset;
    std::string bytes;
  };
  std::vector<std::vector<Written>> written(4);
  {
    auto pack = ResultPack::open(path);
    ASSERT_TRUE(pack.ok()) << pack.status();
    DirtyPacks dirty;
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t) {
      threads.emplace_back([&, t] {
        for (int i = 0; i < 50; ++i) {
          std::string bytes = result_of(t, i);
          const std::uint64_t offset = (*pack)->reserve(bytes.size());
          ASSERT_TRUE((*pack)->write(offset, bytes).ok());
          dirty.add(*pack);
          written[std::size_t(t)].push_back({offset, std::move(bytes)});
        }
      });
    }
    for (std::thread& thread : threads) thread.join();
    EXPECT_TRUE(dirty.sync().ok());
    EXPECT_TRUE(dirty.sync().ok()) << "nothing left to sync";
  }
  std::uint64_t total = 0;
  for (const auto& list : written) {
    for (const Written& w : list) total += w.bytes.size();
  }
  // Ranges tile the file exactly: none overlaps another, and no byte is lost between them.
  EXPECT_EQ(std::filesystem::file_size(path), total);
  auto reopened = ResultPack::open(path);
  ASSERT_TRUE(reopened.ok()) << reopened.status();
  for (const auto& list : written) {
    for (const Written& w : list) {
      auto bytes = (*reopened)->read(w.offset, w.bytes.size(), base::sha256_hex(w.bytes));
      ASSERT_TRUE(bytes.ok()) << bytes.status();
      EXPECT_EQ(*bytes, w.bytes);
    }
  }
  // New results go after the old ones.
  EXPECT_EQ((*reopened)->reserve(10), total);
}

TEST(ResultPackTest, MissingOrDamagedBytesAreDataLossNamingThePackAndTheRange) {
  const std::filesystem::path dir = prism::testing::fresh_dir("result_pack_damage");
  auto pack = ResultPack::open(dir / "results.pack");
  ASSERT_TRUE(pack.ok()) << pack.status();
  const std::string bytes = "a tile result";
  const std::uint64_t offset = (*pack)->reserve(bytes.size());
  ASSERT_TRUE((*pack)->write(offset, bytes).ok());
  const std::string hash = base::sha256_hex(bytes);
  // Damaged: other bytes at the range (as a power loss can leave them).
  const absl::StatusOr<std::string> wrong =
      (*pack)->read(offset, bytes.size(), base::sha256_hex("x"));
  EXPECT_EQ(wrong.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(wrong.status().message().find("results.pack bytes [0, 13)"), std::string::npos)
      << wrong.status();
  // Missing: a range past the end of the file (reserved, never written).
  const absl::StatusOr<std::string> missing = (*pack)->read(offset + 100, bytes.size(), hash);
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(missing.status().message().find("end of file"), std::string::npos) << missing.status();
  // A size no result has.
  EXPECT_EQ((*pack)->read(0, std::uint64_t{1} << 40, hash).status().code(),
            absl::StatusCode::kDataLoss);
  EXPECT_TRUE((*pack)->read(offset, bytes.size(), hash).ok());
  // A pack that cannot be opened is an error naming it.
  const absl::StatusOr<std::shared_ptr<ResultPack>> refused =
      ResultPack::open(dir / "no" / "such" / "dir" / "results.pack");
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInternal);
  EXPECT_NE(refused.status().message().find("no/such/dir/results.pack"), std::string::npos);
}

}  // namespace
}  // namespace prism::coordinator
