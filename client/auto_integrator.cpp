#include "client/auto_integrator.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "coordinator/local_render.h"
#include "services/base/status.h"
#include "services/image/metrics.h"
#include "services/job/job_spec.h"
#include "services/scene/wavelength_dependence.h"
#include "worker/gradient/integrator.h"
#include "worker/light_tracer.h"

namespace prism::client {
namespace {

using Clock = std::chrono::steady_clock;

constexpr std::uint64_t kPilotSeed = 0x5eed0a;
constexpr double kPilotPixels = 10000;

// The relative cost of one ray of each candidate (see the header); hero+caustics is hero's.
double ray_cost(const std::string& method) {
  if (method == "uniform") return kUniformRayCost;
  if (method == "gradient") return kGradientRayCost;
  return kHeroRayCost;
}

// Whether the job these options make runs a prepass (its budget may leave none: job_spec.h).
absl::StatusOr<bool> prepass_runs(const RenderCommandOptions& options,
                                  const scene::SceneDescription& description,
                                  const std::string& bundle_hash,
                                  const std::string& scene_relpath) {
  PRISM_ASSIGN_OR_RETURN(const v1::JobSpec spec,
                         job_spec_of(options, description, bundle_hash, scene_relpath));
  PRISM_ASSIGN_OR_RETURN(const job::JobParameters parameters,
                         job::job_parameters(spec, description));
  return parameters.prepass.has_value();
}

}  // namespace

std::optional<double> clean_caustic_share(const CausticSplit& split, double caustic_variance,
                                          double hero_rays) {
  if (!(split.light_variance > 0) || !(split.light_rays > 0) || !(caustic_variance > 0) ||
      !(hero_rays > 0)) {
    return std::nullopt;
  }
  const double most = kCleanCausticRays * hero_rays / split.light_rays;
  if (!(most >= double(job::kMinCausticPaths))) return std::nullopt;
  const double s = std::min(1.0, std::exp2(std::floor(std::log2(most))));
  if (split.light_variance / s > caustic_variance / kCleanCausticGain) return std::nullopt;
  return s;
}

double CausticSplit::best_share() const {
  // (eye + light/s)(eye_rays + s·light_rays) is least at s = sqrt(light·eye_rays /
  // (eye·light_rays)), snapped to a power of two in [kMinCausticPaths, 1].
  if (!(light_variance > 0) || !(light_rays > 0)) return job::kMinCausticPaths;
  if (!(eye_variance > 0)) return 1.0;
  const double s = std::sqrt(light_variance * eye_rays / (eye_variance * light_rays));
  const double snapped = std::exp2(std::round(std::log2(s)));
  return std::clamp(snapped, double(job::kMinCausticPaths), 1.0);
}

absl::StatusOr<ResolvedIntegrator> resolve_integrator(const RenderCommandOptions& options,
                                                      worker::EmbreeDevice& device,
                                                      const scene::SceneDescription& description,
                                                      const spectral::SpectrumLibrary& library,
                                                      const std::string& bundle_hash,
                                                      const std::string& scene_relpath) {
  ResolvedIntegrator out{options, std::nullopt, std::nullopt, nullptr};
  if (options.integrator != "auto") return out;
  const Clock::time_point start = Clock::now();
  RenderCommandOptions& chosen = out.options;
  chosen.prepass = false;
  // --caustic-paths under auto is the share of light paths should it choose light-traced
  // caustics (set below where it does); elsewhere it does not apply.
  if (options.caustics != "light") chosen.caustic_paths.reset();
  job::AutoReport report;
  if (options.caustics == "light" ||
      (options.splat_width.has_value() && options.caustics.empty())) {
    // Light tracing takes the caustic paths; of the eye tracers, hero carries the rest. (--splat
    // draws light paths, so under auto it asks for them.)
    chosen.integrator = "hero";
    chosen.caustics = "light";
    report.choice = kHeroWithLightCaustics;
    report.reason = options.caustics == "light"
                        ? "--caustics light renders caustics by light tracing and the rest by "
                          "hero; no pilot"
                        : "--splat draws light paths, so caustics by light tracing and the rest "
                          "by hero; no pilot";
    out.report = std::move(report);
    return out;
  }
  if (options.gather_width.has_value()) {
    // Gathering filters an eye-traced image; hero is the eye tracer auto keeps by default.
    chosen.integrator = "hero";
    report.choice = "hero";
    report.reason = "--gather filters hero's image; no pilot";
    out.report = std::move(report);
    return out;
  }
  if (options.prepass == true || has_prepass_options(options)) {
    // Only hero runs the prepass.
    chosen.prepass = options.prepass;
    chosen.integrator = "hero";
    PRISM_ASSIGN_OR_RETURN(const bool runs,
                           prepass_runs(chosen, description, bundle_hash, scene_relpath));
    report.choice = runs ? kHeroWithPrepass : "hero";
    report.reason = runs ? "the prepass was asked for, which hero runs; no pilot"
                         : "the prepass was asked for, which hero runs, but the job's spp leaves "
                           "it no budget; no pilot";
    out.report = std::move(report);
    return out;
  }
  const scene::WavelengthDependence dependence = scene::analyze_wavelength_dependence(description);
  if (!dependence.needs_spectral_transport()) {
    chosen.integrator = "hero";
    report.choice = "hero";
    report.reason =
        "nothing in the scene depends on wavelength (no dispersion, one emitter spectrum, no "
        "medium): hero, whose four lanes all stay live, without a pilot";
    out.report = std::move(report);
    return out;
  }
  // The job's film and spp, as hero would render it. (The gradient's own flags need
  // --integrator gradient, so `options` holds none.)
  RenderCommandOptions probe = options;
  // --caustic-paths is the job's share of light paths should auto choose light-traced caustics;
  // the pilot renders set their own.
  probe.caustic_paths.reset();
  probe.integrator = "hero";
  probe.prepass = false;
  probe.target_error.reset();
  probe.max_spp.reset();
  probe.target_error_scope = "pixel";
  // The scene as a job builds it (at 4 x 4 and 1 spp), for what the description alone does not
  // say. Light tracing is tried unless --caustics was given; a scene that does not allow it (an
  // orthographic or spherical camera, a portal) is built without.
  auto build = [&](const std::string& caustics_mode)
      -> absl::StatusOr<std::unique_ptr<coordinator::LocalRender>> {
    RenderCommandOptions o = probe;
    o.caustics = caustics_mode;
    o.resolution = "4x4";
    o.spp = 1;
    o.max_memory.clear();
    PRISM_ASSIGN_OR_RETURN(PreparedRender prepared, prepare_render(o, device, description, library,
                                                                   bundle_hash, scene_relpath));
    return coordinator::LocalRender::create(device, description, library, prepared.local);
  };
  // Hero with light-traced caustics where --caustics was not given, the scene allows light
  // tracing and has a shape that can scatter as a delta (else it has no caustic path). Its eye
  // paths are rendered alone, and the probe's light-only renders give its light paths' part, so
  // the share of light paths it is judged (and run) at.
  bool caustics = false;
  std::unique_ptr<coordinator::LocalRender> built;
  if (options.caustics.empty()) {
    auto tried = build("light");
    if (tried.ok()) {
      built = std::move(*tried);
      caustics = !worker::caustic_targets(built->scene()).empty();
    }
  }
  if (built == nullptr) {
    PRISM_ASSIGN_OR_RETURN(built, build(options.caustics));
  }
  // A job to a target error runs no light paths (job_spec.cpp): not a candidate then.
  std::string caustics_note;
  if (caustics && options.target_error.has_value()) {
    caustics = false;
    caustics_note =
        "; hero with light-traced caustics is not a candidate: light paths do not combine with "
        "--target-error yet";
  }
  // Gradient with its lanes chosen by the scene is hero's render, and dearer, unless some
  // material refracts smooth-dispersively (worker/gradient/integrator.h); uniform is a
  // candidate where a dielectric disperses.
  const bool gradient = worker::has_smooth_dispersive_refraction(built->scene());
  // The geometry depends on the shapes alone: every pilot render and the job reuse this one.
  out.geometry = built->shared_geometry();
  built.reset();
  std::vector<std::string> candidates = {"hero"};
  if (gradient) candidates.push_back("gradient");
  if (!dependence.dispersive_materials.empty()) candidates.push_back("uniform");
  if (caustics) candidates.push_back(kHeroWithLightCaustics);
  // Hero with several emitter spectra runs the prepass, whose first pass decides whether
  // per-pixel tables pay (coordinator/prepass_run.h) and otherwise stops. Whether it does (not
  // with --no-prepass or a target error, nor where the job's spp leaves it no budget), asked
  // once: by clean caustics below, and by finish.
  std::optional<bool> hero_prepass;
  auto hero_runs_prepass = [&]() -> absl::StatusOr<bool> {
    if (!hero_prepass.has_value()) {
      hero_prepass = false;
      if (dependence.emitter_spectra.size() > 1 && options.prepass != false &&
          !options.target_error.has_value()) {
        RenderCommandOptions with_prepass = chosen;
        with_prepass.integrator = "hero";
        with_prepass.prepass = true;
        PRISM_ASSIGN_OR_RETURN(hero_prepass,
                               prepass_runs(with_prepass, description, bundle_hash, scene_relpath));
      }
    }
    return *hero_prepass;
  };
  auto finish = [&]() -> absl::StatusOr<ResolvedIntegrator> {
    if (report.choice == "hero") {
      PRISM_ASSIGN_OR_RETURN(const bool runs, hero_runs_prepass());
      if (runs) {
        chosen.prepass = true;
        report.choice = kHeroWithPrepass;
        absl::StrAppend(&report.reason, "; ", dependence.emitter_spectra.size(),
                        " emitter spectra: the prepass runs, and its first pass decides whether "
                        "per-pixel tables pay");
      }
    }
    absl::StrAppend(&report.reason, caustics_note);
    report.seconds = std::chrono::duration<double>(Clock::now() - start).count();
    out.report = std::move(report);
    return std::move(out);
  };
  if (candidates.size() == 1) {
    chosen.integrator = "hero";
    report.choice = "hero";
    report.reason = caustics_note.empty()
                        ? "hero is the only candidate (no dispersive dielectric for uniform, no "
                          "smooth dispersive refraction for gradient to shift, no caustic path to "
                          "light trace); no pilot"
                        : "hero is the only candidate (no dispersive dielectric for uniform, no "
                          "smooth dispersive refraction for gradient to shift); no pilot";
    return finish();
  }
  // With caustics: the probe of the caustic paths, whose three renders of light paths alone cost
  // about what one candidate's two renders do (torus-glass: 0.08 s against 0.3 s for four).
  const std::size_t renders_per_half = candidates.size() + (caustics ? 1 : 0);
  PRISM_ASSIGN_OR_RETURN(v1::JobSpec job,
                         job_spec_of(probe, description, bundle_hash, scene_relpath));
  // An eighth of the job's spp (kPilotMinSpp..kPilotMaxSpp) on the job's camera at a quarter of
  // its side at most, fewer pixels where the candidates' 2 x spp samples per pixel would cost
  // more than kPilotShare of the job's samples, and at most about kPilotPixels pixels.
  const std::uint64_t spp =
      std::clamp<std::uint64_t>(job.spp() / kPilotSppDivisor, kPilotMinSpp, kPilotMaxSpp);
  const double pixels = double(job.width()) * double(job.height());
  const double affordable =
      kPilotShare * double(job.spp()) / (2.0 * double(renders_per_half) * double(spp));
  const double scale = std::min({0.25, std::sqrt(affordable), std::sqrt(kPilotPixels / pixels)});
  const int width = std::max(4, static_cast<int>(std::lround(job.width() * scale)));
  const int height = std::max(4, static_cast<int>(std::lround(job.height() * scale)));
  // Its 4x4 floor can cost more than a tiny job itself (a 1x1 film, or 16x12 at 1 spp): past a
  // quarter of the job's samples no pilot pays for itself, and hero, the default, renders.
  const double pilot_samples =
      2.0 * double(renders_per_half) * double(spp) * double(width) * double(height);
  const double job_samples = double(job.spp()) * pixels;
  if (pilot_samples > kTinyJobPilotShare * job_samples) {
    chosen.integrator = "hero";
    report.choice = "hero";
    report.reason = absl::StrFormat(
        "the job (%.0f samples) is too small for a pilot, which would take %.0f: hero, without "
        "one",
        job_samples, pilot_samples);
    return finish();
  }
  // The pilot's seeds follow the job's: another seed of the job is another pilot too.
  const std::uint64_t pilot_seed = kPilotSeed ^ (job.seed() * 0x9e3779b97f4a7c15ULL);

  // Per candidate: the squared difference of its two halves per pixel and bin (twice the
  // variance of one half, unbiased whatever the method), and the rays it traced. Every half also
  // goes into one estimate of the image, whose square weighs the differences as relMSE weighs
  // errors; the same weights for every candidate keep their ranking fair. Every candidate renders
  // with the same two seeds, so their errors per pixel are compared on the same sample numbers.
  struct Measured {
    std::vector<float> squared_difference;
    double rays_per_sample = 0;
  };
  std::vector<Measured> measured;
  std::vector<double> image_sum;
  std::vector<std::string> runs = candidates;
  // Every pilot render: `o` at the pilot's size and spp, one seed, and for hero with --caustics
  // light which of its paths it renders (all, its eye paths alone, or the probe's light paths).
  using Probe = job::RenderOptions::CausticProbe;
  auto prepare_pilot = [&](RenderCommandOptions o) -> absl::StatusOr<PreparedRender> {
    o.resolution = absl::StrCat(width, "x", height);
    o.spp = static_cast<std::int64_t>(spp);
    o.seed = pilot_seed;
    o.max_memory.clear();  // it limits the job; the pilot's small renders fit the machine's
    return prepare_render(o, device, description, library, bundle_hash, scene_relpath);
  };
  auto render_pilot = [&](const PreparedRender& prepared, std::uint64_t seed,
                          Probe kind) -> absl::StatusOr<coordinator::LocalRenderResult> {
    coordinator::LocalRenderOptions local = prepared.local;
    local.render.seed = seed;
    local.render.caustic_probe = kind;
    local.geometry = out.geometry;
    PRISM_ASSIGN_OR_RETURN(auto render,
                           coordinator::LocalRender::create(device, description, library, local));
    return render->render();
  };
  // Gradient's τ pilot on the job as gradient would render it (`chosen` with gradient), so its
  // pilot renders trace at the job's τ and, where it is chosen, the job reuses it.
  if (gradient) {
    RenderCommandOptions g = chosen;
    g.integrator = "gradient";
    g.caustic_paths.reset();
    PRISM_ASSIGN_OR_RETURN(v1::JobSpec spec,
                           job_spec_of(g, description, bundle_hash, scene_relpath));
    PRISM_ASSIGN_OR_RETURN(const std::optional<double> seconds,
                           choose_tau(g, device, description, library, spec, out.geometry));
    out.tau_pilot = TauPilotRun{std::move(spec), seconds.value_or(0.0)};
  }
  for (const std::string& method : runs) {
    RenderCommandOptions o = probe;
    o.integrator = method;
    if (method == "gradient") o.tau = out.tau_pilot->spec.gradient().tau();
    // hero+caustics: its eye paths alone (the probe below renders its light paths).
    Probe kind = Probe::kOff;
    if (method == kHeroWithLightCaustics) {
      o.integrator = "hero";
      o.caustics = "light";
      o.caustic_paths = 1.0;
      kind = Probe::kEyeOnly;
    }
    PRISM_ASSIGN_OR_RETURN(PreparedRender prepared, prepare_pilot(std::move(o)));
    Measured m;
    double rays = 0;
    std::optional<image::SpectralImage> first;
    for (int h = 0; h < 2; ++h) {
      PRISM_ASSIGN_OR_RETURN(
          coordinator::LocalRenderResult result,
          render_pilot(prepared, pilot_seed + static_cast<std::uint64_t>(h), kind));
      rays += double(result.stats.counters.rays);
      const std::span<const float> values = result.image.data();
      if (image_sum.empty()) image_sum.assign(values.size(), 0.0);
      for (std::size_t i = 0; i < values.size(); ++i) {
        if (std::isfinite(values[i])) image_sum[i] += values[i];
      }
      if (h == 0) {
        first = std::move(result.image);
      } else {
        const std::span<const float> a = first->data();
        m.squared_difference.resize(values.size());
        for (std::size_t i = 0; i < values.size(); ++i) {
          const double d = double(a[i]) - values[i];
          m.squared_difference[i] = std::isfinite(d) ? float(d * d) : 0.0f;
        }
      }
    }
    m.rays_per_sample = rays / (2 * double(width) * double(height) * double(spp));
    measured.push_back(std::move(m));
  }
  // The eye tracers' caustic paths (light → delta chain → the camera's first vertex) are rare
  // and bright where the light is small: 2 x spp samples per pixel mostly miss them, so their
  // measured variance is mostly too low. The probe renders those paths from the lights instead:
  // twice plainly with independent seeds, A and B, whose product estimates their mean squared C²
  // without bias and whose difference their variance per light path (the light part of
  // hero+caustics at one path per pixel and sample), and once with every splat times the value
  // an eye path would carry for it, whose mean is the eye tracers' second moment M of those paths
  // per sample (light_tracer.cpp). M − C² per pixel and bin is the variance the eye tracers'
  // caustic paths add per sample.
  std::vector<float> caustic_variance, light_squared_difference;
  double light_rays_per_sample = 0;
  if (caustics) {
    RenderCommandOptions o = probe;
    o.caustics = "light";
    o.caustic_paths = 1.0;
    PRISM_ASSIGN_OR_RETURN(PreparedRender prepared, prepare_pilot(std::move(o)));
    std::optional<coordinator::LocalRenderResult> light[2];
    for (std::uint64_t h = 0; h < 2; ++h) {
      PRISM_ASSIGN_OR_RETURN(light[h],
                             render_pilot(prepared, pilot_seed + 2 + h, Probe::kLightOnly));
    }
    PRISM_ASSIGN_OR_RETURN(coordinator::LocalRenderResult moments,
                           render_pilot(prepared, pilot_seed + 4, Probe::kEyeMoments));
    const std::span<const float> a = light[0]->image.data(), b = light[1]->image.data(),
                                 m = moments.image.data();
    const std::size_t n = std::min({a.size(), b.size(), m.size()});
    caustic_variance.assign(n, 0.0f);
    light_squared_difference.assign(n, 0.0f);
    for (std::size_t i = 0; i < n; ++i) {
      const double v = double(m[i]) - double(a[i]) * b[i];
      if (std::isfinite(v) && v > 0) caustic_variance[i] = float(v);
      const double d = double(a[i]) - b[i];
      if (std::isfinite(d)) light_squared_difference[i] = float(d * d);
    }
    light_rays_per_sample = double(light[0]->stats.counters.rays + light[1]->stats.counters.rays) /
                            (2 * double(width) * double(height) * double(spp));
    // With hero+caustics's eye-only renders, each plain light render completes one of them to an
    // estimate of the image.
    for (std::uint64_t h = 0; h < 2; ++h) {
      const std::span<const float> values = light[h]->image.data();
      for (std::size_t i = 0; i < values.size() && i < image_sum.size(); ++i) {
        if (std::isfinite(values[i])) image_sum[i] += values[i];
      }
    }
  }
  // The weights: 1/(truth² + 0.01), the truth estimated by every render's mean over the pixel
  // and its 3 x 3 neighbours. Without the neighbours, one candidate's outlier would also set the
  // weight of its own pixel.
  const double renders = 2.0 * double(runs.size());
  std::vector<double> weight(image_sum.size());
  const int bins = static_cast<int>(image_sum.size() / (std::size_t(width) * std::size_t(height)));
  auto at = [&](int x, int y, int b) {
    return (std::size_t(y) * std::size_t(width) + std::size_t(x)) * std::size_t(bins) +
           std::size_t(b);
  };
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      for (int b = 0; b < bins; ++b) {
        double sum = 0;
        int n = 0;
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dx = -1; dx <= 1; ++dx) {
            const int u = x + dx, v = y + dy;
            if (u < 0 || v < 0 || u >= width || v >= height) continue;
            sum += image_sum[at(u, v, b)];
            ++n;
          }
        }
        const double truth = sum / (renders * n);
        weight[at(x, y, b)] = 1.0 / (truth * truth + image::kRelMseEpsilon);
      }
    }
  }
  // A per-pixel-and-bin figure's mean over the image, weighted as relMSE weighs errors; and a
  // relMSE per sample from the squared differences of two renders of spp samples.
  auto weighted_mean = [&](const std::vector<float>& values) {
    double sum = 0;
    for (std::size_t i = 0; i < values.size() && i < weight.size(); ++i) {
      sum += double(values[i]) * weight[i];
    }
    return weight.empty() ? 0.0 : sum / double(weight.size());
  };
  auto variance_per_sample = [&](const std::vector<float>& squared_difference) {
    return 0.5 * weighted_mean(squared_difference) * double(spp);
  };
  // Per candidate: its relMSE per sample, its cost per sample (rays times the cost of one), and
  // their product relative to hero's, its predicted relMSE at equal time relative to hero's.
  std::optional<std::size_t> caustic_run;
  std::vector<job::AutoReport::Candidate> figures;
  for (std::size_t c = 0; c < runs.size(); ++c) {
    const double variance = variance_per_sample(measured[c].squared_difference);
    figures.push_back({runs[c], variance, measured[c].rays_per_sample, 0.0, ray_cost(runs[c])});
    if (runs[c] == kHeroWithLightCaustics) caustic_run = c;
  }
  // Hero with light-traced caustics at the share of light paths its run and the probe say is best
  // (or the one given).
  double caustic_paths = options.caustic_paths.value_or(1.0);
  std::string caustic_note;
  std::optional<CausticSplit> split_used;
  std::optional<double> clean_share;
  if (caustic_run.has_value()) {
    // Its renders measured the eye paths' part; the probe's light-only renders the light paths'.
    const CausticSplit split{.eye_variance = figures[*caustic_run].rel_mse_per_sample,
                             .light_variance = variance_per_sample(light_squared_difference),
                             .eye_rays = figures[*caustic_run].rays_per_sample,
                             .light_rays = light_rays_per_sample};
    if (!options.caustic_paths.has_value()) caustic_paths = split.best_share();
    figures[*caustic_run].rel_mse_per_sample = split.variance(caustic_paths);
    figures[*caustic_run].rays_per_sample = split.rays(caustic_paths);
    figures[*caustic_run].caustic_paths = caustic_paths;
    split_used = split;
    if (!options.caustic_paths.has_value()) {
      clean_share =
          clean_caustic_share(split, weighted_mean(caustic_variance), figures[0].rays_per_sample);
    }
    // The eye tracers' variance per sample as the caustic paths' model says: hero's eye paths
    // without them (the split's eye part) and the probe's variance of them. What the pilot's
    // eye tracers did not see of it is added to each (uniform and gradient miss the same rare
    // paths), where it is kUnseenCausticFactor times hero's measured variance or more: below
    // that it is the heavy tail of caustics the eye samples do find, which the job's own render
    // rarely shows either (auto_integrator.h).
    const double unseen = std::max(
        0.0, split.eye_variance + weighted_mean(caustic_variance) - figures[0].rel_mse_per_sample);
    if (unseen > 0 && unseen >= kUnseenCausticFactor * figures[0].rel_mse_per_sample) {
      absl::StrAppend(&caustic_note,
                      absl::StrFormat("; the eye tracers' caustic paths, modelled from light "
                                      "paths, add %.3g to hero's measured relMSE per sample %.3g",
                                      unseen, figures[0].rel_mse_per_sample));
      for (job::AutoReport::Candidate& f : figures) {
        if (f.method == "hero" || f.method == "uniform" || f.method == "gradient") {
          f.rel_mse_per_sample += unseen;
        }
      }
    }
  }
  for (job::AutoReport::Candidate& f : figures) report.candidates.push_back(std::move(f));
  candidates.clear();
  for (const job::AutoReport::Candidate& c : report.candidates) candidates.push_back(c.method);
  auto efficiency = [](const job::AutoReport::Candidate& c) {
    return c.rel_mse_per_sample * c.rays_per_sample * c.ray_cost;
  };
  const double hero = efficiency(report.candidates[0]);
  std::size_t best = 0;
  for (std::size_t c = 0; c < candidates.size(); ++c) {
    job::AutoReport::Candidate& k = report.candidates[c];
    k.relative_efficiency = hero > 0 ? efficiency(k) / hero : 1.0;
    if (k.relative_efficiency < report.candidates[best].relative_efficiency) best = c;
  }
  // Another candidate replaces hero only when it is predicted kAutoMinimumGain better.
  if (best != 0 && report.candidates[best].relative_efficiency > 1.0 - kAutoMinimumGain) best = 0;
  // Clean caustics (auto_integrator.h): hero's caustic paths by light tracing at the share that
  // renders them kCleanCausticGain times cleaner, where that costs at most kCleanCausticRays.
  // Not where hero would run the prepass (several emitter spectra, see finish): light-traced
  // caustics are not combined with it, and the prepass's gain is on the whole image.
  bool prepass_instead = false;
  if (best == 0) {
    PRISM_ASSIGN_OR_RETURN(prepass_instead, hero_runs_prepass());
  }
  std::string clean_note;
  if (clean_share.has_value() && caustic_run.has_value() && (best == 0 || best == *caustic_run) &&
      !prepass_instead && *clean_share > caustic_paths) {
    const bool was_hero = best == 0;
    best = *caustic_run;
    caustic_paths = *clean_share;
    job::AutoReport::Candidate& k = report.candidates[best];
    k.rel_mse_per_sample = split_used->variance(caustic_paths);
    k.rays_per_sample = split_used->rays(caustic_paths);
    k.caustic_paths = caustic_paths;
    k.relative_efficiency = hero > 0 ? efficiency(k) / hero : 1.0;
    clean_note = absl::StrFormat(
        "; %s light paths render the caustic paths %.3g times cleaner than the eye tracers for "
        "%.2g %% more rays",
        was_hero ? "hero is predicted best, and" : "at this share",
        weighted_mean(caustic_variance) * caustic_paths / split_used->light_variance,
        100.0 * caustic_paths * split_used->light_rays / report.candidates[0].rays_per_sample);
  }
  chosen.integrator = candidates[best];
  report.choice = candidates[best];
  if (candidates[best] == kHeroWithLightCaustics) {
    chosen.integrator = "hero";
    chosen.caustics = "light";
    chosen.caustic_paths = caustic_paths;
  }
  report.reason = best == 0 ? absl::StrCat("no candidate was predicted at least ",
                                           static_cast<int>(100 * kAutoMinimumGain),
                                           " % better than hero at equal time")
                            : absl::StrFormat("%spredicted %.2g of hero's relMSE at equal time",
                                              clean_note.empty() ? "" : "clean caustics: ",
                                              report.candidates[best].relative_efficiency);
  if (candidates[best] == kHeroWithLightCaustics && caustic_paths < 1.0) {
    absl::StrAppend(&report.reason,
                    absl::StrFormat(" with %g light paths per pixel and sample", caustic_paths));
  }
  absl::StrAppend(&report.reason, absl::StrFormat(" (pilot: %dx%d, 2 x %d spp per candidate)",
                                                  width, height, static_cast<int>(spp)));
  absl::StrAppend(&report.reason, clean_note, caustic_note);
  if (!gradient) {
    absl::StrAppend(&report.reason,
                    "; gradient is not a candidate: nothing refracts smooth-dispersively, so it "
                    "would render hero's image");
  }
  return finish();
}

void set_auto_choice(const job::AutoReport& report, prism::v1::JobSpec& spec) {
  *spec.mutable_auto_choice() = job::to_proto(report);
}

}  // namespace prism::client
