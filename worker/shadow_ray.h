// Shadow rays, shared by every integrator (the path tracer's next-event estimation, the gradient
// integrator's base connections and its offsets' reconnections): a segment to a point, or a ray
// to infinity for the environment, that passes `interface` boundaries and runs through
// homogeneous media. It gives the transmittance per lane, and the probability that the
// unidirectional technique's free flights would have passed the same segments (equal to the
// transmittance in scattering media, 1 in purely absorbing ones, which are not sampled), both 0
// when anything else blocks the segment. In a scene without interface materials nothing lets a
// shadow ray through, and it is one occlusion query (no hit point, no material).
//
// A finite target is joined by the segment from each (offset) origin to it, not by the first
// direction: that direction was computed from the un-offset point, and its parallel line,
// shifted by the offset, can enter the light's own surface before the target (the floor-facing
// half of a sphere resting on the floor occluded itself for most samples).
#pragma once

#include "services/spectral/sampled.h"
#include "worker/integrator.h"
#include "worker/render_scene.h"
#include "worker/vecmath.h"

namespace prism::worker {

struct Shadow {
  SampledSpectrum transmittance;
  SampledSpectrum pass;
  bool scattering = false;  // some segment ran through a scattering medium
};

// The first `lanes` of `lambdas` are traced; rays are counted in counters.rays. At most 64
// interfaces are crossed (then the segment counts as blocked).
Shadow trace_shadow(const RenderScene& scene, Vec3f origin, Vec3f direction, const Vec3f& target,
                    bool to_infinity, int medium, const SampledWavelengths& lambdas, int lanes,
                    TraceCounters& counters);

}  // namespace prism::worker
