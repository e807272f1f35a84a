#include "coordinator/target_error.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"

namespace prism::coordinator {
namespace {

// Linear sRGB to luminance (the Y row of sRGB's RGB → XYZ matrix).
constexpr double kLuminance[3] = {0.2126729, 0.7151522, 0.0721750};

}  // namespace

std::vector<std::uint64_t> target_error_rounds(std::uint64_t first_spp, std::uint64_t max_spp) {
  std::vector<std::uint64_t> ends;
  std::uint64_t s = std::max<std::uint64_t>(1, first_spp);
  while (s < max_spp) {
    ends.push_back(s);
    s = s > max_spp / 2 ? max_spp : 2 * s;
  }
  ends.push_back(max_spp);
  return ends;
}

TilePlan plan_round(const TilePlan& plan, std::uint64_t s0, std::uint64_t s1,
                    std::uint64_t samples_per_task) {
  TilePlan out;
  out.tiles = plan.tiles;
  out.tiles_x = plan.tiles_x;
  out.tiles_y = plan.tiles_y;
  const std::uint64_t per_task = samples_per_task == 0 ? s1 - s0 : samples_per_task;
  for (std::uint64_t s = s0; s < s1; s += per_task) {
    out.ranges.push_back({s, std::min(s + per_task, s1)});
  }
  return out;
}

absl::StatusOr<TargetErrorTracker> TargetErrorTracker::create(const job::TargetError& target,
                                                              const TilePlan& plan,
                                                              std::uint64_t first_spp) {
  if (!job::target_error_in_range(target.relative)) {
    return absl::InvalidArgumentError(absl::StrCat("target error ", target.relative, " is outside ",
                                                   job::kMinTargetError, "..",
                                                   job::kMaxTargetError));
  }
  // Two samples at least, so that every pixel's standard error is estimated from the start.
  if (first_spp < 2) {
    return absl::InvalidArgumentError(
        absl::StrCat("a target error needs at least 2 spp in its first round, not ", first_spp));
  }
  if (target.max_spp < first_spp) {
    return absl::InvalidArgumentError(
        absl::StrCat("max spp ", target.max_spp, " is below the first round's ", first_spp));
  }
  if (plan.tiles.empty()) return absl::InvalidArgumentError("the plan has no tiles");
  TargetErrorTracker t;
  t.target_ = target;
  t.plan_ = plan;
  t.rounds_ = target_error_rounds(first_spp, target.max_spp);
  const std::size_t n = plan.tiles.size();
  t.active_.assign(n, true);
  t.added_.assign(n, false);
  t.sums_.resize(n);
  t.luminance_.resize(n);
  t.error_.resize(n);
  t.tile_spp_.assign(n, 0);
  return t;
}

image::SampleRange TargetErrorTracker::round_samples() const {
  const std::size_t r = static_cast<std::size_t>(round_);
  return {r == 0 ? 0 : rounds_[r - 1], rounds_[r]};
}

absl::Status TargetErrorTracker::add(int tile, const image::TileResult& merged) {
  if (tile < 0 || static_cast<std::size_t>(tile) >= active_.size()) {
    return absl::InvalidArgumentError(absl::StrCat("tile ", tile, " is not in the plan"));
  }
  const std::size_t t = static_cast<std::size_t>(tile);
  if (finished_ || !active_[t] || added_[t]) {
    return absl::FailedPreconditionError(
        absl::StrCat("tile ", tile, " takes no part in round ", round_ + 1, " or has it already"));
  }
  if (!(merged.samples() == round_samples()) || !(merged.rect() == plan_.tiles[t])) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile ", tile, "'s result is not round ", round_ + 1, "'s for its rect"));
  }
  if (!merged.has_rgb()) {
    return absl::FailedPreconditionError(
        absl::StrCat("tile ", tile, " has no RGB buffers to measure its error by"));
  }
  if (sums_[t].has_value()) {
    PRISM_RETURN_IF_ERROR(sums_[t]->add(merged));
  } else {
    sums_[t] = merged;
  }
  added_[t] = true;
  return measure(tile);
}

absl::Status TargetErrorTracker::measure(int tile) {
  const std::size_t t = static_cast<std::size_t>(tile);
  const image::TileResult& sum = *sums_[t];
  const std::span<const double> rgb = sum.rgb_sums();
  const std::span<const double> squares = sum.rgb_squares();
  const std::span<const std::uint64_t> counts = sum.counts();
  const std::size_t pixels = counts.size();
  luminance_[t].assign(pixels, 0.0);
  error_[t].assign(pixels, 0.0);
  for (std::size_t p = 0; p < pixels; ++p) {
    const double n = double(counts[p]);
    if (!(n > 0)) continue;
    double y = 0, se = 0;
    for (int c = 0; c < 3; ++c) {
      const double mean = rgb[p * 3 + c] / n;
      // One sample: nothing says how far it is from the mean, so nothing is met.
      const double variance = n >= 2 ? std::max(0.0, squares[p * 3 + c] / n - mean * mean) / (n - 1)
                                     : std::numeric_limits<double>::infinity();
      y += kLuminance[c] * mean;
      se += kLuminance[c] * std::sqrt(variance);
    }
    luminance_[t][p] = std::isfinite(y) ? y : 0.0;
    error_[t][p] = std::isnan(se) ? std::numeric_limits<double>::infinity() : se;
  }
  tile_spp_[t] = sum.samples().s1;
  return absl::OkStatus();
}

TargetErrorTracker::ImageTotals TargetErrorTracker::image_totals() const {
  // Over every pixel, tiles in plan order.
  ImageTotals totals;
  for (std::size_t t = 0; t < luminance_.size(); ++t) {
    for (std::size_t p = 0; p < luminance_[t].size(); ++p) {
      totals.y_sum += luminance_[t][p];
      totals.se_squares += error_[t][p] * error_[t][p];
    }
    totals.pixels += luminance_[t].size();
  }
  totals.floor =
      kTargetErrorDarkShare * totals.y_sum / double(std::max<std::size_t>(1, totals.pixels));
  return totals;
}

absl::StatusOr<std::vector<int>> TargetErrorTracker::finish_round() {
  if (finished_) return absl::FailedPreconditionError("every round has run");
  for (std::size_t t = 0; t < active_.size(); ++t) {
    if (active_[t] && !added_[t]) {
      return absl::FailedPreconditionError(
          absl::StrCat("tile ", t, " has not reported round ", round_ + 1));
    }
  }
  const ImageTotals totals = image_totals();
  const double y_sum = totals.y_sum, se_squares = totals.se_squares, floor = totals.floor;
  const bool last = static_cast<std::size_t>(round_) + 1 == rounds_.size();
  bool image_met = false;
  if (target_.image_scope) {
    const double image_error =
        y_sum > 0 ? std::sqrt(se_squares) / y_sum : (se_squares == 0 ? 0.0 : INFINITY);
    image_met = image_error <= target_.relative;
  }
  std::vector<int> done;
  bool all_met = true;
  for (std::size_t t = 0; t < active_.size(); ++t) {
    if (!active_[t]) continue;
    bool met = image_met;
    if (!target_.image_scope) {
      met = true;
      for (std::size_t p = 0; p < luminance_[t].size() && met; ++p) {
        const double scale = std::max(luminance_[t][p], floor);
        const double relative =
            scale > 0 ? error_[t][p] / scale : (error_[t][p] == 0 ? 0 : INFINITY);
        met = relative <= target_.relative;
      }
    }
    all_met = all_met && met;
    if (met || last) {
      active_[t] = false;
      done.push_back(static_cast<int>(t));
    }
    added_[t] = false;
  }
  ++round_;
  if (last || std::none_of(active_.begin(), active_.end(), [](bool a) { return a; })) {
    finished_ = true;
    met_ = all_met;
  }
  return done;
}

const image::TileResult& TargetErrorTracker::sum(int tile) const {
  return *sums_[static_cast<std::size_t>(tile)];
}

void TargetErrorTracker::release(int tile) {
  sums_[static_cast<std::size_t>(tile)].reset();
}

TargetErrorOutcome TargetErrorTracker::outcome() const {
  TargetErrorOutcome o;
  o.target = target_.relative;
  o.image_scope = target_.image_scope;
  o.met = met_;
  o.rounds = round_;
  o.rounds_planned = static_cast<int>(rounds_.size());
  const ImageTotals totals = image_totals();
  const double y_sum = totals.y_sum, se_squares = totals.se_squares, floor = totals.floor;
  const std::size_t pixels = totals.pixels;
  std::vector<double> relative;
  relative.reserve(pixels);
  o.min_spp = pixels > 0 ? std::numeric_limits<std::uint64_t>::max() : 0;
  double spp_sum = 0;
  for (std::size_t t = 0; t < luminance_.size(); ++t) {
    const std::uint64_t spp = tile_spp_[t];
    for (std::size_t p = 0; p < luminance_[t].size(); ++p) {
      const double scale = std::max(luminance_[t][p], floor);
      relative.push_back(scale > 0 ? error_[t][p] / scale : (error_[t][p] == 0 ? 0 : INFINITY));
      o.min_spp = std::min(o.min_spp, spp);
      o.max_spp = std::max(o.max_spp, spp);
      spp_sum += double(spp);
      o.samples += spp;
    }
  }
  o.mean_spp = pixels > 0 ? spp_sum / double(pixels) : 0.0;
  if (!relative.empty()) {
    double sum = 0;
    for (double r : relative) sum += r;
    o.pixel_mean = sum / double(relative.size());
    std::sort(relative.begin(), relative.end());
    o.pixel_max = relative.back();
    // The nearest-rank 99th percentile.
    const std::size_t rank = static_cast<std::size_t>(std::ceil(0.99 * double(relative.size())));
    o.pixel_p99 = relative[std::clamp<std::size_t>(rank, 1, relative.size()) - 1];
  }
  o.image_error = y_sum > 0 ? std::sqrt(se_squares) / y_sum : 0.0;
  return o;
}

}  // namespace prism::coordinator
