// `prism render scene.pbrt`: the embedded render. Loads the scene exactly as `prism check` does
// (named spectra checked against the built-in library, files confined to the scene's
// directory), renders it with the coordinator's LocalRender (the farm's tile/task/merge code
// driving the worker's tile renderer in this process) and writes the spectral EXR, RGB EXR,
// PNG preview and JSON report (coordinator/outputs.h).
//
// Every flag is validated before the scene is loaded, and the output locations before the
// render starts; outputs are written only when the whole render has finished, so any failure
// leaves no file behind. Defaults come from the scene: spp from its Sampler, resolution from
// its Film, bins from the Film's nbuckets (else 64), max depth from its Integrator.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <ostream>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "coordinator/local_render.h"
#include "prism/v1/types.pb.h"
#include "services/job/job_spec.h"
#include "services/job/render_options.h"
#include "services/scene/scene_description.h"
#include "services/spectral/named_spectra.h"
#include "worker/embree_device.h"

namespace prism::client {

// The flags as given; unset optionals take the scene's values.
// `--spool auto` spools the finished bins when they take more than this (1 GiB).
inline constexpr std::uint64_t kSpoolAboveBytes = std::uint64_t{1} << 30;

struct RenderCommandOptions {
  std::filesystem::path scene;
  std::optional<std::filesystem::path> output;  // -o
  std::optional<std::filesystem::path> json;    // --json
  std::optional<std::int64_t> spp;
  std::string integrator = "auto";  // or uniform, hero, gradient (auto_integrator.h)
  std::optional<std::int64_t> bins;
  std::optional<std::string> resolution;  // "WxH"
  std::optional<std::int64_t> threads;    // unset: every hardware thread
  // --max-memory, a byte count (coordinator::parse_bytes); empty: the machine's budget.
  std::string max_memory;
  // --spool: auto (the bins on disk beside the outputs when they exceed kSpoolAboveBytes and
  // the job keeps no other whole image), always, never.
  std::string spool = "auto";
  std::uint64_t seed = 0;
  std::int64_t tile = 32;
  std::string spectral_pdf = "flat";
  std::string emitter_pdf = "emitters";
  std::string light_selection = "power";
  bool spectral_light_selection = true;
  // --caustics: off, light, or empty (not given: off, but `auto` may choose light).
  std::string caustics;
  // --caustic-paths: light paths per pixel and sample with light-traced caustics (job spec
  // caustic_paths); unset: 1, or under auto the pilot's share.
  std::optional<double> caustic_paths;
  // --splat / --splat-width: differential splatting of the light paths, Δλ in nm at sample 0
  // (job spec splat_width); unset: off.
  std::optional<double> splat_width;
  // --gather / --gather-width: gathering for eye-traced jobs, Δλ in nm for spp = 1 (job spec
  // gather_width); unset: off.
  std::optional<double> gather_width;
  std::optional<std::int64_t> max_depth;
  std::optional<std::int64_t> samples_per_task;  // unset: one task per tile
  double exposure = 0.0;                         // PNG preview, in stops
  std::string exr_compression;                   // --exr-compression; empty: the default
  // Spectral gradient sampling (--integrator gradient); unset: the defaults (job_spec.h).
  std::optional<double> delta;  // fraction of the range, snapped to whole bins
  std::optional<double> tau;    // unset: chosen by the pilot, as with tau_auto
  bool tau_auto = false;        // --tau auto
  std::optional<double> alpha;
  std::optional<std::int64_t> gradient_lanes;  // hero lanes of the base paths
  std::string poisson;                         // empty: the job's default, l2
  bool primal_and_gradients = false;  // also write <stem>.primal.exr and <stem>.gradient.exr
  // The multi-pass prepass; unset: off (job::prepass_by_default), unless auto asks for it.
  std::optional<bool> prepass;
  std::optional<std::int64_t> prepass_passes;
  std::optional<std::int64_t> prepass_spp;
  std::string prepass_mode = "samples";
  std::optional<double> prepass_epsilon;
  std::optional<double> prepass_fallback;
  std::optional<double> prepass_sigma_s;
  std::optional<double> prepass_sigma_r;
  // Render a scene with unsupported input, each refused feature substituted (and listed in
  // the JSON report) instead of refusing the scene.
  bool allow_unsupported = false;
  // Render to a target error (coordinator/target_error.h): a relative standard error, spp the
  // first round's; scope "pixel" or "image"; max_spp unset: the job's default.
  std::optional<double> target_error;
  std::string target_error_scope = "pixel";
  std::optional<std::int64_t> max_spp;
  // Where to draw a progress bar (a terminal); null: none.
  std::ostream* progress = nullptr;
  // Where the scene's warnings go (null: nowhere).
  std::ostream* warnings = nullptr;
};

// "WxH" with 1 <= W, H <= 16384; INVALID_ARGUMENT quoting the text otherwise.
absl::StatusOr<std::pair<int, int>> parse_resolution(const std::string& text);

// "0.01" or "1%": a relative error in [1e-4, 1]; INVALID_ARGUMENT quoting the text otherwise.
absl::StatusOr<double> parse_target_error(const std::string& text,
                                          std::string_view flag = "--target-error");

// A decimal integer in 0..2^64-1 (a negative number is refused, not wrapped around).
absl::StatusOr<std::uint64_t> parse_seed(const std::string& text);

// The typed enum values of the string flags; INVALID_ARGUMENT listing the choices.
absl::StatusOr<job::IntegratorKind> parse_integrator(const std::string& name);
absl::StatusOr<job::SpectralPdfKind> parse_spectral_pdf(const std::string& name);
absl::StatusOr<job::EmitterPdfKind> parse_emitter_pdf(const std::string& name);
absl::StatusOr<job::LightSelectionKind> parse_light_selection(const std::string& name);

// Whether any --prepass-* option is given (they ask for the prepass).
bool has_prepass_options(const RenderCommandOptions& options);

// Every check that does not need the scene: ranges of the numbers, the choices of the string
// flags and the output names. INVALID_ARGUMENT naming the flag and the accepted values.
absl::Status validate_render_flags(const RenderCommandOptions& options);

// The job these flags describe, for the scene `description` whose bundle has `bundle_hash` and
// whose file is `scene_path` inside it: validated by job::job_parameters (the farm's own
// rules, which fill the scene's defaults) and returned with every value explicit, so the farm and
// the embedded render run exactly the same job. INVALID_ARGUMENT naming the flag or field.
absl::StatusOr<prism::v1::JobSpec> job_spec_of(const RenderCommandOptions& options,
                                               const scene::SceneDescription& description,
                                               const std::string& bundle_hash,
                                               const std::string& scene_path);

// The gradient integrator's τ when the flags give no number (`--tau auto`, or no --tau): runs the
// pilot (worker/gradient/pilot.h) on the job `spec` describes, on --threads threads, and writes
// its τ and figures into spec.gradient, so the farm and `prism render` trace with the same τ.
// Returns the pilot's wall seconds, or nothing when no pilot ran (not a gradient job, or τ given).
// `geometry`: the description's geometry if already built (RenderScene::build).
absl::StatusOr<std::optional<double>> choose_tau(
    const RenderCommandOptions& options, worker::EmbreeDevice& device,
    const scene::SceneDescription& description, const spectral::SpectrumLibrary& library,
    prism::v1::JobSpec& spec, std::shared_ptr<const worker::Geometry> geometry = nullptr);

// A τ pilot already run (by `auto`, which needs gradient's τ for its own pilot): the gradient
// job's spec as choose_tau left it, and the pilot's wall seconds.
struct TauPilotRun {
  prism::v1::JobSpec spec;
  double seconds = 0;
};

// choose_tau for `spec`, unless `ran` is a pilot of the same job (its spec equal to `spec` but
// for τ, the pilot's figures and the auto choice): then its τ and figures are copied, and the
// same bytes follow without running the pilot again. The pilot's seconds as choose_tau gives
// them (those of `ran` when reused).
struct TauChoice {
  std::optional<double> seconds;
  bool reused = false;
};
absl::StatusOr<TauChoice> choose_or_reuse_tau(const RenderCommandOptions& options,
                                              const std::optional<TauPilotRun>& ran,
                                              worker::EmbreeDevice& device,
                                              const scene::SceneDescription& description,
                                              const spectral::SpectrumLibrary& library,
                                              prism::v1::JobSpec& spec);

// The embedded render of a job, ready to run: the spec, its parameters (every default filled),
// LocalRender's options and the τ pilot's wall seconds when one ran.
struct PreparedRender {
  prism::v1::JobSpec spec;
  job::JobParameters job;
  coordinator::LocalRenderOptions local;
  std::optional<double> pilot_seconds;       // the τ pilot's
  std::optional<double> auto_pilot_seconds;  // `--integrator auto`'s (auto_integrator.h)
  bool tau_pilot_in_auto = false;            // pilot_seconds are part of auto_pilot_seconds
};

// What run_render does before rendering, for callers that run many renders of one loaded scene
// (prism bench): resolve_integrator (`auto`), job_spec_of, choose_tau and the LocalRender
// options. `bundle_hash` and
// `scene_relpath` name the scene's bundle as the farm would.
absl::StatusOr<PreparedRender> prepare_render(const RenderCommandOptions& options,
                                              worker::EmbreeDevice& device,
                                              const scene::SceneDescription& description,
                                              const spectral::SpectrumLibrary& library,
                                              const std::string& bundle_hash,
                                              const std::string& scene_relpath);

// Renders and writes the outputs; returns the one-line summary. Errors: the flags' (above),
// the scene's (file:line:column), NOT_FOUND for a missing output directory, the render's, or
// the names of the outputs that could not be written.
absl::StatusOr<std::string> run_render(const RenderCommandOptions& options,
                                       worker::EmbreeDevice& device);

}  // namespace prism::client
