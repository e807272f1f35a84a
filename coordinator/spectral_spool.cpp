#include "coordinator/spectral_spool.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "absl/strings/str_cat.h"

namespace prism::coordinator {
namespace {

absl::Status io_error(const char* what, std::uint64_t offset) {
  return absl::InternalError(
      absl::StrCat("spool ", what, " at byte ", offset, " failed: ", std::strerror(errno)));
}

}  // namespace

absl::StatusOr<std::unique_ptr<SpectralSpool>> SpectralSpool::create(
    const std::filesystem::path& dir, TilePlan plan, int width, int height, int bins) {
  int fd = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (fd < 0) {
    // File systems without O_TMPFILE: a unique name, unlinked at once.
    std::string name = (dir / ".prism-spool-XXXXXX").string();
    fd = ::mkostemp(name.data(), O_CLOEXEC);
    if (fd >= 0) ::unlink(name.c_str());
  }
  if (fd < 0) {
    return absl::InternalError(
        absl::StrCat("cannot make a spool file in ", dir.string(), ": ", std::strerror(errno)));
  }
  return std::unique_ptr<SpectralSpool>(
      new SpectralSpool(fd, std::move(plan), width, height, bins));
}

SpectralSpool::SpectralSpool(int fd, TilePlan plan, int width, int height, int bins)
    : fd_(fd), plan_(std::move(plan)), width_(width), height_(height), bins_(bins) {
  std::uint64_t offset = 0;
  offsets_.reserve(plan_.tiles.size());
  for (const image::TileRect& rect : plan_.tiles) {
    offsets_.push_back(offset);
    offset += std::uint64_t(rect.width()) * std::uint64_t(rect.height()) * std::uint64_t(bins_) *
              sizeof(float);
  }
}

SpectralSpool::~SpectralSpool() {
  ::close(fd_);
}

absl::Status SpectralSpool::put(int tile, const image::SpectralImage& finalised) const {
  if (tile < 0 || std::size_t(tile) >= plan_.tiles.size()) {
    return absl::InvalidArgumentError(absl::StrCat("spool: no tile ", tile));
  }
  const image::TileRect& rect = plan_.tiles[std::size_t(tile)];
  if (finalised.width() != rect.width() || finalised.height() != rect.height() ||
      finalised.bins() != bins_) {
    return absl::InvalidArgumentError(absl::StrCat("spool: tile ", tile, " is ", finalised.width(),
                                                   "x", finalised.height(), "x", finalised.bins(),
                                                   ", not its rect's"));
  }
  const char* bytes = reinterpret_cast<const char*>(finalised.data().data());
  std::size_t left = finalised.data().size_bytes();
  std::uint64_t offset = offsets_[std::size_t(tile)];
  while (left > 0) {
    const ssize_t n = ::pwrite(fd_, bytes, left, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return io_error("write", offset);
    bytes += n;
    left -= std::size_t(n);
    offset += std::uint64_t(n);
  }
  return absl::OkStatus();
}

image::SpectralRows SpectralSpool::rows(std::vector<float>* buffer) const {
  return [this, buffer](int y0, int rows) -> absl::StatusOr<const float*> {
    buffer->resize(std::size_t(width_) * std::size_t(rows) * std::size_t(bins_));
    std::vector<float> tile;
    bool covered = false;
    for (std::size_t t = 0; t < plan_.tiles.size(); ++t) {
      const image::TileRect& rect = plan_.tiles[t];
      if (rect.y0 != y0) continue;
      if (rect.height() != rows) {
        return absl::InternalError(absl::StrCat("band of ", rows, " rows at y ", y0,
                                                " does not match tile ", to_string(rect)));
      }
      covered = true;
      const std::size_t row_values = std::size_t(rect.width()) * std::size_t(bins_);
      tile.resize(row_values * std::size_t(rect.height()));
      char* bytes = reinterpret_cast<char*>(tile.data());
      std::size_t left = tile.size() * sizeof(float);
      std::uint64_t offset = offsets_[t];
      while (left > 0) {
        const ssize_t n = ::pread(fd_, bytes, left, static_cast<off_t>(offset));
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) return io_error("read", offset);
        bytes += n;
        left -= std::size_t(n);
        offset += std::uint64_t(n);
      }
      for (int y = 0; y < rect.height(); ++y) {
        std::memcpy(buffer->data() + (std::size_t(y) * width_ + rect.x0) * bins_,
                    tile.data() + std::size_t(y) * row_values, row_values * sizeof(float));
      }
    }
    if (!covered) return absl::InternalError(absl::StrCat("no row of tiles starts at y ", y0));
    return buffer->data();
  };
}

}  // namespace prism::coordinator
