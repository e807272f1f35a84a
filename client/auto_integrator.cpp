#include "client/auto_integrator.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "coordinator/local_render.h"
#include "services/base/status.h"
#include "services/image/metrics.h"
#include "services/scene/wavelength_dependence.h"

namespace prism::client {
namespace {

using Clock = std::chrono::steady_clock;

constexpr std::uint64_t kPilotSeed = 0x5eed0a;
constexpr double kPilotPixels = 10000;

}  // namespace

absl::StatusOr<ResolvedIntegrator> resolve_integrator(const RenderCommandOptions& options,
                                                      worker::EmbreeDevice& device,
                                                      const scene::SceneDescription& description,
                                                      const spectral::SpectrumLibrary& library,
                                                      const std::string& bundle_hash,
                                                      const std::string& scene_relpath) {
  ResolvedIntegrator out{options, std::nullopt};
  if (options.integrator != "auto") return out;
  const Clock::time_point start = Clock::now();
  RenderCommandOptions& chosen = out.options;
  chosen.prepass = false;
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
    report.choice = "hero";
    report.reason = "the prepass was asked for, which hero runs; no pilot";
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
  std::vector<std::string> candidates = {"hero", "gradient"};
  if (!dependence.dispersive_materials.empty()) candidates.push_back("uniform");
  // Hero with light-traced caustics unless --caustics was given, where the scene allows light
  // tracing (dropped below when it does not: a lens, media, a portal).
  if (options.caustics.empty()) candidates.push_back(kHeroWithLightCaustics);

  // The job's film and spp, as hero would render it. (The gradient's own flags need
  // --integrator gradient, so `options` holds none.)
  RenderCommandOptions probe = options;
  probe.integrator = "hero";
  probe.prepass = false;
  probe.target_error.reset();
  probe.max_spp.reset();
  probe.target_error_scope = "pixel";
  PRISM_ASSIGN_OR_RETURN(v1::JobSpec job,
                         job_spec_of(probe, description, bundle_hash, scene_relpath));
  // A quarter of the film's side, and at most about kPilotPixels pixels (the job's camera).
  const double scale =
      std::min(0.25, std::sqrt(kPilotPixels / (double(job.width()) * double(job.height()))));
  const int width = std::max(1, static_cast<int>(std::lround(job.width() * scale)));
  const int height = std::max(1, static_cast<int>(std::lround(job.height() * scale)));
  const std::uint64_t spp = std::clamp<std::uint64_t>(job.spp() / 16, 4, 16);
  const double pixel_samples = double(width) * double(height) * double(spp);

  // Per candidate: the squared difference of its two halves per pixel and bin (twice the
  // variance of one half, unbiased whatever the method), and the rays it traced. Every half also
  // goes into one estimate of the image, whose square weighs the differences as relMSE weighs
  // errors; the same weights for every candidate keep their ranking fair.
  struct Measured {
    std::vector<float> squared_difference;
    double cost = 0;
  };
  std::vector<Measured> measured;
  std::vector<double> image_sum;
  std::vector<std::string> measured_candidates;
  for (const std::string& method : candidates) {
    RenderCommandOptions o = probe;
    o.integrator = method;
    if (method == kHeroWithLightCaustics) {
      o.integrator = "hero";
      o.caustics = "light";
    }
    o.resolution = absl::StrCat(width, "x", height);
    o.spp = static_cast<std::int64_t>(spp);
    o.seed = kPilotSeed;
    o.max_memory.clear();  // it limits the job; the pilot's small renders fit the machine's
    PRISM_ASSIGN_OR_RETURN(PreparedRender prepared, prepare_render(o, device, description, library,
                                                                   bundle_hash, scene_relpath));
    if (method == kHeroWithLightCaustics) {
      // A scene the light tracer refuses (worker/light_tracer.h) has no such candidate.
      auto tried = coordinator::LocalRender::create(device, description, library, prepared.local);
      if (!tried.ok()) continue;
    }
    measured_candidates.push_back(method);
    Measured m;
    double rays = 0;
    std::optional<image::SpectralImage> first;
    for (int h = 0; h < 2; ++h) {
      coordinator::LocalRenderOptions local = prepared.local;
      local.render.seed = kPilotSeed + static_cast<std::uint64_t>(h);
      PRISM_ASSIGN_OR_RETURN(auto render,
                             coordinator::LocalRender::create(device, description, library, local));
      PRISM_ASSIGN_OR_RETURN(coordinator::LocalRenderResult result, render->render());
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
    m.cost = rays / (2 * pixel_samples);
    measured.push_back(std::move(m));
  }
  candidates = std::move(measured_candidates);
  // The weights: 1/(truth² + 0.01), the truth estimated by every render's mean over the pixel
  // and its 3 x 3 neighbours (54 renders' worth of samples). Without the neighbours, one
  // candidate's outlier would also set the weight of its own pixel.
  const double renders = 2.0 * double(candidates.size());
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
  for (std::size_t c = 0; c < candidates.size(); ++c) {
    double sum = 0;
    for (std::size_t i = 0; i < image_sum.size(); ++i) {
      sum += 0.5 * measured[c].squared_difference[i] * weight[i];
    }
    const double variance = image_sum.empty() ? 0.0 : sum / double(image_sum.size()) * double(spp);
    report.candidates.push_back({candidates[c], variance, measured[c].cost, 0.0});
  }
  const double hero =
      report.candidates[0].rel_mse_per_sample * report.candidates[0].rays_per_sample;
  std::size_t best = 0;
  for (std::size_t i = 0; i < report.candidates.size(); ++i) {
    job::AutoReport::Candidate& c = report.candidates[i];
    const double efficiency = c.rel_mse_per_sample * c.rays_per_sample;
    c.relative_efficiency = hero > 0 ? efficiency / hero : 1.0;
    if (hero > 0 && c.relative_efficiency < report.candidates[best].relative_efficiency) best = i;
  }
  const double gain = 1.0 - report.candidates[best].relative_efficiency;
  if (best != 0 && gain < kAutoMinimumGain) best = 0;
  chosen.integrator = candidates[best];
  report.choice = candidates[best];
  if (candidates[best] == kHeroWithLightCaustics) {
    chosen.integrator = "hero";
    chosen.caustics = "light";
  }
  report.reason = best == 0 ? absl::StrCat("no candidate was predicted at least ",
                                           static_cast<int>(100 * kAutoMinimumGain),
                                           " % better than hero at equal time")
                            : absl::StrFormat("predicted %.2f of hero's relMSE at equal time",
                                              report.candidates[best].relative_efficiency);
  absl::StrAppend(&report.reason, absl::StrFormat(" (pilot: %dx%d, 2 x %d spp per candidate)",
                                                  width, height, static_cast<int>(spp)));
  report.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  out.report = std::move(report);
  return out;
}

void set_auto_choice(const job::AutoReport& report, prism::v1::JobSpec& spec) {
  prism::v1::AutoChoice* a = spec.mutable_auto_choice();
  a->Clear();
  a->set_choice(report.choice);
  a->set_reason(report.reason);
  a->set_seconds(report.seconds);
  for (const job::AutoReport::Candidate& c : report.candidates) {
    prism::v1::AutoChoice::Candidate* out = a->add_candidates();
    out->set_method(c.method);
    out->set_rel_mse_per_sample(c.rel_mse_per_sample);
    out->set_rays_per_sample(c.rays_per_sample);
    out->set_relative_efficiency(c.relative_efficiency);
  }
}

}  // namespace prism::client
