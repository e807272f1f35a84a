// prism-bench-gradient-equal-time: spectral gradient sampling (docs/estimators.md §5) against the
// `uniform` and `hero` integrators at equal time, on the three gradient evaluation scenes
// (scenes/README.md): a smooth dispersive caustic, a diffuse object inside smooth dispersive
// glass, and rough dispersive glass under coloured lamps. The gradient paper reports clear gains
// where hero cannot help (smooth dispersive glass, where only the hero wavelength survives) and
// near parity on rough glass.
//
// For each scene: a reference (`uniform`, independent samples, many spp, two halves; cached in
// --cache-dir, see equal_time.h), then for each method the same increasing sequence of spp, each
// render timed (LocalRender::render(), which for `gradient` includes the per-tile Poisson
// reconstruction) and compared with the reference: relMSE over all pixels and bins
// (image::compare_spectral, as `prism compare`). The reference's own noise adds its floor to
// every relMSE; the table shows relMSE minus that floor too, and the ratios use it. Equal time:
// each row's ratio divides its relMSE by the uniform curve's relMSE interpolated (log-log) at the
// row's time, and a summary per scene compares the three curves at the time of uniform's
// longest run. With --inset, the same figures over that rect too (one rect for every scene
// given, so it is meant for one scene at a time, e.g. the caustic). With --tau auto the pilot
// (worker/gradient/pilot.h) runs once per job, as `prism render` runs it, and its time is added
// to every run of that curve. Nothing is asserted.
//
// Usage: prism-bench-gradient-equal-time [scene.pbrt ...] [--resolution 80x60]
//          [--spp 16,32,64,128,256] [--reference-spp 16384] [--cache-dir DIR] [--threads N]
//          [--bins B (the scene's)] [--max-depth D (the scene's)] [--delta 0.15]
//          [--tau 0 | auto | auto:EPS, comma-separated: one gradient curve each] [--alpha 0.4]
//          [--gradient-lanes 0,1,4 (comma-separated: one curve per τ and C; 0 by the scene)]
//          [--poisson l2|l1|weighted] [--clock wall|cpu] [--inset x,y,w,h]
//          [--csv path (scene,method,spp,seconds,relmse; relMSE of the whole image)]
#include <tbb/info.h>

#include <cstdio>
#include <fstream>
#include <iostream>
#include <map>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "services/base/status.h"
#include "tests/bench/bench_common.h"
#include "tests/bench/equal_time.h"
#include "worker/gradient/pilot.h"

namespace prism::bench {
namespace {

struct Setup {
  int width = 80, height = 60;
  int threads = 1;
  int bins = -1;       // -1: the scene's
  int max_depth = -1;  // -1: the scene's
  double delta = 0.15;
  double alpha = job::kDefaultPoissonAlpha;
  job::PoissonNorm norm = job::PoissonNorm::kL2;
  bool cpu_clock = false;
};

struct Method {
  std::string name;
  job::IntegratorKind integrator;
  double tau = 0;
  std::optional<double> pilot_epsilon;     // --tau auto: the pilot chooses τ
  int lanes = job::kDefaultGradientLanes;  // the base paths' hero lanes
};

// "0.05", "auto" or "auto:0.2".
absl::StatusOr<Method> gradient_method(const std::string& entry, bool only) {
  Method m{"gradient", job::IntegratorKind::kGradient, 0, std::nullopt};
  if (entry == "auto" || entry.starts_with("auto:")) {
    m.pilot_epsilon = worker::GradientPilotOptions{}.epsilon;
    if (entry.size() > 4) {
      double eps = 0;
      if (!absl::SimpleAtod(entry.substr(5), &eps) || !(eps > 0 && eps <= 1)) {
        return absl::InvalidArgumentError(
            absl::StrCat("--tau ", entry, ": want auto:EPS, 0<EPS<=1"));
      }
      m.pilot_epsilon = eps;
    }
    if (!only) m.name = absl::StrFormat("gradient auto:%g", *m.pilot_epsilon);
    return m;
  }
  if (!absl::SimpleAtod(entry, &m.tau) || !std::isfinite(m.tau) || m.tau < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("--tau ", entry, ": want a value >= 0, auto or auto:EPS"));
  }
  if (!only) m.name = absl::StrFormat("gradient tau=%g", m.tau);
  return m;
}

absl::StatusOr<coordinator::LocalRenderOptions> options_for(
    const Setup& setup, const LoadedBenchScene& scene, job::IntegratorKind integrator,
    std::uint64_t spp, std::uint64_t seed, double tau = 0, int lanes = job::kDefaultGradientLanes) {
  coordinator::LocalRenderOptions o;
  o.render.integrator = integrator;
  o.render.bins = setup.bins > 0 ? setup.bins : scene.description.film.bins.value_or(64);
  o.render.max_depth =
      setup.max_depth >= 0 ? setup.max_depth : scene.description.integrator.max_depth;
  o.render.seed = seed;
  PRISM_ASSIGN_OR_RETURN(o.render.gradient_offset_bins,
                         job::gradient_offset_bins(setup.delta, o.render.bins));
  o.render.gradient_tau = float(tau);
  o.render.gradient_lanes = lanes;
  o.poisson_alpha = setup.alpha;
  o.poisson_norm = setup.norm;
  o.width = setup.width;
  o.height = setup.height;
  o.spp = spp;
  o.threads = setup.threads;
  return o;
}

struct Row {
  std::string method;
  std::uint64_t spp = 0;
  double wall = 0;
  double cpu = 0;
  std::vector<double> rel_mse;  // per region
  double seconds(const Setup& setup) const { return setup.cpu_clock ? cpu : wall; }
};

// The whole image or an inset, with the reference's floor over it and each method's curve of
// relMSE − floor.
struct Region {
  std::string name;
  std::optional<image::Crop> crop;
  double floor = 0;
  double mse_floor = 0;
  std::map<std::string, std::vector<ConvergencePoint>> curves;
};

struct TimedPilot {
  worker::GradientPilot pilot;
  double wall = 0, cpu = 0;
};

// The pilot as `prism render --tau auto` runs it: its own scene built with τ = 0 (the build is
// not timed, like the renders' own), the job's seed.
absl::StatusOr<TimedPilot> run_pilot(worker::EmbreeDevice& device, const Setup& setup,
                                     const LoadedBenchScene& scene, double epsilon,
                                     std::uint64_t seed, int lanes) {
  PRISM_ASSIGN_OR_RETURN(
      coordinator::LocalRenderOptions o,
      options_for(setup, scene, job::IntegratorKind::kGradient, 1, seed, 0.0, lanes));
  PRISM_ASSIGN_OR_RETURN(
      auto built, worker::RenderScene::build(device, scene.description, *scene.library, o.render,
                                             setup.width, setup.height));
  worker::GradientPilotOptions p;
  p.epsilon = epsilon;
  p.threads = setup.threads;
  const double cpu_start = process_cpu_seconds();
  const auto wall_start = std::chrono::steady_clock::now();
  PRISM_ASSIGN_OR_RETURN(worker::GradientPilot pilot,
                         worker::run_gradient_pilot(*built, setup.width, setup.height, p));
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  return TimedPilot{pilot, wall, process_cpu_seconds() - cpu_start};
}

int fail(const absl::Status& status) {
  std::cerr << "prism-bench-gradient-equal-time: " << status.message() << "\n";
  return 1;
}

std::string ratio_text(std::optional<double> value, bool extrapolated) {
  if (!value.has_value()) return "n/a";
  return absl::StrFormat("%.3f%s", *value, extrapolated ? "*" : "");
}

int run(int argc, char** argv) {
  auto flags = parse_flags(argc, argv,
                           {"--resolution", "--spp", "--reference-spp", "--cache-dir", "--threads",
                            "--bins", "--max-depth", "--delta", "--tau", "--alpha", "--poisson",
                            "--clock", "--csv", "--inset", "--seed", "--gradient-lanes"});
  if (!flags.ok()) return fail(flags.status());
  auto size = parse_size(flags->get("--resolution", "80x60"));
  auto spp_list = parse_spp_list(flags->get("--spp", "16,32,64,128,256"));
  auto reference_spp = flags->number("--reference-spp", 16384, 2, 1 << 26);
  auto threads = flags->number("--threads", tbb::info::default_concurrency(), 1, 4096);
  auto bins = flags->number("--bins", -1, -1, 256);
  auto max_depth = flags->number("--max-depth", -1, -1, 1000);
  auto delta = flags->number("--delta", 0.15, 0, 0.5);
  auto alpha = flags->number("--alpha", job::kDefaultPoissonAlpha, 1e-9, 1e9);
  auto seed = flags->number("--seed", 1, 1, 1e9);
  for (const absl::Status& s :
       {size.status(), spp_list.status(), reference_spp.status(), threads.status(), bins.status(),
        max_depth.status(), delta.status(), alpha.status(), seed.status()}) {
    if (!s.ok()) return fail(s);
  }
  auto norm = job::parse_poisson_norm(flags->get("--poisson", "l2"));
  if (!norm.ok()) return fail(norm.status());
  const std::string clock = flags->get("--clock", "wall");
  if (clock != "wall" && clock != "cpu") {
    return fail(absl::InvalidArgumentError("--clock: want wall or cpu"));
  }
  Setup setup;
  setup.width = size->first;
  setup.height = size->second;
  setup.threads = int(*threads);
  setup.bins = int(*bins);
  setup.max_depth = int(*max_depth);
  setup.delta = *delta;
  setup.norm = *norm;
  std::vector<Method> methods = {{"uniform", job::IntegratorKind::kUniform, 0, std::nullopt},
                                 {"hero", job::IntegratorKind::kHero, 0, std::nullopt}};
  const std::vector<std::string> taus = absl::StrSplit(flags->get("--tau", "0"), ',');
  const std::vector<std::string> lane_list =
      absl::StrSplit(flags->get("--gradient-lanes", absl::StrCat(job::kDefaultGradientLanes)), ',');
  for (const std::string& lanes : lane_list) {
    int c = 0;
    if (!absl::SimpleAtoi(lanes, &c) || c < 0 || c > job::kMaxGradientLanes) {
      return fail(absl::InvalidArgumentError(absl::StrCat("--gradient-lanes ", lanes,
                                                          ": want values in 0 (by the scene)..",
                                                          job::kMaxGradientLanes)));
    }
    for (const std::string& entry : taus) {
      auto m = gradient_method(entry, taus.size() == 1);
      if (!m.ok()) return fail(m.status());
      m->lanes = c;
      if (lane_list.size() > 1) {
        m->name = absl::StrCat(m->name, " C=", c == 0 ? std::string("scene") : absl::StrCat(c));
      }
      methods.push_back(*m);
    }
  }
  setup.alpha = *alpha;
  setup.cpu_clock = clock == "cpu";
  std::optional<image::Crop> inset;
  if (!flags->get("--inset", "").empty()) {
    auto crop = parse_crop(flags->get("--inset", ""));
    if (!crop.ok()) return fail(crop.status());
    auto rect = image::crop_rect(*crop, setup.width, setup.height);
    if (!rect.ok()) return fail(rect.status());
    inset = *crop;
  }
  const std::filesystem::path cache_dir =
      flags->get("--cache-dir", std::filesystem::temp_directory_path().string());
  std::vector<std::string> scenes = flags->positional;
  if (scenes.empty()) {
    scenes = {source_path("scenes/dispersive-caustic.pbrt").string(),
              source_path("scenes/glass-enclosed.pbrt").string(),
              source_path("scenes/rough-glass-caustics.pbrt").string()};
  }
  std::ofstream csv;
  const std::string csv_path = flags->get("--csv", "");
  if (!csv_path.empty()) {
    csv.open(csv_path);
    if (!csv) return fail(absl::InvalidArgumentError(absl::StrCat("cannot write ", csv_path)));
    csv << "scene,method,spp,seconds,relmse\n";
  }

  worker::EmbreeDevice device;
  std::printf(
      "%dx%d, %d threads, spp %s, reference %.0f spp (uniform, independent samples), "
      "gradient delta %.3g tau %s alpha %.3g %s, %s clock\n",
      setup.width, setup.height, setup.threads, flags->get("--spp", "16,32,64,128,256").c_str(),
      *reference_spp, setup.delta, flags->get("--tau", "0").c_str(), setup.alpha,
      std::string(job::to_string(setup.norm)).c_str(), clock.c_str());
  for (const std::string& path : scenes) {
    auto scene = load_bench_scene(path);
    if (!scene.ok()) return fail(scene.status());
    auto reference_options = options_for(setup, *scene, job::IntegratorKind::kUniform,
                                         std::uint64_t(*reference_spp), 0x5eed);
    if (!reference_options.ok()) return fail(reference_options.status());
    reference_options->render.sampler = job::SamplerKind::kIndependent;
    auto reference =
        cached_reference(device, *scene, *reference_options, cache_dir, "gradient-equal-time");
    if (!reference.ok()) return fail(reference.status());
    std::vector<Region> regions(1);
    regions[0].name = "image";
    if (inset.has_value()) {
      regions.emplace_back();
      regions[1].name = "inset";
      regions[1].crop = inset;
    }
    for (Region& region : regions) {
      auto floor = reference->floor(region.crop);
      if (!floor.ok()) return fail(floor.status());
      region.floor = floor->rel_mse;
      region.mse_floor = floor->mse;
    }

    std::vector<Row> rows;
    for (const Method& method : methods) {
      double tau = method.tau, pilot_wall = 0, pilot_cpu = 0;
      if (method.pilot_epsilon.has_value()) {
        auto pilot = run_pilot(device, setup, *scene, *method.pilot_epsilon, std::uint64_t(*seed),
                               method.lanes);
        if (!pilot.ok()) return fail(pilot.status());
        tau = pilot->pilot.tau;
        pilot_wall = pilot->wall;
        pilot_cpu = pilot->cpu;
        const worker::GradientPilot& p = pilot->pilot;
        std::printf(
            "%s %s: pilot %d pixels x %d spp, %llu events, %.2f s: tau %.4g shifts %.3f of the "
            "events, %.3f of sum c^2; gives up %.3f of the benefit, sum of squares +%.3f, offset "
            "catch-up %.3f\n",
            scene->name.c_str(), method.name.c_str(), p.pixels, p.spp,
            static_cast<unsigned long long>(p.events), setup.cpu_clock ? pilot_cpu : pilot_wall,
            p.tau, p.shifted_event_fraction, p.shifted_square_fraction, p.lost_benefit_fraction,
            p.second_moment_rise, p.offset_vertex_fraction);
      }
      for (std::uint64_t spp : *spp_list) {
        auto options = options_for(setup, *scene, method.integrator, spp, std::uint64_t(*seed), tau,
                                   method.lanes);
        if (!options.ok()) return fail(options.status());
        auto timed = timed_render(device, *scene, *options);
        if (!timed.ok()) return fail(timed.status());
        Row row{
            method.name, spp, timed->wall_seconds + pilot_wall, timed->cpu_seconds + pilot_cpu, {}};
        for (Region& region : regions) {
          auto metrics =
              image::compare_spectral(timed->result.image, reference->image, region.crop);
          if (!metrics.ok()) return fail(metrics.status());
          row.rel_mse.push_back(metrics->rel_mse);
          region.curves[method.name].push_back(
              {spp, row.seconds(setup), metrics->rel_mse - region.floor});
        }
        rows.push_back(row);
        if (csv.is_open()) {
          csv << scene->name << "," << method.name << "," << spp << ","
              << absl::StrFormat("%.6g", row.seconds(setup)) << ","
              << absl::StrFormat("%.6g", row.rel_mse[0]) << "\n";
        }
        std::fprintf(stderr, "%s %s %llu spp: %.2f s, relMSE %.4g\n", scene->name.c_str(),
                     method.name.c_str(), static_cast<unsigned long long>(spp), row.seconds(setup),
                     row.rel_mse[0]);
      }
    }

    std::printf(
        "\n%s: reference %llu spp (%.0f s), its relMSE floor %.4g (MSE floor %.4g; s^2/n "
        "estimate %.4g)",
        scene->name.c_str(), static_cast<unsigned long long>(reference->spp), reference->seconds,
        regions[0].floor, regions[0].mse_floor, reference->variance_of_mean);
    if (inset.has_value()) {
      std::printf("; inset %d,%d %dx%d, its relMSE floor %.4g", inset->x, inset->y, inset->w,
                  inset->h, regions[1].floor);
    }
    std::printf("\n\n| method | spp | wall s | CPU s |");
    for (const Region& region : regions) {
      std::printf(" %s relMSE | - floor | ratio vs uniform at equal time |", region.name.c_str());
    }
    std::printf("\n|---|---|---|---|");
    for (std::size_t r = 0; r < regions.size(); ++r) std::printf("---|---|---|");
    std::printf("\n");
    for (const Row& row : rows) {
      std::printf("| %s | %llu | %.2f | %.2f |", row.method.c_str(),
                  static_cast<unsigned long long>(row.spp), row.wall, row.cpu);
      for (std::size_t r = 0; r < regions.size(); ++r) {
        const double e = row.rel_mse[r] - regions[r].floor;
        bool extrapolated = false;
        auto uniform =
            error_at_time(regions[r].curves["uniform"], row.seconds(setup), &extrapolated);
        std::optional<double> ratio;
        if (uniform.has_value() && e > 0) ratio = e / *uniform;
        std::printf(" %.4g | %.4g | %s |", row.rel_mse[r], e,
                    ratio_text(ratio, extrapolated).c_str());
      }
      std::printf("\n");
    }
    // The three curves at the time of uniform's longest run.
    for (Region& region : regions) {
      double t = 0;
      for (const ConvergencePoint& p : region.curves["uniform"]) t = std::max(t, p.seconds);
      auto u = error_at_time(region.curves["uniform"], t);
      std::printf("\n%s at %.2f s (uniform's longest run), relMSE - floor:", region.name.c_str(),
                  t);
      for (const Method& method : methods) {
        bool extrapolated = false;
        auto e = error_at_time(region.curves[method.name], t, &extrapolated);
        std::optional<double> ratio;
        if (e.has_value() && u.has_value()) ratio = *e / *u;
        std::printf(" %s %s (ratio %s);", method.name.c_str(),
                    e.has_value() ? absl::StrFormat("%.4g", *e).c_str() : "n/a",
                    ratio_text(ratio, extrapolated).c_str());
      }
    }
    std::printf(
        "\n(* extrapolated from the nearest run with error proportional to 1/time; n/a where "
        "relMSE is at or below the reference floor)\n");
    std::fflush(stdout);
  }
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
