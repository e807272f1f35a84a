// The local pieces of the spectral shift mapping (docs/estimators.md §5, spectral gradient paper
// §3.1): how an offset path at λ' chooses its next direction at one vertex given what the base
// path did there at λ, and the Jacobian of that choice. Everything is in a vertex's local
// shading frame (z = shading normal) except the reconnection, which is in world space.
//
// Measures. A rough vertex's free variable is the sampled direction ω_i (solid angle); the
// offset's direction ω_i' is a function of ω_i, and the Jacobian is dω_i'/dω_i, the density
// ratio that turns an integral over offset directions into one over base directions. A smooth
// (delta) vertex has no free variable: the offset takes the same event (reflect / refract) with
// its own η and its own incoming direction, and the Jacobian is 1; the ratio of the events'
// values (Fresnel, 1/η'²) is part of f, not of J.
//
// Half-vector copy (paper Eq. 12, in relative indices): for a reflection h = normalize(ω_o + ω_i),
// for a refraction from the side of ω_o into a medium of relative index η (the index of ω_i's side
// over ω_o's side) h = normalize(ω_o + η·ω_i), oriented to +z. The offset keeps h and
// reflects or refracts its own ω_o' with its own η'. Jacobians:
//   reflection  dω_i'/dω_i = |ω_o'·h| / |ω_o·h|                    (dω_i/dω_h = 4|ω_o·h|)
//   refraction  dω_i'/dω_i = (η/η')² · |ω_i·h| / |ω_i'·h|
//                             · ((ω_o'·h + η'·ω_i'·h) / (ω_o·h + η·ω_i·h))²
// the second being paper Eq. 13 (dω_i/dω_h = (ω_o·h + η ω_i·h)² / (η²|ω_i·h|), Walter et al.
// 2007 Eq. 16). Both are exact inverses of the same shift run backwards (λ' → λ), which the tests
// check together with finite differences of the mapping itself.
//
// Reconnection: the offset at y joins the base's next vertex z (position p_z, geometric normal
// n_z), which the base reached from x along ω. Then dω_y/dω_x = (|cos θ_y| / d_y²) / (|cos θ_x| /
// d_x²) with the cosines at z (target side), d the distances x→z and y→z.
#pragma once

#include <optional>

#include "worker/vecmath.h"

namespace prism::worker {

struct DirectionShift {
  Vec3f wi;               // the offset's new direction, local frame, unit length
  float jacobian = 1.0f;  // dω_i'/dω_i (1 for smooth vertices)
};

// What the base did at a vertex, in its local frame: its incoming direction wo (pointing away
// from the surface), the sampled wi, whether it refracted, and its relative index η(λ) (inside
// over outside; ignored for reflections). `smooth` marks a delta vertex.
struct BaseScatter {
  Vec3f wo;
  Vec3f wi;
  bool transmission = false;
  bool smooth = false;
  float eta = 1.0f;
};

// The offset's direction at a vertex where it arrives along wo_offset with relative index
// eta_offset. nullopt when the shift fails: total internal reflection where the base refracted,
// a half-vector the offset sees from the wrong side, or a direction on the wrong side of the
// surface for the event (the BSDF would be zero there and the inverse shift could not return).
std::optional<DirectionShift> shift_direction(const BaseScatter& base, const Vec3f& wo_offset,
                                              float eta_offset);

// The base's generalised half-vector (oriented to +z), or nullopt when it is degenerate.
std::optional<Vec3f> generalized_half_vector(const BaseScatter& base);

// dω_y/dω_x for reconnecting the offset at y to the base's vertex z reached from x
// (world space; n_z the geometric normal at z). 0 when a cosine or distance vanishes.
float reconnection_jacobian(const Vec3f& x, const Vec3f& y, const Vec3f& z, const Vec3f& n_z);

}  // namespace prism::worker
