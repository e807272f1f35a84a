#include "coordinator/local_render.h"

#include <tbb/blocked_range.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include <chrono>
#include <condition_variable>
#include <limits>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "absl/strings/str_cat.h"
#include "coordinator/outputs.h"
#include "coordinator/resource_plan.h"
#include "coordinator/spectral_stream.h"
#include "coordinator/tile_merge.h"
#include "services/base/status.h"
#include "services/job/scene_spectra.h"
#include "services/spectral/pixel_tables.h"
#include "worker/tile_renderer.h"

namespace prism::coordinator {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Admission control before the scene is built or any image allocated.
absl::Status check_local_memory(const LocalRenderOptions& options, const TilePlan& plan,
                                int threads) {
  LocalRenderShape shape;
  shape.width = options.width;
  shape.height = options.height;
  shape.render = options.render;
  shape.prepass = options.prepass.has_value();
  shape.target_error = options.target_error.has_value();
  shape.keep_primal_and_gradients = options.keeps_primal_and_gradients();
  shape.threads = threads;
  shape.spooled = !options.spool_dir.empty();
  shape.tile_size = options.tile_size;
  for (const image::TileRect& tile : plan.tiles) {
    shape.largest_tile_area = std::max<std::uint64_t>(
        shape.largest_tile_area, std::uint64_t(tile.width()) * std::uint64_t(tile.height()));
  }
  MemoryBudget budget = machine_memory_budget();
  if (options.max_memory_bytes > 0) budget = {options.max_memory_bytes, "--max-memory", false};
  const std::string job = absl::StrCat("rendering ", options.width, "x", options.height, " with ",
                                       options.render.bins, " bins");
  const ResourcePlan resources = plan_local_render(shape);
  PRISM_RETURN_IF_ERROR(check_memory(
      job, resources, memory_in_use(budget.address_space), budget.bytes, budget.source,
      shape.spooled ? "use fewer --bins or a smaller --resolution"
                    : "use fewer --bins or a smaller --resolution, or --spool always (the bins "
                      "on disk instead of in memory)"));
  if (!shape.spooled) return absl::OkStatus();
  PRISM_ASSIGN_OR_RETURN(std::uint64_t free, free_disk_bytes(options.spool_dir));
  return check_disk(job, resources, free, absl::StrCat("free in ", options.spool_dir.string()),
                    "free some space there or write the outputs elsewhere (-o)");
}

}  // namespace

absl::StatusOr<std::unique_ptr<LocalRender>> LocalRender::create(
    worker::EmbreeDevice& device, const scene::SceneDescription& scene,
    const spectral::SpectrumLibrary& library, const LocalRenderOptions& options) {
  if (options.width < 1 || options.height < 1 || options.width > scene::kMaxResolution ||
      options.height > scene::kMaxResolution) {
    return absl::InvalidArgumentError(absl::StrCat("resolution ", options.width, "x",
                                                   options.height, " is outside 1..",
                                                   scene::kMaxResolution, " per side"));
  }
  if (options.spp < 1 || options.spp > std::numeric_limits<std::uint32_t>::max()) {
    return absl::InvalidArgumentError(absl::StrCat("spp ", options.spp, " is outside 1..",
                                                   std::numeric_limits<std::uint32_t>::max()));
  }
  if (!options.spool_dir.empty() && !options.can_spool()) {
    return absl::InvalidArgumentError(
        "a spooled render keeps no whole image: not with the primal and gradients, splatting or "
        "gathering");
  }
  if (options.threads < 0 || options.threads > job::kMaxThreads) {
    return absl::InvalidArgumentError(
        absl::StrCat("thread count ", options.threads, " is outside 0..", job::kMaxThreads));
  }
  if (options.target_error.has_value()) {
    if (options.target_error->max_spp > std::numeric_limits<std::uint32_t>::max()) {
      return absl::InvalidArgumentError(absl::StrCat("max spp ", options.target_error->max_spp,
                                                     " is outside 1..",
                                                     std::numeric_limits<std::uint32_t>::max()));
    }
    TilePlan one;
    one.tiles.push_back({0, 0, 1, 1});
    PRISM_RETURN_IF_ERROR(
        TargetErrorTracker::create(*options.target_error, one, options.spp).status());
  }
  std::unique_ptr<LocalRender> render(new LocalRender());
  render->options_ = options;
  // The variance-weighted reconstruction needs the workers' squares of G.
  render->options_.render.gradient_variances = options.poisson_norm == job::PoissonNorm::kWeighted;
  PRISM_ASSIGN_OR_RETURN(
      render->plan_, plan_tiles({options.width, options.height, options.tile_size, options.spp,
                                 options.samples_per_task, options.render.traces_light_paths()}));
  render->threads_ = options.threads > 0 ? options.threads : tbb::info::default_concurrency();
  PRISM_RETURN_IF_ERROR(check_local_memory(render->options_, render->plan_, render->threads_));
  const Clock::time_point start = Clock::now();
  PRISM_ASSIGN_OR_RETURN(
      render->scene_, worker::RenderScene::build(device, scene, library, render->options_.render,
                                                 options.width, options.height, options.geometry));
  if (options.render.traces_light_paths()) {
    PRISM_RETURN_IF_ERROR(worker::check_light_tracing(*render->scene_));
  }
  if (options.render.integrator == job::IntegratorKind::kGradient) {
    PRISM_ASSIGN_OR_RETURN(
        PoissonSolver solver,
        PoissonSolver::create(options.render.bins, options.render.gradient_offset_bins,
                              options.poisson_alpha));
    render->finaliser_ = reconstructing_finaliser(
        std::make_shared<const PoissonSolver>(std::move(solver)), options.poisson_norm);
  } else {
    render->finaliser_ = mean_finaliser();
  }
  if (options.prepass.has_value()) {
    PRISM_ASSIGN_OR_RETURN(job::PrepassDistributions distributions,
                           job::prepass_distributions(scene, render->options_.render, library,
                                                      render->options_.render.bins));
    PRISM_ASSIGN_OR_RETURN(
        PrepassRun run,
        PrepassRun::create(*options.prepass, options.width, options.height, options.tile_size,
                           render->options_.render.bins, distributions.job_default,
                           distributions.sensor.has_value() ? &*distributions.sensor : nullptr,
                           prepass_variance_model(render->options_.render)));
    // Image-scaled passes render the same camera on a smaller film.
    for (int k = 1; k <= run.passes(); ++k) {
      const PrepassPass& pass = run.pass(k);
      std::unique_ptr<worker::RenderScene> pass_scene;
      if (pass.width != options.width || pass.height != options.height) {
        PRISM_ASSIGN_OR_RETURN(
            pass_scene,
            worker::RenderScene::build(device, scene, library, render->options_.render, pass.width,
                                       pass.height, render->scene_->shared_geometry()));
      }
      render->pass_scenes_.push_back(std::move(pass_scene));
    }
    render->prepass_template_ = std::make_unique<PrepassRun>(std::move(run));
  }
  render->build_seconds_ = seconds_since(start);
  return render;
}

namespace {

// What run_stage needs to know about one stage (a prepass or the final pass).
struct Stage {
  const worker::RenderScene* scene = nullptr;
  const TilePlan* plan = nullptr;
  std::uint32_t pass = 0;
  bool prepass = false;
  // The tables of a tile in the wire layout, or nothing (the default distribution).
  std::function<absl::StatusOr<std::optional<std::string>>(const image::TileRect&)> tables;
  TileCallback on_tile;
  TileFinaliser finalise;
  // Where the stage's trace counters go (under StageShared::mutex): the report counts the final
  // pass's alone, like the farm.
  worker::TraceCounters* counters = nullptr;
};

struct StageShared {
  std::atomic<bool> stop{false};
  std::atomic<std::uint64_t> progress{0};
  std::mutex mutex;
  absl::Status first_error;
  int peak_tiles_in_flight = 0;

  void fail(absl::Status status) {
    std::lock_guard<std::mutex> lock(mutex);
    if (first_error.ok()) first_error = std::move(status);
    stop.store(true);
  }
};

// Renders every task of a stage in plan order (tile-major: a tile's ranges finish close together,
// which keeps the tiles in flight near the thread count) and assembles its tiles. Each body takes
// the next task from a counter, so tasks start in plan order whichever thread runs them (a
// SpectralStream relies on the rows of tiles finishing from the top), and renders it isolated:
// a thread waiting inside a tile's own parallel loop never picks up another task meanwhile.
// Errors go to shared.first_error.
void run_stage(const Stage& stage, int bins, tbb::task_arena& arena, StageShared& shared,
               const std::atomic<bool>* cancel) {
  absl::StatusOr<std::unique_ptr<TileAssembler>> assembler = TileAssembler::create(
      *stage.plan, bins, stage.on_tile, stage.finalise, TileAssembler::Arrivals::kExactlyOnce);
  if (!assembler.ok()) {
    shared.fail(assembler.status());
    return;
  }
  const TilePlan& plan = *stage.plan;
  const worker::TileRenderer renderer(*stage.scene);
  // Decoded tables per tile, made by the first of its tasks and dropped with the tile.
  std::vector<std::shared_ptr<const spectral::PixelTables>> tables(plan.tiles.size());
  std::mutex tables_mutex;
  auto tables_of = [&](std::size_t tile) -> absl::StatusOr<const spectral::PixelTables*> {
    if (!stage.tables) return nullptr;
    std::lock_guard<std::mutex> lock(tables_mutex);
    if (tables[tile] == nullptr) {
      const image::TileRect& rect = plan.tiles[tile];
      PRISM_ASSIGN_OR_RETURN(std::optional<std::string> bytes, stage.tables(rect));
      if (!bytes.has_value()) return nullptr;
      PRISM_ASSIGN_OR_RETURN(
          spectral::PixelTables decoded,
          spectral::PixelTables::decode(rect.width(), rect.height(), bins, *bytes));
      tables[tile] = std::make_shared<const spectral::PixelTables>(std::move(decoded));
    }
    return tables[tile].get();
  };
  std::atomic<std::size_t> next_task{0};
  arena.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, plan.task_count(), 1),
        [&](const tbb::blocked_range<std::size_t>& tasks) {
          for (std::size_t i = tasks.begin(); i != tasks.end(); ++i) {
            const std::size_t t = next_task++;
            if (shared.stop.load() || (cancel != nullptr && cancel->load())) return;
            const std::size_t tile = t / plan.ranges.size();
            const std::size_t range = t % plan.ranges.size();
            worker::RenderTask task;
            task.tile = plan.tiles[tile];
            task.samples = plan.ranges[range];
            task.pass = stage.pass;
            task.prepass = stage.prepass;
            task.early_stop = stage.prepass;
            task.want_guides = stage.prepass;
            absl::StatusOr<const spectral::PixelTables*> tile_tables = tables_of(tile);
            if (!tile_tables.ok()) {
              shared.fail(tile_tables.status());
              return;
            }
            task.tables = *tile_tables;
            worker::TileStats tile_stats;
            absl::StatusOr<image::TileResult> result = tbb::this_task_arena::isolate(
                [&] { return renderer.render(task, &tile_stats, &shared.stop, &shared.progress); });
            if (!result.ok()) {
              shared.fail(result.status());
              return;
            }
            {
              std::lock_guard<std::mutex> lock(shared.mutex);
              *stage.counters += tile_stats.counters;
            }
            absl::Status added = (*assembler)->add(static_cast<int>(tile), *std::move(result));
            if (!added.ok()) {
              shared.fail(added);
              return;
            }
            if (range + 1 == plan.ranges.size()) {
              std::lock_guard<std::mutex> lock(tables_mutex);
              tables[tile].reset();
            }
          }
        },
        tbb::simple_partitioner());
  });
  if (!shared.stop.load()) {
    absl::Status complete = (*assembler)->check_complete();
    if (!complete.ok()) shared.fail(complete);
  }
  std::lock_guard<std::mutex> lock(shared.mutex);
  shared.peak_tiles_in_flight =
      std::max(shared.peak_tiles_in_flight, (*assembler)->peak_tiles_in_flight());
}

}  // namespace

absl::StatusOr<LocalRenderResult> LocalRender::render(const std::atomic<bool>* cancel) const {
  const int bins = scene_->grid().bins();
  // Not held in memory: the final pass's bins are streamed into the spectral EXR as its tiles
  // finish (SpectralStream, made before the final pass) or, rendered to a target error (whose
  // tiles are final only when the last round ends), go to a spool file tile by tile. The
  // whole-image buffers other than the RGB are then 1x1 placeholders.
  const bool unheld = !options_.spool_dir.empty();
  std::shared_ptr<SpectralSpool> spool;
  std::shared_ptr<SpectralStream> stream;
  if (unheld && options_.target_error.has_value()) {
    PRISM_ASSIGN_OR_RETURN(spool, SpectralSpool::create(options_.spool_dir, plan_, options_.width,
                                                        options_.height, bins));
  }
  const int kept_width = unheld ? 1 : options_.width;
  const int kept_height = unheld ? 1 : options_.height;
  PRISM_ASSIGN_OR_RETURN(image::SpectralImage image,
                         image::SpectralImage::create(kept_width, kept_height, bins));
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb,
                         image::RgbImage::create(options_.width, options_.height));
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb_standard_error,
                         image::RgbImage::create(kept_width, kept_height));
  std::optional<image::SpectralImage> primal, gradient;
  std::optional<image::RgbImage> primal_rgb;
  const bool keep_raw = options_.keeps_primal_and_gradients();
  if (keep_raw) {
    PRISM_ASSIGN_OR_RETURN(primal_rgb, image::RgbImage::create(options_.width, options_.height));
    PRISM_ASSIGN_OR_RETURN(primal,
                           image::SpectralImage::create(options_.width, options_.height, bins));
    PRISM_ASSIGN_OR_RETURN(gradient,
                           image::SpectralImage::create(options_.width, options_.height, bins));
  }
  std::optional<image::SpectralImage> filtered;
  std::optional<image::RgbImage> filtered_rgb;
  // Gathering's full-image inputs, pasted tile by tile (gather.h).
  const bool gathers = options_.render.gathers();
  std::optional<GatherImages> gather_images;
  if (gathers) gather_images.emplace(options_.width, options_.height);
  if (options_.render.splats_differentials()) {
    PRISM_ASSIGN_OR_RETURN(filtered,
                           image::SpectralImage::create(options_.width, options_.height, bins));
    PRISM_ASSIGN_OR_RETURN(filtered_rgb, image::RgbImage::create(options_.width, options_.height));
  }
  BinStatisticsAccumulator statistics(plan_.tiles.size(), bins);
  std::optional<PrepassRun> prepass;
  if (prepass_template_ != nullptr) prepass.emplace(*prepass_template_);
  std::optional<PixelTableImage> prepass_tables;

  std::atomic<std::uint64_t> total = 0;
  const std::uint64_t final_samples = options_.spp * static_cast<std::uint64_t>(options_.width) *
                                      static_cast<std::uint64_t>(options_.height);
  if (prepass.has_value()) {
    for (int k = 1; k <= prepass->passes(); ++k) {
      const PrepassPass& pass = prepass->pass(k);
      total += std::uint64_t{pass.spp} * static_cast<std::uint64_t>(pass.width) *
               static_cast<std::uint64_t>(pass.height);
    }
  }
  total += final_samples;

  StageShared shared;
  // One monitor thread forwards an outside cancel into `stop` (which the renderer polls between
  // pixels) and reports progress, so the callback is never called from two threads at once.
  const Clock::time_point start = Clock::now();
  std::mutex monitor_mutex;
  std::condition_variable monitor_wake;
  bool finished = false;
  std::thread monitor([&] {
    Clock::time_point last_report = start;
    std::unique_lock<std::mutex> lock(monitor_mutex);
    while (!finished) {
      monitor_wake.wait_for(lock, std::chrono::milliseconds(50));
      if (cancel != nullptr && cancel->load()) shared.stop.store(true);
      if (options_.progress && !finished &&
          std::chrono::duration<double>(Clock::now() - last_report).count() >=
              options_.progress_interval_seconds) {
        last_report = Clock::now();
        options_.progress({shared.progress.load(), total.load(), seconds_since(start)});
      }
    }
  });

  tbb::task_arena arena(threads_);
  LocalRenderStats stats;
  worker::TraceCounters prepass_counters, final_counters;
  if (prepass.has_value()) {
    std::mutex prepass_mutex;
    for (int k = 1; k <= prepass->passes() && !shared.stop.load(); ++k) {
      Stage stage;
      stage.scene = pass_scenes_[static_cast<std::size_t>(k - 1)] != nullptr
                        ? pass_scenes_[static_cast<std::size_t>(k - 1)].get()
                        : scene_.get();
      stage.plan = &prepass->plan(k);
      stage.pass = static_cast<std::uint32_t>(k);
      stage.prepass = true;
      stage.tables = [&, k](const image::TileRect& rect) {
        std::lock_guard<std::mutex> lock(prepass_mutex);
        return prepass->tables_for_pass(k, rect);
      };
      stage.on_tile = [&, k](int, const image::TileResult& merged, const image::SpectralImage&) {
        std::lock_guard<std::mutex> lock(prepass_mutex);
        return prepass->add_tile(k, merged);
      };
      stage.finalise = mean_finaliser();
      stage.counters = &prepass_counters;
      run_stage(stage, bins, arena, shared, cancel);
      if (shared.stop.load()) break;
      absl::Status finished_pass = prepass->finish_pass(k);
      if (!finished_pass.ok()) shared.fail(finished_pass);
      if (prepass->finished()) break;
    }
    // Passes the prepass stopped before are never rendered: progress ends at what is.
    for (int k = prepass->passes_run() + 1; k <= prepass->passes(); ++k) {
      const PrepassPass& pass = prepass->pass(k);
      total.fetch_sub(std::uint64_t{pass.spp} * static_cast<std::uint64_t>(pass.width) *
                      static_cast<std::uint64_t>(pass.height));
    }
    stats.prepass_seconds = seconds_since(start);
    if (prepass->finished()) {
      stats.prepass = prepass->outcome();
      if (options_.keep_prepass_tables) prepass_tables = *prepass->tables();
    }
  }

  const Clock::time_point final_start = Clock::now();
  // A finished tile of the final pass: its statistics, RGB, standard errors and bins. Tiles are
  // disjoint and each statistics slot is the tile's own, so concurrent calls for different
  // tiles never touch the same memory.
  auto absorb = [&](int tile, const image::TileResult& merged,
                    const image::SpectralImage& finalised) -> absl::Status {
    statistics.add_tile(static_cast<std::size_t>(tile), merged);
    if (keep_raw) {
      const image::SpectralImage raw = image::finalise(merged);
      PRISM_RETURN_IF_ERROR(image::paste_tile(raw, merged.rect(), *primal));
      PRISM_ASSIGN_OR_RETURN(image::RgbImage raw_rgb, tile_rgb(merged, raw, false, scene_->cmf()));
      PRISM_RETURN_IF_ERROR(primal_rgb->paste(raw_rgb, merged.rect().x0, merged.rect().y0));
      PRISM_RETURN_IF_ERROR(
          image::paste_tile(image::finalise_gradients(merged), merged.rect(), *gradient));
    }
    if (gathers) PRISM_RETURN_IF_ERROR(gather_images->add_tile(merged));
    if (filtered.has_value()) {
      if (!merged.has_filtered()) {
        return absl::InternalError(absl::StrCat("tile ", image::to_string(merged.rect()),
                                                " came back without its filtered sums"));
      }
      PRISM_RETURN_IF_ERROR(
          image::paste_tile(image::finalise_filtered(merged), merged.rect(), *filtered));
      PRISM_ASSIGN_OR_RETURN(image::RgbImage tile_filtered, filtered_tile_rgb(merged));
      PRISM_RETURN_IF_ERROR(filtered_rgb->paste(tile_filtered, merged.rect().x0, merged.rect().y0));
    }
    PRISM_ASSIGN_OR_RETURN(
        image::RgbImage tile_colour,
        tile_rgb(merged, finalised, options_.render.integrator == job::IntegratorKind::kGradient,
                 scene_->cmf()));
    PRISM_RETURN_IF_ERROR(rgb.paste(tile_colour, merged.rect().x0, merged.rect().y0));
    if (spool != nullptr) return spool->put(tile, finalised);
    if (stream != nullptr) return stream->put(tile, finalised);
    PRISM_ASSIGN_OR_RETURN(image::RgbImage tile_error, tile_rgb_standard_error(merged));
    PRISM_RETURN_IF_ERROR(rgb_standard_error.paste(tile_error, merged.rect().x0, merged.rect().y0));
    return image::paste_tile(finalised, merged.rect(), image);
  };
  std::function<absl::StatusOr<std::optional<std::string>>(const image::TileRect&)> final_tables;
  if (prepass.has_value() && prepass->final_pass_has_tables()) {
    final_tables = [&](const image::TileRect& rect) -> absl::StatusOr<std::optional<std::string>> {
      PRISM_ASSIGN_OR_RETURN(std::string bytes, prepass->final_tables(rect));
      return std::optional<std::string>(std::move(bytes));
    };
  }
  std::size_t tasks_run = plan_.task_count();
  std::uint64_t samples_taken = final_samples;
  if (!shared.stop.load() && options_.target_error.has_value()) {
    // Rounds: each renders the tiles still short of the target over the round's samples; the
    // tracker sums them in round order and says which tiles are done.
    absl::StatusOr<TargetErrorTracker> tracker =
        TargetErrorTracker::create(*options_.target_error, plan_, options_.spp);
    if (!tracker.ok()) shared.fail(tracker.status());
    tasks_run = 0;
    std::mutex tracker_mutex;
    while (tracker.ok() && !tracker->finished() && !shared.stop.load()) {
      const image::SampleRange samples = tracker->round_samples();
      const TilePlan whole = plan_round(plan_, samples.s0, samples.s1, options_.samples_per_task);
      TilePlan round = whole;
      round.tiles.clear();
      std::vector<int> tile_of;
      for (std::size_t t = 0; t < whole.tiles.size(); ++t) {
        if (!tracker->active(static_cast<int>(t))) continue;
        round.tiles.push_back(whole.tiles[t]);
        tile_of.push_back(static_cast<int>(t));
      }
      // Round 1 is already in the total.
      if (tracker->round() > 0) {
        for (const image::TileRect& r : round.tiles)
          total += samples.count() * static_cast<std::uint64_t>(r.width() * r.height());
      }
      Stage stage;
      stage.scene = scene_.get();
      stage.plan = &round;
      stage.pass = 0;
      stage.tables = final_tables;
      stage.on_tile = [&](int i, const image::TileResult& merged,
                          const image::SpectralImage&) -> absl::Status {
        std::lock_guard<std::mutex> lock(tracker_mutex);
        return tracker->add(tile_of[static_cast<std::size_t>(i)], merged);
      };
      stage.finalise = mean_finaliser();
      stage.counters = &final_counters;
      run_stage(stage, bins, arena, shared, cancel);
      tasks_run += round.task_count();
      if (shared.stop.load()) break;
      absl::StatusOr<std::vector<int>> done = tracker->finish_round();
      if (!done.ok()) {
        shared.fail(done.status());
        break;
      }
      for (int t : *done) {
        const image::TileResult& merged = tracker->sum(t);
        absl::StatusOr<image::SpectralImage> finalised = finaliser_(merged);
        absl::Status absorbed = finalised.ok() ? absorb(t, merged, *finalised) : finalised.status();
        if (!absorbed.ok()) {
          shared.fail(absorbed);
          break;
        }
        tracker->release(t);
      }
    }
    if (tracker.ok() && tracker->finished()) {
      stats.target_error = tracker->outcome();
      samples_taken = stats.target_error->samples;
    }
  } else if (!shared.stop.load()) {
    if (unheld) {
      // The writer thread runs beside the render's threads; its tail (the last rows of tiles)
      // counts as rendering time, since the file is then complete but for its metadata.
      absl::StatusOr<std::unique_ptr<SpectralStream>> created = SpectralStream::create(
          options_.spool_dir, plan_, options_.width, options_.height, bins, rgb.data().data(),
          {options_.exr_compression, threads_}, [&shared] { return shared.stop.load(); });
      if (created.ok()) {
        stream = *std::move(created);
      } else {
        shared.fail(created.status());
      }
    }
    Stage stage;
    stage.scene = scene_.get();
    stage.plan = &plan_;
    stage.pass = 0;
    stage.tables = final_tables;
    stage.on_tile = absorb;
    stage.finalise = finaliser_;
    stage.counters = &final_counters;
    if (!shared.stop.load()) run_stage(stage, bins, arena, shared, cancel);
    if (stream != nullptr) {
      const absl::Status streamed = stream->finish();
      if (!streamed.ok()) shared.fail(streamed);
    }
  }
  const double render_seconds = seconds_since(final_start);
  {
    std::lock_guard<std::mutex> lock(monitor_mutex);
    finished = true;
  }
  monitor_wake.notify_all();
  monitor.join();

  if (cancel != nullptr && cancel->load()) return absl::CancelledError("the render was cancelled");
  if (!shared.first_error.ok()) return shared.first_error;
  if (options_.progress)
    options_.progress({shared.progress.load(), total.load(), seconds_since(start)});

  if (gathers) {
    GatherStats gathered;
    PRISM_ASSIGN_OR_RETURN(
        filtered,
        gather_filter(gather_images->inputs(image),
                      gather_width_at(options_.render.gather_width_nm, options_.spp), &gathered));
    PRISM_ASSIGN_OR_RETURN(filtered_rgb, to_linear_srgb(*filtered, scene_->cmf()));
    stats.gather = gathered;
  }
  stats.build_seconds = build_seconds_;
  stats.render_seconds = render_seconds;
  stats.samples = samples_taken;
  stats.counters = final_counters;
  stats.threads = threads_;
  stats.tasks = tasks_run;
  stats.tiles = static_cast<int>(plan_.tiles.size());
  stats.peak_tiles_in_flight = shared.peak_tiles_in_flight;
  LocalRenderResult result{std::move(image),
                           std::move(rgb),
                           std::move(rgb_standard_error),
                           std::move(primal),
                           std::move(gradient),
                           std::move(primal_rgb),
                           std::move(filtered),
                           std::move(filtered_rgb),
                           statistics.finish(),
                           stats,
                           std::move(prepass_tables),
                           std::move(spool),
                           std::move(stream)};
  return result;
}

}  // namespace prism::coordinator
