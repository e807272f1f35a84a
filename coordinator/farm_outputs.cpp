// FarmCoordinator's outputs (farm_coordinator.h): a finished job's files written atomically from
// its finished tiles, the files a client fetches, and previews of a running job.
#include <algorithm>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "coordinator/farm_coordinator.h"
#include "coordinator/gather.h"
#include "coordinator/job_report.h"
#include "services/base/atomic_file.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/image/png.h"
#include "services/job/trace_counters.h"

namespace prism::coordinator {

namespace fs = std::filesystem;
using SteadyClock = std::chrono::steady_clock;

namespace {

// Whether a write failed for want of space (the libraries' messages carry strerror's text or
// SQLite's): worth trying again once space is freed, unlike a fault of the job.
bool out_of_space(const absl::Status& status) {
  const absl::string_view m = status.message();
  return absl::StrContains(m, "No space left on device") ||
         absl::StrContains(m, "Disk quota exceeded") ||
         absl::StrContains(m, "database or disk is full");
}

}  // namespace

fs::path FarmCoordinator::output_dir(const std::string& job_id) const {
  return options_.data_dir / "outputs" / job_id;
}

OutputPaths FarmCoordinator::output_paths_of(const std::string& job_id) const {
  const fs::path dir = output_dir(job_id);
  return OutputPaths{dir / (job_id + ".exr"),          dir / (job_id + ".rgb.exr"),
                     dir / (job_id + ".png"),          dir / (job_id + ".json"),
                     dir / (job_id + ".primal.exr"),   dir / (job_id + ".gradient.exr"),
                     dir / (job_id + ".filtered.exr"), dir / (job_id + ".filtered.png")};
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
  if (params.render.filters()) {
    all.push_back({OutputKind::kFilteredExr, paths.filtered_exr, ""});
    all.push_back({OutputKind::kFilteredPng, paths.filtered_png, ""});
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

absl::StatusOr<TileMapStatus> FarmCoordinator::tile_map(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
  TileMapStatus map;
  auto it = active_.find(job_id);
  if (it != active_.end()) {
    const ActiveJob& job = *it->second;
    map.width = job.params.width;
    map.height = job.params.height;
    map.tile_size = job.params.tile_size;
    map.tiles_x = job.plan.tiles_x;
    map.tiles_y = job.plan.tiles_y;
    map.states.assign(job.plan.tiles.size(), 'q');
    for (const WorkerInfo& worker : scheduler_.workers()) {
      for (const Lease& lease : worker.current) {
        if (lease.task.job_id != job_id ||
            job.stage_of(lease.task.index) < job.first_final_stage()) {
          continue;
        }
        const int tile = job.tile_of(lease.task.index);
        if (tile >= 0 && tile < int(map.states.size())) map.states[std::size_t(tile)] = 'l';
      }
    }
    for (std::size_t t = 0; t < job.tile_done.size() && t < map.states.size(); ++t) {
      if (job.tile_done[t]) map.states[t] = 'd';
    }
    return map;
  }
  // An ended job: its plan from the stored spec, its done tiles from the store.
  prism::v1::JobSpec spec;
  if (!spec.ParseFromString(record.spec)) {
    return absl::DataLossError(absl::StrCat("job ", job_id, ": the stored spec does not parse"));
  }
  PRISM_ASSIGN_OR_RETURN(job::JobParameters params,
                         job::job_parameters(spec, scene::SceneDescription{}));
  map.width = params.width;
  map.height = params.height;
  map.tile_size = params.tile_size;
  map.tiles_x = (params.width + params.tile_size - 1) / params.tile_size;
  map.tiles_y = (params.height + params.tile_size - 1) / params.tile_size;
  const char undone = record.state == store::JobState::kFailed      ? 'f'
                      : record.state == store::JobState::kCancelled ? 'c'
                                                                    : 'q';
  map.states.assign(std::size_t(map.tiles_x) * std::size_t(map.tiles_y),
                    record.state == store::JobState::kDone ? 'd' : undone);
  if (record.state != store::JobState::kDone) {
    PRISM_ASSIGN_OR_RETURN(std::vector<int> done, store_->done_final_tiles(job_id));
    for (int t : done) {
      if (t >= 0 && t < int(map.states.size())) map.states[std::size_t(t)] = 'd';
    }
  }
  return map;
}

absl::StatusOr<std::vector<ConvergencePoint>> FarmCoordinator::convergence(
    const std::string& job_id) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    PRISM_RETURN_IF_ERROR(store_->get_job(job_id).status());
    auto it = convergence_.find(job_id);
    if (it != convergence_.end()) return it->second;
  }
  // An older job's (or one from before a restart that is over): its file, read without the lock.
  return read_convergence(convergence_path(job_id));
}

fs::path FarmCoordinator::convergence_path(const std::string& job_id) const {
  return options_.data_dir / "convergence" / job_id;
}

void FarmCoordinator::open_convergence_locked(const std::string& job_id, ActiveJob& job) {
  std::vector<ConvergencePoint> points;
  absl::StatusOr<ConvergenceLog> log = ConvergenceLog::open(convergence_path(job_id), &points);
  if (!log.ok()) {
    // The plot is for people watching; the render goes on without it.
    options_.logger->warn("[job {}] {}; its convergence plot is kept in memory only", job_id,
                          log.status().ToString());
    return;
  }
  job.convergence_log = std::move(*log);
  if (!points.empty()) {
    job.convergence_seconds_at_start = points.back().seconds;
    convergence_[job_id] = std::move(points);
  }
}

void FarmCoordinator::record_convergence_locked(const std::string& job_id, ActiveJob& job,
                                                const ConvergencePoint& point) {
  append_point(convergence_[job_id], point);
  // Job ids grow: the smallest are the oldest. Running jobs stay; the rest are on disk.
  for (auto it = convergence_.begin();
       convergence_.size() > kConvergenceJobsInMemory && it != convergence_.end();) {
    it = active_.contains(it->first) ? std::next(it) : convergence_.erase(it);
  }
  if (!job.convergence_log.has_value()) return;
  if (absl::Status appended = job.convergence_log->append(point); !appended.ok()) {
    options_.logger->warn("[job {}] {}; its convergence plot is kept in memory only", job_id,
                          appended.ToString());
    job.convergence_log.reset();
  }
}

void FarmCoordinator::close_convergence_locked(const std::string& job_id) {
  auto active = active_.find(job_id);
  if (active != active_.end()) active->second->convergence_log.reset();
  auto it = convergence_.find(job_id);
  std::optional<std::vector<ConvergencePoint>> points;
  if (it != convergence_.end()) points = it->second;
  // The rewrite syncs a file: the janitor does it (clean_up_locked wakes it).
  std::lock_guard<std::mutex> lock(janitor_mutex_);
  janitor_series_.emplace_back(job_id, std::move(points));
}

void FarmCoordinator::finish_convergence(
    const std::string& job_id, std::optional<std::vector<ConvergencePoint>> points) const {
  const fs::path path = convergence_path(job_id);
  if (!points.has_value()) points = read_convergence(path);
  if (points->empty()) {
    std::error_code ec;
    fs::remove(path, ec);
    return;
  }
  if (absl::Status written = write_convergence(path, *points); !written.ok()) {
    options_.logger->warn("[job {}] {}", job_id, written.ToString());
  }
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
  report.light_caustics = p.render.light_caustics;
  report.caustic_paths = p.render.caustic_paths;
  report.max_depth = p.render.max_depth;
  // The workers that rendered the final pass, and their threads together.
  report.threads = 0;
  for (const auto& [id, share] : job.worker_shares) {
    RenderReport::WorkerShare w{id, "", 0, share.tasks, share.samples, share.seconds};
    if (absl::StatusOr<store::WorkerRecord> worker = store_->get_worker(id); worker.ok()) {
      w.host = worker->host;
      w.threads = worker->threads;
    }
    report.threads += w.threads;
    report.workers.push_back(std::move(w));
  }
  report.tile_size = p.tile_size;
  report.seed = p.render.seed;
  report.wall_seconds = double(now().count() - record.submitted_ms) / 1000.0;
  // The final pass's wall clock, as `prism render` reports it; the workers' summed seconds apart.
  report.render_seconds =
      job.final_begin.has_value() && job.final_end.has_value()
          ? std::chrono::duration<double>(*job.final_end - *job.final_begin).count()
          : 0.0;
  report.worker_seconds = job.render_seconds;
  report.resumed = job.resumed;
  report.farm = true;
  report.samples =
      p.spp * static_cast<std::uint64_t>(p.width) * static_cast<std::uint64_t>(p.height);
  if (job.target.has_value()) {
    report.target_error = job.target->outcome();
    report.spp = report.target_error->max_spp;
    report.samples = report.target_error->samples;
  }
  report.timed_samples = report.samples;
  if (job.resumed) {
    report.timed_samples = 0;
    for (const RenderReport::WorkerShare& w : report.workers) report.timed_samples += w.samples;
  }
  report.rays = job.rays;
  report.peak_memory_bytes = peak_memory_bytes();
  report.statistics = job.statistics->finish();
  // Every counter `prism render` reports, in its order, zeros included (the results carry only
  // the counters that moved); then any other the workers sent.
  report.counters.clear();
  for (std::string_view name : job::kTraceCounterNames) {
    auto found = job.counters.find(std::string(name));
    report.counters.emplace_back(name, found == job.counters.end() ? 0 : found->second);
  }
  for (const auto& [name, value] : job.counters) {
    if (std::none_of(report.counters.begin(), report.counters.end(),
                     [&](const auto& c) { return c.first == name; })) {
      report.counters.emplace_back(name, value);
    }
  }
  report.scene_features = job.scene_features;
  report.film_filename = job.film_filename;
  add_job_sections(p, report);
  if (report.gradient.has_value()) fill_gradient_counters(report.counters, *report.gradient);
  if (report.filtered.has_value()) fill_filtered_counters(report.counters, *report.filtered);
  if (report.prepass.has_value()) {
    report.prepass->seconds = job.prepass_seconds;
    report.prepass->final_seconds =
        std::chrono::duration<double>(SteadyClock::now() - job.started).count() -
        job.prepass_seconds;
    report.prepass->outcome = job.prepass->outcome();
  }

  finalising_.push_back({job_id, it->second, std::move(report), output_paths_of(job_id)});
  finaliser_wake_.notify_one();
  changed_locked();
  return absl::OkStatus();
}

absl::Status FarmCoordinator::write_job_outputs(const ActiveJob& job, RenderReport& report,
                                                const OutputPaths& paths) const {
  const job::JobParameters& p = job.params;
  auto output_options = [this](const job::JobParameters& params) {
    return OutputOptions{params.outputs.png_exposure,
                         {params.outputs.exr_compression, options_.output_threads}};
  };
  PRISM_RETURN_IF_ERROR(base::make_directories(paths.spectral_exr.parent_path()));
  std::vector<float> band;
  if (p.outputs.primal_and_gradients) {
    // The raw I with its samples' exact R, G, B and G with its bins' (outputs.h), made tile by
    // tile from the files.
    PRISM_ASSIGN_OR_RETURN(image::RgbImage primal_rgb, image::RgbImage::create(p.width, p.height));
    PRISM_ASSIGN_OR_RETURN(image::RgbImage gradient_rgb,
                           image::RgbImage::create(p.width, p.height));
    for (std::size_t t = 0; t < job.plan.tiles.size(); ++t) {
      PRISM_ASSIGN_OR_RETURN(image::TileResult merged, job.tiles->get(static_cast<int>(t)));
      PRISM_ASSIGN_OR_RETURN(image::RgbImage a,
                             tile_rgb(merged, image::finalise(merged), false, cmf_));
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
        gradient_rgb, report, paths, output_options(p)));
  }
  if (p.render.splats_differentials()) {
    // The filtered image, tile by tile from the files like the main one.
    PRISM_ASSIGN_OR_RETURN(image::RgbImage filtered_rgb,
                           image::RgbImage::create(p.width, p.height));
    for (std::size_t t = 0; t < job.plan.tiles.size(); ++t) {
      PRISM_ASSIGN_OR_RETURN(image::TileResult merged, job.tiles->get(static_cast<int>(t)));
      PRISM_ASSIGN_OR_RETURN(image::RgbImage tile, filtered_tile_rgb(merged));
      PRISM_RETURN_IF_ERROR(filtered_rgb.paste(tile, merged.rect().x0, merged.rect().y0));
    }
    std::vector<float> filtered_band;
    PRISM_RETURN_IF_ERROR(write_filtered(
        p.render.bins, job.tiles->band_rows(),
        job.tiles->rows(
            [](const image::TileResult& merged) -> absl::StatusOr<image::SpectralImage> {
              if (!merged.has_filtered()) {
                return absl::InternalError(absl::StrCat("tile ", image::to_string(merged.rect()),
                                                        " has no filtered sums"));
              }
              return image::finalise_filtered(merged);
            },
            &filtered_band),
        filtered_rgb, report, paths, output_options(p)));
  } else if (p.render.gathers()) {
    // Gathering filters the whole image at once: its bins, counts, offsets and guides, made
    // tile by tile from the files.
    PRISM_ASSIGN_OR_RETURN(image::SpectralImage whole,
                           image::SpectralImage::create(p.width, p.height, p.render.bins));
    GatherImages inputs(p.width, p.height);
    for (std::size_t t = 0; t < job.plan.tiles.size(); ++t) {
      PRISM_ASSIGN_OR_RETURN(image::TileResult merged, job.tiles->get(static_cast<int>(t)));
      PRISM_RETURN_IF_ERROR(inputs.add_tile(merged));
      PRISM_ASSIGN_OR_RETURN(image::SpectralImage finalised, job.finalise(merged));
      PRISM_RETURN_IF_ERROR(image::paste_tile(finalised, merged.rect(), whole));
    }
    GatherStats gathered;
    PRISM_ASSIGN_OR_RETURN(
        image::SpectralImage filtered,
        gather_filter(inputs.inputs(whole), gather_width_at(p.render.gather_width_nm, report.spp),
                      &gathered));
    PRISM_ASSIGN_OR_RETURN(image::RgbImage filtered_rgb, to_linear_srgb(filtered, cmf_));
    if (report.filtered.has_value()) {
      report.filtered->pixels_with_offsets = gathered.pixels_with_offsets;
      report.filtered->pixels_filtered = gathered.pixels_filtered;
      report.filtered->pixels_incoherent = gathered.pixels_incoherent;
    }
    PRISM_RETURN_IF_ERROR(write_filtered(filtered, filtered_rgb, report, paths, output_options(p)));
  }
  PRISM_RETURN_IF_ERROR(write_outputs(p.render.bins, job.tiles->band_rows(),
                                      job.tiles->rows(job.finalise, &band), *job.rgb, report, paths,
                                      output_options(p)));
  // write_outputs writes every kind; keep what the job asked for, the report, and the RGB EXR
  // (previews of a finished job are made from it; GetResult serves it only when asked for).
  std::error_code ec;
  if (!p.outputs.spectral_exr) fs::remove(paths.spectral_exr, ec);
  if (!p.outputs.png) fs::remove(paths.png, ec);
  return absl::OkStatus();
}

void FarmCoordinator::requeue_due_finalises_locked() {
  const SteadyClock::time_point now_steady = SteadyClock::now();
  for (auto it = finalise_retries_.begin(); it != finalise_retries_.end();) {
    if (!active_.contains(it->first)) {  // cancelled meanwhile
      it = finalise_retries_.erase(it);
    } else if (it->second.due <= now_steady) {
      // The entry stays (for the job's status and the next delay) until the write ends.
      it->second.due = SteadyClock::time_point::max();
      finalising_.push_back(it->second.item);
      finaliser_wake_.notify_one();
      ++it;
    } else {
      ++it;
    }
  }
}

void FarmCoordinator::finaliser_loop() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    finaliser_wake_.wait(lock, [this] { return stopping_ || !finalising_.empty(); });
    // Jobs still queued stay FINALISING in the store: a restart finalises them again.
    if (stopping_) return;
    Finalising item = std::move(finalising_.front());
    finalising_.pop_front();
    lock.unlock();
    if (options_.before_write_outputs) options_.before_write_outputs();
    absl::Status written = options_.disk_fault ? options_.disk_fault("outputs") : absl::OkStatus();
    if (written.ok()) written = write_job_outputs(*item.job, item.report, item.paths);
    lock.lock();
    finish_finalise_locked(item, written);
  }
}

void FarmCoordinator::finish_finalise_locked(Finalising& item, const absl::Status& written) {
  const std::string job_id = item.job_id;  // a copy: `item` may be moved into a retry
  absl::StatusOr<store::JobRecord> record = store_->get_job(job_id);
  if (!record.ok() || record->state != store::JobState::kFinalising) {
    // Cancelled (or failed) while its outputs were written: they go too.
    std::error_code ec;
    fs::remove_all(output_dir(job_id), ec);
    return;
  }
  absl::Status done = written;
  if (done.ok()) done = store_->set_report(job_id, format_report_json(item.report, item.paths));
  if (done.ok()) {
    done = store_->set_job_state(job_id, store::JobState::kDone, now().count()).status();
  }
  if (!done.ok() && out_of_space(done)) {
    // Nothing is lost yet: the finished tiles stay, and the outputs are written again later
    // (failing the job deleted them, so a full disk lost jobs that had rendered).
    std::error_code ec;
    fs::remove_all(output_dir(job_id), ec);
    auto previous = finalise_retries_.find(job_id);
    const Millis delay =
        previous == finalise_retries_.end()
            ? options_.finalise_retry_delay
            : std::min(Millis(300'000), Millis(previous->second.delay.count() * 2));
    options_.logger->warn("[job {}] cannot write its outputs: {}; trying again in {} s", job_id,
                          done.ToString(), delay.count() / 1000.0);
    finalise_retries_[job_id] = {std::move(item), SteadyClock::now() + delay, delay,
                                 std::string(done.message())};
    changed_locked();
    return;
  }
  finalise_retries_.erase(job_id);
  if (!done.ok()) {
    options_.logger->error("[job {}] cannot write its outputs: {}", job_id, done.ToString());
    std::error_code ec;
    fs::remove_all(output_dir(job_id), ec);
    fail_job_locked(job_id, absl::StrCat("cannot write the outputs: ", done.message()));
    return;
  }
  active_.erase(job_id);
  (void)scheduler_.remove_job(job_id);
  clean_up_locked(job_id);
  options_.logger->info("[job {}] done: wrote {}", job_id, item.paths.spectral_exr.string());
  changed_locked();
}

}  // namespace prism::coordinator
