// prism-bench-prepass-scenes: the multi-pass prepass (prepass.h: second-moment bin masses with the
// default's shape inside each bin, a per-pixel mixture weight α, the early stop, Ñ budgeted from
// the job's spp) against the job's default distribution (`--no-prepass`: the emitter mixture),
// on the prepass evaluation scenes, at each scene's own spp, as `prism render` runs them.
//
// Both methods render the same spp with `hero` and the same seeds; the prepass's time (its
// passes, the coordinator's filters and tables) is included in its time. Error: spectral MSE
// (every bin) and RGB MSE (linear sRGB, as the PNG and RGB EXR record it) against a cached
// reference (hero, emitter mixture, independent samples, two halves; equal_time.h), minus the
// reference's own floor over the same region. Ratios are prepass ÷ default:
//   per sample   (MSE − floor) at the same spp;
//   equal time   (MSE − floor) × seconds, i.e. the error ratio after giving both the same time
//                (Monte Carlo error ∝ 1/time for either, the prepass's overhead included).
// The table also gives the prepass's share of the time, the passes it ran, the gain its tables
// predicted (1 − Σ V(α)/Σ V(0), prepass.h) beside the measured per-sample gain (1 − ratio), and
// the α histogram. Figures are means over --seeds seeds. Nothing is asserted.
//
// --dump DIR writes per scene (first seed) PNG maps of the prepass's choices: <scene>.alpha.png
// (black: default, grey to white: α = ¼ … 1 − ε), <scene>.predicted.png (predicted per-pixel
// gain 1 − V(α)/V(0), black 0 to white 1) and <scene>.measured.png (measured per-pixel gain
// 1 − error ratio over 4x4 blocks, black ≤ 0 to white 1; red where the prepass is worse).
//
// Usage: prism-bench-prepass-scenes [scene.pbrt ...] [--spp N (each scene's)] [--seeds 2]
//          [--reference-spp 16384] [--cache-dir DIR] [--threads N] [--clock cpu|wall]
//          [--inset NAME=x,y,w,h ...] [--prepass-spp N (budgeted)] [--prepass-passes 2]
//          [--prepass-epsilon 0.05] [--prepass-fallback F] [--prepass-sigma-s 1.75]
//          [--min-image-gain G] [--min-final-gain G]
//          [--sampler sobol|independent] [--dump DIR] [--csv path]
// Default scenes: the prepass evaluation set of scenes/README.md. --inset may be repeated as
// one comma-free list "a.pbrt=x,y,w,h;b.pbrt=...": NAME is the scene's file name.
#include <tbb/info.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <map>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "coordinator/outputs.h"
#include "coordinator/prepass.h"
#include "services/base/status.h"
#include "services/image/png.h"
#include "tests/bench/bench_common.h"
#include "tests/bench/equal_time.h"

namespace prism::bench {
namespace {

const char* const kDefaultScenes[] = {
    "scenes/prism-f11.pbrt",      "scenes/emitter-uniform.pbrt",
    "scenes/emitter-led.pbrt",    "scenes/emitter-incandescent.pbrt",
    "scenes/emitter-cfl.pbrt",    "scenes/emitter-lps.pbrt",
    "scenes/three-emitters.pbrt", "scenes/boxes.pbrt",
    "scenes/drinks.pbrt"};

// Insets that come with the scenes (at their own resolution).
std::multimap<std::string, std::pair<std::string, image::Crop>> default_insets() {
  return {{"three-emitters.pbrt", {"dye", {36, 58, 24, 22}}},
          {"three-emitters.pbrt", {"sphere", {94, 54, 44, 48}}}};
}

int fail(const absl::Status& status) {
  std::cerr << "prism-bench-prepass-scenes: " << status.message() << "\n";
  return 1;
}

struct Region {
  std::string name;
  std::optional<image::Crop> crop;
  double floor = 0, rgb_floor = 0;
};

struct Run {
  double seconds = 0, prepass_seconds = 0;
  double s2n = 0;                    // mean over bins of the render's own s²/n
  std::vector<double> mse, rgb_mse;  // per region, floor removed
  std::optional<coordinator::PrepassOutcome> outcome;
};

double clock_seconds(const TimedRender& t, bool cpu) {
  return cpu ? t.cpu_seconds : t.wall_seconds;
}

absl::StatusOr<image::ErrorMetrics> rgb_error(const image::SpectralImage& test,
                                              const image::SpectralImage& reference,
                                              const spectral::ColorMatching& cmf,
                                              const std::optional<image::Crop>& crop) {
  PRISM_ASSIGN_OR_RETURN(image::RgbImage a, coordinator::to_linear_srgb(test, cmf));
  PRISM_ASSIGN_OR_RETURN(image::RgbImage b, coordinator::to_linear_srgb(reference, cmf));
  return image::compare_rgb(a, b, crop);
}

// Per-pixel squared spectral error summed over bins.
std::vector<double> pixel_errors(const image::SpectralImage& test,
                                 const image::SpectralImage& reference) {
  std::vector<double> e(std::size_t(test.width()) * test.height(), 0.0);
  for (int y = 0; y < test.height(); ++y) {
    for (int x = 0; x < test.width(); ++x) {
      double s = 0;
      for (int b = 0; b < test.bins(); ++b) {
        const double d = double(test.value(x, y, b)) - reference.value(x, y, b);
        s += d * d;
      }
      e[std::size_t(y) * test.width() + x] = s;
    }
  }
  return e;
}

absl::Status write_map(const std::filesystem::path& path, int w, int h,
                       const std::function<std::array<float, 3>(int, int)>& colour) {
  PRISM_ASSIGN_OR_RETURN(image::RgbImage img, image::RgbImage::create(w, h));
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const std::array<float, 3> c = colour(x, y);
      for (int k = 0; k < 3; ++k) img.value(x, y, k) = c[k];
    }
  }
  return image::write_png_preview(path, img);
}

int run(int argc, char** argv) {
  auto flags =
      parse_flags(argc, argv,
                  {"--spp", "--seeds", "--reference-spp", "--cache-dir", "--threads", "--clock",
                   "--inset", "--prepass-spp", "--prepass-passes", "--prepass-epsilon",
                   "--prepass-fallback", "--prepass-sigma-s", "--min-image-gain",
                   "--min-final-gain", "--dump", "--csv", "--sampler"});
  if (!flags.ok()) return fail(flags.status());
  std::vector<std::filesystem::path> scenes;
  for (const std::string& p : flags->positional) scenes.emplace_back(p);
  if (scenes.empty()) {
    for (const char* s : kDefaultScenes) scenes.push_back(source_path(s));
  }
  auto seeds = flags->number("--seeds", 2, 1, 100);
  auto reference_spp = flags->number("--reference-spp", 16384, 2, 1 << 26);
  auto threads = flags->number("--threads", tbb::info::default_concurrency(), 1, 4096);
  auto spp_flag = flags->number("--spp", 0, 0, 1 << 24);
  auto prepass_spp = flags->number("--prepass-spp", 0, 0, 1 << 20);
  auto passes = flags->number("--prepass-passes", 2, 1, job::PrepassParameters::kMaxPasses);
  auto epsilon = flags->number("--prepass-epsilon", 0.05, 1e-6, 1 - 1e-6);
  auto fallback = flags->number("--prepass-fallback", job::PrepassParameters{}.fallback, 0, 0.999);
  auto sigma_s = flags->number("--prepass-sigma-s", 1.75, 0.1, 64);
  // The early stop's and the final drop's margins (job_parameters.h), to see the tables they
  // would stop or drop: --min-image-gain -1 goes on whatever pass 1 predicts.
  auto min_image_gain =
      flags->number("--min-image-gain", job::PrepassParameters::kMinImageGain, -1e9, 1);
  auto min_final_gain =
      flags->number("--min-final-gain", job::PrepassParameters::kMinFinalGain, -1e9, 1);
  for (const absl::Status& s :
       {seeds.status(), reference_spp.status(), threads.status(), spp_flag.status(),
        prepass_spp.status(), passes.status(), epsilon.status(), fallback.status(),
        sigma_s.status(), min_image_gain.status(), min_final_gain.status()}) {
    if (!s.ok()) return fail(s);
  }
  const bool cpu_clock = flags->get("--clock", "cpu") == "cpu";
  auto insets = default_insets();
  for (absl::string_view item : absl::StrSplit(flags->get("--inset", ""), ';', absl::SkipEmpty())) {
    const std::vector<std::string> kv = absl::StrSplit(item, '=');
    if (kv.size() != 2) {
      return fail(
          absl::InvalidArgumentError(absl::StrCat("--inset '", item, "': want NAME=x,y,w,h")));
    }
    auto crop = parse_crop(kv[1]);
    if (!crop.ok()) return fail(crop.status());
    insets.insert({kv[0], {absl::StrCat("inset ", kv[1]), *crop}});
  }
  const std::filesystem::path cache_dir =
      flags->get("--cache-dir", std::filesystem::temp_directory_path().string());
  const std::string dump_dir = flags->get("--dump", "");
  if (!dump_dir.empty()) std::filesystem::create_directories(dump_dir);
  std::ofstream csv;
  if (const std::string path = flags->get("--csv", ""); !path.empty()) {
    csv.open(path);
    if (!csv) return fail(absl::InvalidArgumentError(absl::StrCat("cannot write ", path)));
    csv << "scene,method,seed,spp,seconds,prepass_seconds,region,mse,rgb_mse\n";
  }

  worker::EmbreeDevice device;
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  std::printf(
      "| scene | region | spp | default s | prepass s (share) | passes | predicted gain | "
      "measured gain per sample | per sample | equal time | RGB per sample | RGB equal time "
      "| α histogram (0, ¼, ½, ¾, 1−ε) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const std::filesystem::path& scene_path : scenes) {
    auto scene = load_bench_scene(scene_path);
    if (!scene.ok()) return fail(scene.status());
    const scene::SceneDescription& d = scene->description;
    const std::string name = scene_path.filename().string();
    coordinator::LocalRenderOptions base;
    base.render.integrator = job::IntegratorKind::kHero;
    base.render.bins = d.film.bins.value_or(64);
    base.render.max_depth = d.integrator.max_depth;
    base.width = d.film.x_resolution;
    base.height = d.film.y_resolution;
    base.spp =
        *spp_flag > 0 ? std::uint64_t(*spp_flag) : std::uint64_t(d.sampler.samples_per_pixel);
    base.threads = int(*threads);
    if (flags->get("--sampler", "sobol") == "independent") {
      base.render.sampler = job::SamplerKind::kIndependent;
    }

    job::PrepassParameters params;
    params.passes = int(*passes);
    params.epsilon = *epsilon;
    params.fallback = *fallback;
    params.sigma_s = *sigma_s;
    params.min_image_gain = *min_image_gain;
    params.min_final_gain = *min_final_gain;
    params.spp = *prepass_spp > 0
                     ? std::uint32_t(*prepass_spp)
                     : job::budgeted_prepass_spp(base.spp, params.passes, params.image_scaled);
    if (params.spp == 0) {
      std::printf(
          "| %s | – | %llu | – | no prepass: the budget is under %u spp | | | | | | | | |\n",
          name.c_str(), (unsigned long long)base.spp, job::kMinBudgetedSpp);
      std::fflush(stdout);
      continue;  // before the reference, which would not be used
    }
    coordinator::LocalRenderOptions reference_options = base;
    reference_options.spp = std::uint64_t(*reference_spp);
    reference_options.render.seed = 0x5eed;
    reference_options.render.sampler = job::SamplerKind::kIndependent;
    auto reference =
        cached_reference(device, *scene, reference_options, cache_dir, "prepass-scenes");
    if (!reference.ok()) return fail(reference.status());
    std::vector<Region> regions = {{"whole image", std::nullopt}};
    for (auto [it, end] = insets.equal_range(name); it != end; ++it) {
      regions.push_back({it->second.first, it->second.second});
    }
    for (Region& r : regions) {
      auto floor = reference->floor(r.crop);
      auto rgb_floor = rgb_error(reference->half, reference->image, cmf, r.crop);
      if (!floor.ok()) return fail(floor.status());
      if (!rgb_floor.ok()) return fail(rgb_floor.status());
      r.floor = floor->mse;
      r.rgb_floor = rgb_floor->mse;
    }

    std::vector<Run> runs[2];  // 0: default, 1: prepass
    std::vector<double> default_pixels, prepass_pixels;
    std::optional<coordinator::PixelTableImage> tables;
    for (int s = 0; s < int(*seeds); ++s) {
      for (int m = 0; m < 2; ++m) {
        coordinator::LocalRenderOptions o = base;
        o.render.seed = 1 + std::uint64_t(s);
        if (m == 1) {
          o.prepass = params;
          o.keep_prepass_tables = true;
        }
        auto timed = timed_render(device, *scene, o);
        if (!timed.ok()) return fail(timed.status());
        Run r;
        r.seconds = clock_seconds(*timed, cpu_clock);
        r.prepass_seconds = timed->wall_seconds > 0
                                ? r.seconds * std::min(1.0, timed->result.stats.prepass_seconds /
                                                                timed->wall_seconds)
                                : 0.0;
        r.outcome = timed->result.stats.prepass;
        for (double v : timed->result.statistics.variance_of_mean) r.s2n += v;
        r.s2n /= double(timed->result.statistics.variance_of_mean.size());
        for (const Region& region : regions) {
          auto e = image::compare_spectral(timed->result.image, reference->image, region.crop);
          auto rgb = rgb_error(timed->result.image, reference->image, cmf, region.crop);
          if (!e.ok()) return fail(e.status());
          if (!rgb.ok()) return fail(rgb.status());
          r.mse.push_back(e->mse - region.floor);
          r.rgb_mse.push_back(rgb->mse - region.rgb_floor);
          if (csv) {
            csv << name << "," << (m ? "prepass" : "default") << "," << s + 1 << "," << o.spp << ","
                << r.seconds << "," << r.prepass_seconds << "," << region.name << ","
                << r.mse.back() << "," << r.rgb_mse.back() << "\n";
          }
        }
        std::vector<double> pe = pixel_errors(timed->result.image, reference->image);
        std::vector<double>& acc = m ? prepass_pixels : default_pixels;
        if (acc.empty()) acc.assign(pe.size(), 0.0);
        for (std::size_t i = 0; i < pe.size(); ++i) acc[i] += pe[i];
        if (m == 1 && !tables && timed->result.prepass_tables)
          tables = timed->result.prepass_tables;
        runs[m].push_back(std::move(r));
      }
    }
    auto mean = [&](int m, auto field) {
      double sum = 0;
      for (const Run& r : runs[m]) sum += field(r);
      return sum / double(runs[m].size());
    };
    const double t0 = mean(0, [](const Run& r) { return r.seconds; });
    const double t1 = mean(1, [](const Run& r) { return r.seconds; });
    const double tp = mean(1, [](const Run& r) { return r.prepass_seconds; });
    const coordinator::PrepassOutcome& o = *runs[1].front().outcome;
    std::string histogram;
    for (int a = 0; a < coordinator::kAlphaChoices; ++a) {
      absl::StrAppend(&histogram, a ? ", " : "", o.alpha_histogram[a]);
    }
    for (std::size_t g = 0; g < regions.size(); ++g) {
      const double e0 = mean(0, [&](const Run& r) { return r.mse[g]; });
      const double e1 = mean(1, [&](const Run& r) { return r.mse[g]; });
      const double c0 = mean(0, [&](const Run& r) { return r.rgb_mse[g]; });
      const double c1 = mean(1, [&](const Run& r) { return r.rgb_mse[g]; });
      const double predicted = o.stopped_early ? o.first_pass_gain : o.predicted_gain;
      std::printf(
          "| %s | %s | %llu | %.2f | %.2f (%.1f %%) | %d%s | %.3f | %.3f | %.3f | **%.3f** | "
          "%.3f | %.3f | %s |\n",
          name.c_str(), regions[g].name.c_str(), (unsigned long long)base.spp, t0, t1,
          100.0 * tp / t1, o.passes_run, o.stopped_early ? " (stopped)" : "",
          g == 0 ? predicted : NAN, 1.0 - e1 / e0, e1 / e0, (e1 * t1) / (e0 * t0), c1 / c0,
          (c1 * t1) / (c0 * t0), g == 0 ? histogram.c_str() : "");
      std::fflush(stdout);
    }
    if (tables) {
      // Predicted spectral MSE of each method at this spp from the tables' per-pixel variances
      // (per sample, summed over bins): Σ V / (spp · pixels · bins), beside the measured.
      double v0 = 0, v1 = 0;
      for (int y = 0; y < tables->height(); ++y) {
        for (int x = 0; x < tables->width(); ++x) {
          v0 += tables->predicted_default_variance(x, y);
          v1 += tables->predicted_variance(x, y);
        }
      }
      const double norm = double(base.spp) * tables->width() * tables->height() * base.render.bins;
      std::fprintf(stderr,
                   "%s: predicted MSE default %.4g, prepass %.4g; own s2/n %.4g, %.4g; measured "
                   "%.4g, %.4g\n",
                   name.c_str(), v0 / norm, v1 / norm, mean(0, [](const Run& r) { return r.s2n; }),
                   mean(1, [](const Run& r) { return r.s2n; }),
                   mean(0, [](const Run& r) { return r.mse[0]; }),
                   mean(1, [](const Run& r) { return r.mse[0]; }));
    }
    if (!dump_dir.empty() && tables) {
      const std::string stem = scene_path.stem().string();
      const int w = tables->width(), h = tables->height();
      absl::Status s = write_map(std::filesystem::path(dump_dir) / (stem + ".alpha.png"), w, h,
                                 [&](int x, int y) {
                                   const float v = tables->alpha_index(x, y) / 4.0f;
                                   return std::array<float, 3>{v, v, v};
                                 });
      if (s.ok()) {
        s = write_map(
            std::filesystem::path(dump_dir) / (stem + ".predicted.png"), w, h, [&](int x, int y) {
              const float v0 = tables->predicted_default_variance(x, y);
              const float g = v0 > 0 ? 1.0f - tables->predicted_variance(x, y) / v0 : 0.0f;
              return std::array<float, 3>{g, g, g};
            });
      }
      if (s.ok()) {
        s = write_map(std::filesystem::path(dump_dir) / (stem + ".measured.png"), w, h,
                      [&](int x, int y) {
                        double a = 0, b = 0;
                        for (int yy = y / 4 * 4; yy < std::min(h, y / 4 * 4 + 4); ++yy) {
                          for (int xx = x / 4 * 4; xx < std::min(w, x / 4 * 4 + 4); ++xx) {
                            a += prepass_pixels[std::size_t(yy) * w + xx];
                            b += default_pixels[std::size_t(yy) * w + xx];
                          }
                        }
                        const float g = b > 0 ? float(1.0 - a / b) : 0.0f;
                        return g >= 0 ? std::array<float, 3>{g, g, g}
                                      : std::array<float, 3>{std::min(1.0f, -g), 0.0f, 0.0f};
                      });
      }
      if (!s.ok()) return fail(s);
    }
  }
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
