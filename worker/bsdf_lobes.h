// BSDF lobes: value types, gathered into one std::variant by bsdf.h. A BSDF is built at a surface
// hit from its material with every spectral parameter already evaluated at the path's
// wavelength lanes (SampledSpectrum), and works in the local shading frame (z = shading normal).
//
// Hero-wavelength sampling (docs/estimators.md §2): sample() draws a direction with lane 0's (the
// hero's) parameters and returns, for every lane s, f(wo, wi, λ_s) and the density
// p(wi | wo, λ_s) with which lane s would have drawn the same direction. The integrator sums
// those densities over lanes for the CMIS weight. Where a lane cannot produce the direction at all
// (refraction through a dispersive smooth dielectric: each wavelength has its own delta
// direction), its f and pdf are 0 and the sample says `hero_only`: the other lanes are then
// terminated. eval() and pdf() give the same per-lane values for a given pair of directions
// (0 for specular BSDFs, whose lobes are deltas).
//
// Conventions: radiance transport (camera paths), so refraction scales f by 1/η'²; the
// dielectric's eta is η_inside/η_outside with the normal pointing outside; a sample that fails
// returns nullopt ("no contribution"). Values of lanes at or beyond `lanes` are 0.
#pragma once

#include <optional>

#include "services/spectral/sampled.h"
#include "worker/microfacet.h"
#include "worker/vecmath.h"

namespace prism::worker {

using spectral::SampledSpectrum;

struct BsdfSample {
  Vec3f wi;
  SampledSpectrum f;    // per lane, already including nothing of the cosine or the pdf
  SampledSpectrum pdf;  // per lane; for specular lobes the discrete probability of the event
  bool specular = false;
  bool transmission = false;
  bool hero_only = false;  // the other lanes cannot follow: terminate them
  float etap = 1.0f;       // hero's relative index crossed by a transmission, else 1
};

// Lambertian reflection, on whichever side wo is (pbrt-v4 convention).
class DiffuseBsdf {
 public:
  DiffuseBsdf(const SampledSpectrum& reflectance, int lanes) : r_(reflectance), lanes_(lanes) {}
  std::optional<BsdfSample> sample(const Vec3f& wo, float uc, Point2f u) const;
  SampledSpectrum eval(const Vec3f& wo, const Vec3f& wi) const;
  SampledSpectrum pdf(const Vec3f& wo, const Vec3f& wi) const;
  bool specular() const { return false; }
  bool dispersive() const { return false; }

 private:
  SampledSpectrum r_;
  int lanes_;
};

// Smooth or rough (GGX) dielectric with a per-lane index of refraction.
class DielectricBsdf {
 public:
  // eta: per-lane η_inside/η_outside (> 0); dispersive: whether the lanes' η differ.
  DielectricBsdf(const SampledSpectrum& eta, int lanes, bool dispersive, TrowbridgeReitz distrib)
      : eta_(eta), lanes_(lanes), dispersive_(dispersive), distrib_(distrib) {}
  std::optional<BsdfSample> sample(const Vec3f& wo, float uc, Point2f u) const;
  SampledSpectrum eval(const Vec3f& wo, const Vec3f& wi) const;
  SampledSpectrum pdf(const Vec3f& wo, const Vec3f& wi) const;
  bool specular() const { return distrib_.effectively_smooth() || index_matched(); }
  bool dispersive() const { return dispersive_; }
  const TrowbridgeReitz& distribution() const { return distrib_; }
  float eta(int lane) const { return eta_[lane]; }

 private:
  bool index_matched() const { return !dispersive_ && eta_[0] == 1.0f; }
  std::optional<BsdfSample> sample_smooth(const Vec3f& wo, float uc) const;
  std::optional<BsdfSample> sample_rough(const Vec3f& wo, float uc, Point2f u) const;
  // Per-lane f and pdf of a rough pair (wo, wi).
  void eval_rough(const Vec3f& wo, const Vec3f& wi, SampledSpectrum* f, SampledSpectrum* pdf) const;

  SampledSpectrum eta_;
  int lanes_;
  bool dispersive_;
  TrowbridgeReitz distrib_;
};

// Smooth or rough (GGX) conductor with per-lane complex index η + i·k.
class ConductorBsdf {
 public:
  ConductorBsdf(const SampledSpectrum& eta, const SampledSpectrum& k, int lanes,
                TrowbridgeReitz distrib)
      : eta_(eta), k_(k), lanes_(lanes), distrib_(distrib) {}
  std::optional<BsdfSample> sample(const Vec3f& wo, float uc, Point2f u) const;
  SampledSpectrum eval(const Vec3f& wo, const Vec3f& wi) const;
  SampledSpectrum pdf(const Vec3f& wo, const Vec3f& wi) const;
  bool specular() const { return distrib_.effectively_smooth(); }
  bool dispersive() const { return false; }

 private:
  SampledSpectrum fresnel(float cos_theta) const;

  SampledSpectrum eta_;
  SampledSpectrum k_;
  int lanes_;
  TrowbridgeReitz distrib_;
};

// pbrt-v4's DiffuseTransmissionBxDF: Lambertian reflection R/π on wo's side and transmission
// T/π on the other. A lane picks its side with probability R/(R + T) of its own values (so
// each lane's density is its own technique's, as CMIS needs), then a cosine direction.
class DiffuseTransmissionBsdf {
 public:
  DiffuseTransmissionBsdf(const SampledSpectrum& r, const SampledSpectrum& t, int lanes)
      : r_(r), t_(t), lanes_(lanes) {}
  std::optional<BsdfSample> sample(const Vec3f& wo, float uc, Point2f u) const;
  SampledSpectrum eval(const Vec3f& wo, const Vec3f& wi) const;
  SampledSpectrum pdf(const Vec3f& wo, const Vec3f& wi) const;
  bool specular() const { return false; }
  bool dispersive() const { return false; }

 private:
  SampledSpectrum r_, t_;
  int lanes_;
};

// pbrt-v4's ThinDielectricBxDF: a thin slab's two interfaces with every internal bounce summed,
// R' = R + T²R/(1 − R²) and T' = 1 − R' (R the interface's Fresnel reflectance at the lane's η).
// Reflection mirrors and transmission passes straight through, so both events leave in the
// same direction at every wavelength: every lane follows, each with its own probability.
class ThinDielectricBsdf {
 public:
  ThinDielectricBsdf(const SampledSpectrum& eta, int lanes) : eta_(eta), lanes_(lanes) {}
  std::optional<BsdfSample> sample(const Vec3f& wo, float uc, Point2f u) const;
  SampledSpectrum eval(const Vec3f&, const Vec3f&) const { return {}; }
  SampledSpectrum pdf(const Vec3f&, const Vec3f&) const { return {}; }
  bool specular() const { return true; }
  bool dispersive() const { return false; }
  // R' of lane `lane` at cos θ_o.
  float reflectance(int lane, float cos_theta_o) const;

 private:
  SampledSpectrum eta_;
  int lanes_;
};

}  // namespace prism::worker
