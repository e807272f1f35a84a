#include "coordinator/prepass_run.h"

#include <chrono>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::coordinator {
namespace {

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

absl::StatusOr<PrepassRun> PrepassRun::create(
    const PrepassParameters& params, int width, int height, int tile_size, int bins,
    spectral::WavelengthDistribution emitters,
    std::optional<spectral::WavelengthDistribution> sensor) {
  PRISM_RETURN_IF_ERROR(params.validate());
  if (emitters.cells() != bins || (sensor.has_value() && sensor->cells() != bins)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "prepass: the emitter mixture has ", emitters.cells(), " cells and the sensor term ",
        sensor.has_value() ? sensor->cells() : bins, "; want the job's ", bins, " bins"));
  }
  PrepassRun run;
  run.params_ = params;
  run.width_ = width;
  run.height_ = height;
  run.bins_ = bins;
  PRISM_ASSIGN_OR_RETURN(run.schedule_, prepass_schedule(params, width, height));
  for (const PrepassPass& pass : run.schedule_) {
    PRISM_ASSIGN_OR_RETURN(TilePlan plan,
                           plan_tiles({pass.width, pass.height, tile_size, pass.spp, 0}));
    run.plans_.push_back(std::move(plan));
  }
  run.emitters_ = std::move(emitters);
  run.sensor_ = std::move(sensor);
  return run;
}

const PrepassPass& PrepassRun::pass(int k) const {
  PRISM_CHECK(k >= 1 && k <= passes());
  return schedule_[static_cast<std::size_t>(k - 1)];
}

const TilePlan& PrepassRun::plan(int k) const {
  PRISM_CHECK(k >= 1 && k <= passes());
  return plans_[static_cast<std::size_t>(k - 1)];
}

absl::StatusOr<std::optional<std::string>> PrepassRun::tables_for_pass(
    int k, const image::TileRect& rect) const {
  if (k < 1 || k > passes()) {
    return absl::InvalidArgumentError(absl::StrCat("prepass ", k, " of ", passes()));
  }
  if (k == 1) return std::optional<std::string>();
  if (finished_ < k - 1 || !tables_.has_value()) {
    return absl::FailedPreconditionError(
        absl::StrCat("prepass ", k, " needs the tables of prepass ", k - 1));
  }
  const PrepassPass& p = pass(k);
  if (tables_->width() != p.width || tables_->height() != p.height) {
    return absl::FailedPreconditionError(
        absl::StrCat("prepass ", k, " is rendered after the tables moved on"));
  }
  PRISM_ASSIGN_OR_RETURN(std::string bytes, tables_->encode_tile(rect));
  return std::optional<std::string>(std::move(bytes));
}

absl::Status PrepassRun::add_tile(int k, const image::TileResult& merged) {
  if (k != finished_ + 1 || k > passes()) {
    return absl::FailedPreconditionError(
        absl::StrCat("a tile of prepass ", k, " while prepass ", finished_ + 1, " is assembled"));
  }
  const PrepassPass& p = pass(k);
  const TilePlan& tiles = plan(k);
  if (!estimate_.has_value()) {
    PRISM_ASSIGN_OR_RETURN(image::SpectralImage estimate,
                           image::SpectralImage::create(p.width, p.height, bins_));
    PRISM_ASSIGN_OR_RETURN(GuideImage guides, GuideImage::create(p.width, p.height));
    estimate_ = std::move(estimate);
    guides_ = std::move(guides);
    added_.assign(tiles.tiles.size(), false);
    added_count_ = 0;
  }
  std::size_t index = 0;
  while (index < tiles.tiles.size() && !(tiles.tiles[index] == merged.rect())) ++index;
  if (index == tiles.tiles.size()) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile ", image::to_string(merged.rect()), " is not a tile of prepass ", k));
  }
  if (merged.bins() != bins_ || !merged.has_guides()) {
    return absl::InvalidArgumentError(absl::StrCat("prepass ", k, " tile ",
                                                   image::to_string(merged.rect()),
                                                   ": want guides and ", bins_, " bins"));
  }
  if (added_[index]) return absl::OkStatus();
  PRISM_RETURN_IF_ERROR(guides_->add_tile(merged));
  PRISM_RETURN_IF_ERROR(image::paste_tile(image::finalise(merged), merged.rect(), *estimate_));
  added_[index] = true;
  ++added_count_;
  return absl::OkStatus();
}

absl::Status PrepassRun::finish_pass(int k) {
  if (k != finished_ + 1 || k > passes() || !estimate_.has_value() ||
      added_count_ != static_cast<int>(plan(k).tiles.size())) {
    return absl::FailedPreconditionError(
        absl::StrCat("prepass ", k, " cannot be finished: ", added_count_, " of its ",
                     k >= 1 && k <= passes() ? plan(k).tiles.size() : 0, " tiles are in"));
  }
  const auto start = std::chrono::steady_clock::now();
  const PixelTableImage* previous = tables_.has_value() ? &*tables_ : nullptr;
  PRISM_ASSIGN_OR_RETURN(
      image::SpectralImage filtered,
      filter_estimate(*estimate_, *guides_, params_.sigma_s, params_.sigma_r, previous));
  PRISM_ASSIGN_OR_RETURN(PixelTableImage tables,
                         build_tables(filtered, params_, *emitters_,
                                      sensor_.has_value() ? &*sensor_ : nullptr, previous));
  // Carry the tables to the film that samples them next: the next prepass's, else the job's.
  const int next_width = k < passes() ? pass(k + 1).width : width_;
  const int next_height = k < passes() ? pass(k + 1).height : height_;
  if (tables.width() != next_width || tables.height() != next_height) {
    PRISM_ASSIGN_OR_RETURN(tables, upsample_tables(tables, next_width, next_height));
  }
  tables_ = std::move(tables);
  estimate_.reset();
  guides_.reset();
  added_.clear();
  added_count_ = 0;
  finished_ = k;
  reconstruction_seconds_ += seconds_since(start);
  return absl::OkStatus();
}

absl::StatusOr<std::string> PrepassRun::final_tables(const image::TileRect& rect) const {
  if (!finished()) {
    return absl::FailedPreconditionError(absl::StrCat(
        "the final pass needs every prepass: ", finished_, " of ", passes(), " are finished"));
  }
  return tables_->encode_tile(rect);
}

double PrepassRun::fallback_fraction() const {
  return tables_.has_value() && finished() ? tables_->fallback_fraction() : 0.0;
}

}  // namespace prism::coordinator
