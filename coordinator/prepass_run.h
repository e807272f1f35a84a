// One job's prepass as the coordinator drives it (docs/estimators.md §4 with issue 11's changes):
// the passes' task plans, the tables each pass's tiles are shipped with, the accumulation of every
// pass's merged tiles into the whole-image second moments and guides, and after each pass the
// reconstruction (prepass.h: joint bilateral filter, second-moment tables with a per-pixel
// mixture weight) that the next pass (or the final pass) samples. LocalRender and the farm's
// coordinator drive the same object, so the embedded render and the farm learn the same tables
// bit for bit.
//
// Sequence: for k = 1..passes(): render every tile of plan(k) (one task per tile, samples
// [0, pass(k).spp), guides on, early stop on) with tables_for_pass(k, rect); add_tile(k, merged)
// for each; finish_pass(k); stop as soon as finished() (after pass 1 of several, a prepass whose
// tables are predicted to remove less than job::PrepassParameters::min_image_gain of the image's
// variance stops there: every pixel goes back to the default and the later passes are not
// rendered; after the last, tables predicted under min_final_gain are dropped). Then the final
// pass's tiles take final_tables(rect).
//
// Every prepass samples the job's default distribution: pass k > 1 renders only the pixels that
// still have a table after pass k − 1 (the others carry an all-zero row and are skipped), with
// the default's own bin masses as their table. The paper samples later passes with the tables
// learned so far; but where a table starves a bin, the few samples that land there carry values
// 1/q times larger, and the moments they give (unbiased, heavy-tailed) make the next tables and
// their validation noisy. The passes add up to one default-sampled estimate, with a decision
// point after pass 1. Tables are carried to the next film with upsample_tables when
// image-scaled.
//
// Not thread-safe: the caller serialises calls (LocalRender adds tiles under its own lock, the
// farm under its mutex). Every result is a pure function of the merged tiles.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/prepass.h"
#include "coordinator/tile_plan.h"
#include "services/image/tile.h"
#include "services/job/render_options.h"
#include "services/spectral/wavelength_distribution.h"

namespace prism::coordinator {

// How a job's final-pass variance depends on its prepass tables: the prepass's and the job's lanes,
// and stratified wavelengths under the Sobol sampler (prepass.h VarianceModel).
VarianceModel prepass_variance_model(const job::RenderOptions& render);

// What a finished prepass did, for reports and summary lines.
struct PrepassOutcome {
  int passes_run = 0;          // passes rendered
  bool stopped_early = false;  // stopped after pass 1: predicted gain under kMinImageGain
  bool dropped = false;        // the last pass's tables predicted under kMinFinalGain: dropped
  // What the early stop looked at after pass 1 (the smaller of the tables' predicted_gain and
  // decision_gain), and the last pass's tables' predicted_gain (unbiased), or what dropped them.
  double first_pass_gain = 0;
  double predicted_gain = 0;
  double fallback_fraction = 0;                      // pixels on the job's default distribution
  std::array<double, kAlphaChoices> alpha_values{};  // alpha_choice of each index
  std::array<std::int64_t, kAlphaChoices> alpha_histogram{};  // pixels per alpha
  std::array<std::int64_t, kTableShapes> shape_histogram{};   // learned pixels per TableShape
  double reconstruction_seconds = 0;                          // the coordinator's filters, tables
};

class PrepassRun {
 public:
  // `job_default`: the job's default wavelength distribution (what the final pass samples
  // where a pixel has no table; RenderScene::wavelength_pdf). `sensor`: the sensor term over
  // `bins` cells when it is not flat (its masses weight each bin's error as the default does).
  // `model`: how the final pass's variance depends on the tables (VarianceModel::of the prepass's
  // and the final pass's lanes and sampler). INVALID_ARGUMENT for invalid parameters or sizes.
  static absl::StatusOr<PrepassRun> create(const job::PrepassParameters& params, int width,
                                           int height, int tile_size, int bins,
                                           const spectral::WavelengthDistribution& job_default,
                                           const spectral::WavelengthDistribution* sensor,
                                           const VarianceModel& model);

  int passes() const { return static_cast<int>(schedule_.size()); }
  // k in 1..passes() (PRISM_CHECK).
  const PrepassPass& pass(int k) const;
  const TilePlan& plan(int k) const;
  const job::PrepassParameters& parameters() const { return params_; }

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
  // Every pass is rendered and reconstructed, or the prepass stopped early.
  bool finished() const { return finished_ == passes() || stopped_early_; }
  // Passes rendered so far (== passes() unless it stopped early).
  int passes_run() const { return finished_; }
  bool stopped_early() const { return stopped_early_; }

  // The final pass's tables for a rect of the job's film (after the last pass).
  absl::StatusOr<std::string> final_tables(const image::TileRect& rect) const;
  int table_cells() const { return bins_; }
  // Of the final tables: the fraction of pixels that use the default distribution.
  double fallback_fraction() const;
  // Of the final tables: pixels per alpha_choice index, and the predicted fraction of the
  // image's variance per sample they remove (0 when it stopped early).
  std::array<std::int64_t, kAlphaChoices> alpha_histogram() const;
  double predicted_gain() const;
  // What pass 1's tables predicted (the figure the early stop looked at).
  double first_pass_predicted_gain() const { return first_pass_gain_; }
  // After the last pass (or the early stop).
  PrepassOutcome outcome() const;
  // Whether the final pass samples any table (false when every pixel is on the default, e.g.
  // after an early stop: its tasks then carry no tables at all).
  bool final_pass_has_tables() const;
  // The final tables (after the last pass; null before), for reports and dumps.
  const PixelTableImage* tables() const { return finished() ? &*tables_ : nullptr; }
  // CPU-side reconstruction time summed over the passes (filter, tables, upsampling).
  double reconstruction_seconds() const { return reconstruction_seconds_; }

 private:
  PrepassRun() = default;

  job::PrepassParameters params_;
  int width_ = 0;
  int height_ = 0;
  int bins_ = 0;
  std::vector<PrepassPass> schedule_;
  std::vector<TilePlan> plans_;
  std::vector<double> default_masses_;  // D_b of the job's default distribution
  std::vector<double> sensor_weights_;  // s_b, mean 1; empty for a flat sensor
  VarianceModel model_;
  int finished_ = 0;  // passes 1..finished_ are reconstructed
  bool stopped_early_ = false;
  bool dropped_ = false;     // the last pass's tables were predicted too weak and dropped
  double final_gain_ = 0.0;  // what they predicted
  double first_pass_gain_ = 0.0;
  // The pass being assembled (finished_ + 1): tiles added. The moments and guides accumulate
  // over the passes at one resolution (they restart when an image-scaled pass grows the film).
  std::optional<MomentImage> moments_;
  std::optional<GuideImage> guides_;
  std::vector<bool> added_;
  int added_count_ = 0;
  // The tables of pass finished_, carried to the film of the next pass (or the final film), and
  // what the next prepass samples with (the same pixels, the default's masses).
  std::optional<PixelTableImage> tables_;
  std::optional<PixelTableImage> sampling_tables_;
  std::vector<std::uint16_t> default_cdf_;  // the default's bin masses, quantised
  double reconstruction_seconds_ = 0;
};

}  // namespace prism::coordinator
