// Materials with their spectral parameters resolved to services/spectral values: what a
// SceneDescription material becomes once named spectra, tables, RGB colours and dispersion
// formulas are looked up. A material makes the BSDF of a hit for the path's wavelength lanes.
// Closed set as a std::variant; the `interface` material has no BSDF (a medium boundary the
// path crosses without scattering).
#pragma once

#include <optional>
#include <variant>

#include "absl/status/statusor.h"
#include "services/job/scene_spectra.h"
#include "services/scene/scene_description.h"
#include "services/spectral/ior.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/rgb_uplift.h"
#include "services/spectral/sampled.h"
#include "services/spectral/spectrum.h"
#include "worker/bsdf.h"
#include "worker/texture.h"

namespace prism::worker {

// A spectrum slot that may be textured: the texture, when set, replaces the constant.
struct SpectrumSlot {
  spectral::Spectrum constant;  // values in [0, 1] for reflectances
  TexturePtr texture;
  spectral::SampledSpectrum at(const TextureContext& ctx,
                               const spectral::SampledWavelengths& lambda) const {
    return texture ? texture->spectrum(ctx, lambda) : spectral::sample(constant, lambda);
  }
  bool varies_with_wavelength() const {
    return texture ? texture->varies_with_wavelength() : !spectral::is_constant(constant);
  }
};

struct DiffuseMaterial {
  SpectrumSlot reflectance;
};

// Float textures that replace a microfacet alpha per hit (pbrt-v4's textured roughness),
// remapped like the constants; unset axes keep the material's constant alpha.
struct RoughnessTextures {
  TexturePtr u, v;
  bool remap = true;
};

struct DielectricMaterial {
  spectral::Ior eta;
  bool dispersive = false;
  float alpha_x = 0, alpha_y = 0;  // microfacet alphas after pbrt's remapping; 0: smooth
  RoughnessTextures roughness_textures;
};

struct ConductorMaterial {
  spectral::Spectrum eta;
  spectral::Spectrum k;
  float alpha_x = 0, alpha_y = 0;
  // Set when the scene gave an artist `reflectance` r instead of eta/k: make_bsdf then uses
  // pbrt-v4's mapping per lane exactly, η = 1, k = 2·√r / √(1 − clamp(r, 0, 0.9999)); eta and
  // k above hold the same mapping tabulated at 1 nm, for readers that want a spectrum.
  std::optional<spectral::Spectrum> reflectance;
  RoughnessTextures roughness_textures;
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
  TexturePtr amount_texture;  // replaces `amount` per hit when set
};

// Lambertian reflection and transmission; `scale` already applied.
struct DiffuseTransmissionMaterial {
  SpectrumSlot reflectance;
  SpectrumSlot transmittance;
  float scale = 1;
};

// The slab of a coated material (scene::LayerSpec with the albedo resolved, or its texture).
struct Layer {
  float thickness = 0.01f;
  SpectrumSlot albedo{spectral::ConstantSpectrum{0}, nullptr};
  // pbrt-v4's textured thickness and g, evaluated per hit (clamped to > 0 and [-0.99, 0.99]).
  TexturePtr thickness_texture;
  TexturePtr g_texture;
  float g = 0;
  int max_depth = 10;
  int samples = 1;
};

// pbrt-v4's coateddiffuse: a dielectric coat of constant η over a Lambertian base.
struct CoatedDiffuseMaterial {
  SpectrumSlot reflectance;
  float eta = 1.5f;
  // A coat index that varies with wavelength: evaluated at the hero wavelength, the other
  // lanes terminated (terminates_secondary), as pbrt-v4 does.
  std::optional<spectral::Ior> dispersive_eta;
  float alpha_x = 0, alpha_y = 0;
  RoughnessTextures roughness_textures;
  Layer layer;
};

// pbrt-v4's coatedconductor: a dielectric coat over a conductor whose η and k (or reflectance
// mapping) are taken relative to the coat, η_c/η_coat and k/η_coat, when the BSDF is made.
struct CoatedConductorMaterial {
  float interface_eta = 1.5f;
  std::optional<spectral::Ior> dispersive_interface_eta;  // as CoatedDiffuseMaterial's
  float interface_alpha_x = 0, interface_alpha_y = 0;
  RoughnessTextures interface_roughness_textures;
  spectral::Spectrum eta;
  spectral::Spectrum k;
  std::optional<spectral::Spectrum> reflectance;
  float alpha_x = 0, alpha_y = 0;
  RoughnessTextures roughness_textures;
  Layer layer;
};

using Material =
    std::variant<DiffuseMaterial, DielectricMaterial, ConductorMaterial, InterfaceMaterial,
                 DiffuseTransmissionMaterial, ThinDielectricMaterial, MixMaterial,
                 CoatedDiffuseMaterial, CoatedConductorMaterial>;

// Resolves a scene material. Errors name the material's file:line:column (unknown names are
// already refused by the parser; this catches values out of range, e.g. reflectance > 1).
// `textures` are the scene's resolved textures (Texture::resolve_all), by scene index.
absl::StatusOr<Material> resolve_material(const scene::Material& material,
                                          const spectral::SpectrumLibrary& library,
                                          const spectral::RgbUplift& uplift,
                                          const std::vector<TexturePtr>& textures);

// The BSDF at a hit for the given lanes; nullopt for the interface material. `lanes` is the
// path's C; `ctx` is where textures are looked up. Never allocates.
std::optional<Bsdf> make_bsdf(const Material& material, const spectral::SampledWavelengths& lambda,
                              const TextureContext& ctx);

// True when sampling the material depends on wavelength (a dispersive dielectric): the event a
// spectral shift or a lane split needs.
bool is_dispersive(const Material& material);
// Whether a path that meets this material keeps only its hero wavelength from here on: a coat
// whose index varies with wavelength (the layered walk cannot follow several indices at once).
bool terminates_secondary(const Material& material);
// Whether a hit on the material can refract through a smooth dispersive interface, the event only
// the hero wavelength follows (BsdfSample::hero_only): a dispersive dielectric that is smooth or
// whose roughness comes from textures (and so may be smooth somewhere).
bool may_refract_smooth_dispersive(const Material& material);
// True when the material's value varies with wavelength at all (coloured reflectance, a
// conductor whose η or k is not constant, dispersive glass): what "no wavelength-dependent
// event" tests look for. Constant-parameter materials and `interface` are false.
bool depends_on_wavelength(const Material& material);

}  // namespace prism::worker
