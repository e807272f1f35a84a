// The JSON report and the summary lines of a render (outputs.h declares them): what `prism
// render` prints and writes beside the images, and what the farm stores with a job's outputs.
#include <cmath>
#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "coordinator/outputs.h"
#include "services/base/decimal.h"

#ifndef PRISM_VERSION
#error "PRISM_VERSION must be defined by the build"
#endif

namespace prism::coordinator {
namespace {

double per_second(double amount, double seconds) {
  return seconds > 0 ? amount / seconds : std::nan("");
}

// The float's shortest round-trip decimal, as a double the JSON writer prints as that decimal:
// a τ copied from the report to --tau reruns the job (absl::StrCat kept six digits).
double shortest(float value) {
  return std::isfinite(value) ? std::stod(base::shortest_decimal(value)) : std::nan("");
}

}  // namespace

const char* prism_version() {
  return PRISM_VERSION;
}

std::string prepass_summary(const PrepassReport& p) {
  const double total = p.seconds + p.final_seconds;
  const PrepassOutcome& o = p.outcome;
  std::string what;
  if (o.stopped_early) {
    what = absl::StrFormat("stopped after pass 1: predicted gain %.1f %%, default everywhere",
                           100.0 * o.first_pass_gain);
  } else if (o.dropped) {
    what = absl::StrFormat("%d passes, predicted gain %.1f %%: tables dropped, default everywhere",
                           o.passes_run, 100.0 * o.predicted_gain);
  } else {
    what = absl::StrFormat("%d passes, predicted gain %.1f %%, %.1f %% of pixels learned",
                           o.passes_run, 100.0 * o.predicted_gain,
                           100.0 * (1.0 - o.fallback_fraction));
  }
  return absl::StrFormat("%.2f s of prepass (%.1f %% of the time; %s)", p.seconds,
                         total > 0 ? 100.0 * p.seconds / total : 0.0, what);
}

std::string format_report_json(const RenderReport& r, const OutputPaths& paths) {
  nlohmann::ordered_json j;
  j["prism_version"] = prism_version();
  j["scene"] = r.scene;
  if (!r.film_filename.empty()) j["film_filename"] = r.film_filename;
  j["width"] = r.width;
  j["height"] = r.height;
  j["spp"] = r.spp;
  j["bins"] = r.bins;
  j["integrator"] = r.integrator;
  j["spectral_pdf"] = r.spectral_pdf;
  j["emitter_pdf"] = r.emitter_pdf;
  j["light_selection"] = r.light_selection;
  j["spectral_light_selection"] = r.spectral_light_selection;
  j["caustics"] = r.light_caustics ? "light" : "off";
  if (r.light_caustics) j["caustic_paths"] = r.caustic_paths;
  j["max_depth"] = r.max_depth;
  j["threads"] = r.threads;
  j["tile_size"] = r.tile_size;
  j["seed"] = r.seed;
  j["wall_seconds"] = r.wall_seconds;
  j["render_seconds"] = r.render_seconds;
  j["samples"] = r.samples;
  const double timed = static_cast<double>(r.resumed ? r.timed_samples : r.samples);
  j["samples_per_second"] = per_second(timed, r.render_seconds);
  j["samples_per_second_per_core"] =
      r.threads > 0 ? per_second(timed, r.render_seconds) / r.threads : std::nan("");
  j["rays"] = r.rays;
  j["rays_per_second"] = per_second(static_cast<double>(r.rays), r.render_seconds);
  j["peak_memory_bytes"] = r.peak_memory_bytes;
  if (r.farm || r.worker_seconds > 0) j["worker_seconds"] = r.worker_seconds;
  if (r.farm || !r.workers.empty()) {
    nlohmann::ordered_json workers = nlohmann::ordered_json::array();
    for (const RenderReport::WorkerShare& w : r.workers) {
      workers.push_back({{"id", w.id},
                         {"host", w.host},
                         {"threads", w.threads},
                         {"tasks", w.tasks},
                         {"samples", w.samples},
                         {"seconds", w.seconds}});
    }
    j["workers"] = workers;
  }
  if (r.resumed) {
    j["resumed"] = true;
    j["resumed_note"] =
        "the coordinator restarted during the job: counters, rays, seconds, workers and the "
        "rates cover the work since it resumed the job (samples is the whole job's); the "
        "images are whole";
  }
  nlohmann::ordered_json counters = nlohmann::ordered_json::object();
  for (const auto& [name, value] : r.counters) counters[name] = value;
  j["counters"] = counters;
  nlohmann::ordered_json centres = nlohmann::ordered_json::array();
  for (double c : image::bin_centres_nm(r.bins)) centres.push_back(c);
  j["bin_centres_nm"] = centres;
  j["bin_mean"] = r.statistics.mean;
  j["bin_standard_error"] = r.statistics.standard_error;
  j["bin_variance_of_mean"] = r.statistics.variance_of_mean;
  j["pixels_with_error_estimate"] = r.statistics.pixels_with_error;
  if (r.filtered.has_value()) {
    const FilteredReport& f = *r.filtered;
    j["filtered"] = {{"method", f.method},
                     {"width_nm", f.width_nm},
                     {"last_width_nm", f.last_width_nm},
                     {"width_exponent", -f.exponent}};
    if (f.method == "splat") {
      j["filtered"]["splats"] = f.splats;
      j["filtered"]["lines"] = f.lines;
      j["filtered"]["line_fraction"] = f.splats > 0 ? double(f.lines) / double(f.splats) : 0.0;
    } else {
      j["filtered"]["pixels_with_offsets"] = f.pixels_with_offsets;
      j["filtered"]["pixels_filtered"] = f.pixels_filtered;
      j["filtered"]["pixels_incoherent"] = f.pixels_incoherent;
    }
  }
  if (r.gradient.has_value()) {
    const GradientReport& g = *r.gradient;
    auto fraction = [](std::uint64_t part, std::uint64_t whole) {
      return whole > 0 ? double(part) / double(whole) : std::nan("");
    };
    j["gradient"] = {{"offset_bins", g.offset_bins},
                     {"delta", shortest(g.delta)},
                     {"tau", shortest(g.tau)},
                     {"alpha", shortest(g.alpha)},
                     {"poisson", g.norm},
                     // The spectral gradient paper's Table 1: how many base paths were shifted, and
                     // how many shifts were wasted because the offset did not pass the threshold.
                     {"shifted_path_fraction", fraction(g.shifted_paths, g.base_paths)},
                     {"wasted_shift_fraction", fraction(g.wasted_shifts, g.shifts)},
                     {"failed_shift_fraction", fraction(g.failed_shifts, g.shifts)},
                     {"base_paths", g.base_paths},
                     {"shifted_paths", g.shifted_paths},
                     {"shifts", g.shifts},
                     {"failed_shifts", g.failed_shifts},
                     {"wasted_shifts", g.wasted_shifts}};
    j["gradient"]["tau_source"] = g.tau_pilot.has_value() ? "pilot" : "given";
    // The base paths' hero lanes C as traced (the job's --gradient-lanes, or the scene's choice),
    // and what was asked (0: by the scene).
    j["gradient"]["lanes"] =
        g.samples > 0
            ? nlohmann::ordered_json(shortest(float(double(g.lane_sum) / double(g.samples))))
            : nlohmann::ordered_json();
    j["gradient"]["lanes_requested"] = g.lanes_requested;
    if (g.tau_pilot.has_value()) {
      const job::TauPilotReport& t = *g.tau_pilot;
      nlohmann::ordered_json pilot = {
          {"epsilon", shortest(t.epsilon)},
          {"pixels", t.pixels},
          {"spp", t.spp},
          {"events", t.events},
          {"shifted_event_fraction", shortest(t.shifted_event_fraction)},
          {"shifted_square_fraction", shortest(t.shifted_square_fraction)},
          {"lost_benefit_fraction", shortest(t.lost_benefit_fraction)},
          {"predicted_offset_work_fraction", shortest(t.offset_vertex_fraction)},
          {"predicted_second_moment_rise", shortest(t.second_moment_rise)}};
      if (t.seconds.has_value()) pilot["seconds"] = *t.seconds;
      j["gradient"]["tau_pilot"] = pilot;
    }
  }
  if (r.prepass.has_value()) {
    const PrepassReport& p = *r.prepass;
    j["prepass"] = {
        {"passes", p.passes},
        {"pass_spp", p.pass_spp},
        {"pass_resolution", p.pass_resolution},
        {"mode", p.image_scaled ? "image" : "samples"},
        {"epsilon", shortest(p.epsilon)},
        {"fallback", shortest(p.fallback)},
        {"sigma_s", shortest(p.sigma_s)},
        {"sigma_r", shortest(p.sigma_r)},
        {"passes_run", p.outcome.passes_run},
        {"stopped_early", p.outcome.stopped_early},
        {"tables_dropped", p.outcome.dropped},
        {"prepass_seconds", p.seconds},
        {"reconstruction_seconds", p.outcome.reconstruction_seconds},
        {"final_pass_seconds", p.final_seconds},
        {"time_share",
         p.seconds + p.final_seconds > 0 ? p.seconds / (p.seconds + p.final_seconds) : 0.0},
        {"first_pass_predicted_gain", p.outcome.first_pass_gain},
        {"predicted_gain", p.outcome.predicted_gain},
        {"fallback_pixel_fraction", p.outcome.fallback_fraction}};
    nlohmann::ordered_json alphas = nlohmann::ordered_json::array();
    for (int a = 0; a < kAlphaChoices; ++a) {
      alphas.push_back({{"alpha", shortest(float(p.outcome.alpha_values[a]))},
                        {"pixels", p.outcome.alpha_histogram[a]}});
    }
    j["prepass"]["alpha_histogram"] = alphas;
    j["prepass"]["learned_shapes"] = {{"second_moment", p.outcome.shape_histogram[0]},
                                      {"within_lane", p.outcome.shape_histogram[1]}};
  }
  // Where the image is not pbrt-v4's: every substitution (--allow-unsupported), approximation
  // and ignored setting, so a reference says what it is a reference of.
  nlohmann::ordered_json features = {{"substituted", nlohmann::ordered_json::array()},
                                     {"approximated", nlohmann::ordered_json::array()},
                                     {"ignored", nlohmann::ordered_json::array()}};
  for (const SceneFeatureNote& f : r.scene_features) {
    nlohmann::ordered_json entry = {
        {"feature", f.feature}, {"where", f.where}, {"uses", f.uses}, {"note", f.note}};
    if (f.status == "refused") {
      entry["substitution"] = f.substitution;
      features["substituted"].push_back(entry);
    } else if (f.status == "approximated" || f.status == "ignored") {
      features[f.status].push_back(entry);
    }
  }
  j["scene_features"] = features;
  if (r.auto_choice.has_value()) {
    const job::AutoReport& a = *r.auto_choice;
    nlohmann::ordered_json candidates = nlohmann::ordered_json::array();
    for (const job::AutoReport::Candidate& c : a.candidates) {
      candidates.push_back({{"method", c.method},
                            {"rel_mse_per_sample", c.rel_mse_per_sample},
                            {"rays_per_sample", c.rays_per_sample},
                            {"relative_efficiency", c.relative_efficiency},
                            {"ray_cost", c.ray_cost}});
      if (c.caustic_paths > 0) candidates.back()["caustic_paths"] = c.caustic_paths;
    }
    j["auto"] = {{"choice", a.choice},
                 {"reason", a.reason},
                 {"pilot_seconds", a.seconds},
                 {"candidates", candidates}};
  }
  if (r.target_error.has_value()) {
    const TargetErrorOutcome& t = *r.target_error;
    // The target travels as a float (5 % is 0.0500000007): its shortest decimal.
    const double target =
        double(float(t.target)) == t.target ? shortest(float(t.target)) : t.target;
    j["target_error"] = {{"target", target},
                         {"scope", t.image_scope ? "image" : "pixel"},
                         {"met", t.met},
                         {"rounds", t.rounds},
                         {"rounds_planned", t.rounds_planned},
                         {"reached",
                          {{"pixel_max", t.pixel_max},
                           {"pixel_mean", t.pixel_mean},
                           {"pixel_p99", t.pixel_p99},
                           {"image", t.image_error}}},
                         {"spp", {{"min", t.min_spp}, {"mean", t.mean_spp}, {"max", t.max_spp}}}};
  }
  nlohmann::ordered_json outputs = {{"spectral_exr", paths.spectral_exr.string()},
                                    {"rgb_exr", paths.rgb_exr.string()},
                                    {"png", paths.png.string()},
                                    {"json", paths.json.string()}};
  if (r.gradient.has_value() && r.gradient->with_primal_and_gradients) {
    outputs["primal_exr"] = paths.primal_exr.string();
    outputs["gradient_exr"] = paths.gradient_exr.string();
  }
  if (r.filtered.has_value()) {
    outputs["filtered_exr"] = paths.filtered_exr.string();
    outputs["filtered_png"] = paths.filtered_png.string();
  }
  j["outputs"] = outputs;
  return j.dump(2) + "\n";
}

void fill_filtered_counters(const std::vector<std::pair<std::string, std::uint64_t>>& counters,
                            FilteredReport& report) {
  for (const auto& [name, value] : counters) {
    if (name == "light_splats") report.splats = value;
    if (name == "splat_lines") report.lines = value;
  }
}

void fill_gradient_counters(const std::vector<std::pair<std::string, std::uint64_t>>& counters,
                            GradientReport& report) {
  for (const auto& [name, value] : counters) {
    if (name == "camera_rays") report.base_paths = value;
    if (name == "gradient_shifted_paths") report.shifted_paths = value;
    if (name == "gradient_shifts") report.shifts = value;
    if (name == "gradient_shifts_failed") report.failed_shifts = value;
    if (name == "gradient_shifts_wasted") report.wasted_shifts = value;
    if (name == "gradient_samples") report.samples = value;
    if (name == "gradient_lanes") report.lane_sum = value;
  }
}

std::string target_error_summary(const TargetErrorOutcome& t) {
  auto percent = [](double v) { return absl::StrFormat("%.3g %%", 100 * v); };
  return absl::StrCat("to ", percent(t.target),
                      t.image_scope ? " of the image's mean: " : " per pixel: ",
                      t.met ? "met" : "not met (max spp reached)", " in ", t.rounds, " of ",
                      t.rounds_planned, " rounds (image ", percent(t.image_error), "; pixels max ",
                      percent(t.pixel_max), ", p99 ", percent(t.pixel_p99), ", mean ",
                      percent(t.pixel_mean), "), ", t.min_spp, "..", t.max_spp, " spp");
}

}  // namespace prism::coordinator
