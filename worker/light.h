// Emitters, resolved: spectra evaluated through services/spectral. The `scale` a light is
// created with is final: RenderScene applies pbrt-v4's rule before (docs/estimators.md §9: the
// spectrum is divided by ColorMatching::photometric_sum before the scene's `scale`, and
// `power` then rescales to a total power).
// Closed set as a std::variant:
//   AreaLight      a diffuse emitter over one shape (all its triangles, a sphere or a disk), one-
//                  or two-sided; positions are sampled uniformly by area (triangles chosen by
//                  area) or, for a sphere seen from outside, uniformly in the cone it subtends.
//   PointLight     radiant intensity I(λ) at a point.
//   SpotLight      pbrt-v4's spot: intensity times smoothstep falloff between the cone angles.
//   InfiniteLight  constant radiance from every direction (sampled uniformly over the sphere),
//                  or an environment map (sampled by its texels' brightness), optionally
//                  through a portal.
// All radiometric values are per lane (SampledSpectrum) for the path's wavelengths.
#pragma once

#include <memory>
#include <optional>
#include <variant>
#include <vector>

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/rgb_uplift.h"
#include "services/spectral/sampled.h"
#include "services/spectral/spectrum.h"
#include "services/spectral/wavelength_grid.h"
#include "worker/environment_map.h"
#include "worker/geometry.h"
#include "worker/portal.h"
#include "worker/vecmath.h"

namespace prism::worker {

using spectral::SampledSpectrum;
using spectral::SampledWavelengths;

// A point from which a light is sampled: position and (for surfaces) the normal used to skip
// lights behind the surface; n = 0 for points in media.
struct LightContext {
  Vec3f p;
  Vec3f n;
};

struct LightSample {
  SampledSpectrum radiance;  // L(λ_s) arriving at the context point along -wi, before visibility
  Vec3f wi;                  // unit direction from the context point towards the light
  float distance = 0;        // to the sampled point (infinity for the infinite light)
  Vec3f p_light;             // the sampled point (for shadow rays and gradient reconnection)
  Vec3f n_light;             // geometric normal at p_light (area lights; 0 for the others), so
                             // shadow rays can stop just off the emitting surface
  float pdf = 0;             // solid-angle density of wi given this light; 1 for delta lights
  bool delta = false;        // point, spot and distant lights: not reachable by BSDF sampling
};

// A point on an emitting surface and its geometric normal (the emitting side of a one-sided
// light).
struct AreaPoint {
  Vec3f p;
  Vec3f n;
};

class AreaLight {
 public:
  // `shape` indexes the scene's shapes and the Geometry built from it.
  static absl::StatusOr<AreaLight> create(const scene::Shape& shape, int shape_index,
                                          const Geometry& geometry, spectral::Spectrum spectrum,
                                          double scale);
  std::optional<LightSample> sample(const LightContext& ctx, Point2f u, float u_tri,
                                    const SampledWavelengths& lambda) const;
  // A point uniform by area (density 1/area()), for emitting light paths; nullopt where the
  // shape's alpha masks it (the point does not emit).
  std::optional<AreaPoint> sample_point(Point2f u, float u_tri) const;
  // Solid-angle pdf of reaching `hit` (a point on this light) from ctx along wi.
  float pdf(const LightContext& ctx, const Vec3f& wi, const SurfaceHit& hit) const;
  // Emitted radiance leaving the light at a point with geometric normal n towards w.
  SampledSpectrum radiance(const Vec3f& n, const Vec3f& w, const SampledWavelengths& lambda) const;
  // Total world-space area of the emitting surface (all triangles, or 4πr² for a sphere).
  double area() const { return area_; }
  const spectral::Spectrum& spectrum() const { return spectrum_; }
  double scale() const { return scale_; }
  bool two_sided() const { return two_sided_; }
  int shape() const { return shape_; }
  // The AreaLightSource directive (or the shape) in the scene file, for messages.
  const scene::SourceLocation& where() const { return where_; }

 private:
  std::optional<LightSample> sample_triangles(const LightContext& ctx, Point2f u, float u_tri,
                                              const SampledWavelengths& lambda) const;
  // The sample for a chosen point p with normal n seen along wi at distance dist.
  LightSample area_sample(const Vec3f& wi, float dist, const Vec3f& p, const Vec3f& n, float pdf,
                          const SampledWavelengths& lambda) const;
  std::optional<LightSample> sample_sphere(const LightContext& ctx, Point2f u,
                                           const SampledWavelengths& lambda) const;
  std::optional<LightSample> sample_disk(const LightContext& ctx, Point2f u,
                                         const SampledWavelengths& lambda) const;
  std::optional<LightSample> sample_cylinder(const LightContext& ctx, Point2f u,
                                             const SampledWavelengths& lambda) const;
  std::optional<AreaPoint> point_on_triangles(Point2f u, float u_tri) const;
  std::optional<AreaPoint> point_on_disk(Point2f u) const;
  std::optional<AreaPoint> point_on_cylinder(Point2f u) const;
  std::optional<AreaPoint> point_on_sphere(Point2f u) const;
  // A sampled point p with unit normal n (its emitting side) seen from ctx, or nullopt.
  std::optional<LightSample> uniform_area_sample(const LightContext& ctx, const Vec3f& p,
                                                 const Vec3f& n,
                                                 const SampledWavelengths& lambda) const;

  // pbrt-v4's emitter alpha: a sampled point emits when a hash of its position, uniform in
  // [0, 1), is at most the shape's alpha there.
  static bool masked(float alpha, const Vec3f& p);

  int shape_ = -1;
  bool has_alpha_ = false;
  scene::SourceLocation where_;
  const Geometry* geometry_ = nullptr;
  spectral::Spectrum spectrum_;
  double scale_ = 1;
  bool two_sided_ = false;
  double area_ = 0;
  bool is_sphere_ = false;
  Vec3f sphere_centre_;  // world space; spheres as lights need a similarity transform
  float sphere_radius_ = 0;
  bool sphere_flip_ = false;         // reverse orientation XOR handedness swap: emits inwards
  std::vector<float> triangle_cdf_;  // by area, triangles of the shape
  // Each triangle in world space and its WorldTriangle::unit_normal, as point_on_triangles needs
  // them for every sample (computed once here, the same values).
  struct EmitterTriangle {
    Geometry::WorldTriangle t;
    Vec3f n;
    int patch = -1;  // a curved bilinear patch's first triangle: its index in patches_
  };
  std::vector<EmitterTriangle> triangles_;
  // Curved bilinear patches (geometry.h), sampled uniformly by area: a point from the bilinear
  // density of the area element's corner values, kept with probability (area element) /
  // (that bilinear interpolation), which is at most 1 because the area element |N(u, v)| is
  // the norm of an affine function of (u, v), convex along every line of the square.
  struct EmitterPatch {
    Geometry::WorldPatch w;
    std::uint32_t triangle = 0;
    float corner[4] = {};  // area element at (0,0), (1,0), (0,1), (1,1)
  };
  std::vector<EmitterPatch> patches_;
  std::optional<AreaPoint> point_on_patch(const EmitterPatch& patch, Point2f u,
                                          float u_accept) const;
  bool is_disk_ = false;  // sampled uniformly by area in its object-space annulus
  scene::DiskShape disk_;
  scene::Transform disk_to_world_;
  Vec3f disk_normal_;         // world, after the orientation rule: the side it emits to
  bool is_cylinder_ = false;  // uniform in (z, φ): uniform by area under a similarity
  scene::CylinderShape cylinder_;
  scene::Transform cylinder_to_world_;
  bool cylinder_flip_ = false;  // emits inwards
};

// pbrt-v4's projection-light image: per texel an RGB illuminant m·s(λ)·D65(λ) (RgbUplift), and
// the frustum: directions with light-space z > 0 whose perspective projection (x, y)/(z·tan(fov/2))
// falls in [−x_max, x_max] × [−y_max, y_max] (the image's aspect; the shorter axis spans ±1).
struct ProjectionImage {
  int width = 0, height = 0;
  IlluminantTexels texels;
  float tan_half = 1, x_max = 1, y_max = 1;
  double solid_angle_fraction = 0;  // of the sphere the frustum covers
  // pbrt-v4's k_e for `power`: the luminous flux at unit scale, ∫ Y dω over the frustum from
  // the texels' sRGB luminance, each texel centre's solid angle cos³θ · (its area at z = 1).
  double flux_per_unit_scale = 0;

  static absl::StatusOr<std::shared_ptr<const ProjectionImage>> create(
      const scene::TextureImage& image, double fov_deg, const spectral::RgbUplift& uplift);
};

// A point light, or pbrt-v4's goniometric light: the intensity times a grey equal-area image
// looked up (nearest texel) at the light-space direction with y and z swapped, or its projection
// light: the nearest texel's RGB illuminant of a ProjectionImage (light-space y flipped, as
// pbrt-v4), 0 outside the frustum.
class PointLight {
 public:
  static absl::StatusOr<PointLight> create(const scene::Light& light, spectral::Spectrum spectrum,
                                           double scale,
                                           std::shared_ptr<const ProjectionImage> projection = {});
  std::optional<LightSample> sample(const LightContext& ctx,
                                    const SampledWavelengths& lambda) const;
  const spectral::Spectrum& spectrum() const { return spectrum_; }
  double scale() const { return scale_; }
  Vec3f position() const { return position_; }
  const scene::SourceLocation& where() const { return where_; }
  // The goniometric factor towards world direction w (unit, away from the light); 1 without an
  // image.
  float modulation(const Vec3f& w) const;
  // Its mean over the sphere (every texel covers the same solid angle): 1 without an image; for
  // a projection light the fraction of the sphere its frustum covers (its spectrum is then the
  // image's mean colour).
  double mean_modulation() const { return mean_modulation_; }
  // A projection light's intensity towards world direction w (unit, away from the light).
  SampledSpectrum projected(const Vec3f& w, const SampledWavelengths& lambda) const;

 private:
  Vec3f position_;
  spectral::Spectrum spectrum_;
  double scale_ = 1;
  scene::SourceLocation where_;
  std::shared_ptr<const scene::TextureImage> image_;
  std::shared_ptr<const ProjectionImage> projection_;
  float light_from_world_[3][3] = {};
  double mean_modulation_ = 1;
};

class SpotLight {
 public:
  static absl::StatusOr<SpotLight> create(const scene::Light& light, spectral::Spectrum spectrum,
                                          double scale);
  std::optional<LightSample> sample(const LightContext& ctx,
                                    const SampledWavelengths& lambda) const;
  const spectral::Spectrum& spectrum() const { return spectrum_; }
  double scale() const { return scale_; }
  Vec3f position() const { return position_; }
  Vec3f direction() const { return direction_; }  // unit, the cone's axis
  // Cosine of the cone's half-angle: no light outside it.
  float cos_falloff_end() const { return cos_falloff_end_; }
  // Solid angle-weighted mean falloff over the sphere, for power estimates.
  double power_factor() const;
  // The falloff in [0, 1] towards world direction w (unit, pointing away from the light).
  float falloff(const Vec3f& w) const;
  const scene::SourceLocation& where() const { return where_; }

 private:
  Vec3f position_;
  Vec3f direction_;
  float cos_falloff_start_ = 1, cos_falloff_end_ = 1;
  spectral::Spectrum spectrum_;
  double scale_ = 1;
  scene::SourceLocation where_;
};

// Constant, or with an environment map (environment_map.h) whose mean colour is `spectrum`,
// optionally seen only through a portal (portal.h). With a portal, a sample is drawn from the
// map's own density or the window's with probability ½ each, and its density is the mixture's
// (one-sample MIS, balance heuristic): the window's covers a dim sky, the map's a bright sun.
class InfiniteLight {
 public:
  static absl::StatusOr<InfiniteLight> create(const scene::Light& light,
                                              spectral::Spectrum spectrum, double scale,
                                              const Bounds3f& scene_bounds,
                                              std::shared_ptr<const EnvironmentMap> map = nullptr);
  std::optional<LightSample> sample(const LightContext& ctx, Point2f u,
                                    const SampledWavelengths& lambda) const;
  // The solid-angle density of sample() from p at wi.
  float pdf(const Vec3f& p, const Vec3f& wi) const;
  // Radiance seen along a ray from p in direction w that escapes the scene.
  SampledSpectrum radiance(const Vec3f& p, const Vec3f& w, const SampledWavelengths& lambda) const;
  const std::optional<Portal>& portal() const { return portal_; }
  const spectral::Spectrum& spectrum() const { return spectrum_; }
  double scale() const { return scale_; }
  double scene_radius() const { return scene_radius_; }
  const scene::SourceLocation& where() const { return where_; }

 private:
  spectral::Spectrum spectrum_;
  double scale_ = 1;
  double scene_radius_ = 1;
  Vec3f scene_centre_;  // p_light of a sample lies beyond the scene bounds from here
  scene::SourceLocation where_;
  std::shared_ptr<const EnvironmentMap> map_;
  std::optional<Portal> portal_;
};

// Radiance arriving along one direction from infinitely far (pbrt-v4's `distant`): a delta
// light whose samples lie beyond the scene bounds along that direction.
class DistantLight {
 public:
  static absl::StatusOr<DistantLight> create(const scene::Light& light, spectral::Spectrum spectrum,
                                             double scale, const Bounds3f& scene_bounds);
  std::optional<LightSample> sample(const LightContext& ctx,
                                    const SampledWavelengths& lambda) const;
  const spectral::Spectrum& spectrum() const { return spectrum_; }
  double scale() const { return scale_; }
  double scene_radius() const { return scene_radius_; }
  Vec3f direction() const { return direction_; }  // towards the light
  const scene::SourceLocation& where() const { return where_; }

 private:
  Vec3f direction_;
  spectral::Spectrum spectrum_;
  double scale_ = 1;
  double scene_radius_ = 1;
  scene::SourceLocation where_;
};

using Light = std::variant<AreaLight, PointLight, SpotLight, InfiniteLight, DistantLight>;

// Samples a light (dispatching on its kind); `u` and `u_extra` are the sample numbers a light
// may consume (u_extra picks a triangle of an area light).
std::optional<LightSample> sample_light(const Light& light, const LightContext& ctx, Point2f u,
                                        float u_extra, const SampledWavelengths& lambda);
bool is_delta(const Light& light);
// The light's emission spectrum (unscaled) and its scale after pbrt's normalisation.
const spectral::Spectrum& light_spectrum(const Light& light);
double light_scale(const Light& light);
// Where the light was declared in the scene file, for messages naming it.
const scene::SourceLocation& light_location(const Light& light);
// Total emitted power (W, up to the common spectral normalisation), for the `power` pmf:
// scale · ∫ S(λ) dλ · geometric factor (π·area·(two-sided? 2 : 1) for area lights, 4π for
// points, the spot's cone factor, π·r²·4π for the infinite light with scene radius r, π·A
// through a portal of area A).
double light_power(const Light& light);

}  // namespace prism::worker
