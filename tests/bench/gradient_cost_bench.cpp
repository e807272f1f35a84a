// prism-bench-gradient-cost: the cost of a spectral gradient sample next to a `uniform` sample
// (the gradient integrator's base path is exactly the uniform path; the offsets at λ ± δ are
// the overhead; the paper reports shifts as cheaper than new paths) and a `hero` sample (four
// wavelengths on one path: what a gradient sample must compete with). For each scene it renders
// the whole image with the worker's TileRenderer with `uniform`, `hero` and `gradient` (same
// options, same seed, same thread count, in the same run; each the fastest of --repeats renders)
// and prints samples per second, rays per sample and the ratios of the time per sample, plus the
// paper's Table 1 figures: the
// fraction of base paths with a shifted event and the fraction of offsets wasted by the
// threshold τ (and the fraction whose shift failed).
//
// With --tau auto (the default) τ is the one the pilot of `prism render` picks
// (worker/gradient/pilot.h); its time is printed beside the ratios, not added to them.
//
// Usage: prism-bench-gradient-cost [scene.pbrt ...] [--resolution 160x120] [--spp 16]
//        [--threads N] [--bins 64] [--delta 0.15] [--tau auto|T] [--repeats 3]
#include <tbb/info.h>
#include <tbb/task_arena.h>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <utility>

#include "tests/bench/bench_common.h"
#include "worker/embree_device.h"
#include "worker/gradient/pilot.h"
#include "worker/render_scene.h"
#include "worker/tile_renderer.h"

namespace prism::bench {
namespace {

struct Timed {
  double seconds = 0;
  worker::TraceCounters counters;
};

absl::StatusOr<Timed> render(worker::EmbreeDevice& device, const LoadedBenchScene& scene,
                             const job::RenderOptions& options, int width, int height,
                             std::uint64_t spp, int threads) {
  auto built =
      worker::RenderScene::build(device, scene.description, *scene.library, options, width, height);
  if (!built.ok()) return built.status();
  worker::TileRenderer renderer(**built);
  worker::TileStats stats;
  absl::Status status;
  tbb::task_arena arena(threads);
  arena.execute([&] {
    auto result = renderer.render({{0, 0, width, height}, {0, spp}, 0}, &stats);
    if (!result.ok()) status = result.status();
  });
  if (!status.ok()) return status;
  return Timed{stats.seconds, stats.counters};
}

int run(int argc, char** argv) {
  auto flags = parse_flags(
      argc, argv,
      {"--resolution", "--spp", "--threads", "--bins", "--delta", "--tau", "--repeats"});
  if (!flags.ok()) {
    std::cerr << "prism-bench-gradient-cost: " << flags.status().message() << "\n";
    return 2;
  }
  auto size = parse_size(flags->get("--resolution", "160x120"));
  auto spp = flags->number("--spp", 16, 1, 1 << 20);
  auto threads = flags->number("--threads", tbb::info::default_concurrency(), 1, 4096);
  auto bins = flags->number("--bins", 64, 4, 256);
  auto delta = flags->number("--delta", 0.15, 0, 0.5);
  const bool tau_auto = flags->get("--tau", "auto") == "auto";
  auto tau = tau_auto ? absl::StatusOr<double>(0.0) : flags->number("--tau", 0, 0, 1e30);
  auto repeats = flags->number("--repeats", 3, 1, 100);
  for (const absl::Status& s : {size.status(), spp.status(), threads.status(), bins.status(),
                                delta.status(), tau.status(), repeats.status()}) {
    if (!s.ok()) {
      std::cerr << "prism-bench-gradient-cost: " << s.message() << "\n";
      return 2;
    }
  }
  auto k = job::gradient_offset_bins(*delta, int(*bins));
  if (!k.ok()) {
    std::cerr << "prism-bench-gradient-cost: " << k.status().message() << "\n";
    return 2;
  }
  std::vector<std::string> scenes = flags->positional;
  if (scenes.empty()) {
    scenes = {source_path("scenes/prism.pbrt").string(),
              source_path("scenes/cornell-two-lights.pbrt").string(),
              source_path("worker/testdata/gradient_rough_glass.pbrt").string()};
  }

  worker::EmbreeDevice device;
  std::printf(
      "| scene | resolution | spp | threads | uniform samples/s | hero samples/s | "
      "gradient samples/s | gradient / uniform | gradient / hero | tau (pilot s) | rays/sample: "
      "uniform, hero, gradient | paths shifted | shifts wasted (tau) | shifts failed |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const std::string& path : scenes) {
    auto scene = load_bench_scene(path);
    if (!scene.ok()) {
      std::cerr << "prism-bench-gradient-cost: " << scene.status().message() << "\n";
      return 1;
    }
    job::RenderOptions options;
    options.bins = int(*bins);
    options.max_depth = scene->description.integrator.max_depth;
    options.gradient_offset_bins = *k;
    options.gradient_tau = float(*tau);
    double pilot_seconds = 0;
    if (tau_auto) {
      options.integrator = job::IntegratorKind::kGradient;
      auto built = worker::RenderScene::build(device, scene->description, *scene->library, options,
                                              size->first, size->second);
      if (!built.ok()) {
        std::cerr << "prism-bench-gradient-cost: " << built.status().message() << "\n";
        return 1;
      }
      worker::GradientPilotOptions pilot_options;
      pilot_options.threads = int(*threads);
      auto pilot = worker::run_gradient_pilot(**built, size->first, size->second, pilot_options);
      if (!pilot.ok()) {
        std::cerr << "prism-bench-gradient-cost: " << pilot.status().message() << "\n";
        return 1;
      }
      options.gradient_tau = pilot->tau;
      pilot_seconds = pilot->seconds;
    }
    // Interleaved repeats, the fastest of each kept: load on a shared machine only slows.
    absl::StatusOr<Timed> uniform, hero, gradient;
    for (int r = 0; r < int(*repeats); ++r) {
      for (auto [kind, best] : {std::pair{job::IntegratorKind::kUniform, &uniform},
                                std::pair{job::IntegratorKind::kHero, &hero},
                                std::pair{job::IntegratorKind::kGradient, &gradient}}) {
        options.integrator = kind;
        auto timed = render(device, *scene, options, size->first, size->second, std::uint64_t(*spp),
                            int(*threads));
        if (!timed.ok()) {
          std::cerr << "prism-bench-gradient-cost: " << timed.status().message() << "\n";
          return 1;
        }
        if (r == 0 || timed->seconds < (*best)->seconds) *best = std::move(timed);
      }
    }
    const double samples = double(size->first) * size->second * *spp;
    const worker::TraceCounters& g = gradient->counters;
    std::printf(
        "| %s | %dx%d | %.0f | %.0f | %.3g | %.3g | %.3g | %.2f | %.2f | %.3g (%.2f) | %.2f, %.2f, "
        "%.2f | %.1f %% | %.1f %% | %.1f %% |\n",
        scene->name.c_str(), size->first, size->second, *spp, *threads, samples / uniform->seconds,
        samples / hero->seconds, samples / gradient->seconds, gradient->seconds / uniform->seconds,
        gradient->seconds / hero->seconds, options.gradient_tau, pilot_seconds,
        double(uniform->counters.rays) / samples, double(hero->counters.rays) / samples,
        double(g.rays) / samples, 100.0 * double(g.gradient_shifted_paths) / samples,
        g.gradient_shifts > 0 ? 100.0 * double(g.gradient_shifts_wasted) / g.gradient_shifts : 0.0,
        g.gradient_shifts > 0 ? 100.0 * double(g.gradient_shifts_failed) / g.gradient_shifts : 0.0);
    std::fflush(stdout);
  }
  std::printf(
      "\ngradient / uniform, gradient / hero: time per sample (uniform: the same base paths). "
      "Shift percentages are of the offsets evaluated (two per base event with c > tau).\n");
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
