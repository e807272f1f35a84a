// One job's prepass as the coordinator drives it (algorithms.md §4): the passes' task plans, the
// tables each pass's tiles are shipped with, the assembly of every pass's merged tiles into the
// whole-image estimate and guides, and after each pass the reconstruction (prepass.h: joint
// bilateral filter, defensive tables, fallback) that the next pass (or the final pass) samples.
// LocalRender and the farm's coordinator drive the same object, so the embedded render and the
// farm learn the same tables bit for bit.
//
// Sequence: for k = 1..passes(): render every tile of plan(k) (one task per tile, samples
// [0, pass(k).spp), guides on, early stop on) with tables_for_pass(k, rect); add_tile(k, merged)
// for each; finish_pass(k). Then the final pass's tiles take final_tables(rect). Pass k's tables
// come from pass k − 1's result carried to pass k's film (upsample_tables when image-scaled); a
// pixel that fell back (kMatchesDefault) carries an all-zero row, so workers skip it in later
// prepasses and sample the job's default distribution in the final pass.
//
// Not thread-safe: the caller serialises calls (LocalRender adds tiles under its own lock, the
// farm under its mutex). Every result is a pure function of the merged tiles.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/prepass.h"
#include "coordinator/tile_plan.h"
#include "services/image/tile.h"
#include "services/spectral/wavelength_distribution.h"

namespace prism::coordinator {

class PrepassRun {
 public:
  // `emitters` and `sensor` as build_tables wants them (worker::prepass_distributions) with
  // `bins` cells. INVALID_ARGUMENT for invalid parameters or sizes.
  static absl::StatusOr<PrepassRun> create(const PrepassParameters& params, int width, int height,
                                           int tile_size, int bins,
                                           spectral::WavelengthDistribution emitters,
                                           std::optional<spectral::WavelengthDistribution> sensor);

  int passes() const { return static_cast<int>(schedule_.size()); }
  // k in 1..passes() (PRISM_CHECK).
  const PrepassPass& pass(int k) const;
  const TilePlan& plan(int k) const;
  const PrepassParameters& parameters() const { return params_; }

  // The tables of a pass-k tile in the PdfTable wire layout (services/spectral/pixel_tables.h),
  // or nothing for pass 1 (every pixel samples the default distribution). Needs passes < k
  // finished (FAILED_PRECONDITION); INVALID_ARGUMENT for a rect outside pass k's film.
  absl::StatusOr<std::optional<std::string>> tables_for_pass(int k,
                                                             const image::TileRect& rect) const;
  // Adds a merged pass-k tile (samples [0, spp), guides). INVALID_ARGUMENT when the tile is not
  // one of pass k's, lacks guides or has other bins; FAILED_PRECONDITION when pass k is not the
  // pass being assembled.
  absl::Status add_tile(int k, const image::TileResult& merged);
  // Reconstructs pass k's tables from its whole estimate. FAILED_PRECONDITION unless every tile
  // of pass k was added and pass k − 1 is finished.
  absl::Status finish_pass(int k);
  bool pass_finished(int k) const { return k <= finished_; }
  bool finished() const { return finished_ == passes(); }

  // The final pass's tables for a rect of the job's film (after the last pass).
  absl::StatusOr<std::string> final_tables(const image::TileRect& rect) const;
  int table_cells() const { return bins_; }
  // Of the final tables: the fraction of pixels that use the default distribution.
  double fallback_fraction() const;
  // CPU-side reconstruction time summed over the passes (filter, tables, upsampling).
  double reconstruction_seconds() const { return reconstruction_seconds_; }

 private:
  PrepassRun() = default;

  PrepassParameters params_;
  int width_ = 0;
  int height_ = 0;
  int bins_ = 0;
  std::vector<PrepassPass> schedule_;
  std::vector<TilePlan> plans_;
  std::optional<spectral::WavelengthDistribution> emitters_;
  std::optional<spectral::WavelengthDistribution> sensor_;
  int finished_ = 0;  // passes 1..finished_ are reconstructed
  // The pass being assembled (finished_ + 1): its estimate, guides and tiles added.
  std::optional<image::SpectralImage> estimate_;
  std::optional<GuideImage> guides_;
  std::vector<bool> added_;
  int added_count_ = 0;
  // The tables of pass finished_, carried to the film of the next pass (or the final film).
  std::optional<PixelTableImage> tables_;
  double reconstruction_seconds_ = 0;
};

}  // namespace prism::coordinator
