// Spectral ray differentials along whole paths (docs/estimators.md §6): the update through one
// scattering vertex, whatever its material, shared by light paths (light_tracer.cpp) and by eye
// paths' caustic chains (integrator.cpp), and the offset of a caustic's receiver found by an eye
// path, by replaying its delta chain from the light (spectral_differential.h has the per-event
// formulas).
#pragma once

#include <optional>
#include <span>

#include "worker/bsdf.h"
#include "worker/geometry.h"
#include "worker/material.h"
#include "worker/spectral_differential.h"

namespace prism::worker {

// The differential through the scattering at `hit` from unit direction `in` (arriving) to `out`
// (leaving), sampled as `specular` and `transmission`, at wavelength `lambda`. A non-delta
// event on anything but a dielectric ends the tracking (a diffuse receiver, a rough conductor, a
// layer); a dispersive dielectric's transmission starts it; a thin dielectric's transmission
// leaves it as it is; reflections and rough dielectrics turn it (the sampled microfacet normal
// held fixed in the shading frame).
void scatter_differential(SpectralDifferential& diff, const Geometry& geometry,
                          const Material& material, const SurfaceHit& hit, const Vec3f& in,
                          const Vec3f& out, bool specular, bool transmission, float lambda);

// One delta vertex of an eye path's caustic chain, in eye order: where it is, its material, and
// the eye path's arriving and leaving directions there.
struct ChainVertex {
  SurfaceHit hit;
  const Material* material = nullptr;
  Vec3f in, out;
  bool transmission = false;
};

// How a caustic's receiver y moves per nm: the light leaves `emitter` towards chain.back(),
// passes the chain's vertices in reverse (each with the reversed directions) and arrives at y
// (receiver, the eye path's first vertex); the differential is transferred onto y's surface.
// Empty when nothing on the way is dispersive or the differential ends (total internal
// reflection, grazing).
std::optional<Vec3f> receiver_offset(const Geometry& geometry, const SurfaceHit& receiver,
                                     std::span<const ChainVertex> chain, const Vec3f& emitter,
                                     float lambda);

}  // namespace prism::worker
