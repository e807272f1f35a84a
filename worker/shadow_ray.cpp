#include "worker/shadow_ray.h"

#include <cmath>
#include <variant>

#include "worker/material.h"
#include "worker/medium.h"

namespace prism::worker {

Shadow trace_shadow(const RenderScene& scene, Vec3f origin, Vec3f direction, const Vec3f& target,
                    bool to_infinity, int medium, const SampledWavelengths& lambdas, int lanes,
                    TraceCounters& counters) {
  const Geometry& geometry = scene.geometry();
  Shadow shadow;
  for (int i = 0; i < lanes; ++i) shadow.transmittance[i] = shadow.pass[i] = 1.0f;
  for (int crossings = 0; crossings < 64; ++crossings) {
    float distance = kInfinity;
    if (!to_infinity) {
      Vec3f to_target = target - origin;
      float length_to_target = length(to_target);
      // An interface crossed within the offset of the target: nothing is left to test.
      if (!(length_to_target > 0) || dot(to_target, direction) <= 0) return shadow;
      direction = to_target / length_to_target;
      distance = length_to_target * (1.0f - 1e-4f);
    }
    ++counters.rays;
    // Through `medium` for `segment` (infinite: to the environment).
    const auto attenuate = [&](float segment) {
      if (medium < 0) return;
      const HomogeneousMedium& m = scene.media()[medium];
      SampledSpectrum sigma_t = m.sigma_a(lambdas) + m.sigma_s(lambdas);
      SampledSpectrum t;
      for (int i = 0; i < lanes; ++i) {
        t[i] =
            std::isinf(segment) ? (sigma_t[i] > 0 ? 0.0f : 1.0f) : std::exp(-sigma_t[i] * segment);
      }
      shadow.transmittance *= t;
      if (m.scattering()) {
        shadow.pass *= t;
        shadow.scattering = true;
      }
    };
    if (!scene.has_interfaces()) {
      // Whatever is hit blocks: an any-hit query, with no hit point or material to work out,
      // gives the same answer as the closest hit (alpha cut-outs decide each candidate alike).
      if (geometry.occluded({origin, direction}, distance)) return Shadow{};
      attenuate(distance);
      return shadow;
    }
    auto hit = geometry.intersect({origin, direction}, distance);
    attenuate(hit ? hit->t : distance);
    if (!hit) return shadow;
    const ShapeInfo& info = scene.shape(hit->shape);
    if (!std::holds_alternative<InterfaceMaterial>(
            scene.material_at(info.material, *hit, -direction))) {
      return Shadow{};
    }
    if (info.medium_transition) {
      medium = dot(direction, hit->ng) < 0 ? info.medium_inside : info.medium_outside;
    }
    origin = geometry.offset_origin(hit->p, hit->ng, direction);
  }
  return Shadow{};
}

}  // namespace prism::worker
