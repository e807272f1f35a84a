// Homogeneous participating media with spectral coefficients, and the Henyey–Greenstein phase
// function. Distance sampling uses the hero lane's extinction, σ_t(λ_0); with C lanes the
// transmittance and the distance pdf differ per lane, so the integrator weights lane s with
// the spectral MIS (hero) rule, dividing by Σ_k p_k(t) (docs/estimators.md §2), which keeps
// chromatic media unbiased. All values are per lane (SampledSpectrum).
#pragma once

#include <optional>

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/rgb_uplift.h"
#include "services/spectral/sampled.h"
#include "worker/vecmath.h"

namespace prism::worker {

using spectral::SampledSpectrum;
using spectral::SampledWavelengths;

class HenyeyGreenstein {
 public:
  explicit HenyeyGreenstein(float g) : g_(g) {}
  // p(wo, wi) with both pointing away from the scattering point (pbrt-v4 convention):
  // p = (1 − g²) / (4π (1 + g² + 2g cos θ)^{3/2}), cos θ = dot(wo, wi).
  float p(const Vec3f& wo, const Vec3f& wi) const;
  // Samples wi with density p(wo, wi); returns wi and writes its pdf.
  Vec3f sample(const Vec3f& wo, Point2f u, float* pdf) const;
  float g() const { return g_; }

 private:
  float g_;
};

class HomogeneousMedium {
 public:
  static absl::StatusOr<HomogeneousMedium> create(const scene::Medium& medium,
                                                  const spectral::SpectrumLibrary& library,
                                                  const spectral::RgbUplift& uplift);

  // Coefficients per scene unit at the lanes' wavelengths (scale applied).
  SampledSpectrum sigma_a(const SampledWavelengths& lambda) const;
  SampledSpectrum sigma_s(const SampledWavelengths& lambda) const;
  const HenyeyGreenstein& phase() const { return phase_; }
  // True when σ_a or σ_s vary with wavelength (a chromatic medium).
  bool chromatic() const { return chromatic_; }
  bool scattering() const { return scattering_; }

 private:
  spectral::Spectrum sigma_a_;
  spectral::Spectrum sigma_s_;
  float scale_ = 1;
  HenyeyGreenstein phase_{0};
  bool chromatic_ = false;
  bool scattering_ = false;
};

// Free-flight sampling along a segment of length t_max in a homogeneous medium, driven by the
// hero lane: t = −ln(1 − u) / σ_t(λ_0). Returns per lane the transmittance T_s(t) and the
// density (or, past t_max, the probability) with which lane s would have produced this outcome:
//   scattered at t < t_max:   pdf_s = σ_t,s · T_s(t)
//   passed the segment:       pdf_s = T_s(t_max)
// A hero with σ_t = 0 always passes. `t` is the scattering distance, or t_max when the segment
// was passed (t_max may be infinite; a lane with σ_t = 0 then still transmits 1). Lanes at or
// beyond `lanes` are 0. The integrator divides lane contributions by Σ_k pdf_k: when each of the
// C wavelengths takes the hero role equally often (CMIS rotation), Σ_h E_h[f_s / Σ_k pdf_k] is
// exactly the integral of f_s over outcomes (scatter distances and "passed"), for every lane s.
// `u` in [0, 1).
struct FreeFlight {
  bool scattered = false;
  float t = 0;
  SampledSpectrum transmittance;
  SampledSpectrum pdf;
};
FreeFlight sample_free_flight(const SampledSpectrum& sigma_t, float t_max, float u, int lanes);

}  // namespace prism::worker
