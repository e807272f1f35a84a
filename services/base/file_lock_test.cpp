#include "services/base/file_lock.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <string>

#include "services/base/atomic_file.h"
#include "tests/testing/test_dir.h"

namespace prism::base {
namespace {

TEST(FileLockTest, OneHolderAtATimeAndTheOthersMessageNamesIt) {
  const std::filesystem::path dir = testing::fresh_dir("file_lock");
  const std::filesystem::path file = dir / "coordinator.lock";
  absl::StatusOr<FileLock> first = FileLock::acquire(file, "the data directory d");
  ASSERT_TRUE(first.ok()) << first.status();
  // A second open description (a second coordinator in this process, or another process).
  absl::StatusOr<FileLock> second = FileLock::acquire(file, "the data directory d");
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(std::string(second.status().message()), "the data directory d is in use by process " +
                                                        std::to_string(::getpid()) +
                                                        " (lock file " + file.string() + ")");
  // Another process is refused too.
  const pid_t child = ::fork();
  if (child == 0) _exit(FileLock::acquire(file, "d").ok() ? 1 : 0);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  // Released with its holder, moved or not.
  FileLock moved = *std::move(first);
  EXPECT_FALSE(FileLock::acquire(file, "d").ok());
  { FileLock gone = std::move(moved); }
  EXPECT_TRUE(FileLock::acquire(file, "d").ok());
}

TEST(FileLockTest, AFileThatCannotBeOpenedIsAnError) {
  const std::filesystem::path dir = testing::fresh_dir("file_lock_missing");
  absl::StatusOr<FileLock> lock = FileLock::acquire(dir / "no" / "such" / "x.lock", "d");
  EXPECT_EQ(lock.status().code(), absl::StatusCode::kInternal) << lock.status();
}

}  // namespace
}  // namespace prism::base
