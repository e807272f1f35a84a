#include "coordinator/prepass_run.h"

#include <chrono>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"
#include "services/spectral/binned_shape.h"
#include "services/spectral/pixel_tables.h"

namespace prism::coordinator {
namespace {

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

VarianceModel prepass_variance_model(const job::RenderOptions& render) {
  return VarianceModel{job::kPrepassLanes, render.lanes(),
                       render.sampler == job::SamplerKind::kSobol};
}

absl::StatusOr<PrepassRun> PrepassRun::create(const job::PrepassParameters& params, int width,
                                              int height, int tile_size, int bins,
                                              const spectral::WavelengthDistribution& job_default,
                                              const spectral::WavelengthDistribution* sensor,
                                              const VarianceModel& model) {
  PRISM_RETURN_IF_ERROR(params.validate());
  if (sensor != nullptr && sensor->cells() != bins) {
    return absl::InvalidArgumentError(absl::StrCat("prepass: the sensor term has ", sensor->cells(),
                                                   " cells; want the job's ", bins, " bins"));
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
  PRISM_ASSIGN_OR_RETURN(spectral::BinnedShape shape,
                         spectral::BinnedShape::create(job_default, bins));
  run.default_masses_ = shape.bin_masses();
  run.default_cdf_ = spectral::WavelengthDistribution::from_table(run.default_masses_)->quantise();
  run.model_ = model;
  if (sensor != nullptr) {
    run.sensor_weights_.resize(std::size_t(bins));
    for (int b = 0; b < bins; ++b) run.sensor_weights_[b] = sensor->cell_mass(b) * bins;
  }
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
  if (stopped_early_) {
    return absl::FailedPreconditionError(
        absl::StrCat("prepass ", k, " is not rendered: the prepass stopped after pass 1"));
  }
  if (finished_ < k - 1 || !sampling_tables_.has_value()) {
    return absl::FailedPreconditionError(
        absl::StrCat("prepass ", k, " needs the tables of prepass ", k - 1));
  }
  const PrepassPass& p = pass(k);
  if (sampling_tables_->width() != p.width || sampling_tables_->height() != p.height) {
    return absl::FailedPreconditionError(
        absl::StrCat("prepass ", k, " is rendered after the tables moved on"));
  }
  PRISM_ASSIGN_OR_RETURN(std::string bytes, sampling_tables_->encode_tile(rect));
  return std::optional<std::string>(std::move(bytes));
}

absl::Status PrepassRun::add_tile(int k, const image::TileResult& merged) {
  if (k != finished_ + 1 || k > passes() || stopped_early_) {
    return absl::FailedPreconditionError(
        absl::StrCat("a tile of prepass ", k, " while prepass ", finished_ + 1, " is assembled"));
  }
  const PrepassPass& p = pass(k);
  const TilePlan& tiles = plan(k);
  if (added_.empty()) {
    // A new pass: the moments and guides carry over unless the film grew.
    if (!moments_.has_value() || moments_->width() != p.width || moments_->height() != p.height) {
      PRISM_ASSIGN_OR_RETURN(MomentImage moments, MomentImage::create(p.width, p.height, bins_));
      PRISM_ASSIGN_OR_RETURN(GuideImage guides, GuideImage::create(p.width, p.height));
      moments_ = std::move(moments);
      guides_ = std::move(guides);
    }
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
  // Pass k > 1 sampled with the default's quantised masses where pass k − 1 left a table.
  const PixelTableImage* sampled_with =
      k > 1 && sampling_tables_.has_value() ? &*sampling_tables_ : nullptr;
  PRISM_RETURN_IF_ERROR(guides_->add_tile(merged));
  PRISM_RETURN_IF_ERROR(
      moments_->add_tile(merged, sampled_with, default_masses_, model_.prepass_lanes));
  added_[index] = true;
  ++added_count_;
  return absl::OkStatus();
}

absl::Status PrepassRun::finish_pass(int k) {
  if (k != finished_ + 1 || k > passes() || stopped_early_ || !moments_.has_value() ||
      added_count_ != static_cast<int>(plan(k).tiles.size())) {
    return absl::FailedPreconditionError(
        absl::StrCat("prepass ", k, " cannot be finished: ", added_count_, " of its ",
                     k >= 1 && k <= passes() ? plan(k).tiles.size() : 0, " tiles are in"));
  }
  const auto start = std::chrono::steady_clock::now();
  const PixelTableImage* previous = tables_.has_value() ? &*tables_ : nullptr;
  PRISM_ASSIGN_OR_RETURN(PixelTableImage tables,
                         build_tables(moments_->moments(), *guides_, params_, default_masses_,
                                      sensor_weights_, model_, previous));
  // Go on (keep the tables) only when both estimates say so: the pixels' own (unbiased, but a few
  // large values dominate a small prepass) and the smoothed ones the choices were made with (far
  // less noisy, a little optimistic).
  const double decision = std::min(tables.predicted_gain(), tables.decision_gain());
  if (k == 1) first_pass_gain_ = decision;
  if (k == 1 && passes() > 1 && decision < params_.min_image_gain) {
    tables.reset_to_default();
    stopped_early_ = true;
  } else if (k == passes() && decision < params_.min_final_gain) {
    final_gain_ = decision;
    tables.reset_to_default();
    dropped_ = true;
  }
  // Carry the tables to the film that samples them next: the next prepass's, else the job's.
  const bool last = k == passes() || stopped_early_;
  const int next_width = last ? width_ : pass(k + 1).width;
  const int next_height = last ? height_ : pass(k + 1).height;
  if (tables.width() != next_width || tables.height() != next_height) {
    PRISM_ASSIGN_OR_RETURN(tables, upsample_tables(tables, next_width, next_height));
  }
  tables_ = std::move(tables);
  if (last) {
    sampling_tables_.reset();
  } else {
    sampling_tables_ = tables_->with_tables(default_cdf_);
  }
  added_.clear();
  added_count_ = 0;
  finished_ = k;
  if (last) {
    moments_.reset();
    guides_.reset();
  }
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

std::array<std::int64_t, kAlphaChoices> PrepassRun::alpha_histogram() const {
  return tables_.has_value() && finished() ? tables_->alpha_histogram()
                                           : std::array<std::int64_t, kAlphaChoices>{};
}

PrepassOutcome PrepassRun::outcome() const {
  PrepassOutcome o;
  o.passes_run = finished_;
  o.stopped_early = stopped_early_;
  o.first_pass_gain = first_pass_gain_;
  o.dropped = dropped_;
  o.predicted_gain = dropped_ ? final_gain_ : predicted_gain();
  o.fallback_fraction = fallback_fraction();
  for (int a = 0; a < kAlphaChoices; ++a) o.alpha_values[a] = alpha_choice(a, params_.epsilon);
  o.alpha_histogram = alpha_histogram();
  if (tables_.has_value() && finished()) o.shape_histogram = tables_->shape_histogram();
  o.reconstruction_seconds = reconstruction_seconds_;
  return o;
}

bool PrepassRun::final_pass_has_tables() const {
  return finished() && tables_.has_value() && tables_->count(PixelSource::kLearned) > 0;
}

double PrepassRun::predicted_gain() const {
  return tables_.has_value() && finished() ? tables_->predicted_gain() : 0.0;
}

}  // namespace prism::coordinator
