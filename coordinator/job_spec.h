// A job's parameters: the wire JobSpec (proto/prism/v1/types.proto) turned into the typed values
// the worker and the coordinator use, and back. The rules are those of `prism render`'s flags
// (client/render_command.cpp): the same ranges and the same defaults taken from the scene (spp
// from its Sampler, resolution from its Film, bins from the Film's nbuckets else 64, max depth
// from its Integrator), so a job submitted to the farm renders exactly what the embedded render
// would with the same options.
//
// Invariant: a JobParameters returned by job_parameters() is fully validated, and
// job_parameters(to_proto(p), any scene) == p: to_proto() writes every value explicitly, so
// the result no longer depends on the scene's defaults.
//
// The prepass (algorithms.md §4) is off unless a spec's PrepassOptions turns it on
// (prepass_by_default says why).
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "coordinator/outputs.h"
#include "coordinator/poisson.h"
#include "coordinator/prepass.h"
#include "coordinator/target_error.h"
#include "prism/v1/types.pb.h"
#include "services/scene/scene_description.h"
#include "worker/render_options.h"

namespace prism::coordinator {

// The limits `prism render` applies to its flags (client/render_command.h).
inline constexpr std::uint64_t kMaxJobSpp = std::uint64_t{1} << 24;
inline constexpr int kMaxJobDepth = 1000;
inline constexpr double kMaxJobExposureStops = 64.0;
inline constexpr int kMinTileSize = 4;
inline constexpr int kMaxTileSize = 1024;
inline constexpr int kDefaultTileSize = 32;
inline constexpr std::size_t kMaxJobNameBytes = 256;
inline constexpr std::size_t kMaxScenePathBytes = 1024;

// Which output files a job writes; the spec's all-false OutputOptions means all of them.
struct JobOutputs {
  bool spectral_exr = true;
  bool rgb_exr = true;
  bool png = true;
  bool primal_and_gradients = false;  // gradient jobs: also the raw I and G spectral EXRs
  float png_exposure = 0.0f;          // stops

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
  worker::RenderOptions render;
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

// The largest spp a target-error job goes to when its spec gives no max_spp.
inline constexpr std::uint64_t kDefaultTargetErrorMaxSpp = 65536;

// Validates every field of `spec` and fills the unset ones from `scene`. INVALID_ARGUMENT naming
// the field and the accepted values, e.g. "spp 0 is out of range: want 1..16777216".
absl::StatusOr<JobParameters> job_parameters(const prism::v1::JobSpec& spec,
                                             const scene::SceneDescription& scene);

// Whether a job with this integrator runs a prepass when its spec does not say (the rule above).
bool prepass_by_default(worker::IntegratorKind integrator, const scene::SceneDescription& scene);

// The scene's features a report lists: every one not rendered exactly as pbrt-v4 would.
std::vector<SceneFeatureNote> reported_features(const scene::SceneDescription& scene);

// The report's gradient and prepass sections from the job's settings (their measured figures,
// counters and times, are the caller's to fill).
void add_job_sections(const JobParameters& parameters, RenderReport& report);

// The wire values of the option enums (both to_proto and `prism`'s flags use these).
prism::v1::Integrator to_proto(worker::IntegratorKind kind);
prism::v1::LightSelection to_proto(worker::LightSelectionKind kind);
prism::v1::PoissonNorm to_proto(PoissonNorm norm);
prism::v1::GradientTauPilot to_proto(const TauPilotReport& pilot);

// Every value explicit (see the invariant above).
prism::v1::JobSpec to_proto(const JobParameters& parameters);

// Short names of the option values: worker::name() in worker/render_options.h.

}  // namespace prism::coordinator
