#include "coordinator/job_spec.h"

#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::coordinator {
namespace {

absl::Status out_of_range(const char* field, std::int64_t value, std::int64_t lo, std::int64_t hi) {
  return absl::InvalidArgumentError(
      absl::StrCat(field, " ", value, " is out of range: want ", lo, "..", hi));
}

absl::StatusOr<worker::IntegratorKind> integrator_of(prism::v1::Integrator value) {
  switch (value) {
    case prism::v1::INTEGRATOR_UNSPECIFIED:
    case prism::v1::INTEGRATOR_HERO:
      return worker::IntegratorKind::kHero;
    case prism::v1::INTEGRATOR_UNIFORM:
      return worker::IntegratorKind::kUniform;
    case prism::v1::INTEGRATOR_GRADIENT:
      return absl::InvalidArgumentError(
          "integrator gradient is not supported by this farm yet: want uniform or hero");
    default:
      break;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("integrator ", static_cast<int>(value), ": want uniform or hero"));
}

absl::StatusOr<worker::SpectralPdfKind> spectral_pdf_of(prism::v1::SpectralPdf value) {
  switch (value) {
    case prism::v1::SPECTRAL_PDF_UNSPECIFIED:
    case prism::v1::SPECTRAL_PDF_FLAT:
      return worker::SpectralPdfKind::kFlat;
    case prism::v1::SPECTRAL_PDF_VISIBLE:
      return worker::SpectralPdfKind::kVisible;
    default:
      break;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("spectral_pdf ", static_cast<int>(value), ": want flat or visible"));
}

absl::StatusOr<worker::EmitterPdfKind> emitter_pdf_of(prism::v1::EmitterPdf value) {
  switch (value) {
    case prism::v1::EMITTER_PDF_UNSPECIFIED:
    case prism::v1::EMITTER_PDF_EMITTERS:
      return worker::EmitterPdfKind::kEmitters;
    case prism::v1::EMITTER_PDF_UNIFORM:
      return worker::EmitterPdfKind::kUniform;
    default:
      break;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("emitter_pdf ", static_cast<int>(value), ": want uniform or emitters"));
}

absl::StatusOr<worker::LightSelectionKind> light_selection_of(prism::v1::LightSelection value) {
  switch (value) {
    case prism::v1::LIGHT_SELECTION_UNSPECIFIED:
    case prism::v1::LIGHT_SELECTION_POWER:
      return worker::LightSelectionKind::kPower;
    case prism::v1::LIGHT_SELECTION_UNIFORM:
      return worker::LightSelectionKind::kUniform;
    case prism::v1::LIGHT_SELECTION_SPATIAL:
      return worker::LightSelectionKind::kSpatial;
    default:
      break;
  }
  return absl::InvalidArgumentError(absl::StrCat("light_selection ", static_cast<int>(value),
                                                 ": want uniform, power or spatial"));
}

}  // namespace


absl::StatusOr<JobParameters> job_parameters(const prism::v1::JobSpec& spec,
                                             const scene::SceneDescription& scene) {
  JobParameters p;
  if (!base::is_sha256_hex(spec.bundle_hash())) {
    return absl::InvalidArgumentError(absl::StrCat("bundle_hash '", spec.bundle_hash(),
                                                   "': want 64 lower case hex digits (SHA-256)"));
  }
  p.bundle_hash = spec.bundle_hash();
  if (spec.scene_path().empty() || spec.scene_path().size() > kMaxScenePathBytes) {
    return absl::InvalidArgumentError(
        absl::StrCat("scene_path: want the scene file's path inside the bundle, 1..",
                     kMaxScenePathBytes, " bytes"));
  }
  p.scene_path = spec.scene_path();
  if (spec.name().size() > kMaxJobNameBytes) {
    return absl::InvalidArgumentError(
        absl::StrCat("name is ", spec.name().size(), " bytes: want at most ", kMaxJobNameBytes));
  }
  p.name = spec.name();

  if (spec.spp() != 0 && spec.spp() > kMaxJobSpp) {
    return out_of_range("spp", spec.spp(), 1, static_cast<std::int64_t>(kMaxJobSpp));
  }
  if (spec.bins() != 0 && (spec.bins() < spectral::WavelengthGrid::kMinBins ||
                           spec.bins() > spectral::WavelengthGrid::kMaxBins)) {
    return out_of_range("bins", spec.bins(), spectral::WavelengthGrid::kMinBins,
                        spectral::WavelengthGrid::kMaxBins);
  }
  if (spec.tile_size() != 0 &&
      (spec.tile_size() < kMinTileSize || spec.tile_size() > kMaxTileSize)) {
    return out_of_range("tile_size", spec.tile_size(), kMinTileSize, kMaxTileSize);
  }
  if (spec.has_max_depth() && spec.max_depth() > static_cast<std::uint32_t>(kMaxJobDepth)) {
    return out_of_range("max_depth", spec.max_depth(), 0, kMaxJobDepth);
  }
  const bool has_width = spec.width() != 0;
  const bool has_height = spec.height() != 0;
  if (has_width != has_height || spec.width() > static_cast<std::uint32_t>(scene::kMaxResolution) ||
      spec.height() > static_cast<std::uint32_t>(scene::kMaxResolution)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "resolution ", spec.width(), "x", spec.height(), ": want WxH with 1 <= W, H <= ",
        scene::kMaxResolution, " (or both 0 for the scene's Film)"));
  }
  PRISM_ASSIGN_OR_RETURN(p.render.integrator, integrator_of(spec.integrator()));
  PRISM_ASSIGN_OR_RETURN(p.render.spectral_pdf, spectral_pdf_of(spec.spectral_pdf()));
  PRISM_ASSIGN_OR_RETURN(p.render.emitter_pdf, emitter_pdf_of(spec.emitter_pdf()));
  PRISM_ASSIGN_OR_RETURN(p.render.light_selection, light_selection_of(spec.light_selection()));
  if (spec.has_prepass() && spec.prepass().enabled()) {
    return absl::InvalidArgumentError("prepass is not supported by this farm yet: leave it off");
  }
  const float exposure = spec.outputs().png_exposure();
  if (!std::isfinite(exposure) || std::fabs(exposure) > kMaxJobExposureStops) {
    return absl::InvalidArgumentError(
        absl::StrCat("outputs.png_exposure ", exposure, " is out of range: want stops in -",
                     kMaxJobExposureStops, "..", kMaxJobExposureStops));
  }
  if (spec.outputs().primal_and_gradients()) {
    return absl::InvalidArgumentError(
        "outputs.primal_and_gradients needs the gradient integrator, which this farm does not "
        "run yet");
  }

  p.render.spectral_light_selection =
      spec.has_spectral_light_selection() ? spec.spectral_light_selection() : true;
  p.render.bins = spec.bins() != 0
                      ? static_cast<int>(spec.bins())
                      : scene.film.bins.value_or(spectral::WavelengthGrid::kDefaultBins);
  p.render.max_depth =
      spec.has_max_depth() ? static_cast<int>(spec.max_depth()) : scene.integrator.max_depth;
  p.render.seed = spec.seed();
  if (has_width) {
    p.width = static_cast<int>(spec.width());
    p.height = static_cast<int>(spec.height());
  } else {
    p.width = scene.film.x_resolution;
    p.height = scene.film.y_resolution;
  }
  p.spp =
      spec.spp() != 0 ? spec.spp() : static_cast<std::uint64_t>(scene.sampler.samples_per_pixel);
  p.tile_size = spec.tile_size() != 0 ? static_cast<int>(spec.tile_size()) : kDefaultTileSize;
  p.samples_per_task = spec.samples_per_task();

  const auto& out = spec.outputs();
  if (out.spectral_exr() || out.rgb_exr() || out.png()) {
    p.outputs.spectral_exr = out.spectral_exr();
    p.outputs.rgb_exr = out.rgb_exr();
    p.outputs.png = out.png();
  }
  p.outputs.png_exposure = exposure;
  return p;
}

prism::v1::JobSpec to_proto(const JobParameters& p) {
  prism::v1::JobSpec spec;
  spec.set_bundle_hash(p.bundle_hash);
  spec.set_scene_path(p.scene_path);
  spec.set_name(p.name);
  spec.set_integrator(p.render.integrator == worker::IntegratorKind::kUniform
                          ? prism::v1::INTEGRATOR_UNIFORM
                          : prism::v1::INTEGRATOR_HERO);
  spec.set_spectral_pdf(p.render.spectral_pdf == worker::SpectralPdfKind::kFlat
                            ? prism::v1::SPECTRAL_PDF_FLAT
                            : prism::v1::SPECTRAL_PDF_VISIBLE);
  spec.set_emitter_pdf(p.render.emitter_pdf == worker::EmitterPdfKind::kUniform
                           ? prism::v1::EMITTER_PDF_UNIFORM
                           : prism::v1::EMITTER_PDF_EMITTERS);
  switch (p.render.light_selection) {
    case worker::LightSelectionKind::kUniform:
      spec.set_light_selection(prism::v1::LIGHT_SELECTION_UNIFORM);
      break;
    case worker::LightSelectionKind::kPower:
      spec.set_light_selection(prism::v1::LIGHT_SELECTION_POWER);
      break;
    case worker::LightSelectionKind::kSpatial:
      spec.set_light_selection(prism::v1::LIGHT_SELECTION_SPATIAL);
      break;
  }
  spec.set_spectral_light_selection(p.render.spectral_light_selection);
  spec.set_spp(static_cast<std::uint32_t>(p.spp));
  spec.set_width(static_cast<std::uint32_t>(p.width));
  spec.set_height(static_cast<std::uint32_t>(p.height));
  spec.set_bins(static_cast<std::uint32_t>(p.render.bins));
  spec.set_tile_size(static_cast<std::uint32_t>(p.tile_size));
  spec.set_seed(p.render.seed);
  spec.set_max_depth(static_cast<std::uint32_t>(p.render.max_depth));
  spec.set_samples_per_task(static_cast<std::uint32_t>(p.samples_per_task));
  auto* out = spec.mutable_outputs();
  out->set_spectral_exr(p.outputs.spectral_exr);
  out->set_rgb_exr(p.outputs.rgb_exr);
  out->set_png(p.outputs.png);
  out->set_png_exposure(p.outputs.png_exposure);
  return spec;
}

}  // namespace prism::coordinator
