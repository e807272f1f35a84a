#include "coordinator/spectral_stream.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <map>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"

namespace prism::coordinator {
namespace {

// How often a waiting thread looks at the render's stop flags.
constexpr auto kPoll = std::chrono::milliseconds(20);

}  // namespace

absl::StatusOr<std::unique_ptr<SpectralStream>> SpectralStream::create(
    const std::filesystem::path& dir, const TilePlan& plan, int width, int height, int bins,
    const float* rgb, const image::ExrWriteOptions& options, std::function<bool()> stopped,
    int bands_held) {
  if (plan.tiles.empty() || width < 1 || height < 1 || bins < 1 || rgb == nullptr ||
      bands_held < 1) {
    return absl::InvalidArgumentError(absl::StrCat("a spectral stream of ", width, "x", height, "x",
                                                   bins, " with ", plan.tiles.size(), " tiles and ",
                                                   bands_held, " bands held"));
  }
  std::unique_ptr<SpectralStream> s(new SpectralStream());
  s->width_ = width;
  s->height_ = height;
  s->bins_ = bins;
  s->rgb_ = rgb;
  s->stopped_ = std::move(stopped);
  s->bands_held_ = bands_held;
  s->tiles_ = plan.tiles;
  // Bands are the rows of tiles: every tile of one starts and ends on the same rows, and the
  // bands run from row 0 to the last without gaps.
  std::map<int, int> end_of;  // y0 -> y1
  std::map<int, int> width_of;
  for (const image::TileRect& r : plan.tiles) {
    auto [it, added] = end_of.emplace(r.y0, r.y1);
    if (!added && it->second != r.y1) {
      return absl::InvalidArgumentError(
          absl::StrCat("tile ", image::to_string(r), " does not fill its row of tiles"));
    }
    width_of[r.y0] += r.width();
  }
  int y = 0;
  for (const auto& [y0, y1] : end_of) {
    if (y0 != y || y1 <= y0 || width_of[y0] != width) {
      return absl::InvalidArgumentError(absl::StrCat("the plan's rows of tiles do not cover the ",
                                                     width, "x", height, " image at row ", y));
    }
    s->band_y0_.push_back(y0);
    y = y1;
  }
  if (y != height) {
    return absl::InvalidArgumentError(
        absl::StrCat("the plan's rows of tiles end at row ", y, " of ", height));
  }
  s->band_y0_.push_back(height);
  s->band_rows_ = s->band_y0_[1] - s->band_y0_[0];
  const std::size_t bands = s->band_y0_.size() - 1;
  s->tiles_in_band_.assign(bands, 0);
  s->arrived_.assign(bands, 0);
  s->buffers_.resize(bands);
  s->tile_put_.assign(plan.tiles.size(), 0);
  for (const image::TileRect& r : plan.tiles) {
    const int band = static_cast<int>(
        std::lower_bound(s->band_y0_.begin(), s->band_y0_.end(), r.y0) - s->band_y0_.begin());
    s->band_of_.push_back(band);
    ++s->tiles_in_band_[std::size_t(band)];
  }
  PRISM_ASSIGN_OR_RETURN(s->exr_, image::SpectralExrStream::create(dir, image::bin_centres_nm(bins),
                                                                   width, height, options));
  s->writer_ = std::thread([raw = s.get()] { raw->run_writer(); });
  return s;
}

SpectralStream::~SpectralStream() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    aborted_ = true;
  }
  changed_.notify_all();
  if (writer_.joinable()) writer_.join();
}

bool SpectralStream::stopped_locked() const {
  return aborted_ || (stopped_ && stopped_());
}

absl::Status SpectralStream::put(int tile, const image::SpectralImage& finalised) {
  if (tile < 0 || std::size_t(tile) >= tiles_.size()) {
    return absl::InvalidArgumentError(absl::StrCat("spectral stream: no tile ", tile));
  }
  const image::TileRect& rect = tiles_[std::size_t(tile)];
  if (finalised.width() != rect.width() || finalised.height() != rect.height() ||
      finalised.bins() != bins_) {
    return absl::InvalidArgumentError(absl::StrCat("spectral stream: tile ", tile, " is ",
                                                   finalised.width(), "x", finalised.height(), "x",
                                                   finalised.bins(), ", not its rect's"));
  }
  const int band = band_of_[std::size_t(tile)];
  const int band_y0 = band_y0_[std::size_t(band)];
  float* dest = nullptr;
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (tile_put_[std::size_t(tile)] != 0) {
      return absl::InvalidArgumentError(
          absl::StrCat("spectral stream: tile ", tile, " was put twice"));
    }
    while (band >= next_band_ + bands_held_ && !stopped_locked()) changed_.wait_for(lock, kPoll);
    if (stopped_locked()) {
      return writer_status_.ok() ? absl::AbortedError("the render stopped") : writer_status_;
    }
    tile_put_[std::size_t(tile)] = 1;
    std::unique_ptr<float[]>& buffer = buffers_[std::size_t(band)];
    if (buffer == nullptr) {
      const int rows = band_y0_[std::size_t(band) + 1] - band_y0;
      buffer.reset(new float[std::size_t(width_) * std::size_t(rows) * std::size_t(bins_)]);
      peak_held_ = std::max(peak_held_, ++held_);
    }
    dest = buffer.get();
  }
  // Tiles of one band fill disjoint pixels of its buffer, which stays put until they all did.
  const std::size_t row_values = std::size_t(rect.width()) * std::size_t(bins_);
  for (int y = rect.y0; y < rect.y1; ++y) {
    std::memcpy(dest + (std::size_t(y - band_y0) * std::size_t(width_) + std::size_t(rect.x0)) *
                           std::size_t(bins_),
                finalised.data().data() + std::size_t(y - rect.y0) * row_values,
                row_values * sizeof(float));
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (++arrived_[std::size_t(band)] == tiles_in_band_[std::size_t(band)]) changed_.notify_all();
  }
  return absl::OkStatus();
}

void SpectralStream::run_writer() {
  const int bands = static_cast<int>(band_y0_.size()) - 1;
  for (int band = 0; band < bands; ++band) {
    std::unique_ptr<float[]> buffer;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      while (arrived_[std::size_t(band)] < tiles_in_band_[std::size_t(band)] && !stopped_locked())
        changed_.wait_for(lock, kPoll);
      if (arrived_[std::size_t(band)] < tiles_in_band_[std::size_t(band)]) {
        aborted_ = true;
        changed_.notify_all();
        return;
      }
      buffer = std::move(buffers_[std::size_t(band)]);
    }
    const int y0 = band_y0_[std::size_t(band)];
    const absl::Status written =
        exr_->write_rows(band_y0_[std::size_t(band) + 1] - y0, buffer.get(),
                         rgb_ + std::size_t(y0) * std::size_t(width_) * 3);
    buffer.reset();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      next_band_ = band + 1;
      --held_;
      if (!written.ok()) {
        writer_status_ = written;
        aborted_ = true;
      }
    }
    changed_.notify_all();
    if (!written.ok()) return;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  finished_ = true;
}

absl::Status SpectralStream::finish() {
  if (writer_.joinable()) writer_.join();
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return absl::OkStatus();
  return writer_status_.ok() ? absl::AbortedError(
                                   "the render stopped before the spectral EXR "
                                   "was written")
                             : writer_status_;
}

absl::Status SpectralStream::write(const std::filesystem::path& path,
                                   const image::ExrMetadata& metadata) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!finished_) {
      return absl::FailedPreconditionError(absl::StrCat(
          "cannot write ", path.string(), ": the render's bins were not all streamed"));
    }
  }
  return exr_->write(path, metadata);
}

int SpectralStream::peak_bands_held() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return peak_held_;
}

}  // namespace prism::coordinator
