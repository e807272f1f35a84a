// The embedded render: the farm's pipeline in one process, with no network. It builds the
// worker's RenderScene, plans tasks with plan_tiles (tile x sample range), renders the tasks
// with worker::TileRenderer in parallel inside a tbb::task_arena of the requested size, and
// assembles finished tiles with the TileAssembler, exactly as the coordinator does for remote
// workers. A job with a prepass first runs its passes (PrepassRun: the same object the farm
// drives), then the final pass with each tile's learned tables; a gradient job's tiles are
// reconstructed by the screened Poisson solve as each one completes (tile_finaliser.h).
//
// Determinism: samples are pure functions of (seed, pass, pixel, sample index), each task sums a
// pixel's samples in index order, and the assembler adds a tile's ranges in range order. The
// output bytes therefore depend on the job (scene, options, resolution, spp, samples per task)
// but not on the thread count, the tile size or the order tasks finish in.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>

#include "absl/status/statusor.h"
#include "coordinator/gather.h"
#include "coordinator/outputs.h"
#include "coordinator/poisson.h"
#include "coordinator/prepass.h"
#include "coordinator/prepass_run.h"
#include "coordinator/spectral_spool.h"
#include "coordinator/spectral_stream.h"
#include "coordinator/target_error.h"
#include "coordinator/tile_finaliser.h"
#include "coordinator/tile_plan.h"
#include "services/image/tile.h"
#include "services/job/render_options.h"
#include "services/scene/scene_description.h"
#include "services/spectral/named_spectra.h"
#include "worker/embree_device.h"
#include "worker/integrator.h"
#include "worker/render_scene.h"

namespace prism::coordinator {

struct RenderProgress {
  std::uint64_t samples_done = 0;
  std::uint64_t samples_total = 0;
  double seconds = 0;  // since rendering started
};

struct LocalRenderOptions {
  job::RenderOptions render;  // validated by the caller (bins, depth, seed, ...)
  int width = 0;              // the film resolution; must be >= 1
  int height = 0;
  std::uint64_t spp = 1;
  int tile_size = 32;  // 4..1024; does not change the output bytes
  int threads = 0;     // 0: all hardware threads; does not change the output bytes
  // Samples per task (0: all of a pixel's samples in one task). Part of the job: it decides
  // the order in which doubles are added, so it does change the output's last bits.
  std::uint64_t samples_per_task = 0;
  // Called from one reporting thread about every progress_interval_seconds while rendering,
  // and once more when all samples are done.
  std::function<void(const RenderProgress&)> progress;
  double progress_interval_seconds = 0.25;
  // Gradient jobs (render.integrator == kGradient): every finished tile's pixels are
  // reconstructed by the screened Poisson solve (poisson.h) with these settings.
  double poisson_alpha = job::kDefaultPoissonAlpha;
  job::PoissonNorm poisson_norm = job::PoissonNorm::kL2;
  // Gradient jobs: also return the raw primal I and gradient G images.
  bool keep_primal_and_gradients = false;
  // With a prepass: keep the final pass's per-pixel tables in the result (reports, dumps).
  bool keep_prepass_tables = false;
  // The multi-pass prepass (docs/estimators.md §4), when set: its passes run first and the final
  // pass samples each pixel's learned table.
  std::optional<job::PrepassParameters> prepass;
  // Rendering to a target error (target_error.h), when set: `spp` is the first round's, and
  // rounds double it for the tiles short of the target up to target_error->max_spp.
  std::optional<job::TargetError> target_error;
  // The scene's geometry as an earlier LocalRender of the same description on the same device
  // built it (LocalRender::shared_geometry), when set: reused instead of built again
  // (RenderScene::build). The bytes are the same either way.
  std::shared_ptr<const worker::Geometry> geometry;
  // Admission control (resource_plan.h): create() refuses a job whose planned memory, besides
  // what the process already holds, exceeds this many bytes. 0: machine_memory_budget().
  std::uint64_t max_memory_bytes = 0;
  // When set, the finished bins are not held as a whole image in memory: they are streamed into
  // the spectral EXR while the final pass runs (SpectralStream, spectral_stream.h, compressed
  // with exr_compression; result.stream writes the file), or, for a job rendered to a target
  // error, go to a SpectralSpool (spectral_spool.h; result.spool). Either works in this
  // directory, and result.image and result.rgb_standard_error are then 1x1 placeholders. Only
  // for jobs that keep no other whole spectral image (create() refuses it with
  // keep_primal_and_gradients, splatting or gathering). The bytes written are the same as from
  // the image.
  std::filesystem::path spool_dir;
  image::ExrCompression exr_compression = image::kDefaultExrCompression;

  // A gradient job that returns its raw primal and gradient images.
  bool keeps_primal_and_gradients() const {
    return keep_primal_and_gradients && render.integrator == job::IntegratorKind::kGradient;
  }
  // Spooling is possible: the job keeps no whole spectral image besides the bins (no raw primal
  // and gradients, no splatted or gathered image).
  bool can_spool() const {
    return !keeps_primal_and_gradients() && !render.splats_differentials() && !render.gathers();
  }
};

struct LocalRenderStats {
  double build_seconds = 0;   // RenderScene::build (geometry, lights, light sampler)
  double render_seconds = 0;  // all tasks, wall clock
  std::uint64_t samples = 0;  // pixel samples taken
  worker::TraceCounters counters;
  int threads = 0;  // the arena's concurrency
  std::size_t tasks = 0;
  int tiles = 0;
  int peak_tiles_in_flight = 0;
  // The prepass (zero and unset without one): its passes' wall time including the coordinator's
  // filters and tables, and what it did. render_seconds is the final pass alone.
  double prepass_seconds = 0;
  std::optional<PrepassOutcome> prepass;
  // With a target error: what it reached (samples above counts every round's).
  std::optional<TargetErrorOutcome> target_error;
  // With gathering: what its filter did.
  std::optional<GatherStats> gather;
};

struct LocalRenderResult {
  // Bin averages, width x height x bins; for a gradient job the Poisson reconstruction. 1x1
  // (unused) when spooled: then `spool` has them.
  image::SpectralImage image;
  // Its linear sRGB for the RGB outputs, from each sample's exact wavelengths (tile_rgb), and
  // each pixel's standard error of that mean (tile_rgb_standard_error; for a gradient job that
  // of the exact part, before the reconstruction's change).
  image::RgbImage rgb;
  image::RgbImage rgb_standard_error;
  // Gradient jobs with keep_primal_and_gradients: the raw primal I and the gradient G (G[b]
  // estimates I[b+k] − I[b]), per-pixel means like `image`.
  std::optional<image::SpectralImage> primal;
  std::optional<image::SpectralImage> gradient;
  std::optional<image::RgbImage> primal_rgb;  // the primal's samples' exact RGB (tile_rgb)
  // Jobs with differential splatting (RenderOptions::splat_width_nm): the filtered image, its
  // bins' means and its R, G, B from each fragment's wavelength; biased, beside `image`.
  std::optional<image::SpectralImage> filtered;
  std::optional<image::RgbImage> filtered_rgb;
  BinStatistics statistics;
  LocalRenderStats stats;
  // keep_prepass_tables with a prepass: the tables the final pass sampled (their mixture weights
  // and predicted variances per pixel).
  std::optional<PixelTableImage> prepass_tables;
  // With LocalRenderOptions::spool_dir: the finished bins, on disk (spool, with a target error)
  // or already in the spectral EXR but for its metadata (stream).
  std::shared_ptr<const SpectralSpool> spool;
  std::shared_ptr<SpectralStream> stream;
};

class LocalRender {
 public:
  // Builds the render scene and the plan. INVALID_ARGUMENT for sizes out of range; the
  // scene's own errors (file:line:column) from RenderScene::build. `device` must outlive
  // the LocalRender.
  static absl::StatusOr<std::unique_ptr<LocalRender>> create(
      worker::EmbreeDevice& device, const scene::SceneDescription& scene,
      const spectral::SpectrumLibrary& library, const LocalRenderOptions& options);

  // Renders every task. `cancel`, when set, stops the render (CANCELLED). The first task error
  // cancels the others and is returned; no partial image is returned.
  absl::StatusOr<LocalRenderResult> render(const std::atomic<bool>* cancel = nullptr) const;

  const worker::RenderScene& scene() const { return *scene_; }
  // For LocalRenderOptions::geometry of later renders of the same description.
  const std::shared_ptr<const worker::Geometry>& shared_geometry() const {
    return scene_->shared_geometry();
  }
  const TilePlan& plan() const { return plan_; }
  const LocalRenderOptions& options() const { return options_; }
  int threads() const { return threads_; }
  double build_seconds() const { return build_seconds_; }

 private:
  LocalRender() = default;
  LocalRenderOptions options_;
  std::unique_ptr<worker::RenderScene> scene_;
  TilePlan plan_;
  int threads_ = 1;
  double build_seconds_ = 0;
  TileFinaliser finaliser_;
  // The prepass in its initial state (each render() runs a copy) and, per pass, the scene at
  // that pass's film when it is not the job's (image-scaled passes), else null.
  std::unique_ptr<PrepassRun> prepass_template_;
  std::vector<std::unique_ptr<worker::RenderScene>> pass_scenes_;
};

}  // namespace prism::coordinator
