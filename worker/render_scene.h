// Everything a worker needs to trace a job's scene, built once per (bundle, options) from the
// parsed SceneDescription: Embree geometry, the camera at the job's resolution, resolved
// materials, lights and media, the light sampler and the default wavelength distribution. The
// per-pixel prepass tables of later passes are supplied per task, not stored here.
// Immutable after build(); shared by all render threads.
//
// Lights: one AreaLight per shape with an area light (in shape order), then the scene's point,
// spot and infinite lights (in file order). Emission follows pbrt-v4 (docs/estimators.md §9): the
// scale is the scene's `scale` divided by the spectrum's photometric sum (the colour space's
// illuminant alone for RGB emission); `power` / `illuminance` then multiply it by target / k_e
// with pbrt-v4's geometric factors (π·area·sides, 4π, the spot's cone integral, π), so that
// scale · photometric_sum · k_e = `scale` · target. Unlike pbrt-v4, which makes every triangle
// of an emissive mesh its own light, `power` applies to the shape as a whole. At most one
// infinite light (a second one is refused with its location).
#pragma once

#include <memory>
#include <optional>
#include <vector>

#include "absl/status/statusor.h"
#include "services/job/render_options.h"
#include "services/scene/scene_description.h"
#include "services/spectral/binned_shape.h"
#include "services/spectral/color.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/rgb_uplift.h"
#include "services/spectral/wavelength_distribution.h"
#include "services/spectral/wavelength_grid.h"
#include "worker/camera.h"
#include "worker/embree_device.h"
#include "worker/geometry.h"
#include "worker/light.h"
#include "worker/light_sampler.h"
#include "worker/material.h"
#include "worker/medium.h"
#include "worker/pixel_filter.h"
#include "worker/sampler.h"

namespace prism::worker {

struct ShapeInfo {
  int material = 0;                             // index into materials()
  int area_light = -1;                          // index into lights(), or -1
  int medium_inside = -1, medium_outside = -1;  // indices into media(), -1 vacuum
  bool medium_transition = false;
  // A hit here is a wavelength-dependent event (integrator.h): the material depends on
  // wavelength, or the shape emits a spectrum that is not constant.
  bool wavelength_dependent = false;
};

class RenderScene {
 public:
  // Resolves every spectrum with `library` (which must outlive nothing: values are copied).
  // width/height: the job's film resolution. Errors carry the scene position where one exists.
  // `geometry`, when given, is this scene's geometry as an earlier build of the same description
  // on the same device made it (shared_geometry()): it depends on the shapes alone, not on the
  // options, and building it (the BVH) is most of a build's time, so a pilot that renders one
  // scene under several options builds it once.
  static absl::StatusOr<std::unique_ptr<RenderScene>> build(
      EmbreeDevice& device, const scene::SceneDescription& scene,
      const spectral::SpectrumLibrary& library, const job::RenderOptions& options, int width,
      int height, std::shared_ptr<const Geometry> geometry = nullptr);

  const Geometry& geometry() const { return *geometry_; }
  const std::shared_ptr<const Geometry>& shared_geometry() const { return geometry_; }
  const Camera& camera() const { return camera_; }
  // The scene's pixel filter (pbrt-v4's default gaussian when it names none).
  const PixelFilter& pixel_filter() const { return *pixel_filter_; }
  // A pixel sample's camera ray: its film position from the pixel filter (dimensions
  // layout::kDimFilm) and its lens point (layout::kDimLens). The sample's value carries
  // `filter_weight`.
  struct CameraSample {
    Ray ray;
    float filter_weight = 1;
  };
  CameraSample camera_sample(int px, int py, const Sampler& sampler) const;
  const std::vector<Material>& materials() const { return materials_; }
  // Material `index` as it stands at the hit seen from direction wo (unit, away from the
  // surface): a mix resolved to one of its components by pbrt-v4's rule, a hash of (p, wo) and
  // the components against `amount` (its texture's value at the hit when textured), so every
  // query at one vertex agrees.
  const Material& material_at(int index, const SurfaceHit& hit, const Vec3f& wo) const;
  const std::vector<Light>& lights() const { return lights_; }
  const std::vector<HomogeneousMedium>& media() const { return media_; }
  // Whether any material is an `interface` (a surface shadow rays pass through): without one,
  // anything a shadow ray meets blocks it, and an occlusion query answers it.
  bool has_interfaces() const { return has_interfaces_; }
  // The medium a light emits into (pbrt-v4's light MediumInterface, its outside medium current
  // at the directive): -1 for vacuum and for area lights, whose shape's media say it per side.
  int light_medium(int light) const { return light_media_[std::size_t(light)]; }
  const ShapeInfo& shape(int index) const { return shapes_[index]; }
  int shape_count() const { return int(shapes_.size()); }
  int camera_medium() const { return camera_medium_; }
  int infinite_light() const { return infinite_light_; }  // index into lights(), or -1
  const LightSampler& light_sampler() const { return *light_sampler_; }
  const spectral::WavelengthGrid& grid() const { return grid_; }
  // p(λ) ∝ p_s · p_e mixed defensively (docs/estimators.md §1), per the options.
  const spectral::WavelengthDistribution& wavelength_pdf() const { return *wavelength_pdf_; }
  // wavelength_pdf() cut at the job's bins: how a pixel table's bin masses are sampled.
  const spectral::BinnedShape& binned_shape() const { return *binned_shape_; }
  const spectral::ColorMatching& cmf() const { return *cmf_; }
  const job::RenderOptions& options() const { return options_; }

 private:
  RenderScene() = default;
  job::RenderOptions options_;
  std::shared_ptr<const Geometry> geometry_;
  Camera camera_;
  std::unique_ptr<PixelFilter> pixel_filter_;
  std::vector<Material> materials_;
  std::vector<Light> lights_;
  std::vector<int> light_media_;  // per light (light_medium)
  std::vector<HomogeneousMedium> media_;
  std::vector<ShapeInfo> shapes_;
  bool has_interfaces_ = false;
  int camera_medium_ = -1;
  int infinite_light_ = -1;
  std::unique_ptr<LightSampler> light_sampler_;
  spectral::WavelengthGrid grid_ = *spectral::WavelengthGrid::create(64);
  std::unique_ptr<spectral::WavelengthDistribution> wavelength_pdf_;
  std::unique_ptr<spectral::BinnedShape> binned_shape_;
  std::unique_ptr<spectral::ColorMatching> cmf_;
};

}  // namespace prism::worker
