// prism-bench-tracer: how much of the tracer's time is traversal. For each scene it renders
// with `hero` (the scene's max depth, spectral emitter selection on) through LocalRender, then
// casts the same number of rays as the render traced in a bare loop of Geometry::intersect
// (closest hit, hit finishing included) on the same committed Embree scene, with the same
// thread count, in the same run. Bare rays are incoherent and deterministic: origins uniform
// in the scene's bounding box, directions uniform on the sphere, both hashed from the ray index.
// The ratio (tracer rays/s) / (bare rays/s) is the figure of merit: 1 means shading, sampling
// and accumulation cost nothing next to traversal; the goal is >= 0.5. The tracer's rays
// include shadow rays (occlusion queries, cheaper than closest hits), so the ratio flatters the
// tracer slightly; the output says so.
//
// Usage: prism-bench-tracer [scene.pbrt ...] [--resolution 160x120] [--spp 16] [--threads N]
#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>

#include "absl/strings/str_format.h"
#include "coordinator/local_render.h"
#include "tests/bench/bench_common.h"
#include "worker/sampler.h"

namespace prism::bench {
namespace {

using Clock = std::chrono::steady_clock;

float unit(std::uint64_t key) {
  return worker::bits_to_unit_float(static_cast<std::uint32_t>(worker::mix64(key) >> 32));
}

struct BareResult {
  double seconds = 0;
  std::uint64_t hits = 0;
};

// `count` closest-hit queries of incoherent rays on `geometry`, on `threads` threads.
BareResult bare_embree_loop(const worker::Geometry& geometry, std::uint64_t count, int threads) {
  const worker::Bounds3f& b = geometry.bounds();
  const worker::Vec3f extent = b.hi - b.lo;
  tbb::combinable<std::uint64_t> hits([] { return std::uint64_t{0}; });
  tbb::task_arena arena(threads);
  const Clock::time_point start = Clock::now();
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<std::uint64_t>(0, count, 4096),
                      [&](const tbb::blocked_range<std::uint64_t>& range) {
                        std::uint64_t local = 0;
                        for (std::uint64_t i = range.begin(); i != range.end(); ++i) {
                          const std::uint64_t k = i * 8;
                          worker::Ray ray;
                          ray.origin = {b.lo.x + extent.x * unit(k),
                                        b.lo.y + extent.y * unit(k + 1),
                                        b.lo.z + extent.z * unit(k + 2)};
                          const float z = 1.0f - 2.0f * unit(k + 3);
                          const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
                          const float phi = 6.2831853f * unit(k + 4);
                          ray.direction = {r * std::cos(phi), r * std::sin(phi), z};
                          if (geometry.intersect(ray, 1e30f).has_value()) ++local;
                        }
                        hits.local() += local;
                      });
  });
  BareResult result;
  result.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  result.hits = hits.combine(std::plus<std::uint64_t>());
  return result;
}

int run(int argc, char** argv) {
  auto flags = parse_flags(argc, argv, {"--resolution", "--spp", "--threads"});
  if (!flags.ok()) {
    std::cerr << "prism-bench-tracer: " << flags.status().message() << "\n";
    return 2;
  }
  auto size = parse_size(flags->get("--resolution", "160x120"));
  auto spp = flags->number("--spp", 16, 1, 1 << 20);
  auto threads = flags->number("--threads", tbb::info::default_concurrency(), 1, 4096);
  for (const absl::Status& s : {size.status(), spp.status(), threads.status()}) {
    if (!s.ok()) {
      std::cerr << "prism-bench-tracer: " << s.message() << "\n";
      return 2;
    }
  }
  std::vector<std::string> scenes = flags->positional;
  if (scenes.empty()) {
    scenes = {source_path("scenes/bunny-cornell.pbrt").string(),
              source_path("scenes/suzanne-grid.pbrt").string(),
              source_path("scenes/cornell-two-lights.pbrt").string(),
              source_path("scenes/prism.pbrt").string()};
  }

  worker::EmbreeDevice device;
  std::printf(
      "| scene | resolution | spp | threads | tracer rays | tracer s | tracer rays/s | "
      "samples/s | samples/s/core | bare s | bare hits | bare rays/s | ratio |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const std::string& path : scenes) {
    auto scene = load_bench_scene(path);
    if (!scene.ok()) {
      std::cerr << "prism-bench-tracer: " << scene.status().message() << "\n";
      return 1;
    }
    coordinator::LocalRenderOptions options;
    options.render.integrator = job::IntegratorKind::kHero;
    options.render.bins = scene->description.film.bins.value_or(64);
    options.render.max_depth = scene->description.integrator.max_depth;
    options.width = size->first;
    options.height = size->second;
    options.spp = static_cast<std::uint64_t>(*spp);
    options.threads = static_cast<int>(*threads);
    auto render =
        coordinator::LocalRender::create(device, scene->description, *scene->library, options);
    if (!render.ok()) {
      std::cerr << "prism-bench-tracer: " << render.status().message() << "\n";
      return 1;
    }
    auto result = (*render)->render();
    if (!result.ok()) {
      std::cerr << "prism-bench-tracer: " << result.status().message() << "\n";
      return 1;
    }
    const coordinator::LocalRenderStats& stats = result->stats;
    const double tracer_rate = double(stats.counters.rays) / stats.render_seconds;
    const double samples_rate = double(stats.samples) / stats.render_seconds;
    const BareResult bare =
        bare_embree_loop((*render)->scene().geometry(), stats.counters.rays, stats.threads);
    const double bare_rate = double(stats.counters.rays) / bare.seconds;
    std::printf(
        "| %s | %dx%d | %llu | %d | %llu | %.2f | %.3g | %.3g | %.3g | %.2f | %.0f %% | %.3g | "
        "%.2f |\n",
        scene->name.c_str(), options.width, options.height,
        static_cast<unsigned long long>(options.spp), stats.threads,
        static_cast<unsigned long long>(stats.counters.rays), stats.render_seconds, tracer_rate,
        samples_rate, samples_rate / stats.threads, bare.seconds,
        100.0 * double(bare.hits) / double(stats.counters.rays), bare_rate,
        tracer_rate / bare_rate);
    std::fflush(stdout);
  }
  std::printf(
      "\ntracer rays count closest-hit and shadow (occlusion) queries; bare rays are all "
      "closest-hit Geometry::intersect calls.\n");
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
