#include "coordinator/result_pack.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

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

// Released results give their disk blocks back, read as DATA_LOSS, and leave their neighbours
// and every offset as they were.
TEST(ResultPackTest, AReleasedResultFreesItsBlocksAndOnlyItsBytes) {
  const std::filesystem::path dir = prism::testing::fresh_dir("result_pack_release");
  auto pack = ResultPack::open(dir / "results.pack");
  ASSERT_TRUE(pack.ok()) << pack.status();
  std::vector<std::string> results;
  std::vector<std::uint64_t> offsets;
  for (int i = 0; i < 3; ++i) {
    // 1 MiB and a bit, so the ranges do not start or end on a block boundary.
    results.push_back(std::string((std::size_t{1} << 20) + 1000 + i, char('x' + i)));
    offsets.push_back((*pack)->reserve(results.back().size()));
    ASSERT_TRUE((*pack)->write(offsets.back(), results.back()).ok());
  }
  ASSERT_TRUE((*pack)->sync().ok());
  auto allocated = [&] {
    struct stat st {};
    EXPECT_EQ(::stat((dir / "results.pack").c_str(), &st), 0);
    return std::uint64_t(st.st_blocks) * 512;
  };
  const std::uint64_t before = allocated();
  const std::uint64_t length = std::filesystem::file_size(dir / "results.pack");
  absl::Status released = (*pack)->release(offsets[1], results[1].size());
  if (absl::IsUnimplemented(released)) GTEST_SKIP() << released;
  ASSERT_TRUE(released.ok()) << released;
  // The blocks wholly inside the range (all but at most one 4 KiB block at either end).
  EXPECT_LE(allocated(), before - results[1].size() + 2 * 4096) << before;
  EXPECT_EQ(std::filesystem::file_size(dir / "results.pack"), length);
  const auto read = [&](int i) {
    return (*pack)->read(offsets[i], results[i].size(), base::sha256_hex(results[i]));
  };
  EXPECT_EQ(read(1).status().code(), absl::StatusCode::kDataLoss);
  for (int i : {0, 2}) {
    auto bytes = read(i);
    ASSERT_TRUE(bytes.ok()) << bytes.status();
    EXPECT_EQ(*bytes, results[i]);
  }
  // Releasing again is harmless; a new result still goes after everything.
  EXPECT_TRUE((*pack)->release(offsets[1], results[1].size()).ok());
  EXPECT_EQ((*pack)->reserve(1), length);
}

}  // namespace
}  // namespace prism::coordinator
