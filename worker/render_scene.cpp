#include "worker/render_scene.h"

#include <cmath>
#include <numbers>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "services/scene/source_location.h"
#include "services/scene/wavelength_dependence.h"
#include "worker/float_hash.h"
#include "worker/sample_layout.h"

namespace prism::worker {
namespace {

constexpr double kPiD = std::numbers::pi;

// pbrt-v4's SpectrumToPhotometric: Σ ȳ·S over 360..830 nm at 1 nm. For an RGB illuminant only
// the colour space's illuminant counts (the RGB factor is deliberately left in the emission).
double photometric_sum(const spectral::Spectrum& s, const spectral::ColorMatching& cmf) {
  if (const auto* rgb = std::get_if<spectral::RgbIlluminantSpectrum>(&s)) {
    return cmf.photometric_sum(spectral::Spectrum(*rgb->illuminant));
  }
  return cmf.photometric_sum(s);
}

// The emission spectrum in its illuminant role and pbrt-v4's scale for it: the scene's `scale`
// divided by the spectrum's photometric sum, so that `scale` is in units of nits
// (docs/estimators.md §9). `what` names the light for messages.
struct Emission {
  spectral::Spectrum spectrum;
  double scale = 1;
};
absl::StatusOr<Emission> emission(const scene::SpectrumParam& param, double scene_scale,
                                  const scene::SourceLocation& where, const std::string& what,
                                  const spectral::SpectrumLibrary& library,
                                  const spectral::RgbUplift& uplift,
                                  const spectral::ColorMatching& cmf) {
  auto spectrum = job::resolve_spectrum(param, job::SpectrumRole::kIlluminant, library, uplift);
  if (!spectrum.ok()) {
    return scene::location_error(where, absl::StrCat(what, ": ", spectrum.status().message()));
  }
  const double sum = photometric_sum(*spectrum, cmf);
  if (!std::isfinite(sum)) {
    return scene::location_error(
        where, absl::StrCat(what, ": the emission spectrum ", scene::describe(param),
                            " is too large to render (its photometric integral is ", sum,
                            "); give a finite spectrum and set the brightness with 'float "
                            "scale'"));
  }
  if (!(sum > 0.0)) {
    return scene::location_error(
        where, absl::StrCat(what, ": the emission spectrum ", scene::describe(param),
                            " has no visible power (its photometric integral is ", sum,
                            "); pbrt-v4 scales every light by 1 / that integral, summed at whole "
                            "nanometres, which a line narrower than 1 nm between them misses"));
  }
  return Emission{std::move(*spectrum), scene_scale / sum};
}

// pbrt-v4's `power` / `illuminance`: with the photometrically normalised spectrum, the light's
// emission per unit scale is k_e (the geometric factor: π·area·sides, 4π, the spot's cone
// integral, or π for a uniform sky's illuminance), so the scale is multiplied by target / k_e.
absl::Status check_target(const std::optional<double>& target, const char* name,
                          const scene::SourceLocation& where) {
  if (target && !(*target > 0.0)) {
    return scene::location_error(
        where, absl::StrCat("\"", name, "\" = ", *target,
                            " must be > 0 (leave it out to keep the emission as given)"));
  }
  return absl::OkStatus();
}

absl::StatusOr<Light> make_light(const scene::Light& light, const Geometry& geometry,
                                 const spectral::SpectrumLibrary& library,
                                 const spectral::RgbUplift& uplift,
                                 const spectral::ColorMatching& cmf) {
  const scene::SpectrumParam& param = scene::emission_spectrum(light);
  if (const auto* p = std::get_if<scene::PointLight>(&light.kind); p && p->projection) {
    // Texels are RGB illuminants normalised by D65's photometric integral, as pbrt-v4 does; the
    // light's spectrum is its mean colour's, for power and spectral sampling.
    auto image = ProjectionImage::create(*p->projection, p->fov_deg, uplift);
    if (!image.ok()) {
      return scene::location_error(light.where, absl::StrCat("projection light \"", p->filename,
                                                             "\": ", image.status().message()));
    }
    const spectral::Rgb mean = (*image)->texels.mean;
    PRISM_RETURN_IF_ERROR(check_target(p->power, "power", light.where));
    PRISM_ASSIGN_OR_RETURN(
        Emission e, emission(scene::SpectrumRgb{mean.r, mean.g, mean.b}, p->scale, light.where,
                             "projection light image", library, uplift, cmf));
    if (p->power) {
      const double k_e = (*image)->flux_per_unit_scale;
      if (!(k_e > 0)) {
        return scene::location_error(light.where, absl::StrCat("projection light \"", p->filename,
                                                               "\" is black and cannot reach a "
                                                               "\"power\""));
      }
      e.scale *= *p->power / k_e;
    }
    PRISM_ASSIGN_OR_RETURN(
        PointLight l, PointLight::create(light, std::move(e.spectrum), e.scale, *std::move(image)));
    return Light(std::move(l));
  }
  if (const auto* p = std::get_if<scene::PointLight>(&light.kind)) {
    PRISM_RETURN_IF_ERROR(check_target(p->power, "power", light.where));
    PRISM_ASSIGN_OR_RETURN(
        Emission e, emission(param, p->scale, light.where, "point light I", library, uplift, cmf));
    // pbrt-v4: a goniometric light's power integrates its image over the sphere.
    if (p->power) {
      double mean = 1;
      if (p->goniometric) {
        double sum = 0;
        for (float v : p->goniometric->values) sum += std::max(0.0f, v);
        mean = sum / double(p->goniometric->values.size());
        if (!(mean > 0)) {
          return scene::location_error(light.where,
                                       "a goniometric light with a black image cannot reach a "
                                       "\"power\"");
        }
      }
      e.scale *= *p->power / (4.0 * kPiD * mean);
    }
    PRISM_ASSIGN_OR_RETURN(PointLight l, PointLight::create(light, std::move(e.spectrum), e.scale));
    return Light(std::move(l));
  }
  if (const auto* s = std::get_if<scene::SpotLight>(&light.kind)) {
    PRISM_RETURN_IF_ERROR(check_target(s->power, "power", light.where));
    PRISM_ASSIGN_OR_RETURN(
        Emission e, emission(param, s->scale, light.where, "spot light I", library, uplift, cmf));
    if (s->power) {
      const double cos_end = std::cos(s->cone_angle_deg * kPiD / 180.0);
      const double cos_start =
          std::cos((s->cone_angle_deg - s->cone_delta_angle_deg) * kPiD / 180.0);
      const double k_e = 2.0 * kPiD * ((1.0 - cos_start) + (cos_start - cos_end) / 2.0);
      if (!(k_e > 0.0)) {
        return scene::location_error(light.where,
                                     "spot light with a zero cone angle cannot reach a \"power\"");
      }
      e.scale *= *s->power / k_e;
    }
    PRISM_ASSIGN_OR_RETURN(SpotLight l, SpotLight::create(light, std::move(e.spectrum), e.scale));
    return Light(std::move(l));
  }
  if (const auto* d = std::get_if<scene::DistantLight>(&light.kind)) {
    PRISM_RETURN_IF_ERROR(check_target(d->illuminance, "illuminance", light.where));
    PRISM_ASSIGN_OR_RETURN(Emission e, emission(param, d->scale, light.where, "distant light L",
                                                library, uplift, cmf));
    // pbrt-v4: a unit-nit distant light gives illuminance 1 on a surface facing it.
    if (d->illuminance) e.scale *= *d->illuminance;
    PRISM_ASSIGN_OR_RETURN(DistantLight l, DistantLight::create(light, std::move(e.spectrum),
                                                                e.scale, geometry.bounds()));
    return Light(std::move(l));
  }
  const auto& inf = std::get<scene::InfiniteLight>(light.kind);
  PRISM_RETURN_IF_ERROR(check_target(inf.illuminance, "illuminance", light.where));
  if (inf.image) {
    // The map's texels are RGB illuminants normalised, as pbrt-v4 does, by the colour space's
    // illuminant (D65): the light's spectrum is its mean colour's, for power and spectral
    // sampling.
    auto map = EnvironmentMap::create(*inf.image, light.light_to_world, uplift);
    if (!map.ok()) {
      return scene::location_error(light.where, absl::StrCat("infinite light \"", inf.filename,
                                                             "\": ", map.status().message()));
    }
    const spectral::Rgb mean = (*map)->mean_rgb();
    PRISM_ASSIGN_OR_RETURN(
        Emission e, emission(scene::SpectrumRgb{mean.r, mean.g, mean.b}, inf.scale, light.where,
                             "infinite light image", library, uplift, cmf));
    // The texels' radiance at scale 1 / Y(D65) has their RGB luminance, so the map's upper
    // hemisphere illuminance at that scale is k_e.
    if (inf.illuminance) {
      const double k_e = (*map)->upper_hemisphere_illuminance();
      if (!(k_e > 0)) {
        return scene::location_error(light.where,
                                     absl::StrCat("infinite light \"", inf.filename,
                                                  "\" is black above the horizon (light-space "
                                                  "+z) and cannot reach an \"illuminance\""));
      }
      e.scale *= *inf.illuminance / k_e;
    }
    PRISM_ASSIGN_OR_RETURN(InfiniteLight l,
                           InfiniteLight::create(light, std::move(e.spectrum), e.scale,
                                                 geometry.bounds(), *std::move(map)));
    return Light(std::move(l));
  }
  PRISM_ASSIGN_OR_RETURN(Emission e, emission(param, inf.scale, light.where, "infinite light L",
                                              library, uplift, cmf));
  // pbrt-v4: the illuminance of a uniform unit-nit sky on an upward-facing patch is π.
  if (inf.illuminance) e.scale *= *inf.illuminance / kPiD;
  PRISM_ASSIGN_OR_RETURN(InfiniteLight l, InfiniteLight::create(light, std::move(e.spectrum),
                                                                e.scale, geometry.bounds()));
  return Light(std::move(l));
}

absl::StatusOr<AreaLight> make_area_light(const scene::Shape& shape, int index,
                                          const Geometry& geometry,
                                          const spectral::SpectrumLibrary& library,
                                          const spectral::RgbUplift& uplift,
                                          const spectral::ColorMatching& cmf) {
  const scene::AreaLight& a = *shape.area_light;
  PRISM_RETURN_IF_ERROR(check_target(a.power, "power", a.where));
  PRISM_ASSIGN_OR_RETURN(
      Emission e, emission(a.radiance, a.scale, a.where, "area light L", library, uplift, cmf));
  PRISM_ASSIGN_OR_RETURN(AreaLight light,
                         AreaLight::create(shape, index, geometry, e.spectrum, e.scale));
  if (!a.power) return light;
  // pbrt-v4 applies `power` per triangle (each triangle is its own light there); Prism's area
  // light is the whole shape, so the shape as a whole emits the requested power.
  const double k_e = kPiD * light.area() * (light.two_sided() ? 2.0 : 1.0);
  return AreaLight::create(shape, index, geometry, std::move(e.spectrum), e.scale * *a.power / k_e);
}

}  // namespace

absl::StatusOr<std::unique_ptr<RenderScene>> RenderScene::build(
    EmbreeDevice& device, const scene::SceneDescription& scene,
    const spectral::SpectrumLibrary& library, const job::RenderOptions& options, int width,
    int height, std::shared_ptr<const Geometry> geometry) {
  std::unique_ptr<RenderScene> rs(new RenderScene());
  rs->options_ = options;
  auto grid = spectral::WavelengthGrid::create(options.bins);
  if (!grid.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("render options: ", grid.status().message()));
  }
  rs->grid_ = *grid;
  rs->cmf_ = std::make_unique<spectral::ColorMatching>(spectral::ColorMatching::cie1931());
  const spectral::RgbUplift uplift(*rs->cmf_);

  PRISM_ASSIGN_OR_RETURN(const std::vector<TexturePtr> textures,
                         Texture::resolve_all(scene, library, uplift));
  if (geometry != nullptr) {
    rs->geometry_ = std::move(geometry);
  } else {
    std::vector<AlphaFunction> alpha(scene.shapes.size());
    for (size_t i = 0; i < scene.shapes.size(); ++i) {
      const scene::Shape& shape = scene.shapes[i];
      if (shape.alpha_texture >= 0) {
        TexturePtr texture = textures[size_t(shape.alpha_texture)];
        alpha[i] = [texture](const Point2f& uv, const Vec3f& n) {
          return texture->value(TextureContext{uv, n});
        };
      } else if (shape.alpha < 1.0) {
        const float a = float(shape.alpha);
        alpha[i] = [a](const Point2f&, const Vec3f&) { return a; };
      }
    }
    PRISM_ASSIGN_OR_RETURN(rs->geometry_, Geometry::build(device, scene, std::move(alpha)));
  }
  PRISM_ASSIGN_OR_RETURN(rs->camera_, Camera::create(scene.camera, width, height));
  PRISM_ASSIGN_OR_RETURN(PixelFilter filter, PixelFilter::create(scene.filter));
  rs->pixel_filter_ = std::make_unique<PixelFilter>(std::move(filter));

  rs->materials_.reserve(scene.materials.size());
  for (const scene::Material& m : scene.materials) {
    PRISM_ASSIGN_OR_RETURN(Material material, resolve_material(m, library, uplift, textures));
    rs->has_interfaces_ |= std::holds_alternative<InterfaceMaterial>(material);
    rs->materials_.push_back(std::move(material));
  }
  rs->media_.reserve(scene.media.size());
  for (const scene::Medium& m : scene.media) {
    PRISM_ASSIGN_OR_RETURN(HomogeneousMedium medium, HomogeneousMedium::create(m, library, uplift));
    rs->media_.push_back(std::move(medium));
  }

  // Area lights first, in shape order, then the scene's other lights in file order.
  rs->shapes_.reserve(scene.shapes.size());
  for (size_t i = 0; i < scene.shapes.size(); ++i) {
    const scene::Shape& shape = scene.shapes[i];
    PRISM_CHECK(shape.material >= 0 && size_t(shape.material) < scene.materials.size());
    ShapeInfo info;
    info.material = shape.material;
    info.medium_inside = shape.media.inside;
    info.medium_outside = shape.media.outside;
    info.medium_transition = shape.media.is_transition();
    info.wavelength_dependent = depends_on_wavelength(rs->materials_[size_t(shape.material)]);
    // A mix depends on wavelength when a component (recursively) does.
    std::vector<int> pending{shape.material};
    while (!pending.empty()) {
      const int m = pending.back();
      pending.pop_back();
      if (const auto* mix = std::get_if<MixMaterial>(&rs->materials_[size_t(m)])) {
        for (int c : mix->materials) pending.push_back(c);
      } else if (depends_on_wavelength(rs->materials_[size_t(m)])) {
        info.wavelength_dependent = true;
      }
    }
    if (shape.area_light) {
      PRISM_ASSIGN_OR_RETURN(AreaLight light, make_area_light(shape, int(i), *rs->geometry_,
                                                              library, uplift, *rs->cmf_));
      info.area_light = int(rs->lights_.size());
      if (!spectral::is_constant(light.spectrum())) info.wavelength_dependent = true;
      rs->lights_.push_back(std::move(light));
      rs->light_media_.push_back(-1);
    }
    rs->shapes_.push_back(info);
  }
  for (const scene::Light& l : scene.lights) {
    if (std::holds_alternative<scene::InfiniteLight>(l.kind)) {
      if (rs->infinite_light_ >= 0) {
        return scene::location_error(
            l.where,
            "a second infinite light: Prism supports one constant environment per "
            "scene; merge them into one (their radiances add)");
      }
      rs->infinite_light_ = int(rs->lights_.size());
    }
    PRISM_ASSIGN_OR_RETURN(Light light, make_light(l, *rs->geometry_, library, uplift, *rs->cmf_));
    rs->lights_.push_back(std::move(light));
    rs->light_media_.push_back(l.medium);
  }
  rs->camera_medium_ = scene.camera.medium;

  // The sampler keeps a pointer to lights_, which no longer changes.
  PRISM_ASSIGN_OR_RETURN(spectral::WavelengthGrid selection_grid,
                         spectral::WavelengthGrid::create(kLightSelectionBins));
  PRISM_ASSIGN_OR_RETURN(
      LightSampler sampler,
      LightSampler::create(rs->lights_, *rs->geometry_, selection_grid, options.light_selection,
                           options.spectral_light_selection));
  rs->light_sampler_ = std::make_unique<LightSampler>(std::move(sampler));

  auto pdf = job::default_wavelength_pdf(scene, !rs->lights_.empty(), options, library, uplift);
  if (!pdf.ok()) {
    return absl::Status(pdf.status().code(),
                        absl::StrCat("wavelength pdf: ", pdf.status().message()));
  }
  rs->wavelength_pdf_ = std::make_unique<spectral::WavelengthDistribution>(std::move(*pdf));
  PRISM_ASSIGN_OR_RETURN(spectral::BinnedShape shape,
                         spectral::BinnedShape::create(*rs->wavelength_pdf_, options.bins));
  rs->binned_shape_ = std::make_unique<spectral::BinnedShape>(std::move(shape));
  return rs;
}

const Material& RenderScene::material_at(int index, const SurfaceHit& hit, const Vec3f& wo) const {
  const Vec3f& p = hit.p;
  const Material* m = &materials_[std::size_t(index)];
  // Components are defined before the mix that names them, so this ends.
  while (const auto* mix = std::get_if<MixMaterial>(m)) {
    int chosen = mix->materials[0];
    const float amount =
        mix->amount_texture ? mix->amount_texture->value(texture_context(hit)) : mix->amount;
    if (amount >= 1.0f) {
      chosen = mix->materials[1];
    } else if (amount > 0.0f) {
      const float u = unit_float(
          hash_floats(std::uint64_t(mix->materials[0]) * 31 + std::uint64_t(mix->materials[1]),
                      {p.x, p.y, p.z, wo.x, wo.y, wo.z}));
      chosen = amount < u ? mix->materials[0] : mix->materials[1];
    }
    m = &materials_[std::size_t(chosen)];
  }
  return *m;
}

RenderScene::CameraSample RenderScene::camera_sample(int px, int py, const Sampler& sampler) const {
  // A pinhole never reads its lens pair (Camera::generate_ray), so it is not drawn: one Sobol
  // pair of the nine or so of a sample, and the same rays.
  const Point2 film = sampler.at2(layout::kDimFilm);
  const Point2 lens = camera_.has_lens() ? sampler.at2(layout::kDimLens) : Point2{0.5f, 0.5f};
  const FilterSample filtered = pixel_filter().sample(film.u0, film.u1);
  return {
      camera_.generate_ray({float(px) + filtered.x, float(py) + filtered.y}, {lens.u0, lens.u1}),
      filtered.weight};
}

}  // namespace prism::worker
