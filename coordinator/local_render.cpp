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
#include <thread>

#include "absl/strings/str_cat.h"
#include "coordinator/tile_merge.h"
#include "services/base/status.h"
#include "worker/tile_renderer.h"

namespace prism::coordinator {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

constexpr int kMaxThreads = 4096;

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
  if (options.threads < 0 || options.threads > kMaxThreads) {
    return absl::InvalidArgumentError(
        absl::StrCat("thread count ", options.threads, " is outside 0..", kMaxThreads));
  }
  std::unique_ptr<LocalRender> render(new LocalRender());
  render->options_ = options;
  PRISM_ASSIGN_OR_RETURN(render->plan_,
                         plan_tiles({options.width, options.height, options.tile_size, options.spp,
                                     options.samples_per_task}));
  render->threads_ = options.threads > 0 ? options.threads : tbb::info::default_concurrency();
  const Clock::time_point start = Clock::now();
  PRISM_ASSIGN_OR_RETURN(render->scene_,
                         worker::RenderScene::build(device, scene, library, options.render,
                                                    options.width, options.height));
  render->build_seconds_ = seconds_since(start);
  return render;
}

absl::StatusOr<LocalRenderResult> LocalRender::render(const std::atomic<bool>* cancel) const {
  const int bins = scene_->grid().bins();
  PRISM_ASSIGN_OR_RETURN(image::SpectralImage image,
                         image::SpectralImage::create(options_.width, options_.height, bins));
  BinStatisticsAccumulator statistics(plan_.tiles.size(), bins);
  // Tiles are disjoint and each statistics slot is the tile's own, so concurrent callbacks for
  // different tiles never touch the same memory.
  auto on_tile = [&](int tile, const image::TileResult& merged,
                     const image::SpectralImage& finalised) {
    statistics.add_tile(static_cast<std::size_t>(tile), merged);
    return image::paste_tile(finalised, merged.rect(), image);
  };
  PRISM_ASSIGN_OR_RETURN(std::unique_ptr<TileAssembler> assembler,
                         TileAssembler::create(plan_, bins, on_tile));

  const worker::TileRenderer renderer(*scene_);
  const std::uint64_t total = options_.spp * static_cast<std::uint64_t>(options_.width) *
                              static_cast<std::uint64_t>(options_.height);
  std::atomic<bool> stop{false};
  std::atomic<std::uint64_t> progress{0};
  std::mutex mutex;
  absl::Status first_error;
  worker::TraceCounters counters;
  auto fail = [&](absl::Status status) {
    std::lock_guard<std::mutex> lock(mutex);
    if (first_error.ok()) first_error = std::move(status);
    stop.store(true);
  };

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
      if (cancel != nullptr && cancel->load()) stop.store(true);
      if (options_.progress && !finished &&
          std::chrono::duration<double>(Clock::now() - last_report).count() >=
              options_.progress_interval_seconds) {
        last_report = Clock::now();
        options_.progress({progress.load(), total, seconds_since(start)});
      }
    }
  });

  tbb::task_arena arena(threads_);
  arena.execute([&] {
    // Tasks in plan order (tile-major), one per body: a tile's ranges finish close together,
    // which keeps the tiles in flight near the thread count.
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, plan_.task_count(), 1),
        [&](const tbb::blocked_range<std::size_t>& tasks) {
          for (std::size_t t = tasks.begin(); t != tasks.end(); ++t) {
            if (stop.load() || (cancel != nullptr && cancel->load())) return;
            const std::size_t tile = t / plan_.ranges.size();
            const std::size_t range = t % plan_.ranges.size();
            worker::RenderTask task;
            task.tile = plan_.tiles[tile];
            task.samples = plan_.ranges[range];
            worker::TileStats tile_stats;
            absl::StatusOr<image::TileResult> result =
                renderer.render(task, &tile_stats, &stop, &progress);
            if (!result.ok()) {
              fail(result.status());
              return;
            }
            {
              std::lock_guard<std::mutex> lock(mutex);
              counters += tile_stats.counters;
            }
            absl::Status added = assembler->add(static_cast<int>(tile), *std::move(result));
            if (!added.ok()) {
              fail(added);
              return;
            }
          }
        },
        tbb::simple_partitioner());
  });
  const double render_seconds = seconds_since(start);
  {
    std::lock_guard<std::mutex> lock(monitor_mutex);
    finished = true;
  }
  monitor_wake.notify_all();
  monitor.join();

  if (cancel != nullptr && cancel->load()) return absl::CancelledError("the render was cancelled");
  if (!first_error.ok()) return first_error;
  PRISM_RETURN_IF_ERROR(assembler->check_complete());
  if (options_.progress) options_.progress({progress.load(), total, render_seconds});

  LocalRenderStats stats;
  stats.build_seconds = build_seconds_;
  stats.render_seconds = render_seconds;
  stats.samples = total;
  stats.counters = counters;
  stats.threads = threads_;
  stats.tasks = plan_.task_count();
  stats.tiles = static_cast<int>(plan_.tiles.size());
  stats.peak_tiles_in_flight = assembler->peak_tiles_in_flight();
  return LocalRenderResult{std::move(image), statistics.finish(), stats};
}

}  // namespace prism::coordinator
