#include "services/base/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>

#include "absl/strings/str_cat.h"

namespace prism::base {
namespace {

std::filesystem::path temp_name_for(const std::filesystem::path& path) {
  static std::atomic<std::uint64_t> counter{0};
  return path.parent_path() / absl::StrCat(".", path.filename().string(), ".tmp.", ::getpid(), ".",
                                           counter.fetch_add(1));
}

absl::Status errno_status(const std::string& what, const std::filesystem::path& path) {
  return absl::InternalError(absl::StrCat(what, " ", path.string(), ": ", std::strerror(errno)));
}

absl::Status fsync_path(const std::filesystem::path& path) {
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return errno_status("cannot open", path);
  int rc = ::fsync(fd);
  ::close(fd);
  if (rc != 0) return errno_status("cannot fsync", path);
  return absl::OkStatus();
}

bool all_digits(std::string_view text) {
  return !text.empty() &&
         std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; });
}

// Whether `name` is one temp_name_for made: ".<name>.tmp.<pid>.<n>".
bool is_temporary_name(std::string_view name) {
  if (name.size() < 2 || name[0] != '.') return false;
  const std::size_t tmp = name.rfind(".tmp.");
  if (tmp == std::string_view::npos || tmp < 2) return false;
  const std::string_view numbers = name.substr(tmp + 5);
  const std::size_t dot = numbers.find('.');
  return dot != std::string_view::npos && all_digits(numbers.substr(0, dot)) &&
         all_digits(numbers.substr(dot + 1));
}

}  // namespace

void remove_temporaries(const std::filesystem::path& dir) {
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
    if (entry.is_regular_file(ec) && is_temporary_name(entry.path().filename().string())) {
      std::filesystem::remove(entry.path(), ec);
    }
  }
}

absl::StatusOr<std::string> read_file(const std::filesystem::path& path, std::uint64_t max_bytes) {
  std::error_code ec;
  auto status = std::filesystem::status(path, ec);
  if (ec || !std::filesystem::exists(status)) {
    return absl::NotFoundError(absl::StrCat("file not found: ", path.string()));
  }
  if (!std::filesystem::is_regular_file(status)) {
    return absl::InvalidArgumentError(absl::StrCat("not a regular file: ", path.string()));
  }
  auto size = std::filesystem::file_size(path, ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot stat ", path.string(), ": ", ec.message()));
  if (size > max_bytes) {
    return absl::ResourceExhaustedError(
        absl::StrCat(path.string(), " is ", size, " bytes, over the limit of ", max_bytes));
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return errno_status("cannot open", path);
  std::string bytes(size, '\0');
  in.read(bytes.data(), static_cast<std::streamsize>(size));
  if (static_cast<std::uint64_t>(in.gcount()) != size) {
    return absl::InternalError(absl::StrCat("short read of ", path.string()));
  }
  return bytes;
}

absl::Status write_via_temp(
    const std::filesystem::path& path,
    const std::function<absl::Status(const std::filesystem::path&)>& writer) {
  auto temp = temp_name_for(path);
  absl::Status status = writer(temp);
  if (status.ok()) status = fsync_path(temp);
  if (status.ok() && std::rename(temp.c_str(), path.c_str()) != 0) {
    status = errno_status("cannot rename into", path);
  }
  if (!status.ok()) {
    std::error_code ignored;
    std::filesystem::remove(temp, ignored);
  }
  return status;
}

absl::Status write_file_atomic(const std::filesystem::path& path, std::span<const char> bytes) {
  return write_via_temp(path, [&](const std::filesystem::path& temp) -> absl::Status {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    if (!out) return errno_status("cannot create", temp);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (!out) return errno_status("cannot write", temp);
    return absl::OkStatus();
  });
}

namespace {

template <typename Bytes, typename Io>
absl::Status transfer(std::string_view what, const char* verb, Io io, int fd, Bytes* bytes,
                      std::size_t size, std::uint64_t offset) {
  while (size > 0) {
    const ssize_t n = io(fd, bytes, size, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      return absl::InternalError(
          absl::StrCat(std::string(what), " ", verb, " at byte ", offset,
                       " failed: ", n == 0 ? "end of file" : std::strerror(errno)));
    }
    bytes += n;
    size -= std::size_t(n);
    offset += std::uint64_t(n);
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status pwrite_all(int fd, const char* bytes, std::size_t size, std::uint64_t offset,
                        std::string_view what) {
  return transfer(what, "write", ::pwrite, fd, bytes, size, offset);
}

absl::Status pread_all(int fd, char* bytes, std::size_t size, std::uint64_t offset,
                       std::string_view what) {
  return transfer(what, "read", ::pread, fd, bytes, size, offset);
}

absl::StatusOr<int> make_anonymous_file(const std::filesystem::path& dir, std::string_view what) {
  int fd = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (fd < 0) {
    // File systems without O_TMPFILE: a unique name, unlinked at once.
    std::string name = (dir / ".prism-XXXXXX").string();
    fd = ::mkostemp(name.data(), O_CLOEXEC);
    if (fd >= 0) ::unlink(name.c_str());
  }
  if (fd < 0) {
    return absl::InternalError(absl::StrCat("cannot make ", std::string(what), " in ", dir.string(),
                                            ": ", std::strerror(errno)));
  }
  return fd;
}

absl::Status make_directories(const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) {
    return absl::InternalError(
        absl::StrCat("cannot create directory ", dir.string(), ": ", ec.message()));
  }
  return absl::OkStatus();
}

}  // namespace prism::base
