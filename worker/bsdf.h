// The BSDF of a hit: the closed set of BSDFs (bsdf_lobes.h for the single-lobe ones, their
// conventions and hero-wavelength semantics; layered_bsdf.h for pbrt-v4's coated materials) as
// one std::variant, dispatched with std::visit.
#pragma once

#include <optional>
#include <variant>

#include "worker/bsdf_lobes.h"
#include "worker/layered_bsdf.h"

namespace prism::worker {

using Bsdf = std::variant<DiffuseBsdf, DielectricBsdf, ConductorBsdf, DiffuseTransmissionBsdf,
                          ThinDielectricBsdf, LayeredBsdf>;

inline std::optional<BsdfSample> sample(const Bsdf& bsdf, const Vec3f& wo, float uc, Point2f u) {
  return std::visit([&](const auto& b) { return b.sample(wo, uc, u); }, bsdf);
}
inline SampledSpectrum eval(const Bsdf& bsdf, const Vec3f& wo, const Vec3f& wi) {
  return std::visit([&](const auto& b) { return b.eval(wo, wi); }, bsdf);
}
inline SampledSpectrum pdf(const Bsdf& bsdf, const Vec3f& wo, const Vec3f& wi) {
  return std::visit([&](const auto& b) { return b.pdf(wo, wi); }, bsdf);
}
inline bool is_specular(const Bsdf& bsdf) {
  return std::visit([](const auto& b) { return b.specular(); }, bsdf);
}
// Whether sampling depends on the wavelength (the event a gradient shift or a lane split needs).
inline bool is_dispersive(const Bsdf& bsdf) {
  return std::visit([](const auto& b) { return b.dispersive(); }, bsdf);
}

}  // namespace prism::worker
