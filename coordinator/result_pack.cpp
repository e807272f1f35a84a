#include "coordinator/result_pack.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/sha256.h"
#include "services/base/status.h"

namespace prism::coordinator {

absl::StatusOr<std::shared_ptr<ResultPack>> ResultPack::open(const std::filesystem::path& path) {
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    return absl::InternalError(
        absl::StrCat("cannot open the result pack ", path.string(), ": ", std::strerror(errno)));
  }
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    const int error = errno;
    ::close(fd);
    return absl::InternalError(
        absl::StrCat("cannot stat the result pack ", path.string(), ": ", std::strerror(error)));
  }
  return std::shared_ptr<ResultPack>(new ResultPack(path, fd, std::uint64_t(st.st_size)));
}

ResultPack::ResultPack(std::filesystem::path path, int fd, std::uint64_t end)
    : path_(std::move(path)), fd_(fd), end_(end) {}

ResultPack::~ResultPack() {
  ::close(fd_);
}

std::uint64_t ResultPack::reserve(std::uint64_t size) {
  return end_.fetch_add(size);
}

absl::Status ResultPack::write(std::uint64_t offset, std::string_view bytes) const {
  return base::pwrite_all(fd_, bytes.data(), bytes.size(), offset,
                          absl::StrCat("result pack ", path_.string()));
}

absl::Status ResultPack::sync() const {
  if (::fdatasync(fd_) != 0) {
    return absl::InternalError(
        absl::StrCat("cannot sync the result pack ", path_.string(), ": ", std::strerror(errno)));
  }
  return absl::OkStatus();
}

absl::Status ResultPack::release(std::uint64_t offset, std::uint64_t size) const {
  if (size == 0) return absl::OkStatus();
  if (::fallocate(fd_, FALLOC_FL_PUNCH_HOLE | FALLOC_FL_KEEP_SIZE, off_t(offset), off_t(size)) !=
      0) {
    const std::string why = std::strerror(errno);
    const std::string what =
        absl::StrCat("cannot release ", size, " bytes at ", offset, " of ", path_.string(), ": ");
    return errno == EOPNOTSUPP ? absl::UnimplementedError(what + why)
                               : absl::InternalError(what + why);
  }
  return absl::OkStatus();
}

absl::StatusOr<std::string> ResultPack::read(std::uint64_t offset, std::uint64_t size,
                                             std::string_view sha256) const {
  auto lost = [&](const std::string& why) {
    return absl::DataLossError(absl::StrCat("result pack ", path_.string(), " bytes [", offset,
                                            ", ", offset + size, "): ", why));
  };
  if (size > (std::uint64_t{1} << 32)) return lost("too large to be a result");
  std::string bytes(size, '\0');
  absl::Status read = base::pread_all(fd_, bytes.data(), bytes.size(), offset, "read");
  if (!read.ok()) return lost(std::string(read.message()));
  if (base::sha256_hex(bytes) != sha256) {
    return lost(absl::StrCat("do not hash to ", std::string(sha256)));
  }
  return bytes;
}

void DirtyPacks::add(std::shared_ptr<ResultPack> pack) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (std::find(dirty_.begin(), dirty_.end(), pack) == dirty_.end()) {
    dirty_.push_back(std::move(pack));
  }
}

absl::Status DirtyPacks::sync() {
  std::vector<std::shared_ptr<ResultPack>> packs;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    packs.swap(dirty_);
  }
  absl::Status first;
  std::vector<std::shared_ptr<ResultPack>> failed;
  for (std::shared_ptr<ResultPack>& pack : packs) {
    absl::Status synced = pack->sync();
    if (synced.ok()) continue;
    if (first.ok()) first = synced;
    failed.push_back(std::move(pack));
  }
  for (std::shared_ptr<ResultPack>& pack : failed) add(std::move(pack));
  return first;
}

}  // namespace prism::coordinator
