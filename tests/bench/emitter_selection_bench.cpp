// prism-bench-emitter-selection: spectral emitter selection (docs/estimators.md §3) against the
// power-only pmf at equal time, on the two-emitter Cornell box. Both renders use `hero` with
// the `power` base pmf; one multiplies it by the lanes' unit-emission factor, the other not.
//
// Equal time: each configuration is first timed at a few spp, then rendered at the spp that
// fits the budget; the table shows the times actually taken and also MSE × time, which
// compares efficiency even when the times differ a little. Time is the process's CPU time
// (user + system, all threads), not wall time, so other work on a shared machine does not
// hand one configuration more samples than the other. Error: MSE over all pixels and bins
// against a reference rendered first at many spp (cached in the temp directory, keyed by the
// scene file's hash and the parameters). The reference's own noise adds its variance of the
// mean to both MSEs; the table subtracts that estimate in the "MSE − ref noise" column, and
// one ratio uses it. The estimate s²/n from the sums of squares is unbiased only for
// independent samples (Sobol points are stratified and converge faster than s²/n says), so
// the reference is rendered with the independent sampler.
//
// Usage: prism-bench-emitter-selection [scene.pbrt] [--resolution 32x32] [--budget 20 (CPU s)]
//          [--reference-spp 65536] [--threads N] [--cache-dir DIR] [--max-depth D]
//          [--repeats R]   (R independent seeds per configuration, MSE and time averaged)
#include <sys/resource.h>
#include <tbb/info.h>

#include <cmath>
#include <cstdio>
#include <iostream>
#include <numeric>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "coordinator/local_render.h"
#include "coordinator/outputs.h"
#include "services/base/atomic_file.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/image/metrics.h"
#include "tests/bench/bench_common.h"

namespace prism::bench {
namespace {

double cpu_seconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return double(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
         1e-6 * double(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

struct Setup {
  LoadedBenchScene scene;
  int width = 32, height = 32;
  int threads = 1;
  int max_depth = 5;
};

coordinator::LocalRenderOptions options_for(const Setup& setup, bool spectral_factor,
                                            std::uint64_t spp, std::uint64_t seed,
                                            job::SamplerKind sampler = job::SamplerKind::kSobol) {
  coordinator::LocalRenderOptions o;
  o.render.sampler = sampler;
  o.render.integrator = job::IntegratorKind::kHero;
  o.render.light_selection = job::LightSelectionKind::kPower;
  o.render.spectral_light_selection = spectral_factor;
  o.render.bins = setup.scene.description.film.bins.value_or(64);
  o.render.max_depth = setup.max_depth;
  o.render.seed = seed;
  o.width = setup.width;
  o.height = setup.height;
  o.spp = spp;
  o.threads = setup.threads;
  return o;
}

struct Timed {
  coordinator::LocalRenderResult result;
  double cpu_seconds = 0;  // of the render only, not the scene build
};

absl::StatusOr<Timed> render(worker::EmbreeDevice& device, const Setup& setup,
                             const coordinator::LocalRenderOptions& o) {
  PRISM_ASSIGN_OR_RETURN(
      auto renderer,
      coordinator::LocalRender::create(device, setup.scene.description, *setup.scene.library, o));
  const double start = cpu_seconds();
  PRISM_ASSIGN_OR_RETURN(coordinator::LocalRenderResult result, renderer->render());
  return Timed{std::move(result), cpu_seconds() - start};
}

struct Reference {
  image::SpectralImage image;
  double noise = 0;  // mean variance of the reference's pixel means
};

absl::StatusOr<Reference> reference(worker::EmbreeDevice& device, const Setup& setup,
                                    const std::filesystem::path& scene_path, std::uint64_t spp,
                                    const std::filesystem::path& cache_dir) {
  PRISM_ASSIGN_OR_RETURN(std::string scene_text, base::read_file(scene_path));
  const std::string key = base::sha256_hex(
      absl::StrCat(scene_text, "|", setup.width, "x", setup.height, "|", spp, "|", setup.max_depth,
                   "|independent|", setup.scene.description.film.bins.value_or(64)));
  const std::filesystem::path cached =
      cache_dir / absl::StrCat("prism-bench-emitter-reference-", key.substr(0, 16), ".exr");
  if (std::filesystem::exists(cached)) {
    PRISM_ASSIGN_OR_RETURN(image::SpectralExr exr, image::read_spectral_exr(cached));
    auto noise = exr.metadata.find("reference_noise");
    if (noise != exr.metadata.end()) {
      std::fprintf(stderr, "reference: cached %s\n", cached.c_str());
      return Reference{std::move(exr.spectral), std::stod(noise->second)};
    }
  }
  std::fprintf(stderr, "reference: rendering %llu spp (cached afterwards in %s) ...\n",
               static_cast<unsigned long long>(spp), cached.c_str());
  // The reference uses the power-only pmf, its own seed and independent samples (see above).
  PRISM_ASSIGN_OR_RETURN(
      Timed timed, render(device, setup,
                          options_for(setup, false, spp, 0x5eed, job::SamplerKind::kIndependent)));
  coordinator::LocalRenderResult& result = timed.result;
  const auto& v = result.statistics.variance_of_mean;
  const double noise = std::accumulate(v.begin(), v.end(), 0.0) / double(v.size());
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb, coordinator::to_linear_srgb(result.image, cmf));
  image::ExrMetadata metadata{{"spp", absl::StrCat(spp)},
                              {"reference_noise", absl::StrFormat("%.17g", noise)}};
  PRISM_RETURN_IF_ERROR(image::write_spectral_exr(cached, result.image, rgb, metadata));
  std::fprintf(stderr, "reference: %.1f s wall, %.1f s CPU\n", result.stats.render_seconds,
               timed.cpu_seconds);
  return Reference{std::move(result.image), noise};
}

struct Row {
  const char* name;
  std::uint64_t spp = 0;
  double seconds = 0;
  double mse = 0;
  double rel_mse = 0;
};

int fail(const absl::Status& status) {
  std::cerr << "prism-bench-emitter-selection: " << status.message() << "\n";
  return 1;
}

int run(int argc, char** argv) {
  auto flags = parse_flags(argc, argv,
                           {"--resolution", "--budget", "--reference-spp", "--threads",
                            "--cache-dir", "--max-depth", "--repeats"});
  if (!flags.ok()) return fail(flags.status());
  const std::filesystem::path scene_path = flags->positional.empty()
                                               ? source_path("scenes/cornell-two-lights.pbrt")
                                               : std::filesystem::path(flags->positional[0]);
  auto size = parse_size(flags->get("--resolution", "32x32"));
  auto budget = flags->number("--budget", 20, 0.1, 86400);  // CPU seconds
  auto reference_spp = flags->number("--reference-spp", 65536, 1, 1 << 26);
  auto threads = flags->number("--threads", tbb::info::default_concurrency(), 1, 4096);
  auto max_depth = flags->number("--max-depth", -1, -1, 1000);
  auto repeats = flags->number("--repeats", 1, 1, 1000);
  for (const absl::Status& s : {size.status(), budget.status(), reference_spp.status(),
                                threads.status(), max_depth.status(), repeats.status()}) {
    if (!s.ok()) return fail(s);
  }
  auto scene = load_bench_scene(scene_path);
  if (!scene.ok()) return fail(scene.status());
  Setup setup{std::move(*scene), size->first, size->second, static_cast<int>(*threads), 0};
  setup.max_depth =
      *max_depth >= 0 ? static_cast<int>(*max_depth) : setup.scene.description.integrator.max_depth;
  const std::filesystem::path cache_dir =
      flags->get("--cache-dir", std::filesystem::temp_directory_path().string());

  worker::EmbreeDevice device;
  auto ref =
      reference(device, setup, scene_path, static_cast<std::uint64_t>(*reference_spp), cache_dir);
  if (!ref.ok()) return fail(ref.status());

  std::vector<Row> rows;
  for (bool spectral_factor : {true, false}) {
    Row row{spectral_factor ? "power x spectral factor" : "power only"};
    // Time a render long enough (a tenth of the budget) that start-up costs do not skew the
    // seconds per spp, then fill the budget.
    double per_spp = 0;
    for (std::uint64_t spp = 4;; spp *= 2) {
      auto calibration = render(device, setup, options_for(setup, spectral_factor, spp, 2));
      if (!calibration.ok()) return fail(calibration.status());
      per_spp = calibration->cpu_seconds / double(spp);
      if (calibration->cpu_seconds >= 0.1 * *budget || spp >= (1u << 24)) break;
    }
    row.spp = std::max<std::uint64_t>(1, static_cast<std::uint64_t>(*budget / per_spp));
    const int count = static_cast<int>(*repeats);
    for (int seed = 1; seed <= count; ++seed) {
      auto result = render(device, setup, options_for(setup, spectral_factor, row.spp, seed));
      if (!result.ok()) return fail(result.status());
      auto metrics = image::compare_spectral(result->result.image, ref->image);
      if (!metrics.ok()) return fail(metrics.status());
      row.seconds += result->cpu_seconds / count;
      row.mse += metrics->mse / count;
      row.rel_mse += metrics->rel_mse / count;
    }
    rows.push_back(row);
  }

  std::printf(
      "scene %s, %dx%d, hero, max depth %d, %d threads, budget %.1f CPU s, %d repeat(s), "
      "reference %llu spp (independent samples, noise %.3g)\n\n",
      setup.scene.name.c_str(), setup.width, setup.height, setup.max_depth, setup.threads, *budget,
      static_cast<int>(*repeats), static_cast<unsigned long long>(*reference_spp), ref->noise);
  std::printf(
      "| emitter selection | spp | CPU s | MSE | MSE - ref noise | relMSE | MSE x s | "
      "(MSE - ref noise) x spp |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  for (const Row& r : rows) {
    std::printf("| %s | %llu | %.2f | %.4g | %.4g | %.4g | %.4g | %.4g |\n", r.name,
                static_cast<unsigned long long>(r.spp), r.seconds, r.mse, r.mse - ref->noise,
                r.rel_mse, r.mse * r.seconds, (r.mse - ref->noise) * double(r.spp));
  }
  const Row& on = rows[0];
  const Row& off = rows[1];
  std::printf(
      "\nMSE ratio spectral/power-only at equal time: %.4f (reference noise removed: "
      "%.4f; time-normalised: %.4f; per sample: %.4f)\n",
      on.mse / off.mse, (on.mse - ref->noise) / (off.mse - ref->noise),
      (on.mse * on.seconds) / (off.mse * off.seconds),
      ((on.mse - ref->noise) * double(on.spp)) / ((off.mse - ref->noise) * double(off.spp)));
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
