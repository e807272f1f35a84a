#include "services/job/scene_spectra.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "services/scene/wavelength_dependence.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::job {
namespace {

absl::Status invalid(const std::string& message) {
  return absl::InvalidArgumentError(message);
}

absl::Status check_range(const spectral::Spectrum& s, SpectrumRole role, float min_value) {
  if (min_value < 0.0f) {
    return invalid(absl::StrCat("negative value ", min_value,
                                "; spectra of reflectance, emission and media are >= 0"));
  }
  const float max = spectral::max_value(s);
  if (role == SpectrumRole::kReflectance && max > 1.0f) {
    return invalid(absl::StrCat("reflectance reaches ", max,
                                " but must stay within [0, 1] (a value above 1 creates energy)"));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<spectral::Spectrum> resolve_spectrum(const scene::SpectrumParam& param,
                                                    SpectrumRole role,
                                                    const spectral::SpectrumLibrary& library,
                                                    const spectral::RgbUplift& uplift) {
  if (const auto* c = std::get_if<scene::SpectrumConstant>(&param)) {
    spectral::Spectrum s = spectral::ConstantSpectrum{float(c->value)};
    PRISM_RETURN_IF_ERROR(check_range(s, role, float(c->value)));
    return s;
  }
  if (const auto* rgb = std::get_if<scene::SpectrumRgb>(&param)) {
    const spectral::Rgb v{rgb->r, rgb->g, rgb->b};
    if (role == SpectrumRole::kReflectance) {
      if (std::max({v.r, v.g, v.b}) > 1.0) {
        return invalid(absl::StrCat("rgb reflectance (", v.r, ", ", v.g, ", ", v.b,
                                    ") must stay within [0, 1] (a value above 1 creates "
                                    "energy)"));
      }
      PRISM_ASSIGN_OR_RETURN(auto s, uplift.albedo(v));
      return spectral::Spectrum(s);
    }
    if (role == SpectrumRole::kUnbounded) {
      PRISM_ASSIGN_OR_RETURN(auto s, uplift.unbounded(v));
      return spectral::Spectrum(s);
    }
    PRISM_ASSIGN_OR_RETURN(auto s, uplift.illuminant(v));
    return spectral::Spectrum(s);
  }
  if (const auto* t = std::get_if<scene::SpectrumTabulated>(&param)) {
    PRISM_ASSIGN_OR_RETURN(auto table, spectral::PiecewiseLinearSpectrum::create(
                                           t->wavelengths_nm, t->values, t->source));
    const float min = table.min_value();
    spectral::Spectrum s = std::move(table);
    PRISM_RETURN_IF_ERROR(check_range(s, role, min));
    return s;
  }
  if (const auto* n = std::get_if<scene::SpectrumNamed>(&param)) {
    const spectral::Spectrum* s = library.find_spectrum(n->name);
    if (s == nullptr) return invalid(absl::StrCat("unknown named spectrum \"", n->name, "\""));
    const auto* table = std::get_if<spectral::PiecewiseLinearSpectrum>(s);
    PRISM_RETURN_IF_ERROR(check_range(*s, role, table ? table->min_value() : 0.0f));
    return *s;
  }
  const auto& b = std::get<scene::SpectrumBlackbody>(param);
  PRISM_ASSIGN_OR_RETURN(auto bb, spectral::BlackbodySpectrum::create(b.kelvin));
  return spectral::Spectrum(bb);
}

absl::StatusOr<spectral::Ior> resolve_ior(const scene::IorParam& param,
                                          const spectral::SpectrumLibrary& library) {
  if (const auto* c = std::get_if<scene::IorConstant>(&param)) {
    if (!(c->eta > 0.0) || !std::isfinite(c->eta)) {
      return invalid(absl::StrCat("index of refraction ", c->eta, " must be > 0"));
    }
    return spectral::ConstantIor{c->eta};
  }
  if (const auto* n = std::get_if<scene::IorNamed>(&param)) {
    const spectral::Ior* ior = library.find_ior(n->name);
    if (ior == nullptr) {
      return invalid(absl::StrCat("unknown index of refraction \"", n->name,
                                  "\" (glass-*, water, diamond and tabulated *-eta names are "
                                  "known)"));
    }
    return *ior;
  }
  if (const auto* t = std::get_if<scene::IorTabulated>(&param)) {
    PRISM_ASSIGN_OR_RETURN(
        auto table, spectral::PiecewiseLinearSpectrum::create(t->table.wavelengths_nm,
                                                              t->table.values, t->table.source));
    PRISM_ASSIGN_OR_RETURN(auto ior, spectral::TabulatedIor::create(std::move(table)));
    return spectral::Ior(std::move(ior));
  }
  if (const auto* c = std::get_if<scene::IorCauchy>(&param)) {
    PRISM_ASSIGN_OR_RETURN(auto ior, spectral::CauchyIor::create(c->coefficients));
    return spectral::Ior(std::move(ior));
  }
  const auto& s = std::get<scene::IorSellmeier>(param);
  PRISM_ASSIGN_OR_RETURN(auto ior, spectral::SellmeierIor::create(0.0, s.b, s.c));
  return spectral::Ior(std::move(ior));
}

absl::StatusOr<std::vector<spectral::Spectrum>> emitter_spectra(
    const scene::SceneDescription& scene, const spectral::SpectrumLibrary& library,
    const spectral::RgbUplift& uplift) {
  std::vector<spectral::Spectrum> spectra;
  // Distinct as written, the same notion of "distinct emitter spectra" as the job analysis.
  for (const scene::SpectrumParam& p :
       scene::analyze_wavelength_dependence(scene).emitter_spectra) {
    PRISM_ASSIGN_OR_RETURN(spectral::Spectrum s,
                           resolve_spectrum(p, SpectrumRole::kIlluminant, library, uplift));
    spectra.push_back(std::move(s));
  }
  return spectra;
}

absl::StatusOr<spectral::WavelengthDistribution> default_wavelength_pdf(
    const scene::SceneDescription& scene, bool has_lights, const RenderOptions& options,
    const spectral::SpectrumLibrary& library, const spectral::RgbUplift& uplift) {
  using spectral::WavelengthDistribution;
  constexpr int kCells = WavelengthDistribution::kDefaultCells;
  if (!has_lights) return WavelengthDistribution::flat(kCells);
  PRISM_ASSIGN_OR_RETURN(std::vector<spectral::Spectrum> spectra,
                         emitter_spectra(scene, library, uplift));
  PRISM_ASSIGN_OR_RETURN(WavelengthDistribution emitters,
                         WavelengthDistribution::emitters(spectra, kCells));
  PRISM_ASSIGN_OR_RETURN(WavelengthDistribution sensor,
                         options.spectral_pdf == SpectralPdfKind::kVisible
                             ? WavelengthDistribution::visible(kCells)
                             : WavelengthDistribution::flat(kCells));
  if (options.emitter_pdf == EmitterPdfKind::kUniform) {
    return sensor.mix_defensive(options.defensive_epsilon, emitters);
  }
  PRISM_ASSIGN_OR_RETURN(WavelengthDistribution product,
                         WavelengthDistribution::product(sensor, emitters));
  return product.mix_defensive(options.defensive_epsilon, emitters);
}

absl::StatusOr<PrepassDistributions> prepass_distributions(const scene::SceneDescription& scene,
                                                           const RenderOptions& options,
                                                           const spectral::SpectrumLibrary& library,
                                                           int bins) {
  using spectral::WavelengthDistribution;
  if (absl::StatusOr<spectral::WavelengthGrid> grid = spectral::WavelengthGrid::create(bins);
      !grid.ok()) {
    return grid.status();
  }
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  const spectral::RgbUplift uplift(cmf);
  PRISM_ASSIGN_OR_RETURN(std::vector<spectral::Spectrum> spectra,
                         emitter_spectra(scene, library, uplift));
  if (spectra.empty()) {
    return absl::FailedPreconditionError(
        "the prepass learns from the scene's emitters, and this scene has none");
  }
  PRISM_ASSIGN_OR_RETURN(WavelengthDistribution job_default,
                         default_wavelength_pdf(scene, true, options, library, uplift));
  std::optional<WavelengthDistribution> sensor;
  if (options.spectral_pdf == SpectralPdfKind::kVisible) {
    PRISM_ASSIGN_OR_RETURN(sensor, WavelengthDistribution::visible(bins));
  }
  return PrepassDistributions{std::move(job_default), std::move(sensor)};
}

}  // namespace prism::job
