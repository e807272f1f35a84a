// The job layer's parameters: what a job is, as the worker, the coordinator and `prism` share it,
// besides the worker's render options (render_options.h): the limits every entry point checks,
// the Poisson, prepass and target-error settings, the pilots' reports a job carries, and
// JobParameters, the validated job (job_spec.h builds it from the wire spec). Depends on
// nothing above services/; the algorithms that use these settings live with their owners
// (coordinator/poisson.h, prepass.h, target_error.h).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/image/exr_spectral.h"
#include "services/job/render_options.h"

namespace prism::job {

// ---- Limits

// The one set of limits: `prism render`'s flags, the job spec, LocalRender and the worker's
// --threads all check against these.
inline constexpr std::uint64_t kMaxJobSpp = std::uint64_t{1} << 24;
inline constexpr int kMaxThreads = 4096;
inline constexpr int kMaxJobDepth = 1024;  // as a scene's `maxdepth` (scene_entities.cpp)
inline constexpr double kMaxJobExposureStops = 64.0;
inline constexpr int kMinTileSize = 4;
inline constexpr int kMaxTileSize = 1024;
inline constexpr int kDefaultTileSize = 32;
inline constexpr std::size_t kMaxJobNameBytes = 256;
inline constexpr std::size_t kMaxScenePathBytes = 1024;
// A job whose task is the whole image (light paths: RenderOptions::traces_light_paths) returns
// per task, per pixel, the sums and squares of every bin and of R, G, B as doubles; a task's
// result may hold at most this many bytes (1 GiB: 1920x1080 at 32 bins is 0.55 GiB).
inline constexpr std::uint64_t kMaxWholeImageResultBytes = std::uint64_t{1} << 30;

// ---- Spectral gradient sampling: the Poisson reconstruction

// kWeighted: the variance-weighted L2 reconstruction (PoissonSolver::solve_weighted).
enum class PoissonNorm { kL2, kL1, kWeighted };

// "l2" / "l1" / "weighted".
std::string_view to_string(PoissonNorm norm);
// INVALID_ARGUMENT naming the text unless it is "l2", "l1" or "weighted".
absl::StatusOr<PoissonNorm> parse_poisson_norm(const std::string& text);

// The screening weight α's accepted range. It bounds the condition number (α + 4)/α of the
// system by 4e6, so the double solve's error (about κ·B·2⁻⁵³ relative) stays far below float
// rounding and its intermediates (up to |r|/α) far from overflow. Beyond 1e6 the result is I to
// within |G|/α; below 1e-6 only α holds the chain means and the system is nearly singular.
inline constexpr double kMinPoissonAlpha = 1e-6;
inline constexpr double kMaxPoissonAlpha = 1e6;
// The default screening weight. The paper's 0.2 trusts G more than Prism's G deserves: with the
// automatic τ most events go unshifted, and an unshifted event puts the primal's own noise into G
// (±c at b and b − k). At 0.4 the error at equal samples was lower on eight of eleven smooth-glass
// scenes (0.6–9 %), the same on two (where G = DI) and 1 % higher on one (docs/benchmarks.md,
// "The screening weight α").
inline constexpr double kDefaultPoissonAlpha = 0.4;

// ---- The prepass

// The job's prepass options (wire: PrepassOptions; CLI: --prepass-*).
struct PrepassParameters {
  int passes = 2;             // K, 1..kMaxPasses
  std::uint32_t spp = 128;    // Ñ, samples per pixel of the last prepass, >= 1
  bool image_scaled = false;  // earlier passes lower the resolution instead of the sample count
  double epsilon = 0.05;   // least share ε of the default in a table (α <= 1 − ε), in (0, 1)
  double fallback = 0.05;  // least predicted variance reduction for a pixel to leave the
                           // default distribution, in [0, 1)
  double sigma_s = 1.75;   // spatial σ of the bilateral filter, pixels, > 0
  double sigma_r = 0.015;  // range σ on guide feature distances, > 0

  static constexpr int kMaxPasses = 8;
  // σ_s's bound in pixels: large enough for any sensible filter (the paper uses 1–2 px), small
  // enough that a job cannot ask the coordinator for a window of millions of pixels per pixel.
  static constexpr double kMaxSigmaS = 64.0;
  // After pass 1 of several, a job whose tables are predicted (PixelTableImage::decision_gain)
  // to remove less than kMinImageGain of the image's variance per sample stops the prepass and
  // renders with the default; after the last pass, tables predicted to remove less than
  // kMinFinalGain are dropped (every pixel on the default, so the final pass pays nothing for
  // them). The margins are measured
  // (docs/benchmarks.md): going on costs about 9 % of the job (the rest of the prepass and a
  // table lane's extra cost), the tables alone about 3 %, and under the Sobol sampler the realised
  // gain is about half the predicted one.
  static constexpr double kMinImageGain = 0.2;
  static constexpr double kMinFinalGain = 0.1;
  // The two margins a run uses. Not on the wire (a job always has the constants); tests and
  // benchmarks set them to see tables that the margins would drop.
  double min_image_gain = kMinImageGain;
  double min_final_gain = kMinFinalGain;

  // INVALID_ARGUMENT naming the first bad field (and its allowed range) when a value is out of
  // range or not finite.
  absl::Status validate() const;
};

// The prepass's Ñ for a job of `spp` final samples per pixel when the job does not set it: the K
// passes' samples per pixel-equivalent (Ñ·Σ_k 8^−(K−k) sample-scaled, Ñ·Σ_k 4^−(K−k) image-scaled,
// prepass_schedule) are at most kBudgetShare of the final pass's, so with the coordinator's
// reconstruction the prepass stays under a tenth of the job's time; at most kMaxBudgetedSpp. 0,
// and the job runs without a prepass, when that is under kMinBudgetedSpp (too few samples to
// learn a distribution from) or leaves the first of several sample-scaled passes, whose tables
// decide whether the prepass goes on, under kMinDecisionSpp per pixel: from 2 or 4 spp their
// predicted gain ranged from −1.2 to 6.7 on the scenes of scenes/ (a fraction of the variance
// removed, so at most 1) and went on where the last pass then dropped its tables, which cost
// such jobs 7 % of their time for nothing (docs/benchmarks.md).
inline constexpr double kBudgetShare = 0.08;
inline constexpr std::uint32_t kMaxBudgetedSpp = 128;
inline constexpr std::uint32_t kMinBudgetedSpp = 16;
inline constexpr std::uint32_t kMinDecisionSpp = 8;
std::uint32_t budgeted_prepass_spp(std::uint64_t spp, int passes, bool image_scaled = false);

// ---- Rendering to a target error

inline constexpr double kMinTargetError = 1e-4;
inline constexpr double kMaxTargetError = 1.0;
// Whether E is in range as a job holds it (a float field: 1e-4 arrives as 9.99999975e-05, which
// is the limit all the same).
inline bool target_error_in_range(double relative) {
  return relative >= double(static_cast<float>(kMinTargetError)) &&
         relative <= double(static_cast<float>(kMaxTargetError));
}
// The largest spp a target-error job goes to when its spec gives no max_spp.
inline constexpr std::uint64_t kDefaultTargetErrorMaxSpp = 65536;

struct TargetError {
  double relative = 0.01;  // E in [kMinTargetError, kMaxTargetError]
  bool image_scope = false;
  std::uint64_t max_spp = 0;  // >= the job's spp
};

// ---- What the client's pilots chose, carried by the job for its report

// The automatic τ's pilot (worker/gradient/pilot.h, the job spec's gradient.tau_pilot): float,
// as the job spec keeps them.
struct TauPilotReport {
  float epsilon = 0;
  std::uint32_t pixels = 0;
  std::uint32_t spp = 0;
  std::uint64_t events = 0;
  float shifted_event_fraction = 0;
  float shifted_square_fraction = 0;
  float lost_benefit_fraction = 0;
  float offset_vertex_fraction = 0;
  float second_moment_rise = 0;
  std::optional<double> seconds;  // where the pilot ran in this process (`prism render`)

  bool operator==(const TauPilotReport&) const = default;
};

// How `--integrator auto` chose (client/auto_integrator.h).
struct AutoReport {
  struct Candidate {
    std::string method;
    double rel_mse_per_sample = 0;
    double rays_per_sample = 0;
    double relative_efficiency = 0;
    double ray_cost = 0;       // the cost of one of its rays relative to uniform's (0: not given)
    double caustic_paths = 0;  // hero+caustics: the share of light paths judged (0: not given)
    friend bool operator==(const Candidate&, const Candidate&) = default;
  };
  std::string choice;
  std::string reason;
  double seconds = 0;
  std::vector<Candidate> candidates;  // empty when no pilot ran
  friend bool operator==(const AutoReport&, const AutoReport&) = default;
};

// ---- The job

// Which output files a job writes; the spec's all-false OutputOptions means all of them.
struct JobOutputs {
  bool spectral_exr = true;
  bool rgb_exr = true;
  bool png = true;
  bool primal_and_gradients = false;  // gradient jobs: also the raw I and G spectral EXRs
  float png_exposure = 0.0f;          // stops
  image::ExrCompression exr_compression = image::kDefaultExrCompression;

  bool operator==(const JobOutputs&) const = default;
};

// Spectral gradient sampling (§5) besides what the worker needs (RenderOptions has k and τ).
inline constexpr double kDefaultGradientDelta = 0.15;
struct GradientParameters {
  double delta = kDefaultGradientDelta;  // δ as a fraction of the range; k = round(δ·bins)
  double alpha = kDefaultPoissonAlpha;   // screening weight of the reconstruction
  PoissonNorm norm = PoissonNorm::kL2;
  // How the client's pilot chose τ (`--tau auto`); reported only.
  std::optional<TauPilotReport> tau_pilot;

  bool operator==(const GradientParameters&) const = default;
};

struct JobParameters {
  RenderOptions render;
  int width = 0;
  int height = 0;
  std::uint64_t spp = 0;
  int tile_size = kDefaultTileSize;
  std::uint64_t samples_per_task = 0;  // 0: all of a pixel's samples in one task
  std::string scene_path;              // the scene file inside the bundle
  std::string bundle_hash;             // SHA-256 hex of the bundle, lower case
  std::string name;
  JobOutputs outputs;
  GradientParameters gradient;               // used by gradient jobs only
  std::optional<PrepassParameters> prepass;  // set when the job runs a prepass
  bool allow_unsupported = false;            // the scene loads with substitutions
  // Rendering to a target error; `spp` is then the first round's.
  std::optional<TargetError> target_error;
  // How `--integrator auto` chose the integrator, for the report.
  std::optional<AutoReport> auto_choice;
};

}  // namespace prism::job
