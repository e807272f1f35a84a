// Materials with their spectral parameters resolved to services/spectral values: what a
// SceneDescription material becomes once named spectra, tables, RGB colours and dispersion
// formulas are looked up. A material makes the BSDF of a hit for the path's wavelength lanes.
// Closed set as a std::variant; the `interface` material has no BSDF (a medium boundary the
// path crosses without scattering).
#pragma once

#include <optional>
#include <variant>

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"
#include "services/spectral/ior.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/rgb_uplift.h"
#include "services/spectral/sampled.h"
#include "services/spectral/spectrum.h"
#include "worker/bsdf.h"

namespace prism::worker {

struct DiffuseMaterial {
  spectral::Spectrum reflectance;  // values in [0, 1]
};

struct DielectricMaterial {
  spectral::Ior eta;
  bool dispersive = false;
  float alpha_x = 0, alpha_y = 0;  // microfacet alphas after pbrt's remapping; 0: smooth
};

struct ConductorMaterial {
  spectral::Spectrum eta;
  spectral::Spectrum k;
  float alpha_x = 0, alpha_y = 0;
  // Set when the scene gave an artist `reflectance` r instead of eta/k: make_bsdf then uses
  // pbrt-v4's mapping per lane exactly, η = 1, k = 2·√r / √(1 − clamp(r, 0, 0.9999)); eta and
  // k above hold the same mapping tabulated at 1 nm, for readers that want a spectrum.
  std::optional<spectral::Spectrum> reflectance;
};

struct InterfaceMaterial {};

// A thin slab of a dielectric: Fresnel reflection and straight transmission, never bent, so it
// depends on wavelength through its Fresnel terms alone (no lane is ever terminated).
struct ThinDielectricMaterial {
  spectral::Ior eta;
  bool dispersive = false;  // η varies with λ (the reflectance does; directions do not)
};

// Two of the scene's materials (indices into RenderScene::materials()), the second with
// probability `amount`: RenderScene::material_at picks one per vertex before a BSDF is made.
struct MixMaterial {
  int materials[2] = {0, 0};
  float amount = 0.5f;
};

// Lambertian reflection and transmission; `scale` already applied.
struct DiffuseTransmissionMaterial {
  spectral::Spectrum reflectance;
  spectral::Spectrum transmittance;
  float scale = 1;
};

using Material =
    std::variant<DiffuseMaterial, DielectricMaterial, ConductorMaterial, InterfaceMaterial,
                 DiffuseTransmissionMaterial, ThinDielectricMaterial, MixMaterial>;

// Resolves a scene material. Errors name the material's file:line:column (unknown names are
// already refused by the parser; this catches values out of range, e.g. reflectance > 1).
absl::StatusOr<Material> resolve_material(const scene::Material& material,
                                          const spectral::SpectrumLibrary& library,
                                          const spectral::RgbUplift& uplift);

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

// The BSDF at a hit for the given lanes; nullopt for the interface material. `lanes` is the
// path's C. Never allocates.
std::optional<Bsdf> make_bsdf(const Material& material, const spectral::SampledWavelengths& lambda);

// True when sampling the material depends on wavelength (a dispersive dielectric): the event a
// spectral shift or a lane split needs.
bool is_dispersive(const Material& material);
// True when the material's value varies with wavelength at all (coloured reflectance, a
// conductor whose η or k is not constant, dispersive glass): what "no wavelength-dependent
// event" tests look for. Constant-parameter materials and `interface` are false.
bool depends_on_wavelength(const Material& material);

}  // namespace prism::worker
