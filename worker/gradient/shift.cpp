#include "worker/gradient/shift.h"

#include <cmath>

#include "worker/fresnel.h"

namespace prism::worker {
namespace {

// The relative index crossed by a refraction leaving from wo's side (the BSDFs' convention:
// eta is inside over outside, the normal points outside).
float crossed_eta(const Vec3f& wo, float eta) {
  return wo.z > 0 ? eta : 1.0f / eta;
}

// The solid-angle density ratio dω_i/dω_h of a refraction about h (Walter et al. 2007 Eq. 16
// inverted), in the relative index etap of wi's side over wo's side.
float refraction_dwi_dwh(const Vec3f& wo, const Vec3f& wi, const Vec3f& h, float etap) {
  float denom = dot(wo, h) + etap * dot(wi, h);
  return denom * denom / (etap * etap * std::abs(dot(wi, h)));
}

}  // namespace

std::optional<Vec3f> generalized_half_vector(const BaseScatter& base) {
  if (base.smooth) return Vec3f(0, 0, 1);
  Vec3f h =
      base.transmission ? base.wo + base.wi * crossed_eta(base.wo, base.eta) : base.wo + base.wi;
  float len2 = length_squared(h);
  if (!(len2 > 0) || !std::isfinite(len2)) return std::nullopt;
  h = face_forward(h / std::sqrt(len2), Vec3f(0, 0, 1));
  // The BSDFs give these configurations zero value, so a base path never contains them.
  if (!(dot(h, base.wo) * base.wo.z > 0) || !(dot(h, base.wi) * base.wi.z > 0)) {
    return std::nullopt;
  }
  return h;
}

std::optional<DirectionShift> shift_direction(const BaseScatter& base, const Vec3f& wo_offset,
                                              float eta_offset) {
  if (wo_offset.z == 0.0f) return std::nullopt;
  if (base.smooth) {
    // Same event, own incoming direction and own index; a delta has no free variable, J = 1.
    if (!base.transmission) return DirectionShift{{-wo_offset.x, -wo_offset.y, wo_offset.z}, 1.0f};
    auto refraction = refract(wo_offset, Vec3f(0, 0, 1), eta_offset);
    if (!refraction || refraction->wt.z == 0.0f) return std::nullopt;  // TIR: the shift fails
    return DirectionShift{normalize(refraction->wt), 1.0f};
  }
  auto h = generalized_half_vector(base);
  if (!h) return std::nullopt;
  if (!(dot(*h, wo_offset) * wo_offset.z > 0)) return std::nullopt;
  DirectionShift shift;
  if (!base.transmission) {
    shift.wi = reflect(wo_offset, *h);
    if (!same_hemisphere(wo_offset, shift.wi)) return std::nullopt;
    shift.jacobian = std::abs(dot(wo_offset, *h)) / std::abs(dot(base.wo, *h));
  } else {
    auto refraction = refract(wo_offset, *h, eta_offset);
    if (!refraction) return std::nullopt;
    shift.wi = normalize(refraction->wt);
    if (same_hemisphere(wo_offset, shift.wi) || shift.wi.z == 0.0f) return std::nullopt;
    shift.jacobian =
        refraction_dwi_dwh(wo_offset, shift.wi, *h, crossed_eta(wo_offset, eta_offset)) /
        refraction_dwi_dwh(base.wo, base.wi, *h, crossed_eta(base.wo, base.eta));
  }
  if (!(dot(*h, shift.wi) * shift.wi.z > 0) || !std::isfinite(shift.jacobian) ||
      !(shift.jacobian > 0)) {
    return std::nullopt;
  }
  return shift;
}

float reconnection_jacobian(const Vec3f& x, const Vec3f& y, const Vec3f& z, const Vec3f& n_z) {
  Vec3f dx = z - x, dy = z - y;
  float dx2 = length_squared(dx), dy2 = length_squared(dy);
  if (!(dx2 > 0) || !(dy2 > 0)) return 0.0f;
  float cos_x = std::abs(dot(n_z, dx)) / std::sqrt(dx2);
  float cos_y = std::abs(dot(n_z, dy)) / std::sqrt(dy2);
  if (!(cos_x > 0)) return 0.0f;
  float j = (cos_y * dx2) / (cos_x * dy2);
  return std::isfinite(j) ? j : 0.0f;
}

}  // namespace prism::worker
