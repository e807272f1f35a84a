// Spectral ray differentials (spectral ray differentials paper §4, docs/estimators.md §6): how a
// path's point p and direction d move per nanometre of its wavelength, ∂p/∂λ and ∂d/∂λ, carried
// vertex by vertex along an eye or light path.
//
// Both start at zero at the camera and at a light, and stay zero until the path meets a
// dispersive event, so a SpectralDifferential is `tracked` only from the first dispersive
// refraction on: on every other path each update below is one branch and nothing is computed.
//
// The updates, world space, unit d:
//   transfer (Igehy 1999 with λ as the variable) to a surface with normal n at distance t:
//     ∂t = −(∂p + t·∂d)·n / (d·n),  ∂p' = ∂p + t·∂d + ∂t·d,  ∂d' = ∂d;
//   reflection about the shading normal n, which moves by ∂n = Geometry::normal_differential(∂p):
//     d' = d − 2(d·n)n,  ∂d' = ∂d − 2[(∂d·n + d·∂n)·n + (d·n)·∂n];
//   refraction (paper Eq. 1), n turned to face the ray (θ = d·n < 0), η = n_incident/n_transmitted:
//     d' = η·d − μ·n,  μ = η·θ + ω,  ω = √(1 − η² + η²θ²),
//     ∂θ = ∂d·n + d·∂n,  ∂ω = (−η·∂η + η·∂η·θ² + η²·θ·∂θ)/ω,  ∂μ = ∂η·θ + η·∂θ + ∂ω,
//     ∂d' = ∂η·d + η·∂d − ∂μ·n − μ·∂n
//   (algorithms.md §6 fixes the paper's Listing 1, whose sqrt(x) in ω and dO means x²).
//   Total internal reflection (1 − η² + η²θ² <= 0) has no refracted ray: the update reports it
//   and the path's differential ends. So does ω → 0 (grazing refraction, where ∂d' diverges)
//   and a transfer parallel to the surface.
// A rough dielectric refracts or reflects about its sampled microfacet normal m, held fixed in
// the surface's shading frame: m turns with the frame, ∂m = (n × ∂n) × m (the first-order
// rotation that takes n to n + ∂n).
#pragma once

#include "worker/vecmath.h"

namespace prism::worker {

struct SpectralDifferential {
  Vec3f dp;              // ∂p/∂λ, world units per nm
  Vec3f dd;              // ∂d/∂λ, per nm
  bool tracked = false;  // false: both are zero (no dispersive event yet)
};

// The relative index η = n_incident/n_transmitted and its derivative from each side's index and
// derivative: ∂η = (∂n_i·n_t − n_i·∂n_t)/n_t² (paper §4.2).
struct RelativeEta {
  float eta = 1.0f;
  float deta = 0.0f;
};
RelativeEta relative_eta(double n_incident, double dn_incident, double n_transmitted,
                         double dn_transmitted);

// Moves the differential along the unit direction d by distance t onto a surface with normal n
// (either orientation). False (the differential ends) when d is parallel to the surface.
bool transfer(SpectralDifferential& diff, const Vec3f& d, float t, const Vec3f& n);

// Reflection of the unit direction d about the unit normal n (either orientation), whose
// differential along diff.dp is dn.
void reflect(SpectralDifferential& diff, const Vec3f& d, const Vec3f& n, const Vec3f& dn);

// Refraction of the unit direction d through the unit normal n (either orientation; dn as for
// reflect) with relative index eta = n_incident/n_transmitted and its derivative. Starts
// tracking when deta != 0. False (the differential ends) at total internal reflection or at a
// grazing refraction.
bool refract(SpectralDifferential& diff, const Vec3f& d, const Vec3f& n, const Vec3f& dn,
             RelativeEta eta);

// The differential of a microfacet normal m held fixed in a shading frame whose normal n moves by
// dn: (n × dn) × m.
Vec3f microfacet_normal_differential(const Vec3f& n, const Vec3f& dn, const Vec3f& m);

}  // namespace prism::worker
