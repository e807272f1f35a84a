#include "worker/material.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "services/scene/source_location.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::worker {
namespace {

absl::Status invalid(const std::string& message) {
  return absl::InvalidArgumentError(message);
}

// The parameter's problem, prefixed with the scene object's position and the parameter name.
absl::Status at(const scene::SourceLocation& where, const std::string& parameter,
                const absl::Status& status) {
  return scene::location_error(where, absl::StrCat(parameter, ": ", status.message()));
}

float remap(double roughness, bool remap_roughness) {
  const float r = float(roughness);
  return remap_roughness ? TrowbridgeReitz::roughness_to_alpha(r) : r;
}

RoughnessTextures roughness_textures(const scene::Roughness& r,
                                     const std::vector<TexturePtr>& textures) {
  RoughnessTextures t;
  if (r.u_texture >= 0) t.u = textures[size_t(r.u_texture)];
  if (r.v_texture >= 0) t.v = textures[size_t(r.v_texture)];
  t.remap = r.remap;
  return t;
}

// The microfacet distribution at a hit: the constant alphas, or the textures' values remapped.
TrowbridgeReitz distribution(float alpha_x, float alpha_y, const RoughnessTextures& t,
                             const TextureContext& ctx) {
  if (t.u) alpha_x = remap(std::max(0.0f, t.u->value(ctx)), t.remap);
  if (t.v) alpha_y = remap(std::max(0.0f, t.v->value(ctx)), t.remap);
  return TrowbridgeReitz(alpha_x, alpha_y);
}

absl::Status check_roughness(const scene::Roughness& r) {
  if (!(r.u >= 0.0) || !(r.v >= 0.0)) {
    return invalid(absl::StrCat("roughness (", r.u, ", ", r.v, ") must be >= 0"));
  }
  return absl::OkStatus();
}

// pbrt-v4 ConductorMaterial's artist mapping from a reflectance to an absorption coefficient
// (with η = 1, normal-incidence Fresnel reflectance then equals r).
float reflectance_to_k(float r) {
  r = std::clamp(r, 0.0f, 0.9999f);
  return 2.0f * std::sqrt(r) / std::sqrt(1.0f - r);
}

absl::StatusOr<SpectrumSlot> resolve_slot(const scene::SpectrumParam& param, int texture,
                                          const spectral::SpectrumLibrary& library,
                                          const spectral::RgbUplift& uplift,
                                          const std::vector<TexturePtr>& textures) {
  SpectrumSlot slot;
  if (texture >= 0) {
    slot.texture = textures[size_t(texture)];
    return slot;
  }
  PRISM_ASSIGN_OR_RETURN(
      slot.constant,
      job::resolve_spectrum(param, job::SpectrumRole::kReflectance, library, uplift));
  return slot;
}

absl::StatusOr<Layer> resolve_layer(const scene::LayerSpec& l,
                                    const spectral::SpectrumLibrary& library,
                                    const spectral::RgbUplift& uplift,
                                    const std::vector<TexturePtr>& textures) {
  Layer out;
  out.thickness = std::max(float(l.thickness), std::numeric_limits<float>::min());
  auto albedo = resolve_slot(l.albedo, l.albedo_texture, library, uplift, textures);
  if (!albedo.ok()) return invalid(absl::StrCat("albedo: ", albedo.status().message()));
  out.albedo = *std::move(albedo);
  out.g = float(l.g);
  if (l.thickness_texture >= 0) out.thickness_texture = textures[size_t(l.thickness_texture)];
  if (l.g_texture >= 0) out.g_texture = textures[size_t(l.g_texture)];
  out.max_depth = l.max_depth;
  out.samples = l.samples;
  return out;
}

struct CoatEta {
  float constant = 1.5f;
  std::optional<spectral::Ior> dispersive;
};

absl::StatusOr<CoatEta> coat_eta(const scene::IorParam& param,
                                 const spectral::SpectrumLibrary& library) {
  PRISM_ASSIGN_OR_RETURN(spectral::Ior ior, job::resolve_ior(param, library));
  CoatEta out;
  out.constant = float(spectral::eta(ior, 550.0));
  if (spectral::is_dispersive(ior)) out.dispersive = std::move(ior);
  return out;
}

absl::StatusOr<Material> resolve_dielectric(const scene::DielectricMaterial& m,
                                            const spectral::SpectrumLibrary& library) {
  PRISM_RETURN_IF_ERROR(check_roughness(m.roughness));
  PRISM_ASSIGN_OR_RETURN(spectral::Ior eta, job::resolve_ior(m.eta, library));
  DielectricMaterial out{std::move(eta), false, remap(m.roughness.u, m.roughness.remap),
                         remap(m.roughness.v, m.roughness.remap), {}};
  out.dispersive = spectral::is_dispersive(out.eta);
  return out;
}

absl::StatusOr<Material> resolve_conductor(const scene::ConductorMaterial& m,
                                           const spectral::SpectrumLibrary& library,
                                           const spectral::RgbUplift& uplift) {
  PRISM_RETURN_IF_ERROR(check_roughness(m.roughness));
  const float ax = remap(m.roughness.u, m.roughness.remap);
  const float ay = remap(m.roughness.v, m.roughness.remap);
  if (m.reflectance) {
    auto resolved =
        job::resolve_spectrum(*m.reflectance, job::SpectrumRole::kReflectance, library, uplift);
    if (!resolved.ok()) {
      return invalid(absl::StrCat("reflectance: ", resolved.status().message()));
    }
    spectral::Spectrum r = std::move(*resolved);
    std::vector<double> lambda, k;
    for (int i = 0; i <= int(spectral::kLambdaRange); ++i) {
      const float l = spectral::kLambdaMin + float(i);
      lambda.push_back(l);
      k.push_back(reflectance_to_k(spectral::eval(r, l)));
    }
    PRISM_ASSIGN_OR_RETURN(auto k_table, spectral::PiecewiseLinearSpectrum::create(
                                             lambda, k, "conductor reflectance"));
    ConductorMaterial out{spectral::ConstantSpectrum{1.0f}, std::move(k_table), ax, ay,
                          std::move(r), {}};
    return out;
  }
  auto eta = job::resolve_spectrum(m.eta, job::SpectrumRole::kUnbounded, library, uplift);
  if (!eta.ok()) return invalid(absl::StrCat("eta: ", eta.status().message()));
  auto k = job::resolve_spectrum(m.k, job::SpectrumRole::kUnbounded, library, uplift);
  if (!k.ok()) return invalid(absl::StrCat("k: ", k.status().message()));
  return ConductorMaterial{std::move(*eta), std::move(*k), ax, ay, std::nullopt, {}};
}

}  // namespace

absl::StatusOr<Material> resolve_material(const scene::Material& material,
                                          const spectral::SpectrumLibrary& library,
                                          const spectral::RgbUplift& uplift,
                                          const std::vector<TexturePtr>& textures) {
  const std::string label = material.name.empty()
                                ? std::string("material")
                                : absl::StrCat("material \"", material.name, "\"");
  struct Visitor {
    const spectral::SpectrumLibrary& library;
    const spectral::RgbUplift& uplift;
    const std::vector<TexturePtr>& textures;
    absl::StatusOr<Material> operator()(const scene::DiffuseMaterial& m) const {
      auto r = resolve_slot(m.reflectance, m.reflectance_texture, library, uplift, textures);
      if (!r.ok()) return invalid(absl::StrCat("diffuse reflectance: ", r.status().message()));
      return Material(DiffuseMaterial{*std::move(r)});
    }
    absl::StatusOr<Material> operator()(const scene::CoatedDiffuseMaterial& m) const {
      auto r = resolve_slot(m.reflectance, m.reflectance_texture, library, uplift, textures);
      if (!r.ok())
        return invalid(absl::StrCat("coateddiffuse reflectance: ", r.status().message()));
      PRISM_RETURN_IF_ERROR(check_roughness(m.roughness));
      auto layer = resolve_layer(m.layer, library, uplift, textures);
      if (!layer.ok()) return invalid(absl::StrCat("coateddiffuse ", layer.status().message()));
      auto eta = coat_eta(m.eta, library);
      if (!eta.ok()) return invalid(absl::StrCat("coateddiffuse eta: ", eta.status().message()));
      CoatedDiffuseMaterial out{*std::move(r),
                                eta->constant,
                                eta->dispersive,
                                remap(m.roughness.u, m.roughness.remap),
                                remap(m.roughness.v, m.roughness.remap),
                                roughness_textures(m.roughness, textures),
                                *std::move(layer)};
      return Material(std::move(out));
    }
    absl::StatusOr<Material> operator()(const scene::CoatedConductorMaterial& m) const {
      PRISM_RETURN_IF_ERROR(check_roughness(m.interface_roughness));
      PRISM_RETURN_IF_ERROR(check_roughness(m.conductor_roughness));
      scene::ConductorMaterial base;
      base.eta = m.conductor_eta;
      base.k = m.k;
      base.reflectance = m.reflectance;
      base.roughness = m.conductor_roughness;
      auto conductor = resolve_conductor(base, library, uplift);
      if (!conductor.ok()) {
        return invalid(absl::StrCat("coatedconductor conductor ", conductor.status().message()));
      }
      auto layer = resolve_layer(m.layer, library, uplift, textures);
      if (!layer.ok()) return invalid(absl::StrCat("coatedconductor ", layer.status().message()));
      auto& c = std::get<ConductorMaterial>(*conductor);
      CoatedConductorMaterial out;
      auto eta = coat_eta(m.interface_eta, library);
      if (!eta.ok()) {
        return invalid(absl::StrCat("coatedconductor interface.eta: ", eta.status().message()));
      }
      out.interface_eta = eta->constant;
      out.dispersive_interface_eta = eta->dispersive;
      out.interface_alpha_x = remap(m.interface_roughness.u, m.interface_roughness.remap);
      out.interface_alpha_y = remap(m.interface_roughness.v, m.interface_roughness.remap);
      out.interface_roughness_textures = roughness_textures(m.interface_roughness, textures);
      out.roughness_textures = roughness_textures(m.conductor_roughness, textures);
      out.eta = std::move(c.eta);
      out.k = std::move(c.k);
      out.reflectance = std::move(c.reflectance);
      out.alpha_x = c.alpha_x;
      out.alpha_y = c.alpha_y;
      out.layer = *std::move(layer);
      return Material(std::move(out));
    }
    absl::StatusOr<Material> operator()(const scene::DielectricMaterial& m) const {
      auto r = resolve_dielectric(m, library);
      if (!r.ok()) return invalid(absl::StrCat("dielectric: ", r.status().message()));
      std::get<DielectricMaterial>(*r).roughness_textures =
          roughness_textures(m.roughness, textures);
      return r;
    }
    absl::StatusOr<Material> operator()(const scene::ConductorMaterial& m) const {
      auto r = resolve_conductor(m, library, uplift);
      if (!r.ok()) return invalid(absl::StrCat("conductor ", r.status().message()));
      std::get<ConductorMaterial>(*r).roughness_textures =
          roughness_textures(m.roughness, textures);
      return r;
    }
    absl::StatusOr<Material> operator()(const scene::MixMaterial& m) const {
      MixMaterial out{{m.materials[0], m.materials[1]}, float(m.amount), nullptr};
      if (m.amount_texture >= 0) out.amount_texture = textures[size_t(m.amount_texture)];
      return Material(std::move(out));
    }
    absl::StatusOr<Material> operator()(const scene::ThinDielectricMaterial& m) const {
      auto eta = job::resolve_ior(m.eta, library);
      if (!eta.ok()) return invalid(absl::StrCat("thindielectric: ", eta.status().message()));
      ThinDielectricMaterial out{*std::move(eta), false};
      out.dispersive = spectral::is_dispersive(out.eta);
      return Material(std::move(out));
    }
    absl::StatusOr<Material> operator()(const scene::DiffuseTransmissionMaterial& m) const {
      auto r = resolve_slot(m.reflectance, m.reflectance_texture, library, uplift, textures);
      if (!r.ok())
        return invalid(absl::StrCat("diffusetransmission reflectance: ", r.status().message()));
      auto t = resolve_slot(m.transmittance, m.transmittance_texture, library, uplift, textures);
      if (!t.ok()) {
        return invalid(absl::StrCat("diffusetransmission transmittance: ", t.status().message()));
      }
      return Material(DiffuseTransmissionMaterial{*std::move(r), *std::move(t), float(m.scale)});
    }
    absl::StatusOr<Material> operator()(const scene::InterfaceMaterial&) const {
      return Material(InterfaceMaterial{});
    }
  };
  auto resolved = std::visit(Visitor{library, uplift, textures}, material.kind);
  if (!resolved.ok()) return at(material.where, label, resolved.status());
  return resolved;
}

namespace {

SampledSpectrum conductor_eta(const spectral::Spectrum& eta,
                              const std::optional<spectral::Spectrum>& reflectance,
                              const spectral::SampledWavelengths& lambda) {
  if (reflectance) return SampledSpectrum(1.0f);
  return spectral::sample(eta, lambda);
}

SampledSpectrum conductor_k(const spectral::Spectrum& k,
                            const std::optional<spectral::Spectrum>& reflectance,
                            const spectral::SampledWavelengths& lambda) {
  if (!reflectance) return spectral::sample(k, lambda);
  SampledSpectrum out;
  for (int i = 0; i < lambda.count(); ++i) {
    out[i] = reflectance_to_k(spectral::eval(*reflectance, lambda.lambda(i)));
  }
  return out;
}

LayerParams layer_params(const Layer& layer, const spectral::SampledWavelengths& lambda,
                         const TextureContext& ctx) {
  LayerParams p;
  p.thickness = layer.thickness;
  p.albedo = layer.albedo.at(ctx, lambda);
  if (layer.thickness_texture)
    p.thickness = std::max(layer.thickness_texture->value(ctx), std::numeric_limits<float>::min());
  p.g = layer.g_texture ? std::clamp(layer.g_texture->value(ctx), -0.99f, 0.99f) : layer.g;
  p.max_depth = layer.max_depth;
  p.samples = layer.samples;
  return p;
}

}  // namespace

std::optional<Bsdf> make_bsdf(const Material& material, const spectral::SampledWavelengths& lambda,
                              const TextureContext& ctx) {
  const int lanes = lambda.count();
  struct Visitor {
    const spectral::SampledWavelengths& lambda;
    const TextureContext& ctx;
    int lanes;
    std::optional<Bsdf> operator()(const DiffuseMaterial& m) const {
      return Bsdf(DiffuseBsdf(m.reflectance.at(ctx, lambda), lanes));
    }
    std::optional<Bsdf> operator()(const CoatedDiffuseMaterial& m) const {
      SampledSpectrum r = m.reflectance.at(ctx, lambda);
      for (int i = 0; i < lanes; ++i) r[i] = std::clamp(r[i], 0.0f, 1.0f);
      const float eta =
          m.dispersive_eta ? float(spectral::eta(*m.dispersive_eta, lambda.lambda(0))) : m.eta;
      const DielectricBsdf top(SampledSpectrum(eta), lanes, false,
                               distribution(m.alpha_x, m.alpha_y, m.roughness_textures, ctx));
      return Bsdf(
          LayeredBsdf(top, DiffuseBsdf(r, lanes), layer_params(m.layer, lambda, ctx), lanes));
    }
    std::optional<Bsdf> operator()(const CoatedConductorMaterial& m) const {
      const float eta = m.dispersive_interface_eta
                            ? float(spectral::eta(*m.dispersive_interface_eta, lambda.lambda(0)))
                            : m.interface_eta;
      const DielectricBsdf top(SampledSpectrum(eta), lanes, false,
                               distribution(m.interface_alpha_x, m.interface_alpha_y,
                                            m.interface_roughness_textures, ctx));
      const float inverse = 1.0f / eta;
      const ConductorBsdf base(conductor_eta(m.eta, m.reflectance, lambda) * inverse,
                               conductor_k(m.k, m.reflectance, lambda) * inverse, lanes,
                               distribution(m.alpha_x, m.alpha_y, m.roughness_textures, ctx));
      return Bsdf(LayeredBsdf(top, base, layer_params(m.layer, lambda, ctx), lanes));
    }
    std::optional<Bsdf> operator()(const DielectricMaterial& m) const {
      SampledSpectrum eta;
      for (int i = 0; i < lanes; ++i) eta[i] = float(spectral::eta(m.eta, lambda.lambda(i)));
      return Bsdf(DielectricBsdf(eta, lanes, m.dispersive,
                                 distribution(m.alpha_x, m.alpha_y, m.roughness_textures, ctx)));
    }
    std::optional<Bsdf> operator()(const ConductorMaterial& m) const {
      SampledSpectrum eta, k;
      if (m.reflectance) {
        for (int i = 0; i < lanes; ++i) {
          eta[i] = 1.0f;
          k[i] = reflectance_to_k(spectral::eval(*m.reflectance, lambda.lambda(i)));
        }
      } else {
        eta = spectral::sample(m.eta, lambda);
        k = spectral::sample(m.k, lambda);
      }
      return Bsdf(ConductorBsdf(eta, k, lanes,
                                distribution(m.alpha_x, m.alpha_y, m.roughness_textures, ctx)));
    }
    std::optional<Bsdf> operator()(const InterfaceMaterial&) const { return std::nullopt; }
    std::optional<Bsdf> operator()(const MixMaterial&) const {
      // RenderScene::material_at resolves a mix before any BSDF is made.
      PRISM_CHECK(false);
      return std::nullopt;
    }
    std::optional<Bsdf> operator()(const ThinDielectricMaterial& m) const {
      SampledSpectrum eta;
      for (int i = 0; i < lanes; ++i) eta[i] = float(spectral::eta(m.eta, lambda.lambda(i)));
      return Bsdf(ThinDielectricBsdf(eta, lanes));
    }
    std::optional<Bsdf> operator()(const DiffuseTransmissionMaterial& m) const {
      return Bsdf(DiffuseTransmissionBsdf(m.reflectance.at(ctx, lambda) * m.scale,
                                          m.transmittance.at(ctx, lambda) * m.scale, lanes));
    }
  };
  return std::visit(Visitor{lambda, ctx, lanes}, material);
}

bool terminates_secondary(const Material& material) {
  if (const auto* c = std::get_if<CoatedDiffuseMaterial>(&material))
    return c->dispersive_eta.has_value();
  if (const auto* c = std::get_if<CoatedConductorMaterial>(&material))
    return c->dispersive_interface_eta.has_value();
  return false;
}

bool may_refract_smooth_dispersive(const Material& material) {
  const auto* d = std::get_if<DielectricMaterial>(&material);
  if (d == nullptr || !d->dispersive) return false;
  return d->roughness_textures.u != nullptr || d->roughness_textures.v != nullptr ||
         std::max(d->alpha_x, d->alpha_y) < TrowbridgeReitz::kSmoothAlpha;
}

bool is_dispersive(const Material& material) {
  const auto* d = std::get_if<DielectricMaterial>(&material);
  return d != nullptr && d->dispersive;
}

bool depends_on_wavelength(const Material& material) {
  struct Visitor {
    bool operator()(const DiffuseMaterial& m) const {
      return m.reflectance.varies_with_wavelength();
    }
    bool operator()(const CoatedDiffuseMaterial& m) const {
      return m.reflectance.varies_with_wavelength() || m.layer.albedo.varies_with_wavelength() ||
             m.dispersive_eta.has_value();
    }
    bool operator()(const CoatedConductorMaterial& m) const {
      if (m.layer.albedo.varies_with_wavelength() || m.dispersive_interface_eta) return true;
      if (m.reflectance) return !spectral::is_constant(*m.reflectance);
      return !spectral::is_constant(m.eta) || !spectral::is_constant(m.k);
    }
    bool operator()(const DielectricMaterial& m) const { return m.dispersive; }
    bool operator()(const ConductorMaterial& m) const {
      if (m.reflectance) return !spectral::is_constant(*m.reflectance);
      return !spectral::is_constant(m.eta) || !spectral::is_constant(m.k);
    }
    bool operator()(const InterfaceMaterial&) const { return false; }
    bool operator()(const DiffuseTransmissionMaterial& m) const {
      return m.reflectance.varies_with_wavelength() || m.transmittance.varies_with_wavelength();
    }
    bool operator()(const ThinDielectricMaterial& m) const { return m.dispersive; }
    // The scene asks its components (RenderScene::build); a mix alone cannot tell.
    bool operator()(const MixMaterial&) const { return false; }
  };
  return std::visit(Visitor{}, material);
}

}  // namespace prism::worker
