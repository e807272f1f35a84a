// A render's finished tiles written into its spectral EXR while the render runs (issue 18): the
// spectral EXR's compression, which took as long as a 1-spp render of a large image after it,
// overlaps the render instead, and the finished bins never go through a spool file.
//
// Tiles arrive from the render threads in any order; each is copied into its band (one row of
// tiles), and a writer thread hands complete bands, top to bottom, to an image::SpectralExrStream
// with the same rows of the RGB image. Memory stays bounded: put() for a tile more than
// `bands_held` bands below the band being written waits (the local render hands out its tasks
// in plan order, so the band being written is always being rendered, and the wait ends).
// At the end, write() makes the file with the report's metadata by copying the compressed lines:
// the same bytes as writing the whole image afterwards.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/tile_plan.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile.h"

namespace prism::coordinator {

// Bands a SpectralStream holds in memory at most by default (resource_plan.cpp plans for them).
inline constexpr int kStreamBandsHeld = 4;

class SpectralStream {
 public:
  // `plan`'s tiles must cover the width x height image in rows of tiles, as plan_tiles makes
  // them (INVALID_ARGUMENT otherwise). `rgb` is width·height·3 floats that outlive the stream;
  // a tile's rows of it must be final before the tile is put(). `stopped` is polled while
  // waiting, so that a failed or cancelled render never leaves a thread waiting for a band that
  // will not come. The stream's working file is anonymous, in `dir` (image::SpectralExrStream).
  static absl::StatusOr<std::unique_ptr<SpectralStream>> create(
      const std::filesystem::path& dir, const TilePlan& plan, int width, int height, int bins,
      const float* rgb, const image::ExrWriteOptions& options, std::function<bool()> stopped,
      int bands_held = kStreamBandsHeld);
  ~SpectralStream();
  SpectralStream(const SpectralStream&) = delete;
  SpectralStream& operator=(const SpectralStream&) = delete;

  // Tile `tile`'s finalised bins (its rect's size, the stream's bins). Thread-safe for different
  // tiles. INVALID_ARGUMENT for a wrong index or shape or a tile put twice; ABORTED once the
  // render stopped; the writer's error once it failed.
  absl::Status put(int tile, const image::SpectralImage& finalised);

  // Waits until the writer has written every band (or stopped); its status. ABORTED when the
  // render stopped first.
  absl::Status finish();

  // After finish(): the spectral EXR at `path` with `metadata`.
  absl::Status write(const std::filesystem::path& path, const image::ExrMetadata& metadata);

  int band_rows() const { return band_rows_; }
  // The most bands held in memory at once (filled or being filled).
  int peak_bands_held() const;

 private:
  SpectralStream() = default;
  void run_writer();
  bool stopped_locked() const;

  int width_ = 0, height_ = 0, bins_ = 0, band_rows_ = 1, bands_held_ = 1;
  const float* rgb_ = nullptr;
  std::function<bool()> stopped_;
  std::vector<image::TileRect> tiles_;
  std::vector<int> band_of_;        // per tile
  std::vector<char> tile_put_;      // per tile
  std::vector<int> band_y0_;        // per band, and height_ at the end
  std::vector<int> tiles_in_band_;  // per band
  std::vector<int> arrived_;        // per band
  // Per band while held: width x rows x bins, every value written by the band's tiles.
  std::vector<std::unique_ptr<float[]>> buffers_;
  std::unique_ptr<image::SpectralExrStream> exr_;

  mutable std::mutex mutex_;
  std::condition_variable changed_;
  int next_band_ = 0;  // the band the writer writes next
  int held_ = 0, peak_held_ = 0;
  bool finished_ = false, aborted_ = false;
  absl::Status writer_status_;
  std::thread writer_;
};

}  // namespace prism::coordinator
