// A coated surface as one stochastic BSDF: pbrt-v4's LayeredBxDF (Guo, Hašan, Yan and Zhao 2018,
// "Position-Free Monte Carlo Simulation for Arbitrary Layered BSDFs"), the model behind its
// `coateddiffuse` and `coatedconductor` materials. A dielectric coat lies at z = thickness over an
// opaque base (diffuse or conductor) at z = 0; the slab between them may hold a homogeneous
// medium with unit extinction per unit thickness, single-scattering `albedo` and a
// Henyey–Greenstein phase function. Light bounces between the two interfaces any number of times,
// so there is no closed form: eval() is an unbiased random-walk estimate of f (with next-event
// connections through the coat), pdf() an approximate density for MIS, and sample() walks the
// slab until the path leaves it. Two-sided: for wo below the surface both directions are
// mirrored, so the coat always faces the viewer.
//
// Random but reproducible: the renderer promises bytes-identical images for any thread count, so
// every walk draws from a counter-based hash generator seeded by the bit patterns of the call's
// arguments (eval and pdf from (wo, wi) in separate streams, sample from (wo, uc, u)): the same
// call always returns the same bits.
//
// Hero wavelengths (bsdf_lobes.h): one walk serves every lane. Its directions and every random
// decision are made once; f is per lane (the base's reflectance or Fresnel term and the medium's
// albedo vary with λ; the coat's index does not: it is lane 0's η, so a material with a
// dispersive coat must terminate the secondary lanes itself, as pbrt-v4 does). Densities are the
// same in every live lane, so the integrator's per-lane pdf ratios are 1.
//
// A walk's sampling density is not computable, only the product of the densities along it.
// pbrt-v4 marks such samples "pdfIsProportional": the integrator divides by the walk's pdf but
// weights MIS with PDF(). Prism's integrator uses BsdfSample::pdf for both, so sample() returns
// pdf = pdf(wo, wi) and scales f to keep f/pdf equal to the walk's own ratio: the throughput is
// the walk's and BSDF and light sampling weigh MIS with the same density function.
//
// Two deliberate departures from pbrt-v4's f(), both of which bias pbrt's estimate (measured in
// layered_bsdf_test.cpp): a connection to wi through a rough coat is MIS-weighted with the
// density of the technique it competes with, p(w | wi), not p(wi | w); and eval() connects only
// where sample() could still leave within max_depth, so both sum the same set of paths.
#pragma once

#include <optional>
#include <variant>

#include "worker/bsdf_lobes.h"

namespace prism::worker {

struct LayerParams {
  float thickness = 0.01f;   // in units of the medium's mean free path (extinction 1)
  SampledSpectrum albedo{};  // single-scattering albedo per lane; all 0 = no scattering medium
  float g = 0;               // Henyey–Greenstein asymmetry of the medium
  int max_depth = 10;        // events per walk (at an interface or in the medium)
  int samples = 1;           // walks per eval() / pdf() estimate
};

class LayeredBsdf {
 public:
  using Base = std::variant<DiffuseBsdf, ConductorBsdf>;

  // top: the coat (radiance transport, η = η_coat/η_outside; lane 0's η is used for every lane).
  // bottom: the opaque base; for a conductor, η and k relative to the coat (the caller divides).
  LayeredBsdf(const DielectricBsdf& top, const Base& bottom, const LayerParams& params, int lanes);

  // A reflection at a smooth coat is the coat's own sample (specular, pdf = its probability), and
  // so is a walk made of specular events only (smooth coat, smooth conductor, no medium: pdf =
  // the product of its probabilities). Every other sample has pdf = pdf(wo, wi) in every live
  // lane and f scaled so that f/pdf is the walk's own ratio (see above).
  std::optional<BsdfSample> sample(const Vec3f& wo, float uc, Point2f u) const;
  // Unbiased estimate of f from params.samples walks (without the deltas of specular events).
  SampledSpectrum eval(const Vec3f& wo, const Vec3f& wi) const;
  // pbrt-v4's stochastic density estimate (the coat's reflection plus the TRT term), mixed 9:1
  // with the uniform sphere density: positive everywhere, but not normalised.
  SampledSpectrum pdf(const Vec3f& wo, const Vec3f& wi) const;
  bool specular() const { return false; }
  bool dispersive() const { return false; }

 private:
  float eta_;                // the coat's index, lane 0's
  TrowbridgeReitz distrib_;  // the coat's roughness
  Base bottom_;
  LayerParams params_;  // thickness >= FLT_MIN, albedo 0 beyond `lanes`, samples >= 1
  int lanes_;
  bool scattering_;  // any live lane has a non-zero albedo
};

}  // namespace prism::worker
