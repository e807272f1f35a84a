#include "coordinator/active_job.h"

#include "absl/strings/str_cat.h"
#include "coordinator/job_report.h"
#include "services/base/atomic_file.h"
#include "services/base/check.h"
#include "services/base/status.h"
#include "services/job/scene_spectra.h"

namespace prism::coordinator {

using SteadyClock = std::chrono::steady_clock;

absl::StatusOr<std::unique_ptr<ActiveJob>> ActiveJob::create(
    const job::JobParameters& params, const prism::v1::JobSpec& spec,
    const scene::SceneDescription& scene, const spectral::SpectrumLibrary& library,
    const spectral::ColorMatching& cmf) {
  std::unique_ptr<ActiveJob> job(new ActiveJob());
  job->cmf_ = &cmf;
  job->params = params;
  job->spec = spec;
  job->scene_features = reported_features(scene);
  job->film_filename = scene.film.filename;
  PRISM_ASSIGN_OR_RETURN(job->plan,
                         plan_tiles({params.width, params.height, params.tile_size, params.spp,
                                     params.samples_per_task, params.render.traces_light_paths()}));
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb, image::RgbImage::create(params.width, params.height));
  job->rgb = std::make_unique<image::RgbImage>(std::move(rgb));
  job->statistics =
      std::make_unique<BinStatisticsAccumulator>(job->plan.tiles.size(), params.render.bins);
  job->started = SteadyClock::now();
  if (params.render.integrator == job::IntegratorKind::kGradient) {
    PRISM_ASSIGN_OR_RETURN(
        PoissonSolver solver,
        PoissonSolver::create(params.render.bins, params.render.gradient_offset_bins,
                              params.gradient.alpha));
    job->finalise = reconstructing_finaliser(
        std::make_shared<const PoissonSolver>(std::move(solver)), params.gradient.norm);
  } else {
    job->finalise = mean_finaliser();
  }
  ActiveJob* raw = job.get();
  job->stage_first.push_back(0);
  if (params.prepass.has_value()) {
    PRISM_ASSIGN_OR_RETURN(
        job::PrepassDistributions distributions,
        job::prepass_distributions(scene, params.render, library, params.render.bins));
    PRISM_ASSIGN_OR_RETURN(
        PrepassRun run,
        PrepassRun::create(*params.prepass, params.width, params.height, params.tile_size,
                           params.render.bins, distributions.job_default,
                           distributions.sensor.has_value() ? &*distributions.sensor : nullptr,
                           prepass_variance_model(params.render)));
    job->prepass = std::move(run);
    for (int k = 1; k <= job->prepass->passes(); ++k) {
      // Called from add, which runs under the farm's mutex.
      auto on_prepass_tile = [raw, k](int, const image::TileResult& merged,
                                      const image::SpectralImage&) {
        return raw->prepass->add_tile(k, merged);
      };
      PRISM_ASSIGN_OR_RETURN(
          std::unique_ptr<TileAssembler> assembler,
          TileAssembler::create(job->prepass->plan(k), params.render.bins, on_prepass_tile));
      job->prepass_assemblers.push_back(std::move(assembler));
      job->stage_first.push_back(job->stage_first.back() +
                                 static_cast<int>(job->prepass->plan(k).tiles.size()));
    }
  }
  if (params.target_error.has_value()) {
    PRISM_ASSIGN_OR_RETURN(TargetErrorTracker tracker,
                           TargetErrorTracker::create(*params.target_error, job->plan, params.spp));
    job->target = std::move(tracker);
    std::uint64_t s0 = 0;
    for (std::uint64_t s1 : job->target->rounds()) {
      job->round_plans.push_back(plan_round(job->plan, s0, s1, params.samples_per_task));
      s0 = s1;
      // Called from add, which runs under the farm's mutex.
      auto on_round_tile = [raw](int tile, const image::TileResult& merged,
                                 const image::SpectralImage&) {
        return raw->target->add(tile, merged);
      };
      PRISM_ASSIGN_OR_RETURN(std::unique_ptr<TileAssembler> assembler,
                             TileAssembler::create(job->round_plans.back(), params.render.bins,
                                                   on_round_tile, mean_finaliser()));
      job->round_assemblers.push_back(std::move(assembler));
      job->stage_first.push_back(job->stage_first.back() +
                                 static_cast<int>(job->round_plans.back().task_count()));
    }
  } else {
    job->stage_first.push_back(job->stage_first.back() + static_cast<int>(job->plan.task_count()));
  }
  // Called from assembler->add, which runs under the farm's mutex.
  auto on_tile = [raw](int tile, const image::TileResult& merged,
                       const image::SpectralImage& finalised) -> absl::Status {
    PRISM_CHECK(raw->tiles != nullptr);
    std::vector<FinalResult>& ranges = raw->final_results[static_cast<std::size_t>(tile)];
    if (raw->plan.ranges.size() == 1 && ranges.size() == 1 && ranges[0].exact &&
        ranges[0].sha256.has_value()) {
      // The merged tile is that one result, whose bytes are in the result pack already.
      PRISM_RETURN_IF_ERROR(raw->tiles->put_link(tile, std::uint64_t(ranges[0].location.offset),
                                                 ranges[0].location.size, *ranges[0].sha256));
    } else {
      PRISM_RETURN_IF_ERROR(raw->tiles->put(tile, merged));
      // The ranges' bytes are now in the tile pack too.
      for (const FinalResult& range : ranges) raw->reclaimable.push_back(range.location);
    }
    ranges = {};
    return raw->absorb_tile(tile, merged, finalised);
  };
  job->final_results.resize(job->plan.tiles.size());
  PRISM_ASSIGN_OR_RETURN(
      job->assembler, TileAssembler::create(job->plan, params.render.bins, on_tile, job->finalise));
  return job;
}

int ActiveJob::stage_of(int task_index) const {
  int stage = 0;
  while (stage < final_stage() && task_index >= stage_first[static_cast<std::size_t>(stage + 1)]) {
    ++stage;
  }
  return stage;
}

int ActiveJob::tile_of(int task_index) const {
  const int stage = stage_of(task_index);
  const int local = task_index - stage_first[static_cast<std::size_t>(stage)];
  if (stage < first_final_stage()) return local;
  return local / static_cast<int>(stage_plan(stage).ranges.size());
}

std::pair<int, int> ActiveJob::tile_tasks(int stage, int tile) const {
  const int first = stage_first[static_cast<std::size_t>(stage)];
  if (stage < first_final_stage()) return {first + tile, first + tile + 1};
  const int ranges = static_cast<int>(stage_plan(stage).ranges.size());
  return {first + tile * ranges, first + (tile + 1) * ranges};
}

const TilePlan& ActiveJob::stage_plan(int stage) const {
  return target.has_value() ? round_plans[static_cast<std::size_t>(stage - first_final_stage())]
                            : plan;
}

std::vector<TaskSpec> ActiveJob::stage_specs(int stage) const {
  std::vector<TaskSpec> tasks;
  if (stage < first_final_stage()) {
    const int k = stage + 1;
    for (const image::TileRect& tile : prepass->plan(k).tiles) {
      tasks.push_back(TaskSpec{Pass::kPrepass, k, tile, {0, prepass->pass(k).spp}});
    }
    return tasks;
  }
  const TilePlan& stage_tiles = stage_plan(stage);
  tasks.reserve(stage_tiles.task_count());
  for (const image::TileRect& tile : stage_tiles.tiles) {
    for (const image::SampleRange& range : stage_tiles.ranges) {
      tasks.push_back(TaskSpec{Pass::kFinal, 0, tile, range});
    }
  }
  return tasks;
}

std::vector<TaskSpec> ActiveJob::task_specs() const {
  std::vector<TaskSpec> tasks;
  for (int stage = 0; stage <= final_stage(); ++stage) {
    std::vector<TaskSpec> part = stage_specs(stage);
    tasks.insert(tasks.end(), part.begin(), part.end());
  }
  return tasks;
}

ConvergencePoint ActiveJob::track_convergence(const image::TileResult& result, double seconds) {
  if (convergence == nullptr) {
    convergence = std::make_unique<ConvergenceTracker>(
        params.target_error.has_value() ? params.target_error->max_spp : params.spp);
  }
  return convergence->add(result, seconds);
}

store::TaskRecord ActiveJob::task_record(const std::vector<TaskSpec>& specs, int index) const {
  const TaskSpec& spec = specs[static_cast<std::size_t>(index)];
  store::TaskRecord task;
  task.index = index;
  task.pass = spec.pass == Pass::kPrepass ? store::TaskPass::kPrepass : store::TaskPass::kFinal;
  task.pass_index = spec.pass_index;
  task.tile_index = tile_of(index);
  task.rect = spec.tile;
  task.samples = spec.samples;
  return task;
}

absl::Status ActiveJob::finish_round() {
  const std::size_t round = static_cast<std::size_t>(stage - first_final_stage());
  PRISM_RETURN_IF_ERROR(round_assemblers[round]->check_complete());
  PRISM_ASSIGN_OR_RETURN(std::vector<int> done, target->finish_round());
  for (int tile : done) {
    const image::TileResult& merged = target->sum(tile);
    PRISM_ASSIGN_OR_RETURN(image::SpectralImage finalised, finalise(merged));
    if (!tiles->has(tile)) PRISM_RETURN_IF_ERROR(tiles->put(tile, merged));
    PRISM_RETURN_IF_ERROR(absorb_tile(tile, merged, finalised));
    target->release(tile);
  }
  return absl::OkStatus();
}

absl::Status ActiveJob::attach_tiles(const std::filesystem::path& dir) {
  PRISM_RETURN_IF_ERROR(base::make_directories(dir));
  PRISM_ASSIGN_OR_RETURN(results, ResultPack::open(dir.parent_path() / "results.pack"));
  PRISM_ASSIGN_OR_RETURN(FinishedTiles opened,
                         FinishedTiles::open(dir, plan, params.width, params.render.bins, results));
  tiles = std::make_shared<FinishedTiles>(std::move(opened));
  return absl::OkStatus();
}

void ActiveJob::note_final_result(int tile, const FinalResult& result) {
  if (target.has_value() || result.location.offset < 0) return;
  final_results[static_cast<std::size_t>(tile)].push_back(result);
}

absl::Status ActiveJob::absorb_tile(int tile, const image::TileResult& merged,
                                    const image::SpectralImage& finalised) {
  statistics->add_tile(static_cast<std::size_t>(tile), merged);
  PRISM_ASSIGN_OR_RETURN(
      image::RgbImage tile_colour,
      tile_rgb(merged, finalised, params.render.integrator == job::IntegratorKind::kGradient,
               *cmf_));
  PRISM_RETURN_IF_ERROR(rgb->paste(tile_colour, merged.rect().x0, merged.rect().y0));
  ++tiles_finalised;
  if (tile_done.size() < plan.tiles.size()) tile_done.resize(plan.tiles.size(), 0);
  tile_done[static_cast<std::size_t>(tile)] = 1;
  return absl::OkStatus();
}

}  // namespace prism::coordinator
