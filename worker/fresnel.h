// Fresnel reflectance and the laws of reflection and refraction. `eta` is always the relative
// index η_t/η_i of the side the normal points away from (the interior) over the side it points
// to; a negative cos θi means the direction arrives from the interior and η is inverted.
#pragma once

#include <optional>

#include "worker/vecmath.h"

namespace prism::worker {

// Unpolarised reflectance of a dielectric boundary, in [0, 1]; 1 under total internal
// reflection. cos_theta_i may be negative (see above).
float fresnel_dielectric(float cos_theta_i, float eta);

// Unpolarised reflectance of a conductor with complex index eta + i·k for light arriving from a
// dielectric of index 1; cos_theta_i in [0, 1].
float fresnel_complex(float cos_theta_i, float eta, float k);

// Mirror direction of wo about n (both pointing away from the surface).
inline Vec3f reflect(const Vec3f& wo, const Vec3f& n) { return -wo + 2.0f * dot(wo, n) * n; }

struct Refraction {
  Vec3f wt;
  float etap;  // the relative index actually crossed: eta, or 1/eta from the interior
};

// Refracted direction of wi through the boundary with normal n; nullopt under total internal
// reflection.
std::optional<Refraction> refract(const Vec3f& wi, Vec3f n, float eta);

}  // namespace prism::worker
