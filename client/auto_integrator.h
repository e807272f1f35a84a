// `--integrator auto`: the rendering method chosen for the scene, before the job is made.
//
// Asking for the prepass (--prepass or a --prepass-* option) means hero with the prepass,
// without a pilot: only hero runs it. The gradient's own flags need --integrator gradient.
//
// A scene in which nothing depends on wavelength (no dispersive dielectric, one emitter
// spectrum, no medium: scene::analyze_wavelength_dependence) renders with hero and no prepass,
// the cheapest adequate method (its four lanes all stay live), and no pilot runs.
//
// Otherwise a pilot renders each candidate on the job's camera, twice with independent seeds
// (derived from the job's, so that another seed of the job is another pilot too) at an eighth of
// the job's spp (8..64), at a quarter of the film's side or less: fewer pixels where the
// candidates' renders would take more than 4 % of the job's samples, and at most about 10,000.
// It estimates per candidate
//   - its relMSE per sample: half the squared difference of its two renders per pixel and bin
//     (E[(A − B)²] is twice one render's variance), weighted as relMSE weighs errors, by
//     1/(m² + 0.01) with m every candidate's renders averaged over the pixel and its 3 x 3
//     neighbours, and times the pilot's spp;
//   - its cost per sample: the rays its renders traced per pixel sample, counted, so the choice
//     is a pure function of the scene and the options (the same spec gives the same bytes), times
//     the relative cost of one of its rays (uniform 1, hero 1.16, gradient 1.18: the medians of
//     CPU time per ray over the 22 scenes of scenes/ at 64 spp and one thread; hero's lanes and
//     gradient's shifts make a ray 2–28 % and 6–45 % dearer than uniform's, docs/benchmarks.md);
// and predicts its error at equal time as their product. Candidates are hero; gradient where
// some material refracts smooth-dispersively (elsewhere gradient, its lanes chosen by the scene,
// renders hero's image at a higher cost: worker/gradient/integrator.h); uniform where a
// dielectric disperses (hero terminates its secondary lanes there, and the single-wavelength
// tracer is then cheaper per sample); and hero+caustics (hero with
// --caustics light) where the scene can be light traced and has a shape that can scatter as a
// delta (so a caustic path to trace), its rays costed as hero's. That one's eye paths are
// rendered alone (its candidate renders), its light paths alone by the probe (below) at one light
// path per pixel and sample; together they give its variance and rays per sample as eye +
// light/s and eye + s·light for a share s of light paths (CausticSplit), and it is judged at the
// share that minimises their product (a power of two from 1/256 to 1; --caustic-paths fixes it),
// which it then runs with: where the caustics carry little of the error, few light paths are
// traced. (Its renders at one light path per pixel would trace the probe's light paths twice
// more: 13 % of the README demo's pilot.) Each eye-only render plus one of the probe's light-only
// renders is an estimate of the whole image, which the weights above average.
//
// The pilot's eye tracers mostly miss the caustic paths (light → delta chain → the camera's first
// vertex) where the lamp is small: 2 x spp samples per pixel rarely find it through the chain, so
// hero's measured variance is too low exactly where light tracing pays. Where hero+caustics is a
// candidate a probe therefore renders those paths from the lights (one light path per pixel and
// sample at the pilot's size): twice plainly with independent seeds (their product estimates C²,
// C their mean per pixel and bin, and their difference the light part's variance), and once with
// every splat times the value an eye path would carry for the same path (its BSDF sample at the
// receiver, the chain, the light's radiance, the lanes still live, its Russian roulette), whose
// mean is the eye tracers' second moment M of those paths per sample
// (job::RenderOptions::CausticProbe). M − C², weighted as above, is their variance per sample;
// where the split's eye part plus it exceeds hero's measured variance, the difference is what the
// eye tracers did not see. It is added to hero's, uniform's and gradient's (they miss the same
// paths) only where it is at least kUnseenCausticFactor times hero's measured variance: there
// the eye samples find next to none of the caustic, and a render of the job's size finds too
// few of it as well (scenes/slit-prism.pbrt and crossing-caustics.pbrt: about 4000 times, and
// hero's error against a reference 10–100 times hero+caustics' at equal time). Where it is
// comparable (0.1–1.6 times on the other scenes of scenes/), the excess is the heavy tail of
// caustics the eye samples do find, which an expected squared error counts but a render of the
// job's size rarely shows: on torus-glass and glass-enclosed, counting it picked hero+caustics
// where gradient measured 1.6–2 times better, and hero's error against the reference was the
// pilot's measured figure, not the modelled one (docs/benchmarks.md).
//
// The pilot's size is a trade of its cost against its noise, measured over eight pilot seeds on
// five scenes (docs/benchmarks.md): at the same samples, more spp on fewer pixels was less noisy
// than fewer spp on more pixels, and an eighth of the job's spp (twice the samples of a
// sixteenth) halved the spread of the predictions on the single-emitter rooms. With the τ pilot
// it costs 5–9 % of a 3-second job, less of longer ones. The scene's geometry (its BVH, most of
// a scene build) is built once, by the first build below, and every pilot render and the job
// reuse it (ResolvedIntegrator::geometry).
//
// Gradient's τ pilot (worker/gradient/pilot.h) runs once, on the job as gradient would render it
// (32768 samples whatever the film: on the pool at 3 s about 0.12 s, as much as the candidates'
// renders together). The gradient candidate's pilot renders trace at that τ, the one the job
// would use, and a gradient job reuses it (choose_or_reuse_tau) instead of running its own.
//
// Where hero is the only candidate no pilot runs.
//
// Clean caustics. The error auto ranks by (relMSE over spectral bins) and the RGB image a user
// looks at can disagree about caustics: on the README demo the eye tracers' caustic paths are
// about 1 % of hero's relMSE, so light tracing them is a tie by that measure, yet at 1/64 of a
// light path per pixel and sample they take hero's RGB relMSE to 0.83 and its dim floor's
// fireflies away, for 1.5 % more rays (docs/benchmarks.md). So where hero (with or without
// light-traced caustics) is the choice and the probe says light paths render the caustic paths
// at least kCleanCausticGain times cleaner than the eye tracers do (the light part's variance at
// the share s against M − C², both weighted as above) for at most kCleanCausticRays more rays
// than hero traces, the job renders them by light tracing at that share, or at the fitted share
// if it is larger (clean_caustic_share): at most about 2 % of the cost auto ranks by. Not where
// hero would run the prepass (several emitter spectra, below): light-traced caustics are not
// combined with it, and its gain is on the whole image, not on a few caustic paths.
//
// The choice is hero unless another candidate is predicted at least 10 % better (a smaller
// predicted gain is within the pilot's noise). Hero in a scene with several emitter spectra
// runs the prepass (hero+prepass) unless --no-prepass or a target error is given or the job's
// spp leaves it no budget: its first pass predicts whether per-pixel tables beat the emitter
// mixture and stops the prepass when they do not (about 2 % of the job's time then; the prepass
// is not a pilot candidate because it needs the job's own budget to learn anything). The
// choice is recorded in the job spec (JobSpec.auto_choice) with every candidate's figures, so a
// submitted job, and its report, say exactly what ran.
#pragma once

#include <cstdint>
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
// The least ratio of the caustic variance the pilot's eye samples missed to hero's measured
// variance for it to count (see above).
inline constexpr double kUnseenCausticFactor = 10.0;
// Clean caustics (see above): the most extra rays, as a share of hero's, and the least gain on
// the caustic paths' own variance.
inline constexpr double kCleanCausticRays = 0.02;
inline constexpr double kCleanCausticGain = 4.0;
// The candidate name of hero with --caustics light, and the choice of hero with the prepass.
inline constexpr char kHeroWithLightCaustics[] = "hero+caustics";
inline constexpr char kHeroWithPrepass[] = "hero+prepass";
// The pilot's spp per half: an eighth of the job's, in these bounds.
inline constexpr std::uint64_t kPilotSppDivisor = 8;
inline constexpr std::uint64_t kPilotMinSpp = 8;
inline constexpr std::uint64_t kPilotMaxSpp = 64;
// The most of the job's samples the pilot's renders take together (its pixels shrink to stay
// under it).
inline constexpr double kPilotShare = 0.04;
// A job whose smallest pilot (4x4 pixels) would take more than this share of its samples runs
// hero without a pilot.
inline constexpr double kTinyJobPilotShare = 0.25;
// The relative cost of one ray of each method (see above).
inline constexpr double kUniformRayCost = 1.0;
inline constexpr double kHeroRayCost = 1.16;
inline constexpr double kGradientRayCost = 1.18;

// Hero with light-traced caustics split into its eye paths' and its light paths' parts, per
// sample at one light path per pixel: variance(s) = eye + light/s, rays(s) = eye + s·light with
// s the light paths per pixel and sample. From the pilot's renders of its eye paths alone and
// the probe's light-only renders (the light part at s = 1).
struct CausticSplit {
  double eye_variance = 0, light_variance = 0;
  double eye_rays = 0, light_rays = 0;
  double variance(double s) const { return eye_variance + light_variance / s; }
  double rays(double s) const { return eye_rays + s * light_rays; }
  // The share that minimises variance × rays, a power of two in [job::kMinCausticPaths, 1].
  double best_share() const;
};
// The clean-caustics share (see above): the largest power of two s in [job::kMinCausticPaths, 1]
// whose light paths cost at most kCleanCausticRays × hero_rays (s × split.light_rays), if at
// that share their variance (split.light_variance / s) is at most caustic_variance (the eye
// tracers' variance of the caustic paths per sample, M − C²) / kCleanCausticGain; none
// otherwise, and none where any figure is not positive.
std::optional<double> clean_caustic_share(const CausticSplit& split, double caustic_variance,
                                          double hero_rays);

struct ResolvedIntegrator {
  RenderCommandOptions options;           // with an explicit integrator and prepass
  std::optional<job::AutoReport> report;  // set when `auto` chose
  // Gradient's τ pilot, run on the job as gradient would render it where gradient was a
  // candidate: its renders trace at the job's τ, and a gradient job reuses it
  // (choose_or_reuse_tau) rather than run it twice.
  std::optional<TauPilotRun> tau_pilot;
  // The scene's geometry where the pilot built it: its renders and the job reuse it
  // (coordinator::LocalRenderOptions::geometry) instead of building the same BVH again.
  std::shared_ptr<const worker::Geometry> geometry;
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
