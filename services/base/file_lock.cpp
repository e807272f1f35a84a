#include "services/base/file_lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"

namespace prism::base {

absl::StatusOr<FileLock> FileLock::acquire(const std::filesystem::path& file,
                                           std::string_view what) {
  const int fd = ::open(file.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    return absl::InternalError(
        absl::StrCat("cannot open the lock file ", file.string(), ": ", std::strerror(errno)));
  }
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int error = errno;
    char buffer[32] = {};
    const ssize_t n = ::pread(fd, buffer, sizeof(buffer) - 1, 0);
    ::close(fd);
    if (error != EWOULDBLOCK) {
      return absl::InternalError(
          absl::StrCat("cannot lock ", file.string(), ": ", std::strerror(error)));
    }
    const std::string holder(absl::StripAsciiWhitespace(std::string(buffer, n > 0 ? n : 0)));
    return absl::FailedPreconditionError(
        absl::StrCat(absl::string_view(what.data(), what.size()), " is in use by ",
                     holder.empty() ? "another process" : "process " + holder, " (lock file ",
                     file.string(), ")"));
  }
  // The holder's pid, for the message above; the lock itself is what counts.
  const std::string pid = absl::StrCat(::getpid(), "\n");
  if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, pid.data(), pid.size(), 0) < 0) {
    // A lock without the pid still excludes; only the message loses the number.
  }
  return FileLock(fd);
}

FileLock& FileLock::operator=(FileLock&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = other.fd_;
    other.fd_ = -1;
  }
  return *this;
}

FileLock::~FileLock() {
  if (fd_ >= 0) ::close(fd_);
}

}  // namespace prism::base
