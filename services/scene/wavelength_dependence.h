// What in a scene depends on wavelength, so the job pipeline can model only what the scene
// needs (architecture.md, "Analyse"): dielectrics whose index of refraction varies with
// wavelength (dispersion splits paths by wavelength), the distinct emitter spectra as written
// (more than one means emitter selection by spectrum pays off), and participating media
// (whose coefficients are spectra). Computed from the written forms only; two emitters
// count as the same spectrum when their written forms are equal.
#pragma once

#include <vector>

#include "services/scene/scene_description.h"

namespace prism::scene {

struct WavelengthDependence {
  std::vector<int> dispersive_materials;  // indices into SceneDescription::materials
  std::vector<SpectrumParam> emitter_spectra;  // distinct, in first-seen order
  std::vector<int> media;  // indices of media some shape, light or the camera refers to
  bool needs_spectral_transport() const {
    return !dispersive_materials.empty() || emitter_spectra.size() > 1 || !media.empty();
  }
};

WavelengthDependence analyze_wavelength_dependence(const SceneDescription& scene);

// The emission spectrum of a light as written (pbrt `L` or `I`).
const SpectrumParam& emission_spectrum(const Light& light);

}  // namespace prism::scene
