// An exclusive advisory lock (flock) on a file, held for the object's life: one coordinator per
// data directory. The lock goes with the process, so a coordinator killed with -9 leaves nothing
// to clean up; the file keeps the holder's pid for the message a second process gets.
#pragma once

#include <filesystem>
#include <string_view>

#include "absl/status/statusor.h"

namespace prism::base {

class FileLock {
 public:
  // Creates `file` if needed and locks it. FAILED_PRECONDITION when another open description
  // holds it ("<what> is in use by process N"), INTERNAL when the file cannot be opened.
  static absl::StatusOr<FileLock> acquire(const std::filesystem::path& file, std::string_view what);

  FileLock(FileLock&& other) noexcept : fd_(other.fd_) { other.fd_ = -1; }
  FileLock& operator=(FileLock&& other) noexcept;
  FileLock(const FileLock&) = delete;
  FileLock& operator=(const FileLock&) = delete;
  ~FileLock();

 private:
  explicit FileLock(int fd) : fd_(fd) {}
  int fd_ = -1;
};

}  // namespace prism::base
