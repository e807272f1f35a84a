// prism-bench-prepass-equal-time: the multi-pass prepass (algorithms.md §4: per-pixel wavelength
// distributions learned from K prepasses) against the emitter mixture it refines (the multi-pass
// paper's baseline) and against uniform wavelength sampling, at equal time, on the prepass
// evaluation scene (scenes/three-emitters.pbrt: three lamps with different spectra, an absorbing
// dye, dispersive glass). All three use `hero`:
//   prepass           emitter mixture × flat sensor, then the prepass's per-pixel tables
//   emitter mixture   emitter_pdf emitters, spectral_pdf flat (the job's default distribution)
//   uniform           emitter_pdf uniform, spectral_pdf flat
// The multi-pass paper reports 19-23 % lower error than the emitter mixture with absorption,
// and the prepass's share of the time falling from 18 % to 4 % as the sample count grows.
//
// Equal time: for each budget (seconds of LocalRender::render(): wall clock, or with --clock cpu
// the process's CPU time, which other work on a shared machine does not inflate), each method is
// first calibrated (seconds per final-pass spp; for the prepass also the prepass's own time), then
// rendered at the spp that fills the budget; each render's own timing refines the calibration for
// the next budget. The table shows the times actually taken, and MSE × s. The prepass's time (its
// passes, the coordinator's filter and tables) is INCLUDED in its method's time and also reported
// as a share of it (of the wall time: LocalRenderStats times the prepass on the wall clock; with
// --clock cpu that share of the CPU time is counted as the prepass's).
//
// Error: spectral MSE against a cached reference (hero, emitter mixture, independent samples, two
// halves; equal_time.h) over the whole image and two insets, one seen through the dye and one with
// dispersion (the glass sphere and its caustic); the reference's noise floor for each region is
// subtracted in the "- floor" columns and in the ratios. Nothing is asserted.
//
// Usage: prism-bench-prepass-equal-time [scene.pbrt] [--resolution 160x120 (the scene's)]
//          [--budgets 10,40] [--reference-spp 4096] [--cache-dir DIR] [--threads N]
//          [--max-depth D] [--repeats R] [--medium-inset x,y,w,h] [--dispersion-inset x,y,w,h]
//          [--prepass-spp 128] [--prepass-passes 2] [--prepass-epsilon 0.05] [--map 8x6|none]
//          [--clock wall|cpu] [--csv path]
// The insets default to three-emitters.pbrt's at 160x120 (medium 36,58,24,22: the dyed block's
// front face; dispersion 94,54,44,48: the sphere and its caustic), scaled with --resolution;
// give "none" to leave one out. --map CxR also prints the prepass's error ratio to the mixture on
// a grid of C x R cells, to show where it wins and where it loses.
#include <tbb/info.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iostream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "services/base/status.h"
#include "tests/bench/bench_common.h"
#include "tests/bench/equal_time.h"

namespace prism::bench {
namespace {

enum class MethodKind { kPrepass, kMixture, kUniform };

struct Method {
  MethodKind kind;
  const char* name;
};
// The baseline first: every ratio is against it.
constexpr Method kMethods[] = {{MethodKind::kMixture, "emitter mixture"},
                               {MethodKind::kPrepass, "prepass"},
                               {MethodKind::kUniform, "uniform"}};

struct Setup {
  int width = 0, height = 0;
  int threads = 1;
  int max_depth = 0;
  int bins = 0;
  coordinator::PrepassParameters prepass;
};

coordinator::LocalRenderOptions options_for(const Setup& setup, MethodKind kind, std::uint64_t spp,
                                            std::uint64_t seed) {
  coordinator::LocalRenderOptions o;
  o.render.integrator = worker::IntegratorKind::kHero;
  o.render.spectral_pdf = worker::SpectralPdfKind::kFlat;
  o.render.emitter_pdf = kind == MethodKind::kUniform ? worker::EmitterPdfKind::kUniform
                                                      : worker::EmitterPdfKind::kEmitters;
  o.render.bins = setup.bins;
  o.render.max_depth = setup.max_depth;
  o.render.seed = seed;
  if (kind == MethodKind::kPrepass) o.prepass = setup.prepass;
  o.width = setup.width;
  o.height = setup.height;
  o.spp = spp;
  o.threads = setup.threads;
  return o;
}

struct Region {
  std::string name;
  std::optional<image::Crop> crop;  // nullopt: the whole image
  double floor = 0;                 // the reference's MSE floor over the region
};

struct Cost {
  double per_spp = 0;  // clock seconds per final-pass spp
  double prepass = 0;  // clock seconds of the prepass (0 without one)
};

// The seconds of a timed render on the chosen clock. The prepass's share of a CPU time is taken
// to be its share of the wall time (LocalRenderStats times the prepass on the wall clock only).
double clock_seconds(const TimedRender& timed, bool cpu_clock) {
  return cpu_clock ? timed.cpu_seconds : timed.wall_seconds;
}
double prepass_share(const TimedRender& timed) {
  return timed.wall_seconds > 0
             ? std::min(1.0, timed.result.stats.prepass_seconds / timed.wall_seconds)
             : 0.0;
}
double final_seconds(const TimedRender& timed, bool cpu_clock) {
  return std::max(1e-9, clock_seconds(timed, cpu_clock) * (1 - prepass_share(timed)));
}
double prepass_seconds(const TimedRender& timed, bool cpu_clock) {
  return clock_seconds(timed, cpu_clock) * prepass_share(timed);
}

struct Measurement {
  std::uint64_t spp = 0;
  double seconds = 0;  // on the chosen clock, averaged over repeats, prepass included
  double wall = 0;
  double cpu = 0;
  double prepass = 0;
  double fallback = 0;
  std::vector<double> mse;       // per region
  std::vector<double> cell_mse;  // per cell of the ratio map
};

int fail(const absl::Status& status) {
  std::cerr << "prism-bench-prepass-equal-time: " << status.message() << "\n";
  return 1;
}

absl::StatusOr<std::vector<double>> parse_budgets(const std::string& text) {
  std::vector<double> out;
  for (absl::string_view part : absl::StrSplit(text, ',')) {
    double value = 0;
    if (!absl::SimpleAtod(part, &value) || !(value > 0) || value > 86400) {
      return absl::InvalidArgumentError(
          absl::StrCat("--budgets '", text, "': want positive seconds, e.g. 10,40"));
    }
    out.push_back(value);
  }
  return out;
}

// An inset flag: "none", a rect, or the default rect (given at 160x120) scaled to the film.
absl::StatusOr<std::optional<image::Crop>> inset(const Flags& flags, const std::string& name,
                                                 image::Crop fallback, const Setup& setup) {
  const std::string text = flags.get(name, "");
  if (text == "none") return std::optional<image::Crop>();
  image::Crop crop;
  if (text.empty()) {
    const double sx = setup.width / 160.0, sy = setup.height / 120.0;
    crop = {int(fallback.x * sx), int(fallback.y * sy), std::max(1, int(fallback.w * sx)),
            std::max(1, int(fallback.h * sy))};
  } else {
    PRISM_ASSIGN_OR_RETURN(crop, parse_crop(text));
  }
  PRISM_RETURN_IF_ERROR(image::crop_rect(crop, setup.width, setup.height).status());
  return std::optional<image::Crop>(crop);
}

int run(int argc, char** argv) {
  auto flags = parse_flags(
      argc, argv,
      {"--resolution", "--budgets", "--reference-spp", "--cache-dir", "--threads", "--max-depth",
       "--repeats", "--medium-inset", "--dispersion-inset", "--prepass-spp", "--prepass-passes",
       "--prepass-epsilon", "--map", "--clock", "--csv"});
  if (!flags.ok()) return fail(flags.status());
  const std::filesystem::path scene_path = flags->positional.empty()
                                               ? source_path("scenes/three-emitters.pbrt")
                                               : std::filesystem::path(flags->positional[0]);
  auto scene = load_bench_scene(scene_path);
  if (!scene.ok()) return fail(scene.status());
  const scene::SceneDescription& description = scene->description;
  auto size = parse_size(flags->get("--resolution", absl::StrCat(description.film.x_resolution, "x",
                                                                 description.film.y_resolution)));
  auto budgets = parse_budgets(flags->get("--budgets", "10,40"));
  auto reference_spp = flags->number("--reference-spp", 4096, 2, 1 << 26);
  auto threads = flags->number("--threads", tbb::info::default_concurrency(), 1, 4096);
  auto max_depth = flags->number("--max-depth", description.integrator.max_depth, 0, 1000);
  auto repeats = flags->number("--repeats", 1, 1, 1000);
  auto prepass_spp = flags->number("--prepass-spp", 128, 1, 1 << 20);
  auto prepass_passes =
      flags->number("--prepass-passes", 2, 1, coordinator::PrepassParameters::kMaxPasses);
  auto prepass_epsilon = flags->number("--prepass-epsilon", 0.05, 1e-6, 1 - 1e-6);
  for (const absl::Status& s :
       {size.status(), budgets.status(), reference_spp.status(), threads.status(),
        max_depth.status(), repeats.status(), prepass_spp.status(), prepass_passes.status(),
        prepass_epsilon.status()}) {
    if (!s.ok()) return fail(s);
  }
  Setup setup;
  setup.width = size->first;
  setup.height = size->second;
  setup.threads = int(*threads);
  setup.max_depth = int(*max_depth);
  setup.bins = description.film.bins.value_or(64);
  setup.prepass.spp = std::uint32_t(*prepass_spp);
  setup.prepass.passes = int(*prepass_passes);
  setup.prepass.epsilon = *prepass_epsilon;
  std::vector<Region> regions{{"whole image", std::nullopt}};
  auto medium = inset(*flags, "--medium-inset", {36, 58, 24, 22}, setup);
  auto dispersion = inset(*flags, "--dispersion-inset", {94, 54, 44, 48}, setup);
  if (!medium.ok()) return fail(medium.status());
  if (!dispersion.ok()) return fail(dispersion.status());
  if (medium->has_value()) regions.push_back({"medium inset", *medium});
  if (dispersion->has_value()) regions.push_back({"dispersion inset", *dispersion});
  const std::string clock = flags->get("--clock", "wall");
  if (clock != "wall" && clock != "cpu") {
    return fail(absl::InvalidArgumentError("--clock: want wall or cpu"));
  }
  const bool cpu_clock = clock == "cpu";
  // The ratio map: the film cut into columns x rows cells (the last ones take the remainder).
  std::vector<Region> cells;
  int map_columns = 0;
  if (const std::string map = flags->get("--map", "8x6"); map != "none") {
    auto grid = parse_size(map);
    if (!grid.ok()) return fail(grid.status());
    map_columns = std::min(grid->first, setup.width);
    const int map_rows = std::min(grid->second, setup.height);
    for (int j = 0; j < map_rows; ++j) {
      for (int i = 0; i < map_columns; ++i) {
        const int x0 = i * setup.width / map_columns, x1 = (i + 1) * setup.width / map_columns;
        const int y0 = j * setup.height / map_rows, y1 = (j + 1) * setup.height / map_rows;
        cells.push_back({absl::StrCat(i, ",", j), image::Crop{x0, y0, x1 - x0, y1 - y0}});
      }
    }
  }
  const std::filesystem::path cache_dir =
      flags->get("--cache-dir", std::filesystem::temp_directory_path().string());
  std::ofstream csv;
  const std::string csv_path = flags->get("--csv", "");
  if (!csv_path.empty()) {
    csv.open(csv_path);
    if (!csv) return fail(absl::InvalidArgumentError(absl::StrCat("cannot write ", csv_path)));
    csv << "budget,method,spp,seconds,prepass_seconds,region,mse,mse_minus_floor\n";
  }

  worker::EmbreeDevice device;
  coordinator::LocalRenderOptions reference_options =
      options_for(setup, MethodKind::kMixture, std::uint64_t(*reference_spp), 0x5eed);
  reference_options.render.sampler = worker::SamplerKind::kIndependent;
  auto reference =
      cached_reference(device, *scene, reference_options, cache_dir, "prepass-equal-time");
  if (!reference.ok()) return fail(reference.status());
  for (std::vector<Region>* list : {&regions, &cells}) {
    for (Region& region : *list) {
      auto floor = reference->floor(region.crop);
      if (!floor.ok()) return fail(floor.status());
      region.floor = floor->mse;
    }
  }

  // Calibration: time a render long enough (a tenth of the smallest budget) that start-up costs
  // do not skew the seconds per spp. The prepass is calibrated once, at the spp the mixture
  // needed, since every calibration render of it pays the whole prepass again.
  const double calibration_seconds = 0.1 * *std::min_element(budgets->begin(), budgets->end());
  std::vector<Cost> costs;
  std::uint64_t calibration_spp = 4;
  for (const Method& method : kMethods) {
    Cost cost;
    if (method.kind == MethodKind::kPrepass) {
      auto timed =
          timed_render(device, *scene, options_for(setup, method.kind, calibration_spp, 2));
      if (!timed.ok()) return fail(timed.status());
      cost = {final_seconds(*timed, cpu_clock) / double(calibration_spp),
              prepass_seconds(*timed, cpu_clock)};
    } else {
      for (std::uint64_t spp = 4;; spp *= 2) {
        auto timed = timed_render(device, *scene, options_for(setup, method.kind, spp, 2));
        if (!timed.ok()) return fail(timed.status());
        cost.per_spp = final_seconds(*timed, cpu_clock) / double(spp);
        if (method.kind == MethodKind::kMixture) calibration_spp = spp;
        if (final_seconds(*timed, cpu_clock) >= calibration_seconds || spp >= (1u << 24)) break;
      }
    }
    std::fprintf(stderr, "%s: %.4g s per spp, prepass %.2f s\n", method.name, cost.per_spp,
                 cost.prepass);
    costs.push_back(cost);
  }

  std::printf(
      "scene %s, %dx%d, %d bins, hero, max depth %d, %d threads, %d repeat(s); prepass K = %d, "
      "%u spp; reference %llu spp (emitter mixture, independent samples, %.0f s)\n",
      scene->name.c_str(), setup.width, setup.height, setup.bins, setup.max_depth, setup.threads,
      int(*repeats), setup.prepass.passes, setup.prepass.spp,
      static_cast<unsigned long long>(reference->spp), reference->seconds);
  std::printf("reference MSE floor:");
  for (const Region& region : regions) {
    std::printf(" %s %.4g%s", region.name.c_str(), region.floor,
                region.crop.has_value()
                    ? absl::StrFormat(" (%d,%d %dx%d)", region.crop->x, region.crop->y,
                                      region.crop->w, region.crop->h)
                          .c_str()
                    : "");
  }
  std::printf("\n");

  for (double budget : *budgets) {
    std::vector<Measurement> measurements;
    for (std::size_t m = 0; m < std::size(kMethods); ++m) {
      const Method& method = kMethods[m];
      Cost& cost = costs[m];
      Measurement result;
      result.spp = std::max<std::uint64_t>(
          1, std::uint64_t(std::max(0.0, budget - cost.prepass) / cost.per_spp));
      result.mse.assign(regions.size(), 0.0);
      result.cell_mse.assign(cells.size(), 0.0);
      const int count = int(*repeats);
      for (int seed = 1; seed <= count; ++seed) {
        auto timed =
            timed_render(device, *scene, options_for(setup, method.kind, result.spp, seed));
        if (!timed.ok()) return fail(timed.status());
        result.seconds += clock_seconds(*timed, cpu_clock) / count;
        result.wall += timed->wall_seconds / count;
        result.cpu += timed->cpu_seconds / count;
        result.prepass += timed->result.stats.prepass_seconds / count;
        result.fallback +=
            (timed->result.stats.prepass ? timed->result.stats.prepass->fallback_fraction : 0.0) /
            count;
        // The longer the render, the better its seconds per spp: the next budget uses it.
        cost.per_spp = final_seconds(*timed, cpu_clock) / double(result.spp);
        cost.prepass = prepass_seconds(*timed, cpu_clock);
        for (std::size_t r = 0; r < regions.size(); ++r) {
          auto metrics =
              image::compare_spectral(timed->result.image, reference->image, regions[r].crop);
          if (!metrics.ok()) return fail(metrics.status());
          result.mse[r] += metrics->mse / count;
        }
        for (std::size_t c = 0; c < cells.size(); ++c) {
          auto metrics =
              image::compare_spectral(timed->result.image, reference->image, cells[c].crop);
          if (!metrics.ok()) return fail(metrics.status());
          result.cell_mse[c] += metrics->mse / count;
        }
      }
      std::fprintf(stderr, "budget %.0f s, %s: %llu spp, %.2f s\n", budget, method.name,
                   static_cast<unsigned long long>(result.spp), result.seconds);
      if (csv.is_open()) {
        for (std::size_t r = 0; r < regions.size(); ++r) {
          csv << absl::StrFormat("%g,%s,%llu,%.6g,%.6g,%s,%.6g,%.6g\n", budget, method.name,
                                 static_cast<unsigned long long>(result.spp), result.seconds,
                                 result.prepass, regions[r].name, result.mse[r],
                                 result.mse[r] - regions[r].floor);
        }
      }
      measurements.push_back(std::move(result));
    }

    std::printf(
        "\nbudget %.0f %s s\n\n| method | spp | wall s | CPU s | prepass wall s (share) | "
        "fallback pixels |",
        budget, cpu_clock ? "CPU" : "wall");
    for (const Region& region : regions) {
      std::printf(" %s MSE | - floor | ratio |", region.name.c_str());
    }
    std::printf(" MSE x s (whole) |\n|---|---|---|---|---|---|");
    for (std::size_t r = 0; r < regions.size(); ++r) std::printf("---|---|---|");
    std::printf("---|\n");
    const Measurement& baseline = measurements[0];
    for (std::size_t m = 0; m < measurements.size(); ++m) {
      const Measurement& row = measurements[m];
      std::printf(
          "| %s | %llu | %.2f | %.2f | %s | %s |", kMethods[m].name,
          static_cast<unsigned long long>(row.spp), row.wall, row.cpu,
          row.prepass > 0
              ? absl::StrFormat("%.2f (%.1f %%)", row.prepass, 100 * row.prepass / row.wall).c_str()
              : "-",
          kMethods[m].kind == MethodKind::kPrepass
              ? absl::StrFormat("%.1f %%", 100 * row.fallback).c_str()
              : "-");
      for (std::size_t r = 0; r < regions.size(); ++r) {
        const double e = row.mse[r] - regions[r].floor;
        const double b = baseline.mse[r] - regions[r].floor;
        std::printf(" %.4g | %.4g | %s |", row.mse[r], e,
                    e > 0 && b > 0 ? absl::StrFormat("%.3f", e / b).c_str() : "n/a");
      }
      std::printf(" %.4g |\n", row.mse[0] * row.seconds);
    }
    if (!cells.empty()) {
      // Where the prepass wins and loses: its (MSE − floor) over the mixture's, per cell.
      std::printf("\nprepass / emitter mixture, (MSE - floor) per cell:\n\n| |");
      for (int i = 0; i < map_columns; ++i) {
        const image::Crop& crop = *cells[std::size_t(i)].crop;
        std::printf(" x %d-%d |", crop.x, crop.x + crop.w - 1);
      }
      std::printf("\n|---|");
      for (int i = 0; i < map_columns; ++i) std::printf("---|");
      for (std::size_t c = 0; c < cells.size(); ++c) {
        const image::Crop& crop = *cells[c].crop;
        if (c % std::size_t(map_columns) == 0) {
          std::printf("\n| y %d-%d |", crop.y, crop.y + crop.h - 1);
        }
        const double e = measurements[1].cell_mse[c] - cells[c].floor;
        const double b = baseline.cell_mse[c] - cells[c].floor;
        std::printf(" %s |", e > 0 && b > 0 ? absl::StrFormat("%.2f", e / b).c_str() : "n/a");
      }
      std::printf("\n");
    }
    std::fflush(stdout);
  }
  std::printf(
      "\nratio: (MSE - reference floor) / the emitter mixture's, same region and budget; below 1 "
      "the method is better at equal time.\n");
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
