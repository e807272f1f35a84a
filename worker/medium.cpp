#include "worker/medium.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"
#include "services/scene/source_location.h"
#include "worker/material.h"

namespace prism::worker {
namespace {

constexpr float kInv4Pi = 0.25f * kInvPi;

// The HG density as a function of μ = cos θ = dot(wo, wi), per steradian.
float henyey_greenstein(float mu, float g) {
  const float denom = 1.0f + g * g + 2.0f * g * mu;
  return kInv4Pi * (1.0f - g * g) / (denom * safe_sqrt(denom));
}

// exp(−σ·t) with the convention that a lane without extinction transmits everything, even over
// an infinite segment (0·∞ would be NaN).
float transmittance(float sigma, float t) {
  return sigma == 0.0f ? 1.0f : std::exp(-sigma * t);
}

}  // namespace

float HenyeyGreenstein::p(const Vec3f& wo, const Vec3f& wi) const {
  return henyey_greenstein(dot(wo, wi), g_);
}

Vec3f HenyeyGreenstein::sample(const Vec3f& wo, Point2f u, float* pdf) const {
  // Inverting the CDF of μ: with s = 1 + g² + 2gμ, F(μ) = (1 + g)/(2g) − (1 − g²)/(2g·√s), so
  // F = ξ gives √s = (1 − g²)/(1 + g − 2gξ). ξ = 0 maps to μ = −1 (wi = −wo, straight on) in
  // both branches, so the isotropic limit used for tiny |g| is continuous with the general one.
  const float g = g_;
  float mu;
  if (std::abs(g) < 1e-3f) {
    mu = 2.0f * u.x - 1.0f;
  } else {
    const float root = (1.0f - g * g) / (1.0f + g - 2.0f * g * u.x);
    mu = (root * root - 1.0f - g * g) / (2.0f * g);
  }
  mu = std::clamp(mu, -1.0f, 1.0f);
  const float sin_theta = safe_sqrt(1.0f - mu * mu);
  const float phi = 2.0f * kPi * u.y;
  const Frame frame = Frame::from_z(wo);
  const Vec3f wi = frame.from_local({sin_theta * std::cos(phi), sin_theta * std::sin(phi), mu});
  if (pdf != nullptr) *pdf = henyey_greenstein(mu, g);
  return wi;
}

absl::StatusOr<HomogeneousMedium> HomogeneousMedium::create(
    const scene::Medium& medium, const spectral::SpectrumLibrary& library,
    const spectral::RgbUplift& uplift) {
  const auto& m = std::get<scene::HomogeneousMedium>(medium.kind);
  const std::string label = absl::StrCat("medium \"", medium.name, "\"");
  auto fail = [&](const std::string& what) {
    return scene::location_error(medium.where, absl::StrCat(label, ": ", what));
  };
  if (!(m.g > -1.0 && m.g < 1.0)) {
    return fail(absl::StrCat("g = ", m.g, " must be in (-1, 1)"));
  }
  if (!(m.scale >= 0.0) || !std::isfinite(m.scale)) {
    return fail(absl::StrCat("scale = ", m.scale, " must be finite and >= 0"));
  }
  auto sigma_a = job::resolve_spectrum(m.sigma_a, job::SpectrumRole::kUnbounded, library, uplift);
  if (!sigma_a.ok()) return fail(absl::StrCat("sigma_a: ", sigma_a.status().message()));
  auto sigma_s = job::resolve_spectrum(m.sigma_s, job::SpectrumRole::kUnbounded, library, uplift);
  if (!sigma_s.ok()) return fail(absl::StrCat("sigma_s: ", sigma_s.status().message()));

  HomogeneousMedium out;
  out.sigma_a_ = std::move(*sigma_a);
  out.sigma_s_ = std::move(*sigma_s);
  out.scale_ = float(m.scale);
  out.phase_ = HenyeyGreenstein(float(m.g));
  out.chromatic_ = !spectral::is_constant(out.sigma_a_) || !spectral::is_constant(out.sigma_s_);
  // max_value bounds the spectrum from above, and coefficients are >= 0 (resolve_spectrum), so
  // a zero bound means σ_s vanishes everywhere.
  out.scattering_ = out.scale_ > 0.0f && spectral::max_value(out.sigma_s_) > 0.0f;
  return out;
}

SampledSpectrum HomogeneousMedium::sigma_a(const SampledWavelengths& lambda) const {
  return spectral::sample(sigma_a_, lambda) * scale_;
}

SampledSpectrum HomogeneousMedium::sigma_s(const SampledWavelengths& lambda) const {
  return spectral::sample(sigma_s_, lambda) * scale_;
}

FreeFlight sample_free_flight(const SampledSpectrum& sigma_t, float t_max, float u, int lanes) {
  PRISM_CHECK(lanes >= 1 && lanes <= spectral::kMaxLanes);
  FreeFlight out;
  const float hero = sigma_t[0];
  if (hero > 0.0f) {
    // −log(1 − u) with u in [0, 1) is finite and >= 0.
    const float t = -std::log1p(-u) / hero;
    if (t < t_max) {
      out.scattered = true;
      out.t = t;
    }
  }
  if (!out.scattered) out.t = t_max;
  for (int s = 0; s < lanes; ++s) {
    const float tr = transmittance(sigma_t[s], out.t);
    out.transmittance[s] = tr;
    out.pdf[s] = out.scattered ? sigma_t[s] * tr : tr;
  }
  return out;
}

}  // namespace prism::worker
