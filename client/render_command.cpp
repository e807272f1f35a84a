#include "client/render_command.h"

#include <charconv>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <sstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/auto_integrator.h"
#include "coordinator/job_report.h"
#include "coordinator/local_render.h"
#include "coordinator/outputs.h"
#include "coordinator/poisson.h"
#include "coordinator/prepass.h"
#include "coordinator/resource_plan.h"
#include "google/protobuf/util/message_differencer.h"
#include "services/base/decimal.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/job/job_spec.h"
#include "services/scene/bundle.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/wavelength_grid.h"
#include "worker/gradient/pilot.h"
#include "worker/render_scene.h"

namespace prism::client {
namespace {

using Clock = std::chrono::steady_clock;

absl::Status out_of_range(const char* flag, std::int64_t value, std::int64_t lo, std::int64_t hi) {
  return absl::InvalidArgumentError(
      absl::StrCat(flag, " ", value, " is out of range: want ", lo, "..", hi));
}

absl::Status check_range(const char* flag, const std::optional<std::int64_t>& value,
                         std::int64_t lo, std::int64_t hi) {
  if (value.has_value() && (*value < lo || *value > hi)) return out_of_range(flag, *value, lo, hi);
  return absl::OkStatus();
}

// 1234567 -> "1.23 M".
// A line for the summary where samples were not finite: they are left out of the image (the
// report's counters.non_finite), which darkens it where they fell, so the user should know.
std::string non_finite_warning(const std::vector<std::pair<std::string, std::uint64_t>>& counters,
                               std::uint64_t samples) {
  for (const auto& [name, value] : counters) {
    if (name != "non_finite" || value == 0) continue;
    return absl::StrFormat(
        "warning: %d sample contribution(s) were NaN or infinite and were left out (%.3g %% of "
        "%d samples; counters.non_finite in the report): the scene has a value the estimators "
        "cannot use\n",
        value, samples > 0 ? 100.0 * double(value) / double(samples) : 0.0, samples);
  }
  return "";
}

std::string human(double value) {
  if (!std::isfinite(value)) return "-";
  const char* units[] = {"", " k", " M", " G", " T"};
  int u = 0;
  while (std::fabs(value) >= 1000.0 && u < 4) {
    value /= 1000.0;
    ++u;
  }
  return absl::StrFormat("%.3g%s", value, units[u]);
}

std::string clock_time(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "--:--";
  const auto s = static_cast<std::int64_t>(seconds + 0.5);
  if (s >= 3600) return absl::StrFormat("%d:%02d:%02d", s / 3600, (s / 60) % 60, s % 60);
  return absl::StrFormat("%d:%02d", s / 60, s % 60);
}

// One line, redrawn in place with '\r'.
void draw_progress(std::ostream& out, const coordinator::RenderProgress& p) {
  constexpr int kWidth = 30;
  const double fraction =
      p.samples_total > 0 ? double(p.samples_done) / double(p.samples_total) : 1.0;
  const int filled = std::min(kWidth, static_cast<int>(fraction * kWidth));
  const double rate = p.seconds > 0 ? double(p.samples_done) / p.seconds : 0.0;
  const double eta = rate > 0 ? double(p.samples_total - p.samples_done) / rate : NAN;
  out << "\r[" << std::string(filled, '#') << std::string(kWidth - filled, '.') << "] "
      << absl::StrFormat("%5.1f%%", 100.0 * fraction) << "  " << human(rate)
      << " samples/s  elapsed " << clock_time(p.seconds) << "  ETA " << clock_time(eta) << "   "
      << std::flush;
}

}  // namespace

bool has_prepass_options(const RenderCommandOptions& o) {
  return o.prepass_passes || o.prepass_spp || o.prepass_mode != "samples" || o.prepass_epsilon ||
         o.prepass_fallback || o.prepass_sigma_s || o.prepass_sigma_r;
}

absl::StatusOr<std::pair<int, int>> parse_resolution(const std::string& text) {
  const std::size_t x = text.find('x');
  int w = 0, h = 0;
  bool ok = x != std::string::npos && x > 0 && x + 1 < text.size();
  if (ok) {
    auto [end_w, ec_w] = std::from_chars(text.data(), text.data() + x, w);
    auto [end_h, ec_h] = std::from_chars(text.data() + x + 1, text.data() + text.size(), h);
    ok = ec_w == std::errc() && end_w == text.data() + x && ec_h == std::errc() &&
         end_h == text.data() + text.size();
  }
  if (!ok || w < 1 || h < 1 || w > scene::kMaxResolution || h > scene::kMaxResolution) {
    return absl::InvalidArgumentError(
        absl::StrCat("--resolution '", text,
                     "': want WxH with 1 <= W, H <= ", scene::kMaxResolution, ", e.g. 640x480"));
  }
  return std::pair<int, int>{w, h};
}

absl::StatusOr<double> parse_target_error(const std::string& text, std::string_view flag) {
  std::string digits = text;
  const bool percent = !digits.empty() && digits.back() == '%';
  if (percent) digits.pop_back();
  double value = 0;
  auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
  if (percent) value /= 100;
  if (digits.empty() || ec != std::errc() || end != digits.data() + digits.size() ||
      !(value >= job::kMinTargetError && value <= job::kMaxTargetError)) {
    return absl::InvalidArgumentError(
        absl::StrCat(std::string(flag), " '", text, "': want a relative error such as 0.01 or 1% (",
                     job::kMinTargetError, "..", job::kMaxTargetError, ")"));
  }
  return value;
}

absl::StatusOr<std::uint64_t> parse_seed(const std::string& text) {
  std::uint64_t seed = 0;
  auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), seed);
  if (text.empty() || ec != std::errc() || end != text.data() + text.size()) {
    return absl::InvalidArgumentError(
        absl::StrCat("--seed '", text, "': want an integer in 0..18446744073709551615"));
  }
  return seed;
}

absl::StatusOr<job::IntegratorKind> parse_integrator(const std::string& name) {
  if (name == "uniform") return job::IntegratorKind::kUniform;
  if (name == "hero") return job::IntegratorKind::kHero;
  if (name == "gradient") return job::IntegratorKind::kGradient;
  if (name == "light") return job::IntegratorKind::kLight;
  return absl::InvalidArgumentError(
      absl::StrCat("--integrator '", name, "': want uniform, hero, gradient, light or auto"));
}

absl::StatusOr<job::SpectralPdfKind> parse_spectral_pdf(const std::string& name) {
  if (name == "flat") return job::SpectralPdfKind::kFlat;
  if (name == "visible") return job::SpectralPdfKind::kVisible;
  return absl::InvalidArgumentError(
      absl::StrCat("--spectral-pdf '", name, "': want flat or visible"));
}

absl::StatusOr<job::EmitterPdfKind> parse_emitter_pdf(const std::string& name) {
  if (name == "uniform") return job::EmitterPdfKind::kUniform;
  if (name == "emitters") return job::EmitterPdfKind::kEmitters;
  return absl::InvalidArgumentError(
      absl::StrCat("--emitter-pdf '", name, "': want uniform or emitters"));
}

absl::StatusOr<job::LightSelectionKind> parse_light_selection(const std::string& name) {
  if (name == "uniform") return job::LightSelectionKind::kUniform;
  if (name == "power") return job::LightSelectionKind::kPower;
  if (name == "spatial") return job::LightSelectionKind::kSpatial;
  return absl::InvalidArgumentError(
      absl::StrCat("--light-selection '", name, "': want uniform, power or spatial"));
}

absl::Status validate_render_flags(const RenderCommandOptions& o) {
  PRISM_RETURN_IF_ERROR(check_range("--spp", o.spp, 1, std::int64_t(job::kMaxJobSpp)));
  PRISM_RETURN_IF_ERROR(check_range("--bins", o.bins, spectral::WavelengthGrid::kMinBins,
                                    spectral::WavelengthGrid::kMaxBins));
  PRISM_RETURN_IF_ERROR(check_range("--threads", o.threads, 0, job::kMaxThreads));
  PRISM_RETURN_IF_ERROR(check_range("--tile", o.tile, 4, 1024));
  PRISM_RETURN_IF_ERROR(check_range("--max-depth", o.max_depth, 0, job::kMaxJobDepth));
  PRISM_RETURN_IF_ERROR(
      check_range("--samples-per-task", o.samples_per_task, 1, std::int64_t(job::kMaxJobSpp)));
  if (o.resolution.has_value()) PRISM_RETURN_IF_ERROR(parse_resolution(*o.resolution).status());
  const bool automatic = o.integrator == "auto";
  if (!automatic) PRISM_RETURN_IF_ERROR(parse_integrator(o.integrator).status());
  PRISM_RETURN_IF_ERROR(parse_spectral_pdf(o.spectral_pdf).status());
  PRISM_RETURN_IF_ERROR(parse_emitter_pdf(o.emitter_pdf).status());
  PRISM_RETURN_IF_ERROR(parse_light_selection(o.light_selection).status());
  if (!o.caustics.empty() && o.caustics != "off" && o.caustics != "light") {
    return absl::InvalidArgumentError(
        absl::StrCat("--caustics '", o.caustics, "': want off or light"));
  }
  if (o.caustic_paths.has_value()) {
    if (!(*o.caustic_paths >= job::kMinCausticPaths && *o.caustic_paths <= 1.0)) {
      return absl::InvalidArgumentError(
          absl::StrCat("--caustic-paths ", *o.caustic_paths,
                       " is out of range: want light paths per pixel and sample in ",
                       job::kMinCausticPaths, "..1"));
    }
    if (o.caustics != "light" && !(automatic && o.caustics.empty())) {
      return absl::InvalidArgumentError(
          "--caustic-paths is the share of light paths of --caustics light: use it with "
          "--caustics light (or --integrator auto)");
    }
  }
  if (o.splat_width.has_value()) {
    // As the job holds it, a float: 0.1 as a double is below the float 0.1f it becomes.
    const float splat_width_nm = static_cast<float>(*o.splat_width);
    if (!(splat_width_nm >= job::kMinSplatWidthNm && splat_width_nm <= job::kMaxSplatWidthNm)) {
      return absl::InvalidArgumentError(
          absl::StrCat("--splat-width ", *o.splat_width, " is out of range: want nm in ",
                       job::kMinSplatWidthNm, "..", job::kMaxSplatWidthNm));
    }
    const bool light = !automatic && *parse_integrator(o.integrator) == job::IntegratorKind::kLight;
    if (!light && o.caustics != "light" && !(automatic && o.caustics.empty())) {
      return absl::InvalidArgumentError(
          "--splat draws light paths as lines: use it with --integrator light or --caustics "
          "light");
    }
  }
  if (o.gather_width.has_value()) {
    // As the job holds it, a float: 0.1 as a double is below the float 0.1f it becomes.
    const float gather_width_nm = static_cast<float>(*o.gather_width);
    if (!(gather_width_nm >= job::kMinSplatWidthNm && gather_width_nm <= job::kMaxSplatWidthNm)) {
      return absl::InvalidArgumentError(
          absl::StrCat("--gather-width ", *o.gather_width, " is out of range: want nm in ",
                       job::kMinSplatWidthNm, "..", job::kMaxSplatWidthNm));
    }
    if (o.splat_width.has_value()) {
      return absl::InvalidArgumentError(
          "--gather and --splat are two filters of the same output: choose one");
    }
    const bool eye =
        !automatic && (*parse_integrator(o.integrator) == job::IntegratorKind::kHero ||
                       *parse_integrator(o.integrator) == job::IntegratorKind::kUniform);
    if (!(eye || automatic) || o.caustics == "light") {
      return absl::InvalidArgumentError(
          "--gather filters eye-traced images: use it with --integrator hero or uniform, without "
          "--caustics light (light paths have --splat)");
    }
  }
  const bool gradient =
      !automatic && *parse_integrator(o.integrator) == job::IntegratorKind::kGradient;
  if (!gradient && (o.delta || o.tau || o.tau_auto || o.alpha || o.gradient_lanes ||
                    !o.poisson.empty() || o.primal_and_gradients)) {
    return absl::InvalidArgumentError(
        "--delta, --tau, --alpha, --gradient-lanes, --poisson and --primal-and-gradients need "
        "--integrator gradient");
  }
  if (o.gradient_lanes &&
      !(*o.gradient_lanes >= 1 && *o.gradient_lanes <= job::kMaxGradientLanes)) {
    return absl::InvalidArgumentError(absl::StrCat("--gradient-lanes ", *o.gradient_lanes,
                                                   " is out of range: want 1..",
                                                   job::kMaxGradientLanes));
  }
  if (o.delta && !(*o.delta > 0.0 && *o.delta <= 0.5)) {
    return absl::InvalidArgumentError(
        absl::StrCat("--delta ", *o.delta, " is out of range: want a fraction in (0, 0.5]"));
  }
  if (o.tau && !(std::isfinite(*o.tau) && *o.tau >= 0.0)) {
    return absl::InvalidArgumentError(
        absl::StrCat("--tau ", *o.tau, " is out of range: want a finite value >= 0"));
  }
  if (o.alpha && !(std::isfinite(*o.alpha) && *o.alpha >= job::kMinPoissonAlpha &&
                   *o.alpha <= job::kMaxPoissonAlpha)) {
    return absl::InvalidArgumentError(absl::StrCat("--alpha ", *o.alpha, " is out of range: want ",
                                                   job::kMinPoissonAlpha, "..",
                                                   job::kMaxPoissonAlpha, " (alpha must be > 0)"));
  }
  if (!o.poisson.empty()) {
    PRISM_RETURN_IF_ERROR(job::parse_poisson_norm(o.poisson).status());
  }
  if (gradient && o.alpha && o.poisson == "weighted") {
    return absl::InvalidArgumentError(
        "--alpha is the screening weight of the l2 and l1 reconstructions; --poisson weighted "
        "weighs each bin by its variances instead");
  }
  if (o.prepass_mode != "samples" && o.prepass_mode != "image") {
    return absl::InvalidArgumentError(
        absl::StrCat("--prepass-mode '", o.prepass_mode, "': want samples or image"));
  }
  if (o.target_error_scope != "pixel" && o.target_error_scope != "image") {
    return absl::InvalidArgumentError(
        absl::StrCat("--target-error-scope '", o.target_error_scope, "': want pixel or image"));
  }
  if (!o.target_error.has_value() && (o.max_spp.has_value() || o.target_error_scope != "pixel")) {
    return absl::InvalidArgumentError("--max-spp and --target-error-scope go with --target-error");
  }
  PRISM_RETURN_IF_ERROR(check_range("--max-spp", o.max_spp, 2, std::int64_t(job::kMaxJobSpp)));
  if (o.target_error.has_value() && o.spp.has_value() && o.max_spp.has_value() &&
      *o.max_spp < *o.spp) {
    return absl::InvalidArgumentError(absl::StrCat("--max-spp ", *o.max_spp, " is below --spp ",
                                                   *o.spp, " (the first round's samples)"));
  }
  const bool prepass_options = has_prepass_options(o);
  if (o.prepass == false && prepass_options) {
    return absl::InvalidArgumentError("--prepass-* options are given with --no-prepass");
  }
  PRISM_RETURN_IF_ERROR(
      check_range("--prepass-passes", o.prepass_passes, 1, job::PrepassParameters::kMaxPasses));
  PRISM_RETURN_IF_ERROR(
      check_range("--prepass-spp", o.prepass_spp, 1, std::int64_t(job::kMaxJobSpp)));
  {
    // The float options through the coordinator's own rules (names mapped back to the flags).
    job::PrepassParameters p;
    if (o.prepass_epsilon) p.epsilon = *o.prepass_epsilon;
    if (o.prepass_fallback) p.fallback = *o.prepass_fallback;
    if (o.prepass_sigma_s) p.sigma_s = *o.prepass_sigma_s;
    if (o.prepass_sigma_r) p.sigma_r = *o.prepass_sigma_r;
    absl::Status valid = p.validate();
    if (!valid.ok()) {
      return absl::InvalidArgumentError(absl::StrCat("--prepass-*: ", valid.message()));
    }
    // The wire keeps 0 for "default": a value that rounds to 0 in float would be lost.
    for (const auto& [flag, value] : {std::pair{"--prepass-epsilon", o.prepass_epsilon},
                                      std::pair{"--prepass-fallback", o.prepass_fallback},
                                      std::pair{"--prepass-sigma-s", o.prepass_sigma_s},
                                      std::pair{"--prepass-sigma-r", o.prepass_sigma_r}}) {
      if (value && static_cast<float>(*value) == 0.0f && *value != 0.0) {
        return absl::InvalidArgumentError(absl::StrCat(flag, " ", *value, " is too small"));
      }
    }
  }
  if (!std::isfinite(o.exposure) || std::fabs(o.exposure) > job::kMaxJobExposureStops) {
    return absl::InvalidArgumentError(
        absl::StrCat("--exposure ", o.exposure, " is out of range: want stops in -",
                     job::kMaxJobExposureStops, "..", job::kMaxJobExposureStops));
  }
  if (o.spool != "auto" && o.spool != "always" && o.spool != "never") {
    return absl::InvalidArgumentError(
        absl::StrCat("--spool '", o.spool, "': want auto, always or never"));
  }
  if (!o.max_memory.empty()) {
    absl::StatusOr<std::uint64_t> bytes = coordinator::parse_bytes(o.max_memory);
    if (!bytes.ok())
      return absl::InvalidArgumentError(absl::StrCat("--max-memory ", bytes.status().message()));
  }
  if (!o.exr_compression.empty() && !image::parse_exr_compression(o.exr_compression)) {
    return absl::InvalidArgumentError(absl::StrCat("--exr-compression '", o.exr_compression,
                                                   "': want none, rle, zips, zip or piz"));
  }
  // The names alone (the film's filename is not needed to check -o and --json).
  return coordinator::output_paths(o.output, o.json, "render.exr").status();
}

absl::StatusOr<std::optional<double>> choose_tau(const RenderCommandOptions& o,
                                                 worker::EmbreeDevice& device,
                                                 const scene::SceneDescription& description,
                                                 const spectral::SpectrumLibrary& library,
                                                 v1::JobSpec& spec,
                                                 std::shared_ptr<const worker::Geometry> geometry) {
  PRISM_ASSIGN_OR_RETURN(job::IntegratorKind integrator, parse_integrator(o.integrator));
  if (integrator != job::IntegratorKind::kGradient || o.tau.has_value()) return std::nullopt;
  if (!device.valid()) {
    return absl::InternalError(
        absl::StrCat("could not create the Embree device: ", device.take_error().message()));
  }
  spec.mutable_gradient()->set_tau(0.0f);
  spec.mutable_gradient()->clear_tau_pilot();
  PRISM_ASSIGN_OR_RETURN(job::JobParameters job, job::job_parameters(spec, description));
  PRISM_ASSIGN_OR_RETURN(std::unique_ptr<worker::RenderScene> scene,
                         worker::RenderScene::build(device, description, library, job.render,
                                                    job.width, job.height, std::move(geometry)));
  worker::GradientPilotOptions options;
  options.threads = o.threads.has_value() ? static_cast<int>(*o.threads) : 0;
  PRISM_ASSIGN_OR_RETURN(worker::GradientPilot pilot,
                         worker::run_gradient_pilot(*scene, job.width, job.height, options));
  auto* g = spec.mutable_gradient();
  g->set_tau(pilot.tau);
  auto* t = g->mutable_tau_pilot();
  t->set_epsilon(static_cast<float>(pilot.epsilon));
  t->set_pixels(static_cast<std::uint32_t>(pilot.pixels));
  t->set_spp(static_cast<std::uint32_t>(pilot.spp));
  t->set_events(pilot.events);
  t->set_shifted_event_fraction(static_cast<float>(pilot.shifted_event_fraction));
  t->set_shifted_square_fraction(static_cast<float>(pilot.shifted_square_fraction));
  // Kept <= epsilon in float as well, as the spec requires.
  t->set_lost_benefit_fraction(
      std::min(static_cast<float>(pilot.lost_benefit_fraction), static_cast<float>(pilot.epsilon)));
  t->set_second_moment_rise(static_cast<float>(pilot.second_moment_rise));
  t->set_offset_vertex_fraction(static_cast<float>(pilot.offset_vertex_fraction));
  return pilot.seconds;
}

absl::StatusOr<TauChoice> choose_or_reuse_tau(const RenderCommandOptions& o,
                                              const std::optional<TauPilotRun>& ran,
                                              worker::EmbreeDevice& device,
                                              const scene::SceneDescription& description,
                                              const spectral::SpectrumLibrary& library,
                                              v1::JobSpec& spec) {
  if (ran.has_value() && spec.integrator() == v1::INTEGRATOR_GRADIENT && !o.tau.has_value()) {
    auto without_tau = [](v1::JobSpec s) {
      s.mutable_gradient()->clear_tau();
      s.mutable_gradient()->clear_tau_pilot();
      s.clear_auto_choice();
      return s;
    };
    if (google::protobuf::util::MessageDifferencer::Equals(without_tau(spec),
                                                           without_tau(ran->spec))) {
      spec.mutable_gradient()->set_tau(ran->spec.gradient().tau());
      *spec.mutable_gradient()->mutable_tau_pilot() = ran->spec.gradient().tau_pilot();
      return TauChoice{ran->seconds, true};
    }
  }
  PRISM_ASSIGN_OR_RETURN(std::optional<double> seconds,
                         choose_tau(o, device, description, library, spec));
  return TauChoice{seconds, false};
}

absl::StatusOr<v1::JobSpec> job_spec_of(const RenderCommandOptions& o,
                                        const scene::SceneDescription& description,
                                        const std::string& bundle_hash,
                                        const std::string& scene_path) {
  PRISM_RETURN_IF_ERROR(validate_render_flags(o));
  if (o.integrator == "auto") {
    return absl::InternalError("--integrator auto must be resolved (resolve_integrator) first");
  }
  v1::JobSpec spec;
  spec.set_bundle_hash(bundle_hash);
  spec.set_scene_path(scene_path);
  const job::IntegratorKind integrator = *parse_integrator(o.integrator);
  spec.set_integrator(job::to_proto(integrator));
  if (integrator == job::IntegratorKind::kGradient) {
    auto* g = spec.mutable_gradient();
    if (o.delta) g->set_delta(static_cast<float>(*o.delta));
    if (o.tau) g->set_tau(static_cast<float>(*o.tau));
    if (o.alpha) g->set_alpha(static_cast<float>(*o.alpha));
    if (o.gradient_lanes) g->set_lanes(static_cast<std::uint32_t>(*o.gradient_lanes));
    g->set_norm(job::to_proto(o.poisson.empty() ? job::PoissonNorm::kL2
                                                : *job::parse_poisson_norm(o.poisson)));
    spec.mutable_outputs()->set_primal_and_gradients(o.primal_and_gradients);
  }
  const bool prepass_options = has_prepass_options(o);
  // Unset, the job's rule decides (job_spec.h); prepass options alone ask for the prepass.
  if (o.prepass.has_value() || prepass_options) {
    auto* p = spec.mutable_prepass();
    p->set_enabled(o.prepass.value_or(true));
    if (o.prepass_passes) p->set_passes(static_cast<std::uint32_t>(*o.prepass_passes));
    if (o.prepass_spp) p->set_spp(static_cast<std::uint32_t>(*o.prepass_spp));
    p->set_image_scaled(o.prepass_mode == "image");
    if (o.prepass_epsilon) p->set_epsilon(static_cast<float>(*o.prepass_epsilon));
    if (o.prepass_fallback) p->set_fallback(static_cast<float>(*o.prepass_fallback));
    if (o.prepass_sigma_s) p->set_sigma_s(static_cast<float>(*o.prepass_sigma_s));
    if (o.prepass_sigma_r) p->set_sigma_r(static_cast<float>(*o.prepass_sigma_r));
  }
  if (o.spp) spec.set_spp(static_cast<std::uint32_t>(*o.spp));
  if (o.resolution) {
    auto [w, h] = *parse_resolution(*o.resolution);
    spec.set_width(static_cast<std::uint32_t>(w));
    spec.set_height(static_cast<std::uint32_t>(h));
  }
  if (o.bins) spec.set_bins(static_cast<std::uint32_t>(*o.bins));
  spec.set_tile_size(static_cast<std::uint32_t>(o.tile));
  spec.set_seed(o.seed);
  if (o.max_depth) spec.set_max_depth(static_cast<std::uint32_t>(*o.max_depth));
  if (o.samples_per_task)
    spec.set_samples_per_task(static_cast<std::uint32_t>(*o.samples_per_task));
  spec.set_spectral_pdf(*parse_spectral_pdf(o.spectral_pdf) == job::SpectralPdfKind::kVisible
                            ? v1::SPECTRAL_PDF_VISIBLE
                            : v1::SPECTRAL_PDF_FLAT);
  spec.set_emitter_pdf(*parse_emitter_pdf(o.emitter_pdf) == job::EmitterPdfKind::kUniform
                           ? v1::EMITTER_PDF_UNIFORM
                           : v1::EMITTER_PDF_EMITTERS);
  spec.set_light_selection(job::to_proto(*parse_light_selection(o.light_selection)));
  spec.set_spectral_light_selection(o.spectral_light_selection);
  spec.set_light_caustics(o.caustics == "light");
  if (o.caustics == "light" && o.caustic_paths.has_value() && *o.caustic_paths < 1.0) {
    spec.set_caustic_paths(static_cast<float>(*o.caustic_paths));
  }
  if (o.splat_width.has_value()) spec.set_splat_width(static_cast<float>(*o.splat_width));
  if (o.gather_width.has_value()) spec.set_gather_width(static_cast<float>(*o.gather_width));
  spec.mutable_outputs()->set_png_exposure(static_cast<float>(o.exposure));
  if (!o.exr_compression.empty()) {
    spec.mutable_outputs()->set_exr_compression(
        job::to_proto(*image::parse_exr_compression(o.exr_compression)));
  }
  spec.set_name(o.scene.filename().string());
  spec.set_allow_unsupported(o.allow_unsupported);
  if (o.target_error.has_value()) {
    spec.set_target_error(static_cast<float>(*o.target_error));
    spec.set_target_error_image(o.target_error_scope == "image");
    if (o.max_spp.has_value()) spec.set_max_spp(static_cast<std::uint32_t>(*o.max_spp));
  }
  // The coordinator applies the same rules; checking here fails before any upload, and
  // to_proto makes every value explicit so the token does not depend on scene defaults.
  PRISM_ASSIGN_OR_RETURN(job::JobParameters parameters, job::job_parameters(spec, description));
  return job::to_proto(parameters);
}

absl::StatusOr<PreparedRender> prepare_render(const RenderCommandOptions& options,
                                              worker::EmbreeDevice& device,
                                              const scene::SceneDescription& description,
                                              const spectral::SpectrumLibrary& library,
                                              const std::string& bundle_hash,
                                              const std::string& scene_relpath) {
  PreparedRender prepared;
  PRISM_ASSIGN_OR_RETURN(
      ResolvedIntegrator resolved,
      resolve_integrator(options, device, description, library, bundle_hash, scene_relpath));
  const RenderCommandOptions& o = resolved.options;
  PRISM_ASSIGN_OR_RETURN(prepared.spec, job_spec_of(o, description, bundle_hash, scene_relpath));
  if (resolved.report.has_value()) {
    set_auto_choice(*resolved.report, prepared.spec);
    prepared.auto_pilot_seconds = resolved.report->seconds;
  }
  PRISM_ASSIGN_OR_RETURN(
      const TauChoice tau,
      choose_or_reuse_tau(o, resolved.tau_pilot, device, description, library, prepared.spec));
  prepared.pilot_seconds = tau.seconds;
  prepared.tau_pilot_in_auto = tau.reused;
  PRISM_ASSIGN_OR_RETURN(prepared.job, job::job_parameters(prepared.spec, description));
  const job::JobParameters& job = prepared.job;
  coordinator::LocalRenderOptions& local = prepared.local;
  local.render = job.render;
  local.width = job.width;
  local.height = job.height;
  local.spp = job.spp;
  local.samples_per_task = job.samples_per_task;
  local.tile_size = job.tile_size;
  local.threads = o.threads.has_value() ? static_cast<int>(*o.threads) : 0;
  if (!o.max_memory.empty()) {
    PRISM_ASSIGN_OR_RETURN(local.max_memory_bytes, coordinator::parse_bytes(o.max_memory));
  }
  local.poisson_alpha = job.gradient.alpha;
  local.poisson_norm = job.gradient.norm;
  local.keep_primal_and_gradients = job.outputs.primal_and_gradients;
  local.prepass = job.prepass;
  local.target_error = job.target_error;
  local.geometry = resolved.geometry;
  return prepared;
}

absl::StatusOr<std::string> run_render(const RenderCommandOptions& options,
                                       worker::EmbreeDevice& device) {
  const Clock::time_point start = Clock::now();
  PRISM_RETURN_IF_ERROR(validate_render_flags(options));
  if (!device.valid()) {
    return absl::InternalError(
        absl::StrCat("could not create the Embree device: ", device.take_error().message()));
  }

  PRISM_ASSIGN_OR_RETURN(spectral::SpectrumLibrary library,
                         spectral::SpectrumLibrary::load_builtin());
  scene::LoadOptions load = scene::with_library_names(library);
  load.allow_unsupported = options.allow_unsupported;
  PRISM_ASSIGN_OR_RETURN(scene::LoadedScene loaded, scene::load_scene(options.scene, load));
  const scene::SceneDescription& description = loaded.description;
  if (options.warnings != nullptr) {
    for (const std::string& w : description.warnings) *options.warnings << w << "\n";
    for (const std::string& w : scene::feature_warnings(description.features, false))
      *options.warnings << w << "\n";
  }

  PRISM_ASSIGN_OR_RETURN(
      coordinator::OutputPaths paths,
      coordinator::output_paths(options.output, options.json, description.film.filename));
  PRISM_RETURN_IF_ERROR(coordinator::check_output_locations(paths));
  PRISM_RETURN_IF_ERROR(
      coordinator::check_outputs_spare_scene(paths, loaded.root, description.files));

  // The same job the farm would run: one set of rules for defaults and ranges.
  PRISM_ASSIGN_OR_RETURN(scene::Bundle bundle,
                         scene::make_bundle(loaded.root, loaded.scene_relpath, description.files));
  PRISM_ASSIGN_OR_RETURN(PreparedRender prepared,
                         prepare_render(options, device, description, library, bundle.content_hash,
                                        loaded.scene_relpath));
  const job::JobParameters& job = prepared.job;
  const std::optional<double> pilot_seconds = prepared.pilot_seconds;
  coordinator::LocalRenderOptions& local = prepared.local;
  const job::RenderOptions& render = local.render;
  if (options.progress != nullptr) {
    std::ostream* out = options.progress;
    local.progress = [out](const coordinator::RenderProgress& p) { draw_progress(*out, p); };
  }

  // Bins too large to hold are streamed into the spectral EXR as the render runs (or, rendered
  // to a target error, go to a spool file) beside the outputs: the same bytes either way.
  const std::uint64_t bin_bytes = std::uint64_t(local.width) * std::uint64_t(local.height) *
                                  std::uint64_t(render.bins) * sizeof(float);
  if (options.spool == "always" ||
      (options.spool == "auto" && local.can_spool() && bin_bytes > kSpoolAboveBytes)) {
    local.spool_dir = paths.spectral_exr.parent_path();
    if (local.spool_dir.empty()) local.spool_dir = ".";
    local.exr_compression = job.outputs.exr_compression;
  }
  PRISM_ASSIGN_OR_RETURN(std::unique_ptr<coordinator::LocalRender> renderer,
                         coordinator::LocalRender::create(device, description, library, local));
  absl::StatusOr<coordinator::LocalRenderResult> result = renderer->render();
  if (options.progress != nullptr) *options.progress << "\n" << std::flush;
  if (!result.ok()) return result.status();
  const double wall_seconds = std::chrono::duration<double>(Clock::now() - start).count();

  coordinator::RenderReport report;
  // The scene as the job names it (its path inside the bundle), as a farm job's outputs do: the
  // same bytes whether the path was typed absolute or relative, here or on the farm.
  report.scene = loaded.scene_relpath;
  report.film_filename = description.film.filename;
  report.width = local.width;
  report.height = local.height;
  report.spp = local.spp;
  report.bins = render.bins;
  report.integrator = job::name(render.integrator);
  report.spectral_pdf = job::name(render.spectral_pdf);
  report.emitter_pdf = job::name(render.emitter_pdf);
  report.light_selection = job::name(render.light_selection);
  report.spectral_light_selection = render.spectral_light_selection;
  report.light_caustics = render.light_caustics;
  report.caustic_paths = render.caustic_paths;
  report.max_depth = render.max_depth;
  report.threads = result->stats.threads;
  report.tile_size = local.tile_size;
  report.seed = render.seed;
  report.wall_seconds = wall_seconds;
  report.render_seconds = result->stats.render_seconds;
  report.samples = result->stats.samples;
  report.rays = result->stats.counters.rays;
  report.counters = worker::counter_list(result->stats.counters);
  report.peak_memory_bytes = coordinator::peak_memory_bytes();
  report.statistics = std::move(result->statistics);
  report.scene_features = coordinator::reported_features(description);
  coordinator::add_job_sections(job, report);
  if (report.gradient.has_value()) {
    coordinator::fill_gradient_counters(report.counters, *report.gradient);
    if (report.gradient->tau_pilot.has_value()) report.gradient->tau_pilot->seconds = pilot_seconds;
  }
  if (result->stats.target_error.has_value()) {
    report.target_error = result->stats.target_error;
    report.spp = result->stats.target_error->max_spp;
  }
  if (report.prepass.has_value()) {
    report.prepass->seconds = result->stats.prepass_seconds;
    report.prepass->final_seconds = result->stats.render_seconds;
    if (result->stats.prepass.has_value()) report.prepass->outcome = *result->stats.prepass;
  }

  // The render's threads compress the outputs too.
  const Clock::time_point output_start = Clock::now();
  const coordinator::OutputOptions outputs{static_cast<float>(options.exposure),
                                           {job.outputs.exr_compression, result->stats.threads}};
  // All or nothing: when one output cannot be written (a full disk), the ones this render wrote
  // go too, so that no report is left describing an EXR that is not there (earlier files of the
  // same names that it did not replace stay).
  std::vector<std::pair<std::filesystem::path, std::optional<std::filesystem::file_time_type>>>
      before;
  for (const std::filesystem::path& path :
       {paths.spectral_exr, paths.rgb_exr, paths.png, paths.json, paths.primal_exr,
        paths.gradient_exr, paths.filtered_exr, paths.filtered_png}) {
    if (path.empty()) continue;
    std::error_code ec;
    const std::filesystem::file_time_type time = std::filesystem::last_write_time(path, ec);
    before.emplace_back(path,
                        ec ? std::nullopt : std::optional<std::filesystem::file_time_type>(time));
  }
  const absl::Status written = [&]() -> absl::Status {
    if (result->primal.has_value() && result->gradient.has_value()) {
      PRISM_RETURN_IF_ERROR(coordinator::write_primal_and_gradient(
          *result->primal, *result->primal_rgb, *result->gradient, renderer->scene().cmf(), report,
          paths, outputs));
    }
    if (report.filtered.has_value()) {
      coordinator::fill_filtered_counters(report.counters, *report.filtered);
      if (result->stats.gather.has_value()) {
        report.filtered->pixels_with_offsets = result->stats.gather->pixels_with_offsets;
        report.filtered->pixels_filtered = result->stats.gather->pixels_filtered;
        report.filtered->pixels_incoherent = result->stats.gather->pixels_incoherent;
      }
    }
    if (result->filtered.has_value() && result->filtered_rgb.has_value()) {
      PRISM_RETURN_IF_ERROR(coordinator::write_filtered(*result->filtered, *result->filtered_rgb,
                                                        report, paths, outputs));
    }
    if (result->stream != nullptr) {
      PRISM_RETURN_IF_ERROR(coordinator::write_outputs(
          [&](const std::filesystem::path& path, const image::ExrMetadata& metadata) {
            return result->stream->write(path, metadata);
          },
          result->rgb, report, paths, outputs));
    } else if (result->spool != nullptr) {
      std::vector<float> band;
      PRISM_RETURN_IF_ERROR(coordinator::write_outputs(render.bins, result->spool->band_rows(),
                                                       result->spool->rows(&band), result->rgb,
                                                       report, paths, outputs));
    } else {
      PRISM_RETURN_IF_ERROR(
          coordinator::write_outputs(result->image, result->rgb, report, paths, outputs));
    }
    return absl::OkStatus();
  }();
  if (!written.ok()) {
    for (const auto& [path, time] : before) {
      std::error_code ec;
      const std::filesystem::file_time_type now_time = std::filesystem::last_write_time(path, ec);
      if (!ec && (!time.has_value() || now_time != *time)) std::filesystem::remove(path, ec);
    }
    return written;
  }
  const double output_seconds = std::chrono::duration<double>(Clock::now() - output_start).count();
  const double seconds = report.render_seconds;
  return absl::StrCat(
      "rendered ", options.scene.string(), ": ", report.width, "x", report.height, ", ", report.spp,
      " spp, ", report.bins, " bins, ", report.integrator,
      !report.light_caustics        ? std::string()
      : report.caustic_paths < 1.0f ? absl::StrCat(" with light-traced caustics (",
                                                   report.caustic_paths, " light paths per pixel)")
                                    : std::string(" with light-traced caustics"),
      report.auto_choice.has_value()
          ? absl::StrCat(" (chosen by auto: ", report.auto_choice->reason, ")")
          : std::string(),
      options.prepass == true && !report.prepass.has_value() && !report.auto_choice.has_value()
          ? absl::StrCat(" (no prepass: ", report.spp,
                         " spp leave it no budget, which takes 8 % of the job's samples and needs "
                         "at least ",
                         job::kMinBudgetedSpp, " spp for its last pass and ", job::kMinDecisionSpp,
                         " for its first; --prepass-spp N sets it instead)")
          : std::string(),
      report.gradient.has_value()
          ? absl::StrCat(
                " (tau ", base::shortest_decimal(report.gradient->tau),
                report.gradient->tau_pilot.has_value() ? " from the pilot" : "",
                report.gradient->samples > 0 && report.gradient->lane_sum > report.gradient->samples
                    ? absl::StrCat(", ", report.gradient->lane_sum / report.gradient->samples,
                                   " hero lanes")
                    : std::string(),
                ")")
          : std::string(),
      report.target_error.has_value()
          ? absl::StrCat(" ", coordinator::target_error_summary(*report.target_error))
          : std::string(),
      ", ", report.threads, " threads in ",
      report.prepass.has_value() ? coordinator::prepass_summary(*report.prepass) + " + "
                                 : std::string(),
      absl::StrFormat("%.2f", seconds), " s (", human(seconds > 0 ? report.samples / seconds : NAN),
      " samples/s, ", human(seconds > 0 ? report.rays / seconds : NAN), " rays/s, peak ",
      report.peak_memory_bytes >> 20, " MiB); wrote ", paths.spectral_exr.string(), ", ",
      paths.rgb_exr.string(), ", ", paths.png.string(), ", ",
      report.filtered.has_value()
          ? absl::StrCat(paths.filtered_exr.string(), ", ", paths.filtered_png.string(), ", ")
          : std::string(),
      report.gradient.has_value() && report.gradient->with_primal_and_gradients
          ? absl::StrCat(paths.primal_exr.string(), ", ", paths.gradient_exr.string(), ", ")
          : std::string(),
      paths.json.string(), absl::StrFormat(" in %.2f s", output_seconds), "\n",
      non_finite_warning(report.counters, report.samples));
}

}  // namespace prism::client
