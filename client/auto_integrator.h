// `--integrator auto`: the rendering method chosen for the scene, before the job is made.
//
// Asking for the prepass (--prepass or a --prepass-* option) means hero with the prepass,
// without a pilot: only hero runs it. The gradient's own flags need --integrator gradient.
//
// A scene in which nothing depends on wavelength (no dispersive dielectric, one emitter
// spectrum, no medium: scene::analyze_wavelength_dependence) renders with hero and no prepass,
// the cheapest adequate method (its four lanes all stay live), and no pilot runs.
//
// Otherwise a pilot renders each candidate on the job's camera at a quarter of the film's side
// (at most about 10,000 pixels), twice with independent seeds at 4..16 spp (1/16 of the job's),
// and estimates per candidate
//   - its variance per sample: half the squared difference of its two renders per pixel and
//     bin (E[(A − B)²] is twice one render's variance), weighted as relMSE weighs errors, by
//     1/(m² + 0.01) with m every candidate's renders averaged over the pixel and its 3 x 3
//     neighbours, and times the pilot's spp;
//   - its cost per sample: the rays its two renders traced per pixel sample, counted, so the
//     choice is a pure function of the scene and the options (the same spec gives the same
//     bytes); it leaves out per-ray work (`prism render` at 64 spp on four evaluation scenes:
//     uniform 5.7–6.2 M rays/s, hero 4.3–5.3, gradient 3.6–5.4);
// and predicts its error at equal time as their product. Candidates are hero and gradient,
// uniform where a dielectric disperses (hero terminates its secondary lanes there, and the
// single-wavelength tracer is then cheaper per sample), and hero+caustics (hero with
// --caustics light) where the scene can be light traced. A light path's rays are counted like
// an eye path's; on four scenes the rays' ratio to hero's was within 10 % of the CPU time's
// (docs/benchmarks.md). The prepass is not a candidate: at equal
// time it has not beaten the emitter mixture by more than 8 % on any scene measured
// (docs/benchmarks.md, issue 11), and it needs the job's own budget to learn anything.
//
// The choice is hero unless another candidate is predicted at least 10 % better (a smaller
// predicted gain is within the pilot's noise). It is recorded in the job spec
// (JobSpec.auto_choice) with every candidate's figures, so a submitted job, and its report, say
// exactly what ran.
#pragma once

#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "client/render_command.h"
#include "coordinator/outputs.h"
#include "services/scene/scene_description.h"
#include "services/spectral/named_spectra.h"
#include "worker/embree_device.h"

namespace prism::client {

// Predicted equal-time gain a candidate needs to replace hero.
inline constexpr double kAutoMinimumGain = 0.10;
// The candidate name of hero with --caustics light.
inline constexpr char kHeroWithLightCaustics[] = "hero+caustics";

struct ResolvedIntegrator {
  RenderCommandOptions options;           // with an explicit integrator and prepass
  std::optional<job::AutoReport> report;  // set when `auto` chose
};

// `options` as given when its integrator is explicit; otherwise the choice above.
absl::StatusOr<ResolvedIntegrator> resolve_integrator(const RenderCommandOptions& options,
                                                      worker::EmbreeDevice& device,
                                                      const scene::SceneDescription& description,
                                                      const spectral::SpectrumLibrary& library,
                                                      const std::string& bundle_hash,
                                                      const std::string& scene_relpath);

// Records the choice in the job spec (JobSpec.auto_choice), where the report takes it from.
void set_auto_choice(const job::AutoReport& report, prism::v1::JobSpec& spec);

}  // namespace prism::client
