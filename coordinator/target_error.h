// Rendering to a target error (`--target-error E`): the final pass runs in rounds, each adding
// a range of samples to the tiles still short of the target, until they meet it or reach
// max_spp. Round r ends at S_r total samples per pixel: S_1 is the job's spp, then it doubles,
// the last round ending exactly at max_spp (target_error_rounds).
//
// The error is the relative standard error of a pixel's luminance: Y from the mean of its
// samples' exact-wavelength linear sRGB (the RGB the outputs show), its standard error bounded
// by Σ_c w_c·se_c (the channels come from the same samples, so this upper bound never
// understates it), relative to max(Y, 10 % of the image's mean Y): pixels far darker than the
// image are held to the image's brightness, not to their own (a black pixel cannot be
// estimated to a relative error). Scope `pixel`: a tile stops when every one of its pixels
// meets the target; scope `image`: every tile stops when the image's mean luminance does, its
// standard error taken as the root of the pixels' summed squares over their count.
//
// Determinism: the tracker adds each tile's rounds in round order, and decides at the end of a
// round from every tile's sums (tiles in plan order), so the farm and the embedded render stop
// at the same rounds and give the same bytes whatever the workers, threads or retries.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "absl/status/statusor.h"
#include "coordinator/tile_plan.h"
#include "services/image/tile.h"
#include "services/job/job_parameters.h"

namespace prism::coordinator {

// Pixels darker than this share of the image's mean luminance are measured against it.
inline constexpr double kTargetErrorDarkShare = 0.1;

// The cumulative spp at the end of each round: first, 2·first, 4·first, ..., max_spp.
std::vector<std::uint64_t> target_error_rounds(std::uint64_t first_spp, std::uint64_t max_spp);

// The plan's tiles with the samples [s0, s1) split into ranges of samples_per_task (0: one).
TilePlan plan_round(const TilePlan& plan, std::uint64_t s0, std::uint64_t s1,
                    std::uint64_t samples_per_task);

// What the job reached, for the report.
struct TargetErrorOutcome {
  double target = 0;
  bool image_scope = false;
  bool met = false;  // false when max_spp stopped it
  int rounds = 0;    // rounds run
  int rounds_planned = 0;
  // Per pixel at the end: the relative standard error's max, mean and 99th percentile.
  double pixel_max = 0, pixel_mean = 0, pixel_p99 = 0;
  double image_error = 0;  // of the image's mean luminance
  std::uint64_t min_spp = 0, max_spp = 0;
  double mean_spp = 0;
  std::uint64_t samples = 0;  // pixel samples taken
};

class TargetErrorTracker {
 public:
  // `plan`: the final pass's tiles (its ranges are ignored); `first_spp`: round 1's end.
  // INVALID_ARGUMENT for a target or max_spp out of range.
  static absl::StatusOr<TargetErrorTracker> create(const job::TargetError& target,
                                                   const TilePlan& plan, std::uint64_t first_spp);

  const std::vector<std::uint64_t>& rounds() const { return rounds_; }
  // The round now running (0-based) and whether tile t takes part in it.
  int round() const { return round_; }
  bool active(int tile) const { return active_[static_cast<std::size_t>(tile)]; }
  bool finished() const { return finished_; }
  // The current round's samples [s0, s1).
  image::SampleRange round_samples() const;

  // Adds tile t's merged result for the current round (its samples are round_samples()).
  absl::Status add(int tile, const image::TileResult& merged);
  // Ends the round (every active tile added): decides which tiles go on. Returns the tiles that
  // are done now, in plan order; their sums (sum()) are final. After the last round every tile
  // still active is done. FAILED_PRECONDITION when an active tile was not added.
  absl::StatusOr<std::vector<int>> finish_round();
  // Tile t's summed result over its rounds so far.
  const image::TileResult& sum(int tile) const;
  // Drops a finished tile's sum (after the caller has used it); outcome() keeps its errors.
  void release(int tile);
  // Valid once finished().
  TargetErrorOutcome outcome() const;

 private:
  TargetErrorTracker() = default;
  // Every pixel's luminance and its standard error's bound, for tile t's sums.
  absl::Status measure(int tile);
  // The sums over every pixel of Y and of its standard error's square, the pixel count, and
  // the dark pixels' scale (kTargetErrorDarkShare of the mean Y).
  struct ImageTotals {
    double y_sum = 0, se_squares = 0, floor = 0;
    std::size_t pixels = 0;
  };
  ImageTotals image_totals() const;

  job::TargetError target_;
  TilePlan plan_;
  std::vector<std::uint64_t> rounds_;
  int round_ = 0;
  bool finished_ = false;
  std::vector<bool> active_;
  std::vector<bool> added_;
  std::vector<std::optional<image::TileResult>> sums_;
  // Per tile, per pixel (row-major in its rect): Y and the bound on its standard error, and the
  // spp it ended with.
  std::vector<std::vector<double>> luminance_, error_;
  std::vector<std::uint64_t> tile_spp_;
  bool met_ = false;
};

}  // namespace prism::coordinator
