#include "services/job/job_spec.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/scene/wavelength_dependence.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::job {
namespace {

absl::Status out_of_range(const char* field, std::int64_t value, std::int64_t lo, std::int64_t hi) {
  return absl::InvalidArgumentError(
      absl::StrCat(field, " ", value, " is out of range: want ", lo, "..", hi));
}

absl::StatusOr<IntegratorKind> integrator_of(prism::v1::Integrator value) {
  switch (value) {
    case prism::v1::INTEGRATOR_UNSPECIFIED:
    case prism::v1::INTEGRATOR_HERO:
      return IntegratorKind::kHero;
    case prism::v1::INTEGRATOR_UNIFORM:
      return IntegratorKind::kUniform;
    case prism::v1::INTEGRATOR_GRADIENT:
      return IntegratorKind::kGradient;
    case prism::v1::INTEGRATOR_LIGHT:
      return IntegratorKind::kLight;
    default:
      break;
  }
  return absl::InvalidArgumentError(absl::StrCat("integrator ", static_cast<int>(value),
                                                 ": want uniform, hero, gradient or light"));
}

absl::StatusOr<image::ExrCompression> exr_compression_of(prism::v1::ExrCompression value) {
  switch (value) {
    case prism::v1::EXR_COMPRESSION_UNSPECIFIED:
      return image::kDefaultExrCompression;
    case prism::v1::EXR_COMPRESSION_NONE:
      return image::ExrCompression::kNone;
    case prism::v1::EXR_COMPRESSION_RLE:
      return image::ExrCompression::kRle;
    case prism::v1::EXR_COMPRESSION_ZIPS:
      return image::ExrCompression::kZips;
    case prism::v1::EXR_COMPRESSION_ZIP:
      return image::ExrCompression::kZip;
    case prism::v1::EXR_COMPRESSION_PIZ:
      return image::ExrCompression::kPiz;
    default:
      break;
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "outputs.exr_compression ", static_cast<int>(value), ": want none, rle, zips, zip or piz"));
}

absl::StatusOr<SpectralPdfKind> spectral_pdf_of(prism::v1::SpectralPdf value) {
  switch (value) {
    case prism::v1::SPECTRAL_PDF_UNSPECIFIED:
    case prism::v1::SPECTRAL_PDF_FLAT:
      return SpectralPdfKind::kFlat;
    case prism::v1::SPECTRAL_PDF_VISIBLE:
      return SpectralPdfKind::kVisible;
    default:
      break;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("spectral_pdf ", static_cast<int>(value), ": want flat or visible"));
}

absl::StatusOr<EmitterPdfKind> emitter_pdf_of(prism::v1::EmitterPdf value) {
  switch (value) {
    case prism::v1::EMITTER_PDF_UNSPECIFIED:
    case prism::v1::EMITTER_PDF_EMITTERS:
      return EmitterPdfKind::kEmitters;
    case prism::v1::EMITTER_PDF_UNIFORM:
      return EmitterPdfKind::kUniform;
    default:
      break;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("emitter_pdf ", static_cast<int>(value), ": want uniform or emitters"));
}

absl::StatusOr<LightSelectionKind> light_selection_of(prism::v1::LightSelection value) {
  switch (value) {
    case prism::v1::LIGHT_SELECTION_UNSPECIFIED:
    case prism::v1::LIGHT_SELECTION_POWER:
      return LightSelectionKind::kPower;
    case prism::v1::LIGHT_SELECTION_UNIFORM:
      return LightSelectionKind::kUniform;
    case prism::v1::LIGHT_SELECTION_SPATIAL:
      return LightSelectionKind::kSpatial;
    default:
      break;
  }
  return absl::InvalidArgumentError(absl::StrCat("light_selection ", static_cast<int>(value),
                                                 ": want uniform, power or spatial"));
}

// The wire keeps these values as float: defaults are rounded the same way, so a spec with the
// field unset and one with the default written explicitly (to_proto) give the same parameters.
double as_float(double value) {
  return static_cast<double>(static_cast<float>(value));
}

// A float field where 0 means "the default": the default, or the value when it is finite and
// inside [lo, hi] (lo_open: > lo).
absl::StatusOr<double> float_field(const char* field, float value, double fallback, double lo,
                                   bool lo_open, double hi) {
  if (value == 0.0f) return as_float(fallback);
  const double v = value;
  if (!std::isfinite(v) || (lo_open ? v <= lo : v < lo) || v > hi) {
    return absl::InvalidArgumentError(absl::StrCat(field, " ", v, " is out of range: want ",
                                                   lo_open ? "(" : "[", lo, ", ", hi, "]"));
  }
  return v;
}

absl::Status gradient_of(const prism::v1::GradientOptions& g, int bins, JobParameters& p) {
  PRISM_ASSIGN_OR_RETURN(p.gradient.delta, float_field("gradient.delta", g.delta(),
                                                       kDefaultGradientDelta, 0.0, true, 0.5));
  PRISM_ASSIGN_OR_RETURN(p.render.gradient_offset_bins,
                         gradient_offset_bins(p.gradient.delta, bins));
  if (!std::isfinite(g.tau()) || g.tau() < 0.0f) {
    return absl::InvalidArgumentError(
        absl::StrCat("gradient.tau ", g.tau(), " is out of range: want a finite value >= 0"));
  }
  p.render.gradient_tau = g.tau();
  if (g.lanes() > std::uint32_t(kMaxGradientLanes)) {
    return absl::InvalidArgumentError(absl::StrCat("gradient.lanes ", g.lanes(),
                                                   " is out of range: want 1..", kMaxGradientLanes,
                                                   " (0: by the scene)"));
  }
  p.render.gradient_lanes = int(g.lanes());
  if (g.has_tau_pilot()) {
    const prism::v1::GradientTauPilot& t = g.tau_pilot();
    if (!(t.epsilon() > 0.0f && t.epsilon() <= 1.0f)) {
      return absl::InvalidArgumentError(absl::StrCat("gradient.tau_pilot.epsilon ", t.epsilon(),
                                                     " is out of range: want (0, 1]"));
    }
    for (const auto& [name, value] :
         {std::pair{"shifted_event_fraction", t.shifted_event_fraction()},
          std::pair{"shifted_square_fraction", t.shifted_square_fraction()},
          std::pair{"offset_vertex_fraction", t.offset_vertex_fraction()}}) {
      if (!(value >= 0.0f && value <= 1.0f)) {
        return absl::InvalidArgumentError(
            absl::StrCat("gradient.tau_pilot.", name, " ", value, " is out of range: want [0, 1]"));
      }
    }
    if (!(t.lost_benefit_fraction() >= 0.0f && t.lost_benefit_fraction() <= t.epsilon())) {
      return absl::InvalidArgumentError(
          absl::StrCat("gradient.tau_pilot.lost_benefit_fraction ", t.lost_benefit_fraction(),
                       " is out of range: want [0, epsilon ", t.epsilon(), "]"));
    }
    if (!std::isfinite(t.second_moment_rise())) {
      return absl::InvalidArgumentError(absl::StrCat("gradient.tau_pilot.second_moment_rise ",
                                                     t.second_moment_rise(),
                                                     " is out of range: want a finite value"));
    }
    p.gradient.tau_pilot = TauPilotReport{t.epsilon(),
                                          t.pixels(),
                                          t.spp(),
                                          t.events(),
                                          t.shifted_event_fraction(),
                                          t.shifted_square_fraction(),
                                          t.lost_benefit_fraction(),
                                          t.offset_vertex_fraction(),
                                          t.second_moment_rise(),
                                          std::nullopt};
  }
  PRISM_ASSIGN_OR_RETURN(p.gradient.alpha,
                         float_field("gradient.alpha", g.alpha(), kDefaultPoissonAlpha,
                                     kMinPoissonAlpha, false, kMaxPoissonAlpha));
  switch (g.norm()) {
    case prism::v1::POISSON_NORM_UNSPECIFIED:
    case prism::v1::POISSON_NORM_L2:
      p.gradient.norm = PoissonNorm::kL2;
      break;
    case prism::v1::POISSON_NORM_L1:
      p.gradient.norm = PoissonNorm::kL1;
      break;
    case prism::v1::POISSON_NORM_WEIGHTED:
      p.gradient.norm = PoissonNorm::kWeighted;
      break;
    default:
      return absl::InvalidArgumentError(
          absl::StrCat("gradient.norm ", static_cast<int>(g.norm()), ": want l2, l1 or weighted"));
  }
  p.render.gradient_variances = p.gradient.norm == PoissonNorm::kWeighted;
  return absl::OkStatus();
}

// The prepass of a job with `spp` final samples per pixel, or nothing when its Ñ is left to the
// budget and the budget is too small to learn from (budgeted_prepass_spp).
absl::StatusOr<std::optional<PrepassParameters>> prepass_of(const prism::v1::PrepassOptions& o,
                                                            std::uint64_t spp) {
  PrepassParameters d;
  PrepassParameters p;
  if (o.passes() > static_cast<std::uint32_t>(PrepassParameters::kMaxPasses)) {
    return absl::InvalidArgumentError(absl::StrCat("prepass.passes ", o.passes(),
                                                   " is out of range: want 1..",
                                                   PrepassParameters::kMaxPasses));
  }
  p.passes = o.passes() != 0 ? static_cast<int>(o.passes()) : d.passes;
  p.image_scaled = o.image_scaled();
  const std::uint32_t budgeted =
      o.spp() != 0 ? o.spp() : budgeted_prepass_spp(spp, p.passes, p.image_scaled);
  p.spp = budgeted != 0 ? budgeted : kMinBudgetedSpp;  // validated like any, then dropped
  // 0 means the default for every float; a fallback threshold of exactly 0 is asked for with a
  // tiny positive value (a pixel keeps a table when V(α) <= (1 − f)·V(0), so f = 1e-30 behaves as
  // 0 for any real estimate).
  auto value = [](float v, double fallback) { return v != 0.0f ? double(v) : as_float(fallback); };
  p.epsilon = value(o.epsilon(), d.epsilon);
  p.fallback = value(o.fallback(), d.fallback);
  p.sigma_s = value(o.sigma_s(), d.sigma_s);
  p.sigma_r = value(o.sigma_r(), d.sigma_r);
  if (p.spp > kMaxJobSpp) {
    return absl::InvalidArgumentError(
        absl::StrCat("prepass.spp ", p.spp, " is out of range: want 1..", kMaxJobSpp));
  }
  PRISM_RETURN_IF_ERROR(p.validate());
  if (budgeted == 0) return std::optional<PrepassParameters>();
  return std::optional<PrepassParameters>(p);
}

}  // namespace

bool prepass_by_default(IntegratorKind, const scene::SceneDescription&) {
  // Off until it never costs error at equal time: measured on single-lamp scenes the prepass as
  // first specified (bin-constant, mean-proportional tables) was up to 4.2x worse than the
  // emitter mixture, and the second-moment tables of docs/estimators.md §4 still miss some of
  // issue 11's goals (docs/benchmarks.md).
  return false;
}

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
  p.allow_unsupported = spec.allow_unsupported();
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
  const float exposure = spec.outputs().png_exposure();
  if (!std::isfinite(exposure) || std::fabs(exposure) > kMaxJobExposureStops) {
    return absl::InvalidArgumentError(
        absl::StrCat("outputs.png_exposure ", exposure, " is out of range: want stops in -",
                     kMaxJobExposureStops, "..", kMaxJobExposureStops));
  }
  const bool gradient = p.render.integrator == IntegratorKind::kGradient;
  if (spec.outputs().primal_and_gradients() && !gradient) {
    return absl::InvalidArgumentError("outputs.primal_and_gradients needs the gradient integrator");
  }
  if (!gradient && spec.has_gradient() &&
      (spec.gradient().delta() != 0.0f || spec.gradient().tau() != 0.0f ||
       spec.gradient().alpha() != 0.0f || spec.gradient().has_tau_pilot() ||
       spec.gradient().lanes() != 0 ||
       spec.gradient().norm() != prism::v1::POISSON_NORM_UNSPECIFIED)) {
    return absl::InvalidArgumentError(
        absl::StrCat("gradient options (delta, tau, alpha, norm, lanes) need the gradient "
                     "integrator, "
                     "not ",
                     name(p.render.integrator)));
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
  if (spec.target_error() != 0.0f) {
    TargetError t;
    t.relative = spec.target_error();
    if (!target_error_in_range(t.relative)) {
      return absl::InvalidArgumentError(
          absl::StrCat("target_error ", t.relative, " is out of range: want ", kMinTargetError,
                       "..", kMaxTargetError, " (a relative standard error, 0.01 is 1 %)"));
    }
    t.image_scope = spec.target_error_image();
    t.max_spp = spec.max_spp() != 0 ? spec.max_spp()
                                    : std::max<std::uint64_t>(p.spp, kDefaultTargetErrorMaxSpp);
    if (t.max_spp < p.spp || t.max_spp > kMaxJobSpp) {
      return absl::InvalidArgumentError(
          absl::StrCat("the most samples per pixel for the target error (max_spp, --max-spp) ",
                       t.max_spp, " is out of range: want ", p.spp, "..", kMaxJobSpp,
                       ", at least the first round's samples per pixel (--spp or the scene's)"));
    }
    if (p.spp < 2) {
      return absl::InvalidArgumentError(
          absl::StrCat("spp ", p.spp,
                       " is too few for a target error: its first round needs at least 2 (--spp)"));
    }
    p.target_error = t;
  } else if (spec.target_error_image() || spec.max_spp() != 0) {
    return absl::InvalidArgumentError(
        "target_error_image or max_spp is set without a target_error");
  }

  if (gradient) PRISM_RETURN_IF_ERROR(gradient_of(spec.gradient(), p.render.bins, p));
  const bool prepass = spec.has_prepass() ? spec.prepass().enabled()
                                          : prepass_by_default(p.render.integrator, scene);
  if (prepass) {
    PRISM_ASSIGN_OR_RETURN(p.prepass, prepass_of(spec.prepass(), p.spp));
  } else if (spec.has_prepass() &&
             (spec.prepass().passes() != 0 || spec.prepass().spp() != 0 ||
              spec.prepass().image_scaled() || spec.prepass().epsilon() != 0.0f ||
              spec.prepass().fallback() != 0.0f || spec.prepass().sigma_s() != 0.0f ||
              spec.prepass().sigma_r() != 0.0f)) {
    return absl::InvalidArgumentError("prepass options are set but the prepass is off");
  }

  if (spec.has_auto_choice()) {
    const prism::v1::AutoChoice& a = spec.auto_choice();
    if (a.candidates_size() > 8 || a.reason().size() > 1024) {
      return absl::InvalidArgumentError(
          "auto_choice: want at most 8 candidates and a reason of at most 1024 bytes");
    }
    // `hero+caustics` is hero with light_caustics, `hero+prepass` hero with a prepass that runs
    // (client/auto_integrator.h).
    const std::string ran =
        absl::StrCat(name(p.render.integrator), spec.light_caustics() ? "+caustics" : "",
                     p.prepass.has_value() ? "+prepass" : "");
    if (a.choice() != ran) {
      return absl::InvalidArgumentError(
          absl::StrCat("auto_choice says '", a.choice(), "' but the integrator is ", ran));
    }
    AutoReport r;
    r.choice = a.choice();
    r.reason = a.reason();
    r.seconds = a.seconds();
    for (const auto& c : a.candidates()) {
      r.candidates.push_back({c.method(), c.rel_mse_per_sample(), c.rays_per_sample(),
                              c.relative_efficiency(), c.ray_cost(), c.caustic_paths()});
    }
    p.auto_choice = std::move(r);
  }

  p.render.light_caustics = spec.light_caustics();
  if (spec.caustic_paths() != 0.0f) {
    if (!spec.light_caustics()) {
      return absl::InvalidArgumentError(
          "caustic_paths is the share of light paths of light_caustics: set light_caustics");
    }
    if (!(spec.caustic_paths() >= kMinCausticPaths && spec.caustic_paths() <= 1.0f)) {
      return absl::InvalidArgumentError(absl::StrCat("caustic_paths ", spec.caustic_paths(),
                                                     " is out of range: want light paths per "
                                                     "pixel and sample in ",
                                                     kMinCausticPaths, "..1"));
    }
    p.render.caustic_paths = spec.caustic_paths();
  }
  // The filters' widths (splat_width, gather_width): 0 (off) or nm in range.
  auto check_width = [](const char* field, float nm) -> absl::Status {
    if (nm == 0.0f || (nm >= kMinSplatWidthNm && nm <= kMaxSplatWidthNm)) return absl::OkStatus();
    return absl::InvalidArgumentError(absl::StrCat(field, " ", nm, " nm is out of range: want ",
                                                   kMinSplatWidthNm, "..", kMaxSplatWidthNm));
  };
  PRISM_RETURN_IF_ERROR(check_width("splat_width", spec.splat_width()));
  PRISM_RETURN_IF_ERROR(check_width("gather_width", spec.gather_width()));
  if (spec.splat_width() != 0.0f) {
    if (!p.render.traces_light_paths()) {
      return absl::InvalidArgumentError(
          "splat_width splats light paths: it needs the light integrator or light_caustics");
    }
    p.render.splat_width_nm = spec.splat_width();
  }
  if (spec.gather_width() != 0.0f) {
    if ((p.render.integrator != IntegratorKind::kHero &&
         p.render.integrator != IntegratorKind::kUniform) ||
        p.render.light_caustics) {
      return absl::InvalidArgumentError(
          "gathering (--gather, gather_width) filters eye-traced images: it needs the hero or "
          "the uniform integrator without light-traced caustics (light paths have --splat)");
    }
    if (spec.target_error() != 0.0f) {
      return absl::InvalidArgumentError(
          "gathering (--gather, gather_width) does not combine with a target error "
          "(--target-error) yet: the filter runs once over the finished image");
    }
    p.render.gather_width_nm = spec.gather_width();
  }
  if (p.render.traces_light_paths()) {
    // sums, squares, R, G, B and their squares, counts; a filtered image's sums and R, G, B.
    const std::uint64_t per_pixel =
        2 * std::uint64_t(p.render.bins) + 2 * 3 + 1 +
        (p.render.splats_differentials() ? std::uint64_t(p.render.bins) + 3 : 0);
    const std::uint64_t bytes = std::uint64_t(p.width) * std::uint64_t(p.height) * per_pixel * 8;
    if (bytes > kMaxWholeImageResultBytes) {
      return absl::InvalidArgumentError(
          absl::StrCat("light paths make each task the whole image, and a ", p.width, "x", p.height,
                       " image at ", p.render.bins, " bins returns ", bytes >> 20,
                       " MiB per task, over the limit of ", kMaxWholeImageResultBytes >> 20,
                       " MiB: use fewer bins or pixels"));
    }
  }
  if (p.render.light_caustics) {
    if (p.render.integrator != IntegratorKind::kHero &&
        p.render.integrator != IntegratorKind::kUniform) {
      return absl::InvalidArgumentError(
          absl::StrCat("light-traced caustics (--caustics light, light_caustics) need the hero "
                       "or the uniform integrator, not ",
                       name(p.render.integrator)));
    }
    if (prepass || p.target_error) {
      return absl::InvalidArgumentError(
          "light-traced caustics (--caustics light, light_caustics) do not combine with the "
          "prepass or a target error (--target-error) yet: their task is the whole image");
    }
  }
  if (p.render.integrator == IntegratorKind::kLight) {
    if (prepass) {
      return absl::InvalidArgumentError(
          "the prepass learns eye paths' wavelength distributions; the light integrator has no "
          "use for it");
    }
    if (p.target_error) {
      return absl::InvalidArgumentError(
          "a target error (--target-error, target_error) is not available with the light "
          "integrator yet: its task is the whole image, and rounds are planned per tile");
    }
  }

  const auto& out = spec.outputs();
  if (out.has_spectral_exr() || out.has_rgb_exr() || out.has_png()) {
    if (!out.spectral_exr() && !out.rgb_exr() && !out.png()) {
      return absl::InvalidArgumentError(
          "outputs: spectral_exr, rgb_exr and png are all false: a job writes at least one of "
          "them (leave all three out for all three)");
    }
    p.outputs.spectral_exr = out.spectral_exr();
    p.outputs.rgb_exr = out.rgb_exr();
    p.outputs.png = out.png();
  }
  p.outputs.png_exposure = exposure;
  p.outputs.primal_and_gradients = out.primal_and_gradients();
  PRISM_ASSIGN_OR_RETURN(p.outputs.exr_compression, exr_compression_of(out.exr_compression()));
  return p;
}

prism::v1::Integrator to_proto(IntegratorKind kind) {
  switch (kind) {
    case IntegratorKind::kUniform:
      return prism::v1::INTEGRATOR_UNIFORM;
    case IntegratorKind::kHero:
      return prism::v1::INTEGRATOR_HERO;
    case IntegratorKind::kGradient:
      return prism::v1::INTEGRATOR_GRADIENT;
    case IntegratorKind::kLight:
      return prism::v1::INTEGRATOR_LIGHT;
  }
  return prism::v1::INTEGRATOR_UNSPECIFIED;
}

prism::v1::ExrCompression to_proto(image::ExrCompression compression) {
  switch (compression) {
    case image::ExrCompression::kNone:
      return prism::v1::EXR_COMPRESSION_NONE;
    case image::ExrCompression::kRle:
      return prism::v1::EXR_COMPRESSION_RLE;
    case image::ExrCompression::kZips:
      return prism::v1::EXR_COMPRESSION_ZIPS;
    case image::ExrCompression::kZip:
      return prism::v1::EXR_COMPRESSION_ZIP;
    case image::ExrCompression::kPiz:
      return prism::v1::EXR_COMPRESSION_PIZ;
  }
  return prism::v1::EXR_COMPRESSION_UNSPECIFIED;
}

prism::v1::LightSelection to_proto(LightSelectionKind kind) {
  switch (kind) {
    case LightSelectionKind::kUniform:
      return prism::v1::LIGHT_SELECTION_UNIFORM;
    case LightSelectionKind::kPower:
      return prism::v1::LIGHT_SELECTION_POWER;
    case LightSelectionKind::kSpatial:
      return prism::v1::LIGHT_SELECTION_SPATIAL;
  }
  return prism::v1::LIGHT_SELECTION_UNSPECIFIED;
}

prism::v1::PoissonNorm to_proto(PoissonNorm norm) {
  switch (norm) {
    case PoissonNorm::kL2:
      return prism::v1::POISSON_NORM_L2;
    case PoissonNorm::kL1:
      return prism::v1::POISSON_NORM_L1;
    case PoissonNorm::kWeighted:
      return prism::v1::POISSON_NORM_WEIGHTED;
  }
  return prism::v1::POISSON_NORM_UNSPECIFIED;
}

prism::v1::AutoChoice to_proto(const AutoReport& report) {
  prism::v1::AutoChoice a;
  a.set_choice(report.choice);
  a.set_reason(report.reason);
  a.set_seconds(report.seconds);
  for (const AutoReport::Candidate& c : report.candidates) {
    prism::v1::AutoChoice::Candidate* out = a.add_candidates();
    out->set_method(c.method);
    out->set_rel_mse_per_sample(c.rel_mse_per_sample);
    out->set_rays_per_sample(c.rays_per_sample);
    out->set_relative_efficiency(c.relative_efficiency);
    out->set_ray_cost(c.ray_cost);
    out->set_caustic_paths(c.caustic_paths);
  }
  return a;
}

prism::v1::GradientTauPilot to_proto(const TauPilotReport& r) {
  prism::v1::GradientTauPilot t;
  t.set_epsilon(r.epsilon);
  t.set_pixels(r.pixels);
  t.set_spp(r.spp);
  t.set_events(r.events);
  t.set_shifted_event_fraction(r.shifted_event_fraction);
  t.set_shifted_square_fraction(r.shifted_square_fraction);
  t.set_lost_benefit_fraction(r.lost_benefit_fraction);
  t.set_offset_vertex_fraction(r.offset_vertex_fraction);
  t.set_second_moment_rise(r.second_moment_rise);
  return t;
}

prism::v1::JobSpec to_proto(const JobParameters& p) {
  prism::v1::JobSpec spec;
  spec.set_bundle_hash(p.bundle_hash);
  spec.set_scene_path(p.scene_path);
  spec.set_name(p.name);
  spec.set_allow_unsupported(p.allow_unsupported);
  spec.set_integrator(to_proto(p.render.integrator));
  if (p.render.integrator == IntegratorKind::kGradient) {
    auto* g = spec.mutable_gradient();
    g->set_delta(static_cast<float>(p.gradient.delta));
    g->set_tau(p.render.gradient_tau);
    if (p.gradient.tau_pilot.has_value()) *g->mutable_tau_pilot() = to_proto(*p.gradient.tau_pilot);
    g->set_alpha(static_cast<float>(p.gradient.alpha));
    g->set_norm(to_proto(p.gradient.norm));
    if (p.render.gradient_lanes != 0) g->set_lanes(std::uint32_t(p.render.gradient_lanes));
  }
  auto* prepass = spec.mutable_prepass();
  prepass->set_enabled(p.prepass.has_value());
  if (p.prepass.has_value()) {
    prepass->set_passes(static_cast<std::uint32_t>(p.prepass->passes));
    prepass->set_spp(p.prepass->spp);
    prepass->set_image_scaled(p.prepass->image_scaled);
    prepass->set_epsilon(static_cast<float>(p.prepass->epsilon));
    prepass->set_fallback(static_cast<float>(p.prepass->fallback));
    prepass->set_sigma_s(static_cast<float>(p.prepass->sigma_s));
    prepass->set_sigma_r(static_cast<float>(p.prepass->sigma_r));
  }
  spec.set_spectral_pdf(p.render.spectral_pdf == SpectralPdfKind::kFlat
                            ? prism::v1::SPECTRAL_PDF_FLAT
                            : prism::v1::SPECTRAL_PDF_VISIBLE);
  spec.set_emitter_pdf(p.render.emitter_pdf == EmitterPdfKind::kUniform
                           ? prism::v1::EMITTER_PDF_UNIFORM
                           : prism::v1::EMITTER_PDF_EMITTERS);
  spec.set_light_selection(to_proto(p.render.light_selection));
  spec.set_spectral_light_selection(p.render.spectral_light_selection);
  spec.set_light_caustics(p.render.light_caustics);
  if (p.render.light_caustics && p.render.caustic_paths < 1.0f) {
    spec.set_caustic_paths(p.render.caustic_paths);
  }
  spec.set_splat_width(p.render.splat_width_nm);
  spec.set_gather_width(p.render.gather_width_nm);
  spec.set_spp(static_cast<std::uint32_t>(p.spp));
  if (p.auto_choice.has_value()) *spec.mutable_auto_choice() = to_proto(*p.auto_choice);
  if (p.target_error.has_value()) {
    spec.set_target_error(static_cast<float>(p.target_error->relative));
    spec.set_target_error_image(p.target_error->image_scope);
    spec.set_max_spp(static_cast<std::uint32_t>(p.target_error->max_spp));
  }
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
  out->set_primal_and_gradients(p.outputs.primal_and_gradients);
  out->set_png_exposure(p.outputs.png_exposure);
  out->set_exr_compression(to_proto(p.outputs.exr_compression));
  return spec;
}

std::string request_identity(const prism::v1::JobSpec& spec) {
  prism::v1::JobSpec canonical = spec;
  if (canonical.has_auto_choice()) canonical.mutable_auto_choice()->clear_seconds();
  return canonical.SerializeAsString();
}

}  // namespace prism::job
