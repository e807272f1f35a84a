#include "coordinator/farm_coordinator.h"

#include <spdlog/sinks/null_sink.h>

#include <algorithm>
#include <cmath>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "coordinator/job_report.h"
#include "services/base/atomic_file.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/image/png.h"
#include "services/image/tile_codec.h"
#include "services/job/scene_spectra.h"
#include "services/scene/bundle.h"
#include "services/scene/scene_loader.h"

namespace prism::coordinator {
namespace {

namespace fs = std::filesystem;
using SteadyClock = std::chrono::steady_clock;

Millis unix_now() {
  return std::chrono::duration_cast<Millis>(std::chrono::system_clock::now().time_since_epoch());
}

store::TaskPass store_pass(Pass pass) {
  return pass == Pass::kPrepass ? store::TaskPass::kPrepass : store::TaskPass::kFinal;
}

absl::Status io_error(const std::string& what, const fs::path& path, const std::error_code& ec) {
  return absl::InternalError(absl::StrCat(what, " ", path.string(), ": ", ec.message()));
}

absl::Status make_dirs(const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return io_error("cannot create directory", dir, ec);
  return absl::OkStatus();
}

}  // namespace

FarmCoordinator::FarmCoordinator(FarmOptions options)
    : options_(std::move(options)),
      cmf_(spectral::ColorMatching::cie1931()),
      scheduler_(options_.scheduler) {}

absl::StatusOr<std::unique_ptr<FarmCoordinator>> FarmCoordinator::open(FarmOptions options) {
  if (options.data_dir.empty()) return absl::InvalidArgumentError("--data-dir is empty");
  if (!options.clock) options.clock = unix_now;
  if (options.logger == nullptr) {
    options.logger = std::make_shared<spdlog::logger>(
        "coordinator", std::make_shared<spdlog::sinks::null_sink_mt>());
  }
  if (options.tick_interval.count() <= 0) {
    return absl::InvalidArgumentError("the tick interval must be positive");
  }
  // A fresh lease prefix per incarnation: a worker reattaching with an old lease id can never
  // match a lease of this process.
  options.scheduler.lease_prefix = absl::StrCat("l", options.clock().count(), "-");
  std::unique_ptr<FarmCoordinator> farm(new FarmCoordinator(std::move(options)));
  PRISM_RETURN_IF_ERROR(farm->start());
  return farm;
}

absl::Status FarmCoordinator::start() {
  const fs::path& dir = options_.data_dir;
  for (const char* sub : {"blobs", "bundles", "jobs", "scenes", "outputs", "tmp"}) {
    PRISM_RETURN_IF_ERROR(make_dirs(dir / sub));
  }
  // Leftovers of an interrupted upload are never referenced.
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir / "tmp", ec))
    fs::remove_all(entry.path(), ec);

  PRISM_ASSIGN_OR_RETURN(library_, spectral::SpectrumLibrary::load_builtin());
  PRISM_ASSIGN_OR_RETURN(store::JobStore job_store, store::JobStore::open(dir / "jobs.sqlite"));
  store_.emplace(std::move(job_store));
  PRISM_ASSIGN_OR_RETURN(store::BlobStore blob_store, store::BlobStore::open(dir / "blobs"));
  blobs_.emplace(std::move(blob_store));

  {
    std::lock_guard<std::mutex> lock(mutex_);
    PRISM_ASSIGN_OR_RETURN(std::vector<store::JobRecord> resume, store_->jobs_to_resume());
    for (const store::JobRecord& record : resume) {
      absl::Status resumed = resume_locked(record);
      if (!resumed.ok()) {
        options_.logger->error("[job {}] cannot resume: {}", record.id, resumed.ToString());
        fail_job_locked(record.id,
                        absl::StrCat("cannot resume after a restart: ", resumed.message()));
      }
    }
    if (!resume.empty()) options_.logger->info("resumed {} unfinished jobs", resume.size());
    // A job that ended just before a crash may have left its tiles and results behind.
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir / "jobs", ec)) {
      const std::string id = entry.path().filename().string();
      absl::StatusOr<store::JobRecord> record = store_->get_job(id);
      if (record.ok() && store::is_terminal(record->state)) clean_up_locked(id);
    }
    process_events_locked();
  }
  ticker_ = std::thread([this] { tick_loop(); });
  return absl::OkStatus();
}

FarmCoordinator::~FarmCoordinator() {
  shutdown();
}

void FarmCoordinator::shutdown() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
    changed_locked();
  }
  if (ticker_.joinable()) ticker_.join();
}

void FarmCoordinator::tick_loop() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_) {
    changed_.wait_for(lock, options_.tick_interval);
    if (stopping_) break;
    scheduler_.tick(now());
    process_events_locked();
  }
}

void FarmCoordinator::changed_locked() {
  ++change_counter_;
  changed_.notify_all();
}

std::uint64_t FarmCoordinator::change_counter() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return change_counter_;
}

std::uint64_t FarmCoordinator::wait_for_change(std::uint64_t seen, Millis timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait_for(lock, timeout, [&] { return stopping_ || change_counter_ != seen; });
  return change_counter_;
}

fs::path FarmCoordinator::bundle_path(const std::string& hash) const {
  return options_.data_dir / "bundles" / hash;
}
fs::path FarmCoordinator::scene_dir(const std::string& hash) const {
  return options_.data_dir / "scenes" / hash;
}
fs::path FarmCoordinator::tiles_dir(const std::string& job_id) const {
  return options_.data_dir / "jobs" / job_id / "tiles";
}
fs::path FarmCoordinator::output_dir(const std::string& job_id) const {
  return options_.data_dir / "outputs" / job_id;
}

OutputPaths FarmCoordinator::output_paths_of(const std::string& job_id) const {
  const fs::path dir = output_dir(job_id);
  return OutputPaths{dir / (job_id + ".exr"),        dir / (job_id + ".rgb.exr"),
                     dir / (job_id + ".png"),        dir / (job_id + ".json"),
                     dir / (job_id + ".primal.exr"), dir / (job_id + ".gradient.exr")};
}

// ---- bundles ----

absl::StatusOr<std::string> FarmCoordinator::upload_bundle(const std::string& claimed_hash,
                                                           std::string_view bytes) {
  if (bytes.size() > options_.max_bundle_bytes) {
    return absl::ResourceExhaustedError(absl::StrCat("bundle of ", bytes.size(),
                                                     " bytes is over the limit of ",
                                                     options_.max_bundle_bytes, " bytes"));
  }
  scene::BundleLimits limits;
  limits.max_total_bytes = std::min(limits.max_total_bytes, options_.max_bundle_bytes);
  limits.max_file_bytes = std::min(limits.max_file_bytes, options_.max_bundle_bytes);
  PRISM_ASSIGN_OR_RETURN(scene::UnpackedBundle bundle, scene::unpack(bytes, limits));
  const std::string hash = bundle.content_hash;
  if (!claimed_hash.empty() && claimed_hash != hash) {
    return absl::InvalidArgumentError(absl::StrCat("bundle hash mismatch: the upload claims ",
                                                   claimed_hash, " but its content hash is ",
                                                   hash));
  }
  if (has_bundle(hash)) return hash;

  std::uint64_t serial = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    serial = ++temp_counter_;
  }
  const fs::path tmp = options_.data_dir / "tmp" / absl::StrCat("bundle-", serial, "-", hash);
  std::error_code ec;
  fs::remove_all(tmp, ec);
  absl::Status extracted = scene::extract_to(bundle, tmp);
  if (!extracted.ok()) {
    fs::remove_all(tmp, ec);
    return extracted;
  }
  // The upload checks that the scene is well formed; whether its unsupported features may be
  // substituted is each job's choice (JobSpec.allow_unsupported), checked at submit.
  scene::LoadOptions load = scene::with_library_names(library_);
  load.allow_unsupported = true;
  absl::StatusOr<scene::LoadedScene> loaded = scene::load_scene(tmp / bundle.scene_path, load);
  if (!loaded.ok()) {
    fs::remove_all(tmp, ec);
    options_.logger->info("refused bundle {}: {}", hash, loaded.status().ToString());
    if (loaded.status().code() == absl::StatusCode::kResourceExhausted) return loaded.status();
    return absl::InvalidArgumentError(
        absl::StrCat("the bundle's scene does not load: ", loaded.status().message()));
  }
  // Publish: the extracted scene, its scene path, then the packed bundle (has_bundle's marker).
  const fs::path dest = scene_dir(hash);
  if (!fs::exists(dest)) {
    fs::rename(tmp, dest, ec);
    if (ec && !fs::exists(dest)) return io_error("cannot move the extracted bundle to", dest, ec);
  }
  fs::remove_all(tmp, ec);
  const std::string scene_path = bundle.scene_path;
  PRISM_RETURN_IF_ERROR(
      base::write_file_atomic(bundle_path(hash) += ".scene", std::span<const char>(scene_path)));
  PRISM_RETURN_IF_ERROR(base::write_file_atomic(bundle_path(hash),
                                                std::span<const char>(bytes.data(), bytes.size())));
  options_.logger->info("stored bundle {} ({} bytes, scene {})", hash, bytes.size(), scene_path);
  return hash;
}

bool FarmCoordinator::has_bundle(const std::string& hash) const {
  if (!base::is_sha256_hex(hash)) return false;
  std::error_code ec;
  return fs::is_regular_file(bundle_path(hash), ec);
}

absl::StatusOr<std::string> FarmCoordinator::bundle_bytes(const std::string& hash) const {
  if (!has_bundle(hash)) {
    return absl::NotFoundError(absl::StrCat("no bundle ", hash, " on the coordinator"));
  }
  return base::read_file(bundle_path(hash));
}

// ---- jobs ----

int FarmCoordinator::stage_of(const ActiveJob& job, int task_index) {
  int stage = 0;
  while (stage < final_stage_of(job) &&
         task_index >= job.stage_first[static_cast<std::size_t>(stage + 1)]) {
    ++stage;
  }
  return stage;
}

int FarmCoordinator::tile_of(const ActiveJob& job, int task_index) {
  const int stage = stage_of(job, task_index);
  const int local = task_index - job.stage_first[static_cast<std::size_t>(stage)];
  if (stage < first_final_stage(job)) return local;
  const TilePlan& plan =
      job.target.has_value()
          ? job.round_plans[static_cast<std::size_t>(stage - first_final_stage(job))]
          : job.plan;
  return local / static_cast<int>(plan.ranges.size());
}

std::pair<int, int> FarmCoordinator::tile_tasks(const ActiveJob& job, int stage, int tile) {
  const int first = job.stage_first[static_cast<std::size_t>(stage)];
  if (stage < first_final_stage(job)) return {first + tile, first + tile + 1};
  const TilePlan& plan =
      job.target.has_value()
          ? job.round_plans[static_cast<std::size_t>(stage - first_final_stage(job))]
          : job.plan;
  const int ranges = static_cast<int>(plan.ranges.size());
  return {first + tile * ranges, first + (tile + 1) * ranges};
}

std::vector<TaskSpec> FarmCoordinator::stage_specs(const ActiveJob& job, int stage) const {
  std::vector<TaskSpec> tasks;
  if (stage < first_final_stage(job)) {
    const int k = stage + 1;
    for (const image::TileRect& tile : job.prepass->plan(k).tiles) {
      tasks.push_back(TaskSpec{Pass::kPrepass, k, tile, {0, job.prepass->pass(k).spp}});
    }
    return tasks;
  }
  const TilePlan& plan =
      job.target.has_value()
          ? job.round_plans[static_cast<std::size_t>(stage - first_final_stage(job))]
          : job.plan;
  tasks.reserve(plan.task_count());
  for (const image::TileRect& tile : plan.tiles) {
    for (const image::SampleRange& range : plan.ranges) {
      tasks.push_back(TaskSpec{Pass::kFinal, 0, tile, range});
    }
  }
  return tasks;
}

std::vector<TaskSpec> FarmCoordinator::task_specs(const ActiveJob& job) const {
  std::vector<TaskSpec> tasks;
  for (int stage = 0; stage <= final_stage_of(job); ++stage) {
    std::vector<TaskSpec> part = stage_specs(job, stage);
    tasks.insert(tasks.end(), part.begin(), part.end());
  }
  return tasks;
}

absl::StatusOr<scene::LoadedScene> FarmCoordinator::load_bundle_scene(
    bool allow_unsupported, const std::string& hash, const std::string& scene_path) const {
  scene::LoadOptions load = scene::with_library_names(library_);
  load.allow_unsupported = allow_unsupported;
  return scene::load_scene(scene_dir(hash) / scene_path, load);
}

absl::StatusOr<std::unique_ptr<FarmCoordinator::ActiveJob>> FarmCoordinator::make_active(
    const job::JobParameters& params, const prism::v1::JobSpec& spec,
    const scene::SceneDescription& scene) {
  auto job = std::make_unique<ActiveJob>();
  job->params = params;
  job->spec = spec;
  job->scene_features = reported_features(scene);
  PRISM_ASSIGN_OR_RETURN(job->plan, plan_tiles({params.width, params.height, params.tile_size,
                                                params.spp, params.samples_per_task}));
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
        job::prepass_distributions(scene, params.render, library_, params.render.bins));
    PRISM_ASSIGN_OR_RETURN(
        PrepassRun run,
        PrepassRun::create(*params.prepass, params.width, params.height, params.tile_size,
                           params.render.bins, distributions.job_default,
                           distributions.sensor.has_value() ? &*distributions.sensor : nullptr,
                           prepass_variance_model(params.render)));
    job->prepass = std::move(run);
    for (int k = 1; k <= job->prepass->passes(); ++k) {
      // Called from add, which runs under mutex_.
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
      // Called from add, which runs under mutex_.
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
  // Called from assembler->add, which runs under mutex_.
  auto on_tile = [this, raw](int tile, const image::TileResult& merged,
                             const image::SpectralImage& finalised) -> absl::Status {
    PRISM_CHECK(raw->tiles != nullptr);
    PRISM_RETURN_IF_ERROR(raw->tiles->put(tile, merged));
    return absorb_tile(*raw, tile, merged, finalised);
  };
  PRISM_ASSIGN_OR_RETURN(
      job->assembler, TileAssembler::create(job->plan, params.render.bins, on_tile, job->finalise));
  return job;
}

absl::Status FarmCoordinator::advance_locked(const std::string& job_id) {
  auto it = active_.find(job_id);
  if (it == active_.end()) {
    return absl::InternalError(absl::StrCat("job ", job_id, " finished but is not active"));
  }
  ActiveJob& job = *it->second;
  auto finalise = [&]() -> absl::Status {
    absl::Status finalised = finalise_locked(job_id);
    if (finalised.ok()) return finalised;
    return absl::Status(finalised.code(),
                        absl::StrCat("cannot write the outputs: ", finalised.message()));
  };
  if (job.target.has_value() && job.stage >= first_final_stage(job)) {
    if (!job.target->finished()) PRISM_RETURN_IF_ERROR(finish_round_locked(job));
    if (!job.target->finished()) {
      ++job.stage;
      return hand_round_locked(job, job_id);
    }
    // Done before its last planned round: the rounds left keep their task numbers, skipped.
    for (; job.stage < final_stage_of(job); ++job.stage) {
      const std::size_t next = static_cast<std::size_t>(job.stage + 1);
      PRISM_ASSIGN_OR_RETURN(int first,
                             scheduler_.add_tasks(job_id, stage_specs(job, job.stage + 1), true));
      if (first != job.stage_first[next]) {
        return absl::InternalError(absl::StrCat("job ", job_id, ": skipped round starts at task ",
                                                first, ", the plan says ", job.stage_first[next]));
      }
      PRISM_RETURN_IF_ERROR(
          store_->skip_tasks(job_id, job.stage_first[next], job.stage_first[next + 1]));
    }
    return finalise();
  }
  if (job.stage == final_stage_of(job)) return finalise();
  const int k = job.stage + 1;
  PRISM_RETURN_IF_ERROR(job.prepass_assemblers[static_cast<std::size_t>(k - 1)]->check_complete());
  PRISM_RETURN_IF_ERROR(job.prepass->finish_pass(k));
  ++job.stage;
  // A prepass that stopped early leaves its later passes unrendered: they keep their task
  // numbers, skipped, so the final pass's tasks are numbered as planned.
  for (; job.prepass->finished() && job.stage < first_final_stage(job); ++job.stage) {
    const std::size_t s = static_cast<std::size_t>(job.stage);
    PRISM_ASSIGN_OR_RETURN(int first,
                           scheduler_.add_tasks(job_id, stage_specs(job, job.stage), true));
    if (first != job.stage_first[s]) {
      return absl::InternalError(absl::StrCat("job ", job_id, ": skipped stage ", job.stage,
                                              " starts at task ", first, ", the plan says ",
                                              job.stage_first[s]));
    }
    PRISM_RETURN_IF_ERROR(store_->skip_tasks(job_id, job.stage_first[s], job.stage_first[s + 1]));
  }
  if (job.stage == first_final_stage(job)) {
    job.prepass_seconds = std::chrono::duration<double>(SteadyClock::now() - job.started).count();
    const PrepassOutcome o = job.prepass->outcome();
    options_.logger->info(
        "[job {}] prepass done after {} of {} passes{}: predicted gain {:.1f} %, {:.1f} % of "
        "pixels on the default distribution",
        job_id, o.passes_run, job.prepass->passes(), o.stopped_early ? " (stopped early)" : "",
        100.0 * (o.stopped_early ? o.first_pass_gain : o.predicted_gain),
        100.0 * o.fallback_fraction);
  }
  PRISM_ASSIGN_OR_RETURN(int first, scheduler_.add_tasks(job_id, stage_specs(job, job.stage)));
  if (first != job.stage_first[static_cast<std::size_t>(job.stage)]) {
    return absl::InternalError(absl::StrCat("job ", job_id, ": stage ", job.stage,
                                            " starts at task ", first, ", the plan says ",
                                            job.stage_first[static_cast<std::size_t>(job.stage)]));
  }
  return absl::OkStatus();
}

absl::Status FarmCoordinator::finish_round_locked(ActiveJob& job) {
  const std::size_t round = static_cast<std::size_t>(job.stage - first_final_stage(job));
  PRISM_RETURN_IF_ERROR(job.round_assemblers[round]->check_complete());
  PRISM_ASSIGN_OR_RETURN(std::vector<int> done, job.target->finish_round());
  for (int tile : done) {
    const image::TileResult& merged = job.target->sum(tile);
    PRISM_ASSIGN_OR_RETURN(image::SpectralImage finalised, job.finalise(merged));
    if (!job.tiles->has(tile)) PRISM_RETURN_IF_ERROR(job.tiles->put(tile, merged));
    PRISM_RETURN_IF_ERROR(absorb_tile(job, tile, merged, finalised));
    job.target->release(tile);
  }
  return absl::OkStatus();
}

absl::Status FarmCoordinator::hand_round_locked(ActiveJob& job, const std::string& job_id) {
  const int stage = job.stage;
  const std::size_t round = static_cast<std::size_t>(stage - first_final_stage(job));
  const std::vector<TaskSpec> specs = stage_specs(job, stage);
  const int per_tile = static_cast<int>(job.round_plans[round].ranges.size());
  for (std::size_t t = 0; t < job.round_plans[round].tiles.size(); ++t) {
    const int tile = static_cast<int>(t);
    const bool skipped = !job.target->active(tile);
    const auto [first, last] = tile_tasks(job, stage, tile);
    const std::vector<TaskSpec> part(specs.begin() + tile * per_tile,
                                     specs.begin() + (tile + 1) * per_tile);
    PRISM_ASSIGN_OR_RETURN(int added, scheduler_.add_tasks(job_id, part, skipped));
    if (added != first) {
      return absl::InternalError(absl::StrCat("job ", job_id, ": round ", round + 1, " tile ", tile,
                                              " starts at task ", added, ", the plan says ",
                                              first));
    }
    if (skipped) {
      PRISM_RETURN_IF_ERROR(store_->skip_tasks(job_id, first, last));
      PRISM_RETURN_IF_ERROR(job.round_assemblers[round]->mark_finished(tile));
    }
  }
  return absl::OkStatus();
}

absl::Status FarmCoordinator::attach_tiles(ActiveJob& job, const std::string& job_id) const {
  PRISM_ASSIGN_OR_RETURN(
      FinishedTiles tiles,
      FinishedTiles::open(tiles_dir(job_id), job.plan, job.params.width, job.params.render.bins));
  job.tiles = std::make_unique<FinishedTiles>(std::move(tiles));
  return absl::OkStatus();
}

absl::Status FarmCoordinator::absorb_tile(ActiveJob& job, int tile, const image::TileResult& merged,
                                          const image::SpectralImage& finalised) const {
  job.statistics->add_tile(static_cast<std::size_t>(tile), merged);
  PRISM_ASSIGN_OR_RETURN(
      image::RgbImage rgb,
      tile_rgb(merged, finalised, job.params.render.integrator == job::IntegratorKind::kGradient,
               cmf_));
  PRISM_RETURN_IF_ERROR(job.rgb->paste(rgb, merged.rect().x0, merged.rect().y0));
  ++job.tiles_finalised;
  return absl::OkStatus();
}

void FarmCoordinator::clean_up_locked(const std::string& job_id) {
  std::error_code ec;
  fs::remove_all(options_.data_dir / "jobs" / job_id, ec);
  if (ec) {
    options_.logger->warn("[job {}] cannot remove its tiles: {}", job_id, ec.message());
  }
  absl::StatusOr<std::vector<std::string>> unshared = store_->unshared_results(job_id);
  if (!unshared.ok()) {
    options_.logger->warn("[job {}] cannot list its results: {}", job_id,
                          unshared.status().ToString());
    return;
  }
  for (const std::string& hash : *unshared) {
    if (absl::Status removed = blobs_->remove(hash); !removed.ok()) {
      options_.logger->warn("[job {}] cannot delete result {}: {}", job_id, hash,
                            removed.ToString());
    }
  }
}

absl::StatusOr<JobStatus> FarmCoordinator::submit(const prism::v1::JobSpec& spec,
                                                  const std::string& client_token) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (!client_token.empty()) {
    absl::StatusOr<store::JobRecord> known = store_->find_by_client_token(client_token);
    if (known.ok()) return status_locked(*known);
    if (known.status().code() != absl::StatusCode::kNotFound) return known.status();
  }
  // Checked again after planning, which runs unlocked.
  auto check_queue = [this]() -> absl::Status {
    if (active_.size() < options_.max_queued_jobs) return absl::OkStatus();
    return absl::ResourceExhaustedError(absl::StrCat(
        "the coordinator already has ", active_.size(), " unfinished jobs (--max-queued-jobs ",
        options_.max_queued_jobs, "): try again later"));
  };
  PRISM_RETURN_IF_ERROR(check_queue());
  // Loading the scene and planning touch no shared state (the library is read-only once
  // started): other calls go on meanwhile.
  lock.unlock();
  if (!base::is_sha256_hex(spec.bundle_hash())) {
    return absl::InvalidArgumentError(absl::StrCat("bundle_hash '", spec.bundle_hash(),
                                                   "': want 64 lower case hex digits (SHA-256)"));
  }
  if (!has_bundle(spec.bundle_hash())) {
    return absl::FailedPreconditionError(
        absl::StrCat("bundle ", spec.bundle_hash(), " is not on the coordinator: upload it first"));
  }
  PRISM_ASSIGN_OR_RETURN(std::string bundle_scene,
                         base::read_file(bundle_path(spec.bundle_hash()) += ".scene", 1 << 16));
  if (spec.scene_path() != bundle_scene) {
    return absl::InvalidArgumentError(absl::StrCat(
        "scene_path '", spec.scene_path(), "' is not the bundle's scene '", bundle_scene, "'"));
  }
  scene::LoadOptions load = scene::with_library_names(library_);
  load.allow_unsupported = spec.allow_unsupported();
  PRISM_ASSIGN_OR_RETURN(scene::LoadedScene loaded,
                         scene::load_scene(scene_dir(spec.bundle_hash()) / bundle_scene, load));
  PRISM_ASSIGN_OR_RETURN(job::JobParameters params, job::job_parameters(spec, loaded.description));
  const prism::v1::JobSpec explicit_spec = to_proto(params);
  PRISM_ASSIGN_OR_RETURN(std::unique_ptr<ActiveJob> active,
                         make_active(params, explicit_spec, loaded.description));

  store::JobRecord record;
  record.client_token = client_token;
  record.spec = explicit_spec.SerializeAsString();
  record.bundle_hash = params.bundle_hash;
  record.submitted_ms = now().count();
  const std::vector<TaskSpec> specs = task_specs(*active);
  std::vector<store::TaskRecord> tasks(specs.size());
  for (std::size_t i = 0; i < specs.size(); ++i) {
    tasks[i].index = static_cast<int>(i);
    tasks[i].pass = store_pass(specs[i].pass);
    tasks[i].pass_index = specs[i].pass_index;
    tasks[i].tile_index = tile_of(*active, static_cast<int>(i));
    tasks[i].rect = specs[i].tile;
    tasks[i].samples = specs[i].samples;
  }
  lock.lock();
  PRISM_RETURN_IF_ERROR(check_queue());
  PRISM_ASSIGN_OR_RETURN(store::CreateJobResult created, store_->create_job(record, tasks));
  if (created.existed) return status_locked(created.job);
  const std::string id = created.job.id;
  if (absl::Status attached = attach_tiles(*active, id); !attached.ok()) {
    (void)store_->set_job_state(id, store::JobState::kFailed, now().count(),
                                absl::StrCat("cannot store its tiles: ", attached.message()));
    return attached;
  }
  // The first stage only: later stages need the tables their predecessor learns.
  PRISM_RETURN_IF_ERROR(scheduler_.add_job(id, stage_specs(*active, 0)));
  PRISM_ASSIGN_OR_RETURN(store::JobRecord rendering,
                         store_->set_job_state(id, store::JobState::kRendering, now().count()));
  active_[id] = std::move(active);
  options_.logger->info("[job {}] submitted: {}x{}, {} spp, {} bins, {}, {} tasks{}, bundle {}", id,
                        params.width, params.height, params.spp, params.render.bins,
                        job::name(params.render.integrator), specs.size(),
                        params.prepass.has_value() ? " (with a prepass)" : "", params.bundle_hash);
  process_events_locked();
  changed_locked();
  PRISM_ASSIGN_OR_RETURN(store::JobRecord now_record, store_->get_job(id));
  return status_locked(now_record);
}

absl::Status FarmCoordinator::resume_locked(const store::JobRecord& record) {
  prism::v1::JobSpec spec;
  if (!spec.ParseFromString(record.spec)) {
    return absl::DataLossError("the stored job spec does not parse");
  }
  // The stored spec is explicit, so the scene's defaults are not needed to decode it; a prepass
  // needs the scene's emitter spectra, and the report its features.
  PRISM_ASSIGN_OR_RETURN(job::JobParameters params,
                         job::job_parameters(spec, scene::SceneDescription{}));
  PRISM_ASSIGN_OR_RETURN(
      scene::LoadedScene loaded,
      load_bundle_scene(params.allow_unsupported, params.bundle_hash, params.scene_path));
  PRISM_ASSIGN_OR_RETURN(std::unique_ptr<ActiveJob> active,
                         make_active(params, spec, loaded.description));
  PRISM_ASSIGN_OR_RETURN(std::vector<store::TaskRecord> tasks, store_->tasks_of(record.id));
  const std::vector<TaskSpec> specs = task_specs(*active);
  if (tasks.size() != specs.size()) {
    return absl::DataLossError(
        absl::StrCat("the store has ", tasks.size(), " tasks but the plan has ", specs.size()));
  }
  for (const store::TaskRecord& task : tasks) {
    const TaskSpec& planned = specs[static_cast<std::size_t>(task.index)];
    if (!(task.rect == planned.tile) || !(task.samples == planned.samples)) {
      return absl::DataLossError(
          absl::StrCat("stored task ", task.index, " differs from the plan"));
    }
  }
  PRISM_RETURN_IF_ERROR(attach_tiles(*active, record.id));
  const int final_stage = final_stage_of(*active);
  const int first_final = first_final_stage(*active);
  const int stages = final_stage + 1;
  auto stage_done = [&](int stage) {
    for (int i = active->stage_first[stage]; i < active->stage_first[stage + 1]; ++i) {
      if (tasks[static_cast<std::size_t>(i)].state != store::TaskState::kDone) return false;
    }
    return true;
  };
  // Prepasses are replayed in order from their stored results (their reconstruction is a pure
  // function of them) up to the first that is not complete: that stage runs on.
  std::vector<int> done;
  int stage = 0;
  for (; stage < first_final; ++stage) {
    const bool complete = stage_done(stage);
    TileAssembler& assembler = *active->prepass_assemblers[static_cast<std::size_t>(stage)];
    for (int i = active->stage_first[stage]; i < active->stage_first[stage + 1]; ++i) {
      const store::TaskRecord& task = tasks[static_cast<std::size_t>(i)];
      if (task.state != store::TaskState::kDone) continue;
      PRISM_ASSIGN_OR_RETURN(std::string bytes, blobs_->get(task.result_hash));
      PRISM_ASSIGN_OR_RETURN(image::TileResult result, image::parse_tile(bytes));
      PRISM_RETURN_IF_ERROR(assembler.add(tile_of(*active, i), std::move(result)));
      done.push_back(i);
    }
    if (!complete) break;
    PRISM_RETURN_IF_ERROR(active->prepass->finish_pass(stage + 1));
    if (active->prepass->finished() && stage + 1 < first_final) {
      // It stopped early (a pure function of the results, so as before the restart): the later
      // passes are skipped.
      for (int skipped = stage + 1; skipped < first_final; ++skipped) {
        for (int i = active->stage_first[skipped]; i < active->stage_first[skipped + 1]; ++i) {
          done.push_back(i);
        }
        PRISM_RETURN_IF_ERROR(store_->skip_tasks(record.id, active->stage_first[skipped],
                                                 active->stage_first[skipped + 1]));
      }
      stage = first_final;
      break;
    }
  }
  if (stage == first_final && active->target.has_value()) {
    // Rounds are replayed in order from their stored results, as the prepasses: the tracker's
    // decisions are a pure function of them, so the same tiles go on as before the restart.
    // A tile that was done has its round's tasks skipped (again, if the restart came between
    // the decision and the skip).
    TargetErrorTracker& tracker = *active->target;
    for (; stage <= final_stage; ++stage) {
      const std::size_t round = static_cast<std::size_t>(stage - first_final);
      TileAssembler& assembler = *active->round_assemblers[round];
      bool complete = true;
      for (std::size_t t = 0; t < active->plan.tiles.size(); ++t) {
        const int tile = static_cast<int>(t);
        const auto [first, last] = tile_tasks(*active, stage, tile);
        if (!tracker.finished() && !tracker.active(tile)) {
          PRISM_RETURN_IF_ERROR(store_->skip_tasks(record.id, first, last));
          PRISM_RETURN_IF_ERROR(assembler.mark_finished(tile));
          for (int i = first; i < last; ++i) done.push_back(i);
          continue;
        }
        for (int i = first; i < last; ++i) {
          const store::TaskRecord& task = tasks[static_cast<std::size_t>(i)];
          if (task.state != store::TaskState::kDone) {
            complete = false;
            continue;
          }
          PRISM_ASSIGN_OR_RETURN(std::string bytes, blobs_->get(task.result_hash));
          PRISM_ASSIGN_OR_RETURN(image::TileResult result, image::parse_tile(bytes));
          PRISM_RETURN_IF_ERROR(assembler.add(tile, std::move(result)));
          done.push_back(i);
        }
      }
      if (!complete) break;
      active->stage = stage;
      PRISM_RETURN_IF_ERROR(finish_round_locked(*active));
      if (tracker.finished()) {
        for (int skipped = stage + 1; skipped <= final_stage; ++skipped) {
          for (int i = active->stage_first[skipped]; i < active->stage_first[skipped + 1]; ++i) {
            done.push_back(i);
          }
          PRISM_RETURN_IF_ERROR(store_->skip_tasks(record.id, active->stage_first[skipped],
                                                   active->stage_first[skipped + 1]));
        }
        stage = final_stage;
        break;
      }
    }
    stage = std::min(stage, final_stage);
  }
  active->stage = stage;
  if (stage == final_stage && !active->target.has_value()) {
    // Tiles finished before the restart come back from their files (their range results are
    // not merged again); a damaged file falls back to the range results, which are kept until
    // the job is over.
    std::vector<bool> restored(active->plan.tiles.size(), false);
    for (std::size_t t = 0; t < restored.size(); ++t) {
      const int tile = static_cast<int>(t);
      if (!active->tiles->has(tile)) continue;
      absl::StatusOr<image::TileResult> merged = active->tiles->get(tile);
      if (!merged.ok()) {
        options_.logger->warn("[job {}] {}; merging its results again", record.id,
                              merged.status().ToString());
        continue;
      }
      absl::StatusOr<image::SpectralImage> finalised = active->finalise(*merged);
      if (!finalised.ok()) {
        options_.logger->warn("[job {}] {}; merging its results again", record.id,
                              finalised.status().ToString());
        continue;
      }
      PRISM_RETURN_IF_ERROR(active->assembler->mark_finished(tile));
      PRISM_RETURN_IF_ERROR(absorb_tile(*active, tile, *merged, *finalised));
      restored[t] = true;
    }
    for (int i = active->stage_first[final_stage]; i < active->stage_first[stages]; ++i) {
      const store::TaskRecord& task = tasks[static_cast<std::size_t>(i)];
      if (task.state != store::TaskState::kDone) continue;
      const int tile = tile_of(*active, i);
      if (!restored[static_cast<std::size_t>(tile)]) {
        PRISM_ASSIGN_OR_RETURN(std::string bytes, blobs_->get(task.result_hash));
        PRISM_ASSIGN_OR_RETURN(image::TileResult result, image::parse_tile(bytes));
        PRISM_RETURN_IF_ERROR(active->assembler->add(tile, std::move(result)));
      }
      done.push_back(i);
    }
  }
  active->samples_at_start = record.progress.samples_done;
  const std::vector<TaskSpec> handed(specs.begin(), specs.begin() + active->stage_first[stage + 1]);
  PRISM_RETURN_IF_ERROR(scheduler_.add_job(record.id, handed, done));
  if (record.state == store::JobState::kQueued) {
    PRISM_RETURN_IF_ERROR(
        store_->set_job_state(record.id, store::JobState::kRendering, now().count()).status());
  }
  active_[record.id] = std::move(active);
  options_.logger->info("[job {}] resumed at stage {} of {}: {} of {} tasks already done",
                        record.id, stage + 1, stages, done.size(), specs.size());
  return absl::OkStatus();
}

JobStatus FarmCoordinator::status_locked(const store::JobRecord& record) const {
  JobStatus status;
  status.record = record;
  auto it = active_.find(record.id);
  if (it != active_.end()) {
    const ActiveJob& job = *it->second;
    status.tiles_finalised = job.tiles_finalised;
    status.tiles_total = static_cast<int>(job.plan.tiles.size());
    const double seconds = std::chrono::duration<double>(SteadyClock::now() - job.started).count();
    const std::uint64_t fresh = record.progress.samples_done >= job.samples_at_start
                                    ? record.progress.samples_done - job.samples_at_start
                                    : 0;
    if (seconds > 0 && fresh > 0) {
      status.samples_per_second = double(fresh) / seconds;
      status.eta_seconds = double(record.progress.samples_total - record.progress.samples_done) /
                           status.samples_per_second;
    }
  } else if (record.state == store::JobState::kDone) {
    prism::v1::JobSpec spec;
    if (spec.ParseFromString(record.spec)) {
      absl::StatusOr<job::JobParameters> params =
          job::job_parameters(spec, scene::SceneDescription{});
      if (params.ok()) {
        const int tile = params->tile_size;
        status.tiles_total =
            ((params->width + tile - 1) / tile) * ((params->height + tile - 1) / tile);
        status.tiles_finalised = status.tiles_total;
      }
    }
    status.eta_seconds = 0;
  }
  return status;
}

absl::StatusOr<JobStatus> FarmCoordinator::job(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
  return status_locked(record);
}

absl::StatusOr<prism::v1::JobSpec> FarmCoordinator::job_spec(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
  prism::v1::JobSpec spec;
  if (!spec.ParseFromString(record.spec)) {
    return absl::DataLossError(absl::StrCat("job ", job_id, ": the stored spec does not parse"));
  }
  return spec;
}

absl::StatusOr<std::vector<JobStatus>> FarmCoordinator::jobs(
    std::size_t limit, const std::vector<store::JobState>& states) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(std::vector<store::JobRecord> records, store_->list_jobs(limit, states));
  std::vector<JobStatus> out;
  out.reserve(records.size());
  for (const store::JobRecord& record : records) out.push_back(status_locked(record));
  return out;
}

absl::StatusOr<JobStatus> FarmCoordinator::cancel(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
  if (record.state == store::JobState::kCancelled) return status_locked(record);
  if (store::is_terminal(record.state)) {
    return absl::FailedPreconditionError(
        absl::StrCat("job ", job_id, " is already ", store::to_string(record.state)));
  }
  absl::Status cancelled = scheduler_.cancel_job(job_id);
  if (!cancelled.ok() && cancelled.code() != absl::StatusCode::kNotFound) return cancelled;
  PRISM_ASSIGN_OR_RETURN(record, store_->set_job_state(job_id, store::JobState::kCancelled,
                                                       now().count(), "cancelled by a client"));
  // The Scheduler keeps the cancelled job so that heartbeats listing its leases get CANCEL_TASK.
  active_.erase(job_id);
  clean_up_locked(job_id);
  options_.logger->info("[job {}] cancelled", job_id);
  changed_locked();
  return status_locked(record);
}

absl::StatusOr<std::vector<OutputFile>> FarmCoordinator::result_files(
    const std::string& job_id, const std::vector<OutputKind>& kinds) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
  if (record.state != store::JobState::kDone) {
    return absl::FailedPreconditionError(absl::StrCat("job ", job_id, " is ",
                                                      store::to_string(record.state),
                                                      ": its outputs exist once it is DONE"));
  }
  prism::v1::JobSpec spec;
  if (!spec.ParseFromString(record.spec)) {
    return absl::DataLossError(absl::StrCat("job ", job_id, ": the stored spec does not parse"));
  }
  PRISM_ASSIGN_OR_RETURN(job::JobParameters params,
                         job::job_parameters(spec, scene::SceneDescription{}));
  const OutputPaths paths = output_paths_of(job_id);
  std::vector<OutputFile> all;
  if (params.outputs.spectral_exr)
    all.push_back({OutputKind::kSpectralExr, paths.spectral_exr, ""});
  if (params.outputs.rgb_exr) all.push_back({OutputKind::kRgbExr, paths.rgb_exr, ""});
  if (params.outputs.png) all.push_back({OutputKind::kPng, paths.png, ""});
  all.push_back({OutputKind::kReportJson, paths.json, ""});
  if (params.outputs.primal_and_gradients) {
    all.push_back({OutputKind::kPrimalExr, paths.primal_exr, ""});
    all.push_back({OutputKind::kGradientExr, paths.gradient_exr, ""});
  }
  std::vector<OutputFile> out;
  for (OutputFile& file : all) {
    file.file_name = file.path.filename().string();
    if (kinds.empty() || std::find(kinds.begin(), kinds.end(), file.kind) != kinds.end()) {
      out.push_back(file);
    }
  }
  if (out.empty()) {
    return absl::NotFoundError(absl::StrCat("job ", job_id, " has none of the requested outputs"));
  }
  return out;
}

absl::StatusOr<std::string> FarmCoordinator::preview_png(const std::string& job_id,
                                                         float exposure_stops) {
  if (!std::isfinite(exposure_stops) || std::fabs(exposure_stops) > job::kMaxJobExposureStops) {
    return absl::InvalidArgumentError(
        absl::StrCat("exposure ", exposure_stops, " is out of range: want stops in -",
                     job::kMaxJobExposureStops, "..", job::kMaxJobExposureStops));
  }
  std::optional<image::RgbImage> rgb;
  std::uint64_t serial = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
    auto it = active_.find(job_id);
    if (it != active_.end()) {
      if (it->second->tiles_finalised == 0) {
        return absl::FailedPreconditionError(
            absl::StrCat("job ", job_id, " has no finished tile yet"));
      }
      rgb = *it->second->rgb;
    } else if (record.state != store::JobState::kDone) {
      return absl::FailedPreconditionError(absl::StrCat(
          "job ", job_id, " is ", store::to_string(record.state), ": it has no image"));
    }
    serial = ++temp_counter_;
  }
  if (!rgb.has_value()) {
    PRISM_ASSIGN_OR_RETURN(image::RgbExr exr, image::read_rgb_exr(output_paths_of(job_id).rgb_exr));
    rgb = std::move(exr.rgb);
  }
  const fs::path tmp = options_.data_dir / "tmp" / absl::StrCat("preview-", serial, ".png");
  PRISM_RETURN_IF_ERROR(image::write_png_preview(tmp, *rgb, exposure_stops));
  absl::StatusOr<std::string> bytes = base::read_file(tmp);
  std::error_code ec;
  fs::remove(tmp, ec);
  return bytes;
}

// ---- events and outputs ----

void FarmCoordinator::process_events_locked() {
  for (const SchedulerEvent& event : scheduler_.take_events()) {
    switch (event.kind) {
      case SchedulerEvent::Kind::kJobDone: {
        absl::Status advanced = advance_locked(event.job_id);
        if (!advanced.ok()) {
          options_.logger->error("[job {}] cannot go on: {}", event.job_id, advanced.ToString());
          fail_job_locked(event.job_id, std::string(advanced.message()));
        }
        break;
      }
      case SchedulerEvent::Kind::kJobFailed:
        options_.logger->warn("[job {}] failed: {}", event.job_id, event.message);
        fail_job_locked(event.job_id, event.message);
        break;
      case SchedulerEvent::Kind::kWorkerLost:
        options_.logger->warn("[worker {}] lost: {}", event.worker_id, event.message);
        break;
    }
    changed_locked();
  }
}

void FarmCoordinator::fail_job_locked(const std::string& job_id, const std::string& message) {
  absl::StatusOr<store::JobRecord> failed =
      store_->set_job_state(job_id, store::JobState::kFailed, now().count(), message);
  if (!failed.ok()) {
    options_.logger->error("[job {}] cannot record the failure: {}", job_id,
                           failed.status().ToString());
  }
  active_.erase(job_id);
  (void)scheduler_.cancel_job(job_id);
  clean_up_locked(job_id);
  changed_locked();
}

absl::Status FarmCoordinator::finalise_locked(const std::string& job_id) {
  auto it = active_.find(job_id);
  if (it == active_.end()) {
    return absl::InternalError(absl::StrCat("job ", job_id, " finished but is not active"));
  }
  ActiveJob& job = *it->second;
  if (job.target.has_value()) {
    if (!job.target->finished()) {
      return absl::InternalError(absl::StrCat("job ", job_id, " has rounds left to run"));
    }
  } else {
    PRISM_RETURN_IF_ERROR(job.assembler->check_complete());
  }
  PRISM_ASSIGN_OR_RETURN(
      store::JobRecord record,
      store_->set_job_state(job_id, store::JobState::kFinalising, now().count()));
  const job::JobParameters& p = job.params;
  RenderReport report;
  report.scene = p.scene_path;
  report.width = p.width;
  report.height = p.height;
  report.spp = p.spp;
  report.bins = p.render.bins;
  report.integrator = job::name(p.render.integrator);
  report.spectral_pdf = job::name(p.render.spectral_pdf);
  report.emitter_pdf = job::name(p.render.emitter_pdf);
  report.light_selection = job::name(p.render.light_selection);
  report.spectral_light_selection = p.render.spectral_light_selection;
  report.max_depth = p.render.max_depth;
  report.threads = 0;  // spread over the farm's workers
  report.tile_size = p.tile_size;
  report.seed = p.render.seed;
  report.wall_seconds = double(now().count() - record.submitted_ms) / 1000.0;
  report.render_seconds = job.render_seconds;
  report.samples =
      p.spp * static_cast<std::uint64_t>(p.width) * static_cast<std::uint64_t>(p.height);
  if (job.target.has_value()) {
    report.target_error = job.target->outcome();
    report.spp = report.target_error->max_spp;
    report.samples = report.target_error->samples;
  }
  report.rays = job.rays;
  report.peak_memory_bytes = peak_memory_bytes();
  report.statistics = job.statistics->finish();
  report.counters.assign(job.counters.begin(), job.counters.end());
  report.scene_features = job.scene_features;
  add_job_sections(p, report);
  if (report.gradient.has_value()) fill_gradient_counters(report.counters, *report.gradient);
  if (report.prepass.has_value()) {
    report.prepass->seconds = job.prepass_seconds;
    report.prepass->final_seconds =
        std::chrono::duration<double>(SteadyClock::now() - job.started).count() -
        job.prepass_seconds;
    report.prepass->outcome = job.prepass->outcome();
  }

  const OutputPaths paths = output_paths_of(job_id);
  PRISM_RETURN_IF_ERROR(make_dirs(output_dir(job_id)));
  std::vector<float> band;
  if (p.outputs.primal_and_gradients) {
    // The raw I and G with the R, G, B of their own values, made tile by tile from the files.
    PRISM_ASSIGN_OR_RETURN(image::RgbImage primal_rgb, image::RgbImage::create(p.width, p.height));
    PRISM_ASSIGN_OR_RETURN(image::RgbImage gradient_rgb,
                           image::RgbImage::create(p.width, p.height));
    for (std::size_t t = 0; t < job.plan.tiles.size(); ++t) {
      PRISM_ASSIGN_OR_RETURN(image::TileResult merged, job.tiles->get(static_cast<int>(t)));
      PRISM_ASSIGN_OR_RETURN(image::RgbImage a, to_linear_srgb(image::finalise(merged), cmf_));
      PRISM_ASSIGN_OR_RETURN(image::RgbImage b,
                             to_linear_srgb(image::finalise_gradients(merged), cmf_));
      PRISM_RETURN_IF_ERROR(primal_rgb.paste(a, merged.rect().x0, merged.rect().y0));
      PRISM_RETURN_IF_ERROR(gradient_rgb.paste(b, merged.rect().x0, merged.rect().y0));
    }
    std::vector<float> gradient_band;
    PRISM_RETURN_IF_ERROR(write_primal_and_gradient(
        p.render.bins, job.tiles->band_rows(), job.tiles->rows(mean_finaliser(), &band), primal_rgb,
        job.tiles->rows(
            [](const image::TileResult& merged) -> absl::StatusOr<image::SpectralImage> {
              return image::finalise_gradients(merged);
            },
            &gradient_band),
        gradient_rgb, report, paths));
  }
  PRISM_RETURN_IF_ERROR(write_outputs(p.render.bins, job.tiles->band_rows(),
                                      job.tiles->rows(job.finalise, &band), *job.rgb, report, paths,
                                      {p.outputs.png_exposure}));
  // write_outputs writes every kind; keep what the job asked for, the report, and the RGB EXR
  // (previews of a finished job are made from it; GetResult serves it only when asked for).
  std::error_code ec;
  if (!p.outputs.spectral_exr) fs::remove(paths.spectral_exr, ec);
  if (!p.outputs.png) fs::remove(paths.png, ec);
  PRISM_RETURN_IF_ERROR(store_->set_report(job_id, format_report_json(report, paths)));
  PRISM_RETURN_IF_ERROR(
      store_->set_job_state(job_id, store::JobState::kDone, now().count()).status());
  active_.erase(it);
  (void)scheduler_.remove_job(job_id);
  clean_up_locked(job_id);
  options_.logger->info("[job {}] done: wrote {}", job_id, paths.spectral_exr.string());
  return absl::OkStatus();
}

// ---- workers ----

absl::StatusOr<store::WorkerRecord> FarmCoordinator::register_worker(
    store::WorkerRecord record, const std::string& previous_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  record.id.clear();
  if (!previous_id.empty() && store_->get_worker(previous_id).ok()) record.id = previous_id;
  record.last_seen_ms = now().count();
  PRISM_ASSIGN_OR_RETURN(store::WorkerRecord stored, store_->register_worker(std::move(record)));
  scheduler_.register_worker(stored.id, stored.threads, now());
  options_.logger->info("[worker {}] registered: host {}, version {}, {} threads", stored.id,
                        stored.host, stored.version, stored.threads);
  changed_locked();
  return stored;
}

absl::StatusOr<std::optional<LeaseGrant>> FarmCoordinator::acquire(const std::string& worker_id,
                                                                   Millis wait) {
  const SteadyClock::time_point deadline = SteadyClock::now() + wait;
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_ && scheduler_.knows_worker(worker_id)) {
    std::optional<Lease> lease = scheduler_.acquire(worker_id, now());
    if (lease.has_value()) {
      auto it = active_.find(lease->task.job_id);
      if (it == active_.end()) {
        // Cannot happen: the Scheduler only serves running jobs, which are all active.
        (void)scheduler_.fail(worker_id, lease->id, FailureClass::kInfrastructure,
                              "the job is not active on the coordinator", now());
        continue;
      }
      absl::StatusOr<int> attempt = store_->record_attempt(lease->task.job_id, lease->task.index);
      if (!attempt.ok()) {
        options_.logger->warn("[job {}] cannot record an attempt: {}", lease->task.job_id,
                              attempt.status().ToString());
      }
      options_.logger->debug("[job {} task {}] leased to {} as {}", lease->task.job_id,
                             lease->task.index, worker_id, lease->id);
      ActiveJob& job = *it->second;
      LeaseGrant grant{*lease, job.spec, job.params.bundle_hash};
      if (job.prepass.has_value()) {
        const TaskSpec& spec = lease->task.spec;
        absl::StatusOr<std::optional<std::string>> tables = std::optional<std::string>();
        if (spec.pass == Pass::kPrepass) {
          const PrepassPass& pass = job.prepass->pass(spec.pass_index);
          tables = job.prepass->tables_for_pass(spec.pass_index, spec.tile);
          grant.want_guides = true;
          grant.early_stop = true;
          if (pass.width != job.params.width || pass.height != job.params.height) {
            grant.film_width = pass.width;
            grant.film_height = pass.height;
          }
        } else if (job.prepass->final_pass_has_tables()) {
          absl::StatusOr<std::string> final_tables = job.prepass->final_tables(spec.tile);
          if (final_tables.ok()) {
            tables = std::optional<std::string>(*std::move(final_tables));
          } else {
            tables = final_tables.status();
          }
        }
        if (!tables.ok()) {
          // Cannot happen: a stage's tasks are handed out only once its tables exist.
          (void)scheduler_.fail(worker_id, lease->id, FailureClass::kInfrastructure,
                                std::string(tables.status().message()), now());
          continue;
        }
        grant.pdf_table = *std::move(tables);
        grant.table_cells = job.prepass->table_cells();
      }
      changed_locked();
      return std::optional<LeaseGrant>(std::move(grant));
    }
    const SteadyClock::time_point current = SteadyClock::now();
    if (current >= deadline) break;
    // Woken by any change; the short cap also covers leases requeued by tick().
    changed_.wait_until(lock, std::min(deadline, current + Millis(100)));
  }
  return std::optional<LeaseGrant>();
}

HeartbeatReply FarmCoordinator::heartbeat(const std::string& worker_id,
                                          const std::vector<std::string>& lease_ids) {
  std::lock_guard<std::mutex> lock(mutex_);
  HeartbeatReply reply = scheduler_.heartbeat(worker_id, lease_ids, now());
  if (scheduler_.knows_worker(worker_id)) (void)store_->touch_worker(worker_id, now().count());
  process_events_locked();
  return reply;
}

absl::StatusOr<CompleteResult> FarmCoordinator::complete(
    const std::string& worker_id, const std::string& lease_id, std::string bytes,
    const std::string& sha256, double render_seconds, std::uint64_t rays,
    const std::vector<std::pair<std::string, std::uint64_t>>& counters) {
  // Parsing is the expensive part and needs no state.
  absl::StatusOr<image::TileResult> parsed = image::parse_tile(bytes);
  std::unique_lock<std::mutex> lock(mutex_);
  const std::optional<Lease> lease = scheduler_.lease(lease_id);
  if (lease.has_value() && lease->worker_id == worker_id) {
    auto it = active_.find(lease->task.job_id);
    std::string problem;
    if (!parsed.ok()) {
      problem = std::string(parsed.status().message());
    } else if (!(parsed->rect() == lease->task.spec.tile) ||
               !(parsed->samples() == lease->task.spec.samples)) {
      problem = "the result's tile or sample range is not the task's";
    } else if (it != active_.end() && parsed->bins() != it->second->params.render.bins) {
      problem = absl::StrCat("the result has ", parsed->bins(), " bins, the job ",
                             it->second->params.render.bins);
    } else if (it != active_.end()) {
      // The buffers the task's stage merges: a prepass needs guides, a gradient job's final
      // pass its gradients. Refused here as the worker's fault, before they could fail the job.
      const bool prepass = lease->task.spec.pass == Pass::kPrepass;
      const bool gradient = it->second->params.render.integrator == job::IntegratorKind::kGradient;
      if (prepass && !parsed->has_guides()) {
        problem = "a prepass result without guide buffers";
      } else if (!prepass && !parsed->has_rgb()) {
        problem = "a final-pass result without RGB buffers (the RGB outputs need them)";
      } else if (!prepass && gradient && !parsed->has_gradients()) {
        problem = "a gradient job's result without gradients";
      } else if (!prepass && gradient &&
                 it->second->params.render.gradient_variances != parsed->has_halves()) {
        problem = parsed->has_halves()
                      ? "a gradient job's result with halves its reconstruction does not use"
                      : "a variance-weighted gradient job's result without halves";
      }
    }
    if (!problem.empty()) {
      const std::string message = absl::StrCat("result for lease ", lease_id, ": ", problem);
      PRISM_RETURN_IF_ERROR(
          scheduler_.fail(worker_id, lease_id, FailureClass::kWorker, message, now()));
      process_events_locked();
      return absl::InvalidArgumentError(message);
    }
  }
  // Stale leases are refused by the Scheduler before anything is stored.
  std::optional<CompleteReply> reply;
  if (!lease.has_value() || lease->worker_id != worker_id) {
    reply = scheduler_.complete(worker_id, lease_id, sha256, now());
  } else {
    // Store the bytes first: a task is only marked done once its result is durable. The blob
    // store is thread-safe, so the (synced) write does not hold up other calls; a lease that
    // goes stale meanwhile leaves only an unreferenced blob.
    lock.unlock();
    absl::Status stored = blobs_->put_verified(sha256, bytes);
    lock.lock();
    PRISM_RETURN_IF_ERROR(stored);
    reply = scheduler_.complete(worker_id, lease_id, sha256, now());
  }
  switch (reply->outcome) {
    case CompleteOutcome::kStale:
      return absl::FailedPreconditionError(reply->reason);
    case CompleteOutcome::kDuplicate:
      return CompleteResult::kDuplicate;
    case CompleteOutcome::kAccepted:
      break;
  }
  PRISM_CHECK(reply->task.has_value());
  const Task& task = *reply->task;
  ++tasks_completed_[worker_id];
  absl::StatusOr<bool> marked = store_->mark_task_done(task.job_id, task.index, sha256);
  if (!marked.ok()) {
    fail_job_locked(task.job_id, absl::StrCat("cannot record task ", task.index, ": ",
                                              marked.status().message()));
    return marked.status();
  }
  auto it = active_.find(task.job_id);
  if (it != active_.end()) {
    ActiveJob& job = *it->second;
    job.render_seconds += render_seconds;
    job.rays += rays;
    const int stage = stage_of(job, task.index);
    const int tile = tile_of(job, task.index);
    const bool final_stage = stage >= first_final_stage(job);
    if (final_stage) {
      for (const auto& [name, value] : counters) job.counters[name] += value;
    }
    absl::Status added =
        !final_stage
            ? job.prepass_assemblers[static_cast<std::size_t>(stage)]->add(tile, *std::move(parsed))
        : job.target.has_value()
            ? job.round_assemblers[static_cast<std::size_t>(stage - first_final_stage(job))]->add(
                  tile, *std::move(parsed))
            : job.assembler->add(tile, *std::move(parsed));
    if (!added.ok()) {
      fail_job_locked(task.job_id,
                      absl::StrCat("merging task ", task.index, ": ", added.message()));
      return added;
    }
    options_.logger->debug("[job {} task {}] accepted from {}", task.job_id, task.index, worker_id);
  }
  process_events_locked();
  changed_locked();
  return CompleteResult::kAccepted;
}

absl::Status FarmCoordinator::fail(const std::string& worker_id, const std::string& lease_id,
                                   FailureClass failure_class, const std::string& message) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_RETURN_IF_ERROR(scheduler_.fail(worker_id, lease_id, failure_class, message, now()));
  options_.logger->info("[worker {}] lease {} failed ({}): {}", worker_id, lease_id,
                        to_string(failure_class), message);
  process_events_locked();
  changed_locked();
  return absl::OkStatus();
}

absl::StatusOr<std::vector<WorkerStatus>> FarmCoordinator::workers() {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(std::vector<store::WorkerRecord> records, store_->list_workers());
  std::map<std::string, WorkerInfo> live;
  for (const WorkerInfo& info : scheduler_.workers()) live[info.id] = info;
  std::vector<WorkerStatus> out;
  for (const store::WorkerRecord& record : records) {
    WorkerStatus status;
    status.record = record;
    status.last_seen_ms = record.last_seen_ms;
    auto it = live.find(record.id);
    if (it == live.end()) {
      status.state = "lost";
    } else {
      status.leases = it->second.leases;
      status.current = it->second.current;
      status.state = it->second.leases > 0 ? "busy" : "idle";
      status.last_seen_ms = it->second.last_seen.count();
    }
    auto done = tasks_completed_.find(record.id);
    if (done != tasks_completed_.end()) status.tasks_completed = done->second;
    out.push_back(std::move(status));
  }
  return out;
}

}  // namespace prism::coordinator
