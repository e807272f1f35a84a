// A job's finished tiles, on disk. The coordinator keeps in memory only the tiles in flight
// (their range results, in the TileAssembler) and the job's linear sRGB (3 floats per pixel,
// for previews and the RGB outputs); a finished tile's merged result (the tile codec's bytes:
// sums, sums of squares, counts, and gradients or guides when present) goes to
// <dir>/<tile index>.tile, written atomically, and the spectral EXR is streamed from these files
// one row of tiles at a time. The files are also what a restarted coordinator resumes finished
// tiles from, so the range results they were merged from can be deleted once they are written.
#pragma once

#include <filesystem>
#include <functional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/tile_finaliser.h"
#include "coordinator/tile_plan.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile.h"

namespace prism::coordinator {

class FinishedTiles {
 public:
  // Creates `dir` (and its parents) if needed; keeps what is already there.
  static absl::StatusOr<FinishedTiles> open(std::filesystem::path dir, TilePlan plan, int width,
                                            int bins);

  // Writes (or rewrites, with the same bytes) tile `tile`'s merged result. INVALID_ARGUMENT
  // when the index or the rect is not the plan's; INTERNAL naming the file on an I/O error.
  absl::Status put(int tile, const image::TileResult& merged) const;
  bool has(int tile) const;
  // DATA_LOSS naming the file when it is missing, unreadable or not this tile of this job.
  absl::StatusOr<image::TileResult> get(int tile) const;

  // The finished image for image::write_spectral_exr_rows, in bands of band_rows() rows (one
  // row of tiles): each band reads and finalises that row's tiles into `buffer`.
  image::SpectralRows rows(TileFinaliser finalise, std::vector<float>* buffer) const;
  int band_rows() const { return plan_.tiles.empty() ? 1 : plan_.tiles.front().height(); }

  // Deletes the directory and everything in it (the job is over).
  absl::Status remove() const;

  const std::filesystem::path& dir() const { return dir_; }

 private:
  FinishedTiles(std::filesystem::path dir, TilePlan plan, int width, int bins)
      : dir_(std::move(dir)), plan_(std::move(plan)), width_(width), bins_(bins) {}
  std::filesystem::path path_of(int tile) const;

  std::filesystem::path dir_;
  TilePlan plan_;
  int width_;
  int bins_;
};

}  // namespace prism::coordinator
