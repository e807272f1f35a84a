// Options that decide what a worker computes for a job, besides the scene: one typed struct,
// validated once where it is built (the CLI or the job spec) and passed down as const&. Every
// field that changes output bytes is part of the job spec (proto/prism/v1/types.proto). Part of
// the job layer (services/job): the worker traces with them, the coordinator plans with them.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"

namespace prism::job {

enum class IntegratorKind {
  kUniform,   // one wavelength per path (C = 1): the unbiased baseline
  kHero,      // C = 4 lanes with CMIS rotation (docs/estimators.md §2)
  kGradient,  // spectral gradient sampling (§5): C = 1 base paths with offsets at λ ± δ
  kLight,     // light tracing (§6): C = 1 light paths connected to a pinhole camera
};

enum class SpectralPdfKind { kFlat, kVisible };                // sensor term p_s (§1)
enum class EmitterPdfKind { kUniform, kEmitters };             // emitter term p_e (§1)
enum class LightSelectionKind { kUniform, kPower, kSpatial };  // base pmf q_base (§3)
// Which sample sequence a worker draws from (worker/sampler.h): independent per-dimension hashes,
// or the Owen-scrambled Sobol sequence.
enum class SamplerKind { kIndependent, kSobol };

// The names the CLI flags, job specs and reports use for the option values.
inline const char* name(IntegratorKind kind) {
  switch (kind) {
    case IntegratorKind::kUniform:
      return "uniform";
    case IntegratorKind::kHero:
      return "hero";
    case IntegratorKind::kGradient:
      return "gradient";
    case IntegratorKind::kLight:
      return "light";
  }
  return "?";
}
inline const char* name(SpectralPdfKind kind) {
  return kind == SpectralPdfKind::kFlat ? "flat" : "visible";
}
inline const char* name(EmitterPdfKind kind) {
  return kind == EmitterPdfKind::kUniform ? "uniform" : "emitters";
}
inline const char* name(LightSelectionKind kind) {
  switch (kind) {
    case LightSelectionKind::kUniform:
      return "uniform";
    case LightSelectionKind::kPower:
      return "power";
    case LightSelectionKind::kSpatial:
      return "spatial";
  }
  return "?";
}

// RenderOptions::gradient_lanes: the default, 0, lets the scene decide (GradientIntegrator: 1
// where a material may refract smooth-dispersively, else kSceneGradientLanes); the largest C
// (the base, two offsets and C − 1 more lanes share one set of spectral evaluations,
// spectral::kMaxLanes = 8).
inline constexpr int kDefaultGradientLanes = 0;
inline constexpr int kSceneGradientLanes = 4;
inline constexpr int kMaxGradientLanes = 6;

struct RenderOptions {
  IntegratorKind integrator = IntegratorKind::kHero;
  SpectralPdfKind spectral_pdf = SpectralPdfKind::kFlat;
  EmitterPdfKind emitter_pdf = EmitterPdfKind::kEmitters;
  double defensive_epsilon = 0.05;
  LightSelectionKind light_selection = LightSelectionKind::kPower;
  // Multiply the base pmf by the lanes' unit-emission factor Σ_s Ê[e][bin(λ_s)] (§3).
  bool spectral_light_selection = true;
  SamplerKind sampler = SamplerKind::kSobol;
  int bins = 64;         // 4..256
  int max_depth = 5;     // path vertices after the camera; 0 renders only direct emission
  int rr_min_depth = 3;  // Russian roulette from this depth on
  std::uint64_t seed = 0;
  // Gradient sampling (§5): the spectral offset k in bins and the shift threshold τ >= 0 (paper
  // Eq. 16, made symmetric). Whoever builds the options snaps k with gradient_offset_bins below;
  // the gradient integrator checks 1 <= k < bins as an invariant.
  int gradient_offset_bins = 10;
  // Also accumulate the squares of G and the even-indexed samples' sums (TileBuffers::halves),
  // for the variance-weighted reconstruction.
  bool gradient_variances = false;
  float gradient_tau = 0;
  // Hero lanes C of the gradient integrator's base paths (paper §3.4 as built here,
  // gradient/integrator.h): 1, single-wavelength base paths; 2..kMaxGradientLanes, C rotated
  // wavelengths, shifted only after a smooth dispersive refraction; 0, by the scene.
  int gradient_lanes = kDefaultGradientLanes;
  // `--caustics light` (hero and uniform, docs/estimators.md §6): light paths render the caustic
  // paths light → delta chain (one vertex or more) → the camera's first, non-delta vertex, and
  // the eye paths everything else; a task is then the whole image (both kinds splat or cover
  // every pixel).
  bool light_caustics = false;
  // With light_caustics: light paths per pixel and sample (kMinCausticPaths..1); a batch is
  // light_paths_per_batch(W·H) paths.
  float caustic_paths = 1.0f;
  // With light_caustics, for `--integrator auto`'s pilot only (never on the wire): kLightOnly
  // renders the light paths alone, no eye samples; kEyeMoments renders them alone with every
  // splat times the value an eye path of `lanes()` lanes would carry for the same path
  // (light_tracer.h), so the image estimates the eye tracer's second moment per sample of the
  // caustic paths, which its own few samples see too rarely (client/auto_integrator.h);
  // kEyeOnly renders the eye paths alone, without the caustic paths the light paths would add.
  enum class CausticProbe { kOff, kLightOnly, kEyeMoments, kEyeOnly };
  CausticProbe caustic_probe = CausticProbe::kOff;
  // Differential splatting of the light paths (§6.1) when > 0: Δλ in nm at sample 0, shrinking
  // as (s + 1)^(-1/5); also a filtered image beside the unbiased one (TileBuffers::filtered).
  float splat_width_nm = 0;
  // Gathering (§6.2) for eye-traced jobs when > 0: eye paths record each caustic event's
  // spectral offset on the film, and the coordinator filters the image along each pixel's mean
  // offset over ±Δλ, Δλ = gather_width_nm·spp^(−1/5), into the filtered image.
  float gather_width_nm = 0;

  int lanes() const { return integrator == IntegratorKind::kHero ? 4 : 1; }
  // Light paths splat over the whole film, so such a job's task is the whole image.
  bool traces_light_paths() const { return integrator == IntegratorKind::kLight || light_caustics; }
  // The light paths of one batch (one sample of every pixel) on a film of `pixels` pixels: all of
  // them for the light integrator, a share of them for caustics (at least one).
  std::int64_t light_paths_per_batch(std::int64_t pixels) const {
    if (!light_caustics || caustic_paths >= 1.0f) return pixels;
    return std::max<std::int64_t>(1, std::llround(double(caustic_paths) * double(pixels)));
  }
  bool splats_differentials() const { return splat_width_nm > 0; }
  bool gathers() const { return gather_width_nm > 0; }
  // Either filter: the job writes a filtered image.
  bool filters() const { return splats_differentials() || gathers(); }

  // Every field: what a worker compares before it reuses a RenderScene built for other options
  // (a field added above is compared without anyone having to remember it).
  friend bool operator==(const RenderOptions&, const RenderOptions&) = default;
};

// Range of RenderOptions::caustic_paths.
inline constexpr float kMinCausticPaths = 1.0f / 256.0f;

// Range of RenderOptions::splat_width_nm when on, and the CLI's default.
inline constexpr float kMinSplatWidthNm = 0.1f;
inline constexpr float kMaxSplatWidthNm = 470.0f;
inline constexpr float kDefaultSplatWidthNm = 100.0f;
// Δλ of differential splatting at sample s (0-based): width·(s + 1)^(−1/5), the kernel width of
// a consistent density estimate (bias O(Δλ²), variance O(1/(n·Δλ))): docs/estimators.md §6.1.
inline double splat_width_at(float width_nm, std::uint64_t s) {
  return double(width_nm) * std::pow(double(s) + 1.0, -0.2);
}

// The lanes C of a prepass task: the hero path tracer with its default C (docs/estimators.md §2,
// §4), whatever the job's integrator.
inline constexpr int kPrepassLanes = 4;

// k = round(δ_frac · bins): the offset δ = k·w snapped to whole bins so that λ ± δ falls in bin
// b ± k exactly. INVALID_ARGUMENT when δ_frac is not in (0, 0.5] (beyond half the range the
// cyclic offset −δ is the shorter one) or when it snaps to 0 bins (or to all of them).
inline absl::StatusOr<int> gradient_offset_bins(double delta_frac, int bins) {
  if (!(delta_frac > 0.0 && delta_frac <= 0.5)) {
    return absl::InvalidArgumentError(
        absl::StrCat("gradient offset ", delta_frac, " is not in (0, 0.5] of the spectral range"));
  }
  const int k = int(std::lround(delta_frac * bins));
  if (k < 1 || k >= bins) {
    return absl::InvalidArgumentError(
        absl::StrCat("gradient offset ", delta_frac, " of ", bins, " bins rounds to ", k,
                     " bins; use a larger offset (at least ", 0.5 / bins, ") or more bins"));
  }
  return k;
}

}  // namespace prism::job
