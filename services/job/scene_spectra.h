// A scene's spectra as a job resolves them, the same for the worker that traces it and the
// coordinator that plans its prepass: spectrum and index-of-refraction parameters resolved with
// the spectrum library in their role, the scene's emitter spectra, and the job's default
// wavelength distribution (docs/estimators.md §1) built from them. Job layer: scene and spectral
// only.
#pragma once

#include <optional>
#include <vector>

#include "absl/status/statusor.h"
#include "services/job/render_options.h"
#include "services/scene/scene_description.h"
#include "services/spectral/ior.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/rgb_uplift.h"
#include "services/spectral/spectrum.h"
#include "services/spectral/wavelength_distribution.h"

namespace prism::job {

// Resolves a spectrum parameter in a given role. Reflectances are bounded to [0,1] (RGB via the
// albedo uplift); unbounded values (media coefficients) use the unbounded uplift; illuminants
// (emission) use the RGB illuminant uplift (colour × D65), as pbrt-v4 does. INVALID_ARGUMENT
// (without a location: callers add the scene object's) for an unknown name, a negative value,
// or a reflectance above 1. resolve_ior likewise refuses unknown names and indices <= 0.
enum class SpectrumRole { kReflectance, kUnbounded, kIlluminant };
absl::StatusOr<spectral::Spectrum> resolve_spectrum(const scene::SpectrumParam& param,
                                                    SpectrumRole role,
                                                    const spectral::SpectrumLibrary& library,
                                                    const spectral::RgbUplift& uplift);
absl::StatusOr<spectral::Ior> resolve_ior(const scene::IorParam& param,
                                          const spectral::SpectrumLibrary& library);

// The scene's distinct emitter spectra as written (scene::analyze_wavelength_dependence's notion
// of distinct), resolved as illuminants.
absl::StatusOr<std::vector<spectral::Spectrum>> emitter_spectra(
    const scene::SceneDescription& scene, const spectral::SpectrumLibrary& library,
    const spectral::RgbUplift& uplift);

// The job's default wavelength distribution: p_s · p_e mixed defensively with the emitters'
// support (docs/estimators.md §1), or flat when the scene has no lights (`has_lights`).
absl::StatusOr<spectral::WavelengthDistribution> default_wavelength_pdf(
    const scene::SceneDescription& scene, bool has_lights, const RenderOptions& options,
    const spectral::SpectrumLibrary& library, const spectral::RgbUplift& uplift);

// What the coordinator's prepass needs of the job's wavelength sampling (coordinator/prepass.h):
// the job's default distribution exactly as RenderScene::wavelength_pdf builds it (its bin masses
// weigh the learned tables, and workers sample inside each bin with its shape), and the sensor
// term over `bins` cells when it is not flat. FAILED_PRECONDITION when the scene has no emitters
// (there is nothing to learn a wavelength pdf from).
struct PrepassDistributions {
  spectral::WavelengthDistribution job_default;
  std::optional<spectral::WavelengthDistribution> sensor;
};
absl::StatusOr<PrepassDistributions> prepass_distributions(const scene::SceneDescription& scene,
                                                           const RenderOptions& options,
                                                           const spectral::SpectrumLibrary& library,
                                                           int bins);

}  // namespace prism::job
