// Options that decide what a worker computes for a job, besides the scene: one typed struct,
// validated once where it is built (the CLI or the job spec) and passed down as const&. Every
// field that changes output bytes is part of the job spec (proto/prism/v1/types.proto).
#pragma once

#include <cstdint>

#include "worker/sampler.h"

namespace prism::worker {

enum class IntegratorKind {
  kUniform,  // one wavelength per path (C = 1): the unbiased baseline
  kHero,     // C = 4 lanes with CMIS rotation (algorithms.md §2)
};

enum class SpectralPdfKind { kFlat, kVisible };      // sensor term p_s (§1)
enum class EmitterPdfKind { kUniform, kEmitters };   // emitter term p_e (§1)
enum class LightSelectionKind { kUniform, kPower, kSpatial };  // base pmf q_base (§3)

// The names the CLI flags, job specs and reports use for the option values.
inline const char* name(IntegratorKind kind) {
  return kind == IntegratorKind::kUniform ? "uniform" : "hero";
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

struct RenderOptions {
  IntegratorKind integrator = IntegratorKind::kHero;
  SpectralPdfKind spectral_pdf = SpectralPdfKind::kFlat;
  EmitterPdfKind emitter_pdf = EmitterPdfKind::kEmitters;
  double defensive_epsilon = 0.05;
  LightSelectionKind light_selection = LightSelectionKind::kPower;
  // Multiply the base pmf by the lanes' unit-emission factor Σ_s Ê[e][bin(λ_s)] (§3).
  bool spectral_light_selection = true;
  SamplerKind sampler = SamplerKind::kSobol;
  int bins = 64;            // 4..256
  int max_depth = 5;        // path vertices after the camera; 0 renders only direct emission
  int rr_min_depth = 3;     // Russian roulette from this depth on
  std::uint64_t seed = 0;

  int lanes() const { return integrator == IntegratorKind::kUniform ? 1 : 4; }
};

}  // namespace prism::worker
