#include "services/scene/wavelength_dependence.h"

#include <algorithm>
#include <set>

namespace prism::scene {

const SpectrumParam& emission_spectrum(const Light& light) {
  struct Visitor {
    const SpectrumParam& operator()(const PointLight& p) const { return p.intensity; }
    const SpectrumParam& operator()(const SpotLight& s) const { return s.intensity; }
    const SpectrumParam& operator()(const InfiniteLight& i) const { return i.radiance; }
    const SpectrumParam& operator()(const DistantLight& d) const { return d.radiance; }
  };
  return std::visit(Visitor{}, light.kind);
}

WavelengthDependence analyze_wavelength_dependence(const SceneDescription& scene) {
  WavelengthDependence out;
  std::set<int> used_materials;
  std::set<int> used_media;
  auto add_emitter = [&](const SpectrumParam& s) {
    if (std::find(out.emitter_spectra.begin(), out.emitter_spectra.end(), s) ==
        out.emitter_spectra.end())
      out.emitter_spectra.push_back(s);
  };
  auto add_medium = [&](int m) {
    if (m >= 0) used_media.insert(m);
  };
  for (const Shape& shape : scene.shapes) {
    used_materials.insert(shape.material);
    if (shape.area_light) add_emitter(shape.area_light->radiance);
    add_medium(shape.media.inside);
    add_medium(shape.media.outside);
  }
  for (const Light& light : scene.lights) {
    add_emitter(emission_spectrum(light));
    add_medium(light.medium);
  }
  add_medium(scene.camera.medium);
  for (int m : used_materials) {
    const MaterialKind& kind = scene.materials[static_cast<size_t>(m)].kind;
    // A coat whose index varies with wavelength disperses as a dielectric does.
    bool dispersive = false;
    if (const auto* d = std::get_if<DielectricMaterial>(&kind)) dispersive = is_dispersive(d->eta);
    if (const auto* c = std::get_if<CoatedDiffuseMaterial>(&kind))
      dispersive = is_dispersive(c->eta);
    if (const auto* c = std::get_if<CoatedConductorMaterial>(&kind))
      dispersive = is_dispersive(c->interface_eta);
    if (dispersive) out.dispersive_materials.push_back(m);
  }
  out.media.assign(used_media.begin(), used_media.end());
  return out;
}

}  // namespace prism::scene
