#include "coordinator/spectral_spool.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/status.h"

namespace prism::coordinator {
absl::StatusOr<std::unique_ptr<SpectralSpool>> SpectralSpool::create(
    const std::filesystem::path& dir, TilePlan plan, int width, int height, int bins) {
  PRISM_ASSIGN_OR_RETURN(const int fd, base::make_anonymous_file(dir, "a spool file"));
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
  return base::pwrite_all(fd_, reinterpret_cast<const char*>(finalised.data().data()),
                          finalised.data().size_bytes(), offsets_[std::size_t(tile)], "spool");
}

image::SpectralRows SpectralSpool::rows(std::vector<float>* buffer) const {
  return [this, buffer](int y0, int rows) -> absl::StatusOr<const float*> {
    std::vector<float> tile;
    PRISM_RETURN_IF_ERROR(assemble_band(
        plan_, width_, bins_, y0, rows,
        [&](std::size_t t) -> absl::StatusOr<const float*> {
          const image::TileRect& rect = plan_.tiles[t];
          tile.resize(std::size_t(rect.width()) * std::size_t(rect.height()) * std::size_t(bins_));
          PRISM_RETURN_IF_ERROR(base::pread_all(fd_, reinterpret_cast<char*>(tile.data()),
                                                tile.size() * sizeof(float), offsets_[t], "spool"));
          return tile.data();
        },
        buffer));
    return buffer->data();
  };
}

}  // namespace prism::coordinator
