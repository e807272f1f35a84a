// Renders one task (tile rect x sample range) into a TileResult, on a TBB thread pool. (A
// light-tracing job's task is the whole image and a range of light-path batches instead; see
// render_light.) Pixels
// are independent and every random number is a pure function of (seed, pass, pixel, sample,
// dimension), and each pixel's samples are accumulated in index order into doubles, so the
// result's bytes are identical for any thread count, tile size or task split. With the
// `gradient` integrator the result also carries the gradients buffer (per pixel, the sums of the
// G[b] estimates, added in sample order like the primal sums), except for prepass tasks, which
// the hero path tracer renders whatever the job's integrator.
#pragma once

#include <tbb/combinable.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <optional>

#include "absl/status/statusor.h"
#include "services/image/tile.h"
#include "services/spectral/pixel_tables.h"
#include "worker/gradient/integrator.h"
#include "worker/integrator.h"
#include "worker/light_tracer.h"
#include "worker/render_scene.h"

namespace prism::worker {

struct BatchImage;    // light_task.cpp
struct FilteredSums;  // differential_splat.h

struct RenderTask {
  image::TileRect tile;
  image::SampleRange samples;
  std::uint32_t pass = 0;  // 0: the final pass; k: prepass k (its own sample streams)
  bool want_guides = false;
  // A prepass task (docs/estimators.md §4): traced by the hero path tracer (C = 4 lanes) whatever
  // the job's integrator, and with `early_stop` paths that have met no wavelength-dependent event
  // after 3 bounces stop (they only shape a pdf).
  bool prepass = false;
  bool early_stop = false;
  // The tile's per-pixel wavelength tables (tile-local pixels, the tile's size), or null: every
  // pixel samples the scene's default distribution. Pixels without a table use the default too,
  // except in a prepass, which skips them (count 0: they fell back in an earlier pass). Must
  // outlive the render call.
  const spectral::PixelTables* tables = nullptr;
};

struct TileStats {
  TraceCounters counters;
  double seconds = 0;
};

class TileRenderer {
 public:
  explicit TileRenderer(const RenderScene& scene);

  // Renders the task, each pixel with its table from task.tables or else the scene's wavelength
  // distribution. INVALID_ARGUMENT when the tables' size is not the tile's, early_stop is set
  // without prepass (it would bias a final pass), or the sample range passes 2^32. `cancel`,
  // when set, is polled between pixels; a cancelled render returns CANCELLED and no result.
  // `progress` (may be null) is incremented by the samples finished, for progress bars.
  absl::StatusOr<image::TileResult> render(const RenderTask& task, TileStats* stats,
                                           const std::atomic<bool>* cancel = nullptr,
                                           std::atomic<std::uint64_t>* progress = nullptr) const;

 private:
  // INVALID_ARGUMENT for a task this renderer cannot take (see render).
  absl::Status check_task(const RenderTask& task) const;
  // The buffers a task's result carries.
  image::TileBuffers buffers_for(const RenderTask& task) const;
  // A light-tracing task (light_task.cpp): the whole image, a range of batches of W·H paths.
  absl::StatusOr<image::TileResult> render_light(const RenderTask& task, TileStats* stats,
                                                 const std::atomic<bool>* cancel,
                                                 std::atomic<std::uint64_t>* progress) const;
  // The task's counters, summed over the threads, and its seconds since `start`.
  static void record_stats(TileStats* stats, tbb::combinable<TraceCounters>& counters,
                           std::chrono::steady_clock::time_point start);
  // With --caustics light: every pixel's eye samples of the task's range, added into the light
  // paths' sums in `result` (light_task.cpp says how the squares combine), and into the filtered
  // sums when there are some.
  void add_eye_paths(const RenderTask& task, image::TileResult& result, FilteredSums* filtered,
                     tbb::combinable<TraceCounters>& counters, const std::atomic<bool>* cancel,
                     std::atomic<std::uint64_t>* progress) const;

  const RenderScene& scene_;
  PathIntegrator integrator_;
  std::optional<GradientIntegrator> gradient_;  // set for job::IntegratorKind::kGradient
  std::optional<LightTracer> light_;            // set for job::IntegratorKind::kLight
};

}  // namespace prism::worker
