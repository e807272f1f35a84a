#include "services/scene/scene_summary.h"

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "services/scene/wavelength_dependence.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::scene {
namespace {

std::string optional_number(const char* label, const std::optional<double>& v) {
  return v ? absl::StrCat(", ", label, " ", *v) : std::string();
}

std::string material_label(const SceneDescription& scene, int index) {
  const Material& m = scene.materials[static_cast<size_t>(index)];
  std::string name =
      m.name.empty() ? absl::StrCat("material #", index) : absl::StrCat("\"", m.name, "\"");
  return absl::StrCat(name, " (", m.where.to_string(), ")");
}

}  // namespace

std::string format_scene_summary(const SceneDescription& scene) {
  std::string out;
  const Film& film = scene.film;
  absl::StrAppend(&out, "resolution: ", film.x_resolution, "x", film.y_resolution, "\n");
  absl::StrAppend(&out, "film: ", film.type == FilmType::kSpectral ? "spectral" : "rgb", " \"",
                  film.filename, "\"\n");
  absl::StrAppend(&out, "samples per pixel: ", scene.sampler.samples_per_pixel, "\n");
  absl::StrAppend(&out, "spectral bins: ",
                  film.bins
                      ? absl::StrCat(*film.bins)
                      : absl::StrCat(spectral::WavelengthGrid::kDefaultBins, " (the default)"),
                  "\n");
  absl::StrAppend(&out, "integrator: ", scene.integrator.name, ", max depth ",
                  scene.integrator.max_depth, "\n");
  size_t meshes = 0;
  size_t spheres = 0;
  size_t quadrics = 0;
  for (const Shape& s : scene.shapes) {
    if (std::holds_alternative<SphereShape>(s.geometry)) {
      ++spheres;
    } else if (std::holds_alternative<DiskShape>(s.geometry) ||
               std::holds_alternative<CylinderShape>(s.geometry)) {
      ++quadrics;
    } else {
      ++meshes;
    }
  }
  absl::StrAppend(&out, "shapes: ", scene.shapes.size(), " (", meshes, " triangle meshes, ",
                  spheres, " spheres",
                  quadrics > 0 ? absl::StrCat(", ", quadrics, " disks and cylinders") : "", ")\n");
  if (!scene.textures.empty()) absl::StrAppend(&out, "textures: ", scene.textures.size(), "\n");
  absl::StrAppend(&out, "triangles: ", scene.triangle_count(), "\n");

  WavelengthDependence dependence = analyze_wavelength_dependence(scene);
  absl::StrAppend(&out, "emitters: ", scene.area_light_count() + scene.lights.size(), " (",
                  dependence.emitter_spectra.size(), " distinct spectra)\n");
  for (const Shape& s : scene.shapes) {
    if (!s.area_light) continue;
    const AreaLight& a = *s.area_light;
    absl::StrAppend(&out, "  area light at ", s.where.to_string(), ": L ", describe(a.radiance),
                    ", scale ", a.scale, a.two_sided ? ", two-sided" : "",
                    optional_number("power", a.power), "\n");
  }
  for (const Light& l : scene.lights) {
    struct Visitor {
      std::string operator()(const PointLight& p) const {
        if (p.projection) {
          return absl::StrCat("projection light: image ", p.filename, ", fov ", p.fov_deg,
                              " deg, scale ", p.scale, optional_number("power", p.power));
        }
        return absl::StrCat(p.goniometric ? "goniometric light: image " : "point light: ",
                            p.goniometric ? p.filename + ", I " : "I ", describe(p.intensity),
                            ", scale ", p.scale, optional_number("power", p.power));
      }
      std::string operator()(const SpotLight& p) const {
        return absl::StrCat("spot light: I ", describe(p.intensity), ", scale ", p.scale,
                            optional_number("power", p.power), ", cone ", p.cone_angle_deg, " deg");
      }
      std::string operator()(const InfiniteLight& p) const {
        if (p.image) {
          return absl::StrCat("infinite light: image ", p.filename, ", scale ", p.scale,
                              optional_number("illuminance", p.illuminance),
                              p.portal ? ", through a portal" : "");
        }
        return absl::StrCat("infinite light: L ", describe(p.radiance), ", scale ", p.scale,
                            optional_number("illuminance", p.illuminance));
      }
      std::string operator()(const DistantLight& p) const {
        return absl::StrCat("distant light: L ", describe(p.radiance), ", scale ", p.scale,
                            optional_number("illuminance", p.illuminance));
      }
    };
    absl::StrAppend(&out, "  ", std::visit(Visitor{}, l.kind), " (", l.where.to_string(), ")\n");
  }
  absl::StrAppend(&out, "dispersive materials: ", dependence.dispersive_materials.size(), "\n");
  for (int m : dependence.dispersive_materials) {
    const auto& d = std::get<DielectricMaterial>(scene.materials[static_cast<size_t>(m)].kind);
    absl::StrAppend(&out, "  ", material_label(scene, m), ": dielectric eta ", describe(d.eta),
                    "\n");
  }
  absl::StrAppend(&out, "media: ", scene.media.size(), "\n");
  for (const Medium& m : scene.media) {
    const auto& h = std::get<HomogeneousMedium>(m.kind);
    absl::StrAppend(&out, "  \"", m.name, "\" (", m.where.to_string(), "): homogeneous sigma_a ",
                    describe(h.sigma_a), ", sigma_s ", describe(h.sigma_s), ", scale ", h.scale,
                    ", g ", h.g, "\n");
  }
  absl::StrAppend(&out, "warnings: ", scene.warnings.size(), "\n");
  for (const std::string& w : scene.warnings) absl::StrAppend(&out, "  ", w, "\n");
  return out;
}

std::string format_scene_features(const std::vector<FeatureUse>& features) {
  std::string out = absl::StrCat(
      "features: ", features.size(), " (", count_features(features, FeatureStatus::kSupported),
      " supported, ", count_features(features, FeatureStatus::kApproximated), " approximated, ",
      count_features(features, FeatureStatus::kIgnored), " ignored, ",
      count_features(features, FeatureStatus::kRefused), " refused)\n");
  for (const FeatureUse& f : features) {
    absl::StrAppend(&out, "  ", absl::StrFormat("%-12s", feature_status_name(f.status)), " ",
                    f.feature, f.uses > 1 ? absl::StrCat(" x", f.uses) : "", " (",
                    f.where.to_string(), ")");
    if (!f.note.empty()) absl::StrAppend(&out, ": ", f.note);
    if (f.status == FeatureStatus::kRefused)
      absl::StrAppend(&out, "; --allow-unsupported renders ", f.substitution);
    absl::StrAppend(&out, "\n");
  }
  return out;
}

}  // namespace prism::scene
