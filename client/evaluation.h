// Equal-time evaluation, shared by `prism bench` and the benchmark programs under tests/bench:
// renders timed the same way for every method, a reference image cached on disk together with
// its own noise, and the error of a method interpolated at a given time from its convergence
// curve.
//
// The reference is rendered as two independent halves (different seeds, half the samples each)
// and stored as their average. Its noise adds E[(ref − truth)²] to every squared error measured
// against it; the halves give that floor for any metric and region without assuming anything
// about the sampler: for A, B independent with the same variance, avg = (A + B)/2 and
// (A − avg)² = (A − B)²/4, whose expectation is the variance of avg. The per-bin mean of s²/n
// (BinStatistics::variance_of_mean, unbiased only for independent samples) is kept beside it as
// a check.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "coordinator/local_render.h"
#include "services/image/metrics.h"
#include "services/image/tile.h"
#include "services/scene/scene_description.h"
#include "services/spectral/named_spectra.h"
#include "worker/embree_device.h"

namespace prism::evaluation {

// A scene loaded once for many renders: as `prism render` loads it (named spectra checked
// against the built-in library, files confined to the scene's directory).
struct BenchScene {
  std::unique_ptr<spectral::SpectrumLibrary> library;
  scene::SceneDescription description;
  std::string name;           // the file name as given
  std::string bundle_hash;    // of the scene and every file it reads
  std::string scene_relpath;  // inside the bundle
};
absl::StatusOr<BenchScene> load_bench_scene(const std::filesystem::path& path,
                                            bool allow_unsupported = false);

// User + system CPU seconds of this process (all threads).
double process_cpu_seconds();

struct TimedRender {
  coordinator::LocalRenderResult result;
  double wall_seconds = 0;  // LocalRender::render() only (a prepass included), not the build
  double cpu_seconds = 0;   // the same span in process CPU time
};

// Builds a LocalRender for `options` and times its render().
absl::StatusOr<TimedRender> timed_render(worker::EmbreeDevice& device, const BenchScene& scene,
                                         const coordinator::LocalRenderOptions& options);

struct Reference {
  image::SpectralImage image;  // the average of the two halves
  image::SpectralImage half;   // the first half, for noise floors of any region
  std::uint64_t spp = 0;       // of the average
  double seconds = 0;          // wall time it took to render (both halves)
  // Mean over bins of the halves' variance_of_mean / 4: the s²/n estimate of the MSE floor.
  double variance_of_mean = 0;

  // What the reference's noise adds, in expectation, to a metric of a test image against it
  // over `crop` (whole image when absent): mse and rel_mse of `half` against `image`.
  absl::StatusOr<image::ErrorMetrics> floor(
      const std::optional<image::Crop>& crop = std::nullopt) const;
};

// Renders one half of a reference: `half` is the reference's options with the half's seed and
// spp (or target error). The image is what matters; statistics.variance_of_mean may be left
// empty (the s²/n check is then 0) and stats.target_error must be set for a target-error half.
using HalfRenderer =
    std::function<absl::StatusOr<TimedRender>(const coordinator::LocalRenderOptions& half)>;

// The reference for `options` (options.spp is the total, split in two halves of spp/2 with seeds
// options.render.seed and options.render.seed + 1), loaded from `cache_dir` when a file for the
// same bundle (the scene and every file it reads) and options is there, else rendered and
// written there (atomically). The halves are rendered by `render_half` when given (prism bench
// on the farm, whose output is byte for byte the local render's, so the cache is shared), else
// by timed_render in this process. `tag` names the benchmark in the file name and in progress
// lines on stderr. Errors from rendering, reading or writing are passed on; the cache directory
// is created when missing.
absl::StatusOr<Reference> cached_reference(worker::EmbreeDevice& device, const BenchScene& scene,
                                           const coordinator::LocalRenderOptions& options,
                                           const std::filesystem::path& cache_dir,
                                           const std::string& tag,
                                           const HalfRenderer& render_half = nullptr);

// One measurement of a convergence curve.
struct ConvergencePoint {
  std::uint64_t spp = 0;
  double seconds = 0;
  double error = 0;  // > 0
};

// A method's error at time `t`, from its points (any order, errors > 0): linear in log error
// over log time between the two points that bracket t; outside their range, from the nearest
// point with error ∝ 1/time (Monte Carlo convergence), and *extrapolated is set. nullopt when
// no point has a positive error and time.
std::optional<double> error_at_time(std::span<const ConvergencePoint> points, double t,
                                    bool* extrapolated = nullptr);

// "a,b,c" of positive integers, strictly increasing (INVALID_ARGUMENT otherwise).
absl::StatusOr<std::vector<std::uint64_t>> parse_spp_list(const std::string& text);

}  // namespace prism::evaluation
