#include "services/base/atomic_file.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <vector>

namespace prism::base {
namespace {

namespace fs = std::filesystem;

class AtomicFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("prism_atomic_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
            "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(AtomicFileTest, WriteThenReadRoundTrips) {
  std::string bytes("abc\0def", 7);
  ASSERT_TRUE(write_file_atomic(dir_ / "x.bin", bytes).ok());
  auto read = read_file(dir_ / "x.bin");
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(*read, bytes);
}

TEST_F(AtomicFileTest, FailedWriterLeavesPreviousFileAndNoTemporary) {
  ASSERT_TRUE(write_file_atomic(dir_ / "out.exr", std::string("old")).ok());
  auto status = write_via_temp(dir_ / "out.exr", [](const fs::path& temp) {
    std::string partial = "half";
    EXPECT_TRUE(write_file_atomic(temp, partial).ok());
    return absl::InternalError("encoder failed");
  });
  EXPECT_EQ(status.code(), absl::StatusCode::kInternal);
  EXPECT_EQ(*read_file(dir_ / "out.exr"), "old");
  int entries = 0;
  for ([[maybe_unused]] auto& e : fs::directory_iterator(dir_)) ++entries;
  EXPECT_EQ(entries, 1);
}

// A process killed while writing leaves its temporary: the next one to own the directory
// removes what write_via_temp names so, and nothing else.
TEST_F(AtomicFileTest, RemoveTemporariesTakesOnlyWhatAKilledWriterLeft) {
  fs::path left;
  auto status = write_via_temp(dir_ / "out.exr", [&](const fs::path& temp) {
    left = temp;
    return absl::InternalError("killed");
  });
  ASSERT_FALSE(status.ok());
  ASSERT_FALSE(left.empty());
  ASSERT_TRUE(write_file_atomic(left, std::string("half")).ok());  // as the kill left it
  const std::vector<std::string> kept = {"out.exr",      ".hidden",  "x.tmp.1.2",
                                         ".x.tmp.12a.3", ".x.tmp.1", ".tmp.1.2"};
  for (const std::string& name : kept) ASSERT_TRUE(write_file_atomic(dir_ / name, name).ok());
  remove_temporaries(dir_);
  EXPECT_FALSE(fs::exists(left)) << left;
  for (const std::string& name : kept) EXPECT_TRUE(fs::exists(dir_ / name)) << name;
}

TEST_F(AtomicFileTest, ReadRefusesMissingAndOversizedFiles) {
  EXPECT_EQ(read_file(dir_ / "missing").status().code(), absl::StatusCode::kNotFound);
  ASSERT_TRUE(write_file_atomic(dir_ / "big", std::string(100, 'x')).ok());
  auto read = read_file(dir_ / "big", 10);
  EXPECT_EQ(read.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_NE(read.status().message().find("over the limit of 10"), std::string::npos);
}

}  // namespace
}  // namespace prism::base
