// `--integrator light`: an unbiased spectral light tracer (docs/estimators.md §6). A light path
// picks a wavelength λ from the scene's distribution p(λ) and a light with probability
// proportional to its spectral power at λ, emits from a point on it, and at every vertex
// whose BSDF is not a delta connects to the camera through a shadow ray: each connection is a
// splat at the raster position where the vertex projects. An area light's own point connects
// too (a point or spot light's does not: no camera ray can hit a point, so no eye tracer shows
// one). The path continues by sampling the adjoint BSDF: the value of a
// scattering is f(towards the camera side, towards the light side), with pbrt-v4's
// shading-normal correction and no 1/η² at refractions (importance, not radiance, is carried).
//
// What one path of index (x, y) in batch s (a "sample") contributes, summed over its splats,
// estimates W·H times the eye tracer's per-pixel radiance at the pixels it lands in, so a batch
// of W·H paths is worth one sample per pixel (LightTaskRenderer divides by W·H).
//
// Homogeneous media: a path starts in its light's medium (an area light's per side of its shape,
// any other light's the one declared with it, pbrt-v4's light MediumInterface; light from
// infinitely far declared in a medium that attenuates at λ reaches nothing, as an eye path
// escaping through it finds) and changes medium where it crosses a boundary. On each segment in
// a scattering medium it samples a free flight with the density σ_t·T(t) (weight σ_s/σ_t where it
// scatters, 1 where it passes); a medium vertex connects to the camera with the phase function
// per unit volume and scatters by sampling it; absorbing media weigh by their transmittance. With
// --caustics light a caustic path never scatters in a medium (the eye paths take those that do),
// so every segment weighs by its transmittance. Camera connections run through the media by
// trace_shadow.
//
// Limits, refused by check_light_tracing with the reason: a perspective camera only (a pinhole,
// or a thin lens with a lens point of its own per connection: Camera::connect), no portal on
// the environment. What a light tracer cannot render at all
// and an eye tracer can: whatever the camera sees through a delta BSDF (a mirror, smooth glass)
// and the environment seen directly, since no light path can hit the camera. Those pixels stay
// dark; `--caustics light` (hero plus light paths) is the combination that renders everything.
//
// With --caustics light (RenderOptions::light_caustics) a path connects only at its first
// non-delta vertex, and only after one delta vertex or more (light → delta chain → receiver),
// and ends there; the eye paths leave out exactly those paths (integrator.h's caustic_chain),
// so the two add up to each path once. A caustic path's first vertex is a delta one, so its
// first segment meets the bounding sphere of a shape whose material can be a delta (anything
// but diffuse, diffuse transmission and interface): in this mode lights emit only towards those
// spheres (a direction in the cone of one, chosen uniformly, the density the mixture of every
// cone holding it; for light from infinitely far a point on the disk of one across the beam),
// which covers every caustic path and wastes no path on the rest.
//
// For `--integrator auto`'s pilot (RenderOptions::caustic_probe) the caustic paths are rendered
// alone, without eye samples, plainly or with each splat times the value an eye path would have
// carried for the same path (the BSDF sample at the receiver, the chain's factors, the light's
// radiance, over p(λ)·bin width, the lanes still live and the eye path's Russian-roulette
// survival): that image's mean is the eye tracers' second moment of the caustic paths per sample
// (client/auto_integrator.h).
//
// Spectral ray differentials (spectral_differential.h) are carried from the first dispersive
// refraction to the first non-delta vertex, the receiver; each splat records its raster
// position's derivative per nm, for differential splatting.
#pragma once

#include <cstdint>
#include <vector>

#include "absl/status/status.h"
#include "worker/integrator.h"
#include "worker/render_scene.h"

namespace prism::worker {

// The sample stream of light paths: its own pass, apart from every eye path's.
inline constexpr std::uint32_t kLightPathPass = 1u << 20;

// With --caustics light, a sphere around a shape that may scatter as a delta (a caustic path's
// first vertex lies on one): light paths are emitted towards these only.
struct CausticTarget {
  Vec3f centre;
  float radius = 0;
};

struct LightSplat {
  Point2f raster;         // film position (pixel x + offset)
  int bin = 0;            // the wavelength's bin
  float value = 0;        // per-bin radiance estimate: contribution / (p(λ)·bin width)
  float rgb[3] = {};      // its linear sRGB from the exact wavelength (contribution·r̄(λ)/p(λ))
  float lambda = 0;       // nm
  Point2f raster_per_nm;  // d(raster)/dλ (0 unless the path met a dispersive refraction)
  bool has_differential = false;
  // The receiver (the vertex that connected): its point, unit geometric normal and ∂p/∂λ (world
  // units per nm; with has_differential), for differential splatting's bilateral weights.
  Vec3f position, normal, position_per_nm;
  int light = -1;  // the light the path started from (RenderScene::lights())
};

// The spheres around the scene's shapes that may scatter as a delta: empty when the scene has no
// caustic path for --caustics light to trace.
std::vector<CausticTarget> caustic_targets(const RenderScene& scene);

// OK when the scene can be light traced; otherwise INVALID_ARGUMENT saying what stands in the
// way (with the scene position where there is one).
absl::Status check_light_tracing(const RenderScene& scene);

class LightTracer {
 public:
  // The scene must pass check_light_tracing.
  explicit LightTracer(const RenderScene& scene);

  // Traces light path (x, y) of batch `sample_index`, appending its splats to `out`. Pure
  // function of its arguments.
  void trace(int x, int y, std::uint32_t sample_index, std::vector<LightSplat>& out,
             TraceCounters& counters) const;

  // The largest distance, in pixels, from a splat to a pixel centre it reaches.
  float filter_radius() const { return filter_radius_; }

 private:
  const RenderScene& scene_;
  std::vector<double> power_;           // per light: total power (light_power)
  std::vector<double> mean_value_;      // per light: its spectrum's mean over Λ
  std::vector<CausticTarget> targets_;  // --caustics light only
  float filter_radius_ = 0.5f;
};

}  // namespace prism::worker
