// A render's finished bins on disk instead of in memory, so `prism render` holds a bounded
// amount of memory whatever the image size (issue 18): an 8K frame at 64 bins is 8.5 GB of
// float32 bins. Each finished tile's finalised bins go to the tile's own slot of one anonymous
// file (pwrite: tiles from any thread, in any order); the spectral EXR is then streamed from it
// one row of tiles at a time (image::write_spectral_exr_rows), as the coordinator streams a job
// from its finished-tile files.
//
// The file is created unlinked in the directory given (O_TMPFILE, else created and unlinked at
// once): it never outlives the process, and nothing is left behind by a crash. Its size is the
// image's bins, width x height x bins x 4 bytes; the caller plans that disk space
// (resource_plan.h).
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/tile_plan.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile.h"

namespace prism::coordinator {

class SpectralSpool {
 public:
  // INTERNAL naming the directory when the file cannot be made. `plan`'s tiles must cover the
  // width x height image in rows of tiles, as plan_tiles makes them.
  static absl::StatusOr<std::unique_ptr<SpectralSpool>> create(const std::filesystem::path& dir,
                                                               TilePlan plan, int width, int height,
                                                               int bins);
  ~SpectralSpool();
  SpectralSpool(const SpectralSpool&) = delete;
  SpectralSpool& operator=(const SpectralSpool&) = delete;

  // Stores tile `tile`'s finalised bins (its rect's size, the spool's bins). Thread-safe for
  // different tiles. INVALID_ARGUMENT for a wrong index or shape, INTERNAL on an I/O error.
  absl::Status put(int tile, const image::SpectralImage& finalised) const;

  // The finished image for image::write_spectral_exr_rows, in bands of band_rows() rows (one row
  // of tiles), read into `buffer`. Every tile must have been put.
  image::SpectralRows rows(std::vector<float>* buffer) const;
  int band_rows() const { return plan_.tiles.empty() ? 1 : plan_.tiles.front().height(); }

  int width() const { return width_; }
  int height() const { return height_; }
  int bins() const { return bins_; }

 private:
  SpectralSpool(int fd, TilePlan plan, int width, int height, int bins);

  int fd_;
  TilePlan plan_;
  int width_, height_, bins_;
  std::vector<std::uint64_t> offsets_;  // byte offset of each tile's slot
};

}  // namespace prism::coordinator
