#include "worker/integrator.h"

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "services/job/trace_counters.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/testing/chi_square.h"
#include "tests/testing/test_dir.h"
#include "worker/testing/bin_stats.h"
#include "worker/testing/skewed_tables.h"
#include "worker/testing/tracer_test.h"
#include "worker/tile_renderer.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

// The coordinator names a farm job's counters from job::kTraceCounterNames without linking the
// tracer: the same names, in the same order, as a local render's report.
TEST(TraceCountersTest, TheCoordinatorsNamesAreTheTracersCounters) {
  const auto list = counter_list(TraceCounters{});
  ASSERT_EQ(list.size(), job::kTraceCounterNames.size());
  for (std::size_t i = 0; i < list.size(); ++i)
    EXPECT_EQ(list[i].first, job::kTraceCounterNames[i]);
}

const fs::path kTestData = fs::path(PRISM_SOURCE_DIR) / "worker" / "testdata";

class IntegratorTest : public testing::TracerTest {
 protected:
  static scene::SceneDescription load(const std::string& name) {
    scene::LoadOptions options;
    auto loaded = scene::load_scene(kTestData / name, options);
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    return loaded->description;
  }

  static std::unique_ptr<RenderScene> build(const scene::SceneDescription& desc,
                                            const job::RenderOptions& options) {
    auto built = RenderScene::build(*device_, desc, *library_, options, desc.film.x_resolution,
                                    desc.film.y_resolution);
    EXPECT_TRUE(built.ok()) << built.status();
    return std::move(*built);
  }

  static image::TileResult render(const RenderScene& scene, std::uint64_t spp,
                                  std::uint32_t pass = 0) {
    TileRenderer renderer(scene);
    RenderTask task{{0, 0, scene.camera().width(), scene.camera().height()}, {0, spp}, pass};
    auto result = renderer.render(task, nullptr);
    EXPECT_TRUE(result.ok()) << result.status();
    return std::move(*result);
  }
};

using testing::bin_stats;
using testing::BinStats;

// Two-sample z statistics per bin between independent renders.
struct Agreement {
  double max_z = 0;         // largest |a − b| / combined standard error
  double chi2_p_value = 1;  // Σ z² against chi-square with one degree of freedom per bin
};

Agreement agreement(const BinStats& a, const BinStats& b) {
  Agreement result;
  double chi2 = 0;
  for (std::size_t i = 0; i < a.mean.size(); ++i) {
    double se = std::hypot(a.standard_error[i], b.standard_error[i]);
    double z = (a.mean[i] - b.mean[i]) / se;
    result.max_z = std::max(result.max_z, std::abs(z));
    chi2 += z * z;
  }
  result.chi2_p_value = spectral::testing::chi_square_survival(chi2, int(a.mean.size()));
  return result;
}

// Five standard errors per bin, and the joint chi-square of all bins at p > 1e-4: false
// failures are rarer than 1e-4 per comparison, while a bias of a few percent in one bin, or a
// smaller one spread over many, is caught (the reference's relative errors are 1-2 %).
constexpr double kZ = 5.0;
constexpr double kMinPValue = 1e-4;

void expect_agreement(const BinStats& a, const BinStats& b, const std::string& what) {
  Agreement r = agreement(a, b);
  EXPECT_LT(r.max_z, kZ) << what;
  EXPECT_GT(r.chi2_p_value, kMinPValue) << what;
}

TEST_F(IntegratorTest, WhiteFurnaceReturnsTheEnvironment) {
  auto desc = load("furnace.pbrt");
  for (job::IntegratorKind kind : {job::IntegratorKind::kUniform, job::IntegratorKind::kHero}) {
    job::RenderOptions options;
    options.integrator = kind;
    options.bins = 8;
    options.max_depth = 100;
    options.seed = 11;
    auto scene = build(desc, options);
    ASSERT_TRUE(scene);
    auto stats = bin_stats(render(*scene, kind == job::IntegratorKind::kUniform ? 1024 : 256));
    for (int b = 0; b < 8; ++b) {
      EXPECT_LT(std::abs(stats.mean[b] - 1.0), kZ * stats.standard_error[b] + 1e-3)
          << "bin " << b << " mean " << stats.mean[b] << " se " << stats.standard_error[b];
      EXPECT_LT(stats.standard_error[b], 0.01) << "bin " << b;
    }
  }
}

class AgreementTest : public IntegratorTest {
 protected:
  static const BinStats& reference() {
    static const BinStats stats = [] {
      job::RenderOptions options;
      options.integrator = job::IntegratorKind::kUniform;
      options.bins = 16;
      options.max_depth = 8;
      options.seed = 1;
      auto scene = build(load("unbiased.pbrt"), options);
      return bin_stats(render(*scene, 4096));
    }();
    return stats;
  }
  static BinStats run(const job::RenderOptions& overrides) {
    job::RenderOptions options = overrides;
    options.bins = 16;
    options.max_depth = 8;
    auto scene = build(load("unbiased.pbrt"), options);
    return bin_stats(render(*scene, 1024));
  }
  // Like run(), the whole image as one task shaped by `shape` (tables, prepass).
  template <typename Shape>
  static BinStats run_task(const job::RenderOptions& overrides, Shape&& shape) {
    job::RenderOptions options = overrides;
    options.bins = 16;
    options.max_depth = 8;
    auto scene = build(load("unbiased.pbrt"), options);
    RenderTask task{{0, 0, scene->camera().width(), scene->camera().height()}, {0, 1024}, 0};
    shape(task);
    auto result = TileRenderer(*scene).render(task, nullptr);
    EXPECT_TRUE(result.ok()) << result.status();
    return bin_stats(*result);
  }
};

// `hero` with every wavelength pdf option agrees with the single-wavelength tracer per bin.
TEST_F(AgreementTest, HeroAgreesWithUniformForEveryWavelengthPdf) {
  const BinStats& ref = reference();
  std::uint64_t seed = 100;
  for (job::SpectralPdfKind sensor :
       {job::SpectralPdfKind::kFlat, job::SpectralPdfKind::kVisible}) {
    for (job::EmitterPdfKind emitter :
         {job::EmitterPdfKind::kUniform, job::EmitterPdfKind::kEmitters}) {
      job::RenderOptions options;
      options.integrator = job::IntegratorKind::kHero;
      options.spectral_pdf = sensor;
      options.emitter_pdf = emitter;
      options.seed = seed++;
      expect_agreement(
          run(options), ref,
          "sensor " + std::to_string(int(sensor)) + " emitter " + std::to_string(int(emitter)));
    }
  }
  for (double se : ref.standard_error) EXPECT_GT(se, 0.0);
}

// Emitter selection with and without the spectral unit-emission factor, for every base pmf,
// stays unbiased.
TEST_F(AgreementTest, EmitterSelectionVariantsAgreeWithUniform) {
  const BinStats& ref = reference();
  std::uint64_t seed = 200;
  for (job::LightSelectionKind base :
       {job::LightSelectionKind::kUniform, job::LightSelectionKind::kPower,
        job::LightSelectionKind::kSpatial}) {
    for (bool spectral_factor : {true, false}) {
      job::RenderOptions options;
      options.integrator = job::IntegratorKind::kHero;
      options.light_selection = base;
      options.spectral_light_selection = spectral_factor;
      options.seed = seed++;
      expect_agreement(run(options), ref,
                       "base " + std::to_string(int(base)) + " spectral factor " +
                           std::to_string(spectral_factor));
    }
  }
}

// `hero` sampling every pixel from its own table, deliberately unlike the default distribution
// (spikes and steep ramps that move from pixel to pixel over the 16 bins, the default's shape
// inside each bin, some pixels on the default), agrees with the single-wavelength tracer per bin:
// lanes are drawn and weighted by the pixel's table only. Both ways of sampling a table: its
// composite CDF (a task of 1024 samples per pixel) and its two searches (a task of fewer than
// CompositeCdf::kMinSamples).
TEST_F(AgreementTest, HeroWithPerPixelTablesAgreesWithUniform) {
  const spectral::PixelTables tables =
      testing::skewed_tables(24, 24, 16, [](int x, int y) { return (x * 7 + y) % 11 == 0; });
  ASSERT_GT(tables.default_pixels(), 0);
  static_assert(spectral::CompositeCdf::kMinSamples > 96 &&
                spectral::CompositeCdf::kMinSamples <= 1024);
  job::RenderOptions options;
  options.integrator = job::IntegratorKind::kHero;
  options.seed = 150;
  expect_agreement(run_task(options, [&](RenderTask& task) { task.tables = &tables; }), reference(),
                   "hero with per-pixel tables, composite");
  options.seed = 151;
  expect_agreement(run_task(options,
                            [&](RenderTask& task) {
                              task.tables = &tables;
                              task.samples = {0, 96};
                            }),
                   reference(), "hero with per-pixel tables, two searches");
}

// A prepass task of a `uniform` job traces 4 hero lanes (without early stop it is an unbiased
// render), with tables too.
TEST_F(AgreementTest, PrepassTasksOfAUniformJobAreUnbiasedHeroRenders) {
  const spectral::PixelTables tables = testing::skewed_tables(24, 24, 16);
  job::RenderOptions options;
  options.integrator = job::IntegratorKind::kUniform;
  options.seed = 160;
  expect_agreement(run_task(options,
                            [&](RenderTask& task) {
                              task.pass = 1;
                              task.prepass = true;
                            }),
                   reference(), "prepass of a uniform job");
  options.seed = 161;
  expect_agreement(run_task(options,
                            [&](RenderTask& task) {
                              task.pass = 2;
                              task.prepass = true;
                              task.tables = &tables;
                            }),
                   reference(), "prepass of a uniform job with tables");
}

// The uniform tracer with a non-uniform wavelength pdf and independent samples also agrees
// (checks the 1/p(λ) weighting and the sampler choice).
TEST_F(AgreementTest, UniformWithVisiblePdfAndIndependentSamplerAgrees) {
  job::RenderOptions options;
  options.integrator = job::IntegratorKind::kUniform;
  options.spectral_pdf = job::SpectralPdfKind::kVisible;
  options.sampler = job::SamplerKind::kIndependent;
  options.seed = 300;
  expect_agreement(run(options), reference(), "uniform, visible pdf, independent sampler");
}

TEST_F(IntegratorTest, OutputDoesNotDependOnThreadsOrTiles) {
  auto desc = load("unbiased.pbrt");
  job::RenderOptions options;
  options.bins = 16;
  auto scene = build(desc, options);
  TileRenderer renderer(*scene);
  RenderTask whole{{0, 0, 24, 24}, {0, 8}, 0};
  auto one_thread = tbb::task_arena(1).execute([&] { return *renderer.render(whole, nullptr); });
  auto two_threads = tbb::task_arena(2).execute([&] { return *renderer.render(whole, nullptr); });
  EXPECT_TRUE(one_thread == two_threads);
  // Four quarter tiles give the same numbers as the whole image (a pixel's samples do not
  // depend on which tile it is in).
  for (auto [x0, y0] : {std::pair{0, 0}, {12, 0}, {0, 12}, {12, 12}}) {
    RenderTask quarter{{x0, y0, x0 + 12, y0 + 12}, {0, 8}, 0};
    auto part = *renderer.render(quarter, nullptr);
    for (int y = y0; y < y0 + 12; ++y) {
      for (int x = x0; x < x0 + 12; ++x) {
        for (int b = 0; b < 16; ++b) {
          ASSERT_EQ(part.sum(x, y, b), one_thread.sum(x, y, b));
          ASSERT_EQ(part.sum_squares(x, y, b), one_thread.sum_squares(x, y, b));
        }
      }
    }
  }
}

// A sphere light of radius 1 resting on a floor 200 wide (so the ray offset, scaled by the scene,
// is large next to the sphere), seen from straight above a patch of floor beside it, the sphere
// itself out of view. Next to the contact most of the visible sphere faces the floor: a shadow
// ray that left the floor by the offset but kept the direction sampled from the floor point ran
// parallel to the true segment, entered the sphere before the sampled point and occluded it.
// NEE lost that light while MIS still counted on it (the floor was ~30 % too dark, and the
// image depended on the light-selection pmf).
constexpr char kSphereOnFloor[] = R"(LookAt 1.5 3 0  1.5 0 0  0 0 1
Camera "perspective" "float fov" 20
Film "spectral" "integer xresolution" 16 "integer yresolution" 16 "integer nbuckets" 4
WorldBegin
Material "diffuse" "float reflectance" 0.5
Shape "trianglemesh" "point3 P" [-100 0 -100  100 0 -100  100 0 100  -100 0 100]
  "integer indices" [0 1 2 0 2 3]
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" [360 1 830 1]
  Translate 0 1 0
  Shape "sphere" "float radius" 1
AttributeEnd
)";

scene::SceneDescription load_text(const std::string& name, const std::string& text) {
  const fs::path file = prism::testing::test_dir() / name;
  std::ofstream(file) << text;
  scene::LoadOptions options;
  auto loaded = scene::load_scene(file, options);
  EXPECT_TRUE(loaded.ok()) << loaded.status();
  return loaded.ok() ? loaded->description : scene::SceneDescription();
}

job::RenderOptions direct_light_options(std::uint64_t seed) {
  job::RenderOptions options;
  options.integrator = job::IntegratorKind::kUniform;
  options.sampler = job::SamplerKind::kIndependent;
  options.spectral_light_selection = false;
  options.bins = 4;
  options.max_depth = 1;  // direct light on the floor: NEE and BSDF sampling, nothing else
  options.seed = seed;
  return options;
}

// The floor's radiance is exact: a Lambertian sphere of radiance L entirely above the plane
// gives irradiance πL(R/d)²cos θ = πL·R³/d³ at distance d from its centre, so the floor
// (reflectance ρ) shows ρ·L·R³/d³. The oracle averages it over each pixel's footprint.
TEST_F(IntegratorTest, SphereLightOnFloorMatchesAnalyticRadiance) {
  auto desc = load_text("sphere_on_floor.pbrt", kSphereOnFloor);
  auto scene = build(desc, direct_light_options(500));
  ASSERT_TRUE(scene);
  ASSERT_EQ(scene->lights().size(), 1u);
  SampledWavelengths lambda(1);
  lambda.set(0, 550.0f, 1.0f);
  const Vec3f up(0, 1, 0);
  const double radiance = std::get<AreaLight>(scene->lights()[0]).radiance(up, up, lambda)[0];
  const Vec3f centre(0, 1, 0);
  const int width = scene->camera().width(), height = scene->camera().height();
  constexpr int kStrata = 32;
  double expected = 0;
  for (int py = 0; py < height; ++py) {
    for (int px = 0; px < width; ++px) {
      for (int j = 0; j < kStrata; ++j) {
        for (int i = 0; i < kStrata; ++i) {
          Ray ray = scene->camera().generate_ray(
              {px + (i + 0.5f) / kStrata, py + (j + 0.5f) / kStrata}, {0.5f, 0.5f});
          ASSERT_LT(ray.direction.y, 0.0f);
          Vec3f x = ray.origin + ray.direction * (-ray.origin.y / ray.direction.y);
          double d = length(x - centre);
          expected += 0.5 * radiance / (d * d * d);
        }
      }
    }
  }
  expected /= double(width) * height * kStrata * kStrata;
  BinStats stats = bin_stats(render(*scene, 1024));
  for (int b = 0; b < 4; ++b) {
    EXPECT_LT(std::abs(stats.mean[b] - expected), kZ * stats.standard_error[b])
        << "bin " << b << " mean " << stats.mean[b] << " expected " << expected << " se "
        << stats.standard_error[b];
  }
}

// The reported symptom: with a dim second light the sphere's selection pmf is 1/2 under
// `uniform` and nearly 1 under `power`; any pmf must give the same expectation.
TEST_F(IntegratorTest, LightSelectionPmfDoesNotBiasSphereLightOnFloor) {
  auto desc = load_text("sphere_on_floor_two_lights.pbrt", std::string(kSphereOnFloor) + R"(
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" [360 1 830 1] "float scale" 0.01
  Shape "trianglemesh" "point3 P" [-1 20 -1  1 20 -1  1 20 1  -1 20 1]
    "integer indices" [0 1 2 0 2 3]
AttributeEnd
)");
  auto run = [&](job::LightSelectionKind base, std::uint64_t seed) {
    job::RenderOptions options = direct_light_options(seed);
    options.light_selection = base;
    auto scene = build(desc, options);
    return bin_stats(render(*scene, 1024));
  };
  BinStats uniform = run(job::LightSelectionKind::kUniform, 400);
  BinStats power = run(job::LightSelectionKind::kPower, 401);
  expect_agreement(uniform, power, "sphere light on a floor, uniform vs power selection");
  for (double m : uniform.mean) EXPECT_GT(m, 0.0);
}

// TraceOptions::lanes overrides the job's C (prepass tasks trace 4 lanes for any job).
TEST_F(IntegratorTest, TraceOptionsForceTheLaneCount) {
  job::RenderOptions options;
  options.integrator = job::IntegratorKind::kUniform;
  options.bins = 16;
  auto scene = build(load("unbiased.pbrt"), options);
  ASSERT_TRUE(scene);
  PathIntegrator integrator(*scene);
  TraceCounters counters;
  EXPECT_EQ(integrator.trace(12, 12, 1, 0, scene->wavelength_pdf(), counters).lanes, 1);
  SampleContribution c =
      integrator.trace(12, 12, 1, 0, scene->wavelength_pdf(), counters, nullptr, {4, false});
  ASSERT_EQ(c.lanes, 4);
  // CMIS rotation: the lanes are spread over the spectrum, not one wavelength four times.
  EXPECT_FALSE(c.bin[0] == c.bin[1] && c.bin[1] == c.bin[2] && c.bin[2] == c.bin[3]);
}

// Early stop (integrator.h). A box of constant-reflectance grey walls lit by one emitter of a
// constant spectrum: nothing on any path depends on wavelength.
constexpr char kGreyBox[] = R"(LookAt 0 1 -2.5  0 1 0  0 1 0
Camera "perspective" "float fov" 60
Film "spectral" "integer xresolution" 12 "integer yresolution" 12 "integer nbuckets" 8
WorldBegin
Material "diffuse" "float reflectance" 0.7
Shape "trianglemesh" "point3 P" [-2 0 -3  2 0 -3  2 0 2  -2 0 2] "integer indices" [0 1 2 0 2 3]
Shape "trianglemesh" "point3 P" [-2 2 -3  -2 2 2  2 2 2  2 2 -3] "integer indices" [0 1 2 0 2 3]
Shape "trianglemesh" "point3 P" [-2 0 2  2 0 2  2 2 2  -2 2 2] "integer indices" [0 1 2 0 2 3]
Shape "trianglemesh" "point3 P" [-2 0 -3  -2 0 2  -2 2 2  -2 2 -3] "integer indices" [0 1 2 0 2 3]
Shape "trianglemesh" "point3 P" [2 0 -3  2 2 -3  2 2 2  2 0 2] "integer indices" [0 1 2 0 2 3]
AttributeBegin
  AreaLightSource "diffuse" "float L" 5
  Translate 0 1.4 0.5
  Shape "sphere" "float radius" 0.3
AttributeEnd
)";

job::RenderOptions early_stop_options() {
  job::RenderOptions options;
  options.integrator = job::IntegratorKind::kHero;
  options.bins = 8;
  options.max_depth = 12;
  options.rr_min_depth = 6;  // roulette would end many paths before the stop otherwise
  options.seed = 600;
  return options;
}

struct PrepassRender {
  image::TileResult result;
  TileStats stats;
};

PrepassRender render_prepass(const RenderScene& scene, bool early_stop) {
  RenderTask task{{0, 0, scene.camera().width(), scene.camera().height()}, {0, 16}, 1};
  task.prepass = true;
  task.early_stop = early_stop;
  TileStats stats;
  auto result = TileRenderer(scene).render(task, &stats);
  EXPECT_TRUE(result.ok()) << result.status();
  return {std::move(*result), stats};
}

// With no wavelength-dependent event anywhere, every path that reaches its vertex after 3
// scattering events stops there: the prepass is exactly one with max_depth 3, sample for
// sample, and traces far fewer rays than the full-depth prepass.
TEST_F(IntegratorTest, EarlyStopEndsGreyPathsAfterThreeBounces) {
  auto desc = load_text("grey_box.pbrt", kGreyBox);
  job::RenderOptions options = early_stop_options();
  auto scene = build(desc, options);
  ASSERT_TRUE(scene);
  for (const ShapeInfo* info : {&scene->shape(0), &scene->shape(5)}) {
    EXPECT_FALSE(info->wavelength_dependent);
  }
  PrepassRender stopped = render_prepass(*scene, true);
  PrepassRender full = render_prepass(*scene, false);
  options.max_depth = kEarlyStopBounces;
  PrepassRender shallow = render_prepass(*build(desc, options), false);

  EXPECT_TRUE(stopped.result == shallow.result);
  EXPECT_FALSE(stopped.result == full.result);
  EXPECT_GT(stopped.stats.counters.early_stops, 0u);
  EXPECT_EQ(full.stats.counters.early_stops, 0u);
  EXPECT_EQ(stopped.stats.counters.rays, shallow.stats.counters.rays);
  EXPECT_LT(double(stopped.stats.counters.rays), 0.75 * double(full.stats.counters.rays));
  std::cout << "rays with early stop " << stopped.stats.counters.rays << ", without "
            << full.stats.counters.rays << "; paths stopped " << stopped.stats.counters.early_stops
            << "\n";
}

// The same box seen from inside a dispersive glass sphere around the camera: every path's first
// vertex is wavelength dependent, so no path stops early and the prepass is the full one.
TEST_F(IntegratorTest, EarlyStopKeepsPathsThatMetADispersiveVertex) {
  auto desc = load_text("grey_box_glass.pbrt", std::string(kGreyBox) + R"(
AttributeBegin
  Material "dielectric" "float sellmeier" [1.73759695 0.313747346 1.89878101 0.013188707 0.0623068142 155.23629]
  Translate 0 1 -2.5
  Shape "sphere" "float radius" 0.2
AttributeEnd
)");
  auto scene = build(desc, early_stop_options());
  ASSERT_TRUE(scene);
  EXPECT_TRUE(scene->shape(6).wavelength_dependent);
  PrepassRender stopped = render_prepass(*scene, true);
  PrepassRender full = render_prepass(*scene, false);
  EXPECT_EQ(stopped.stats.counters.early_stops, 0u);
  EXPECT_TRUE(stopped.result == full.result);
  EXPECT_GT(full.stats.counters.lane_splits, 0u);
}

// A coloured emitter or material is an event too (the flag is per shape).
TEST_F(IntegratorTest, ColouredEmittersAndMaterialsAreWavelengthDependentHits) {
  auto desc = load_text("coloured_box.pbrt", R"(LookAt 0 1 -2.5  0 1 0  0 1 0
Camera "perspective" "float fov" 60
Film "spectral" "integer xresolution" 4 "integer yresolution" 4 "integer nbuckets" 8
WorldBegin
Material "diffuse" "float reflectance" 0.7
Shape "trianglemesh" "point3 P" [-2 0 -3  2 0 -3  2 0 2  -2 0 2] "integer indices" [0 1 2 0 2 3]
Material "diffuse" "rgb reflectance" [0.7 0.2 0.1]
Shape "trianglemesh" "point3 P" [-2 2 -3  -2 2 2  2 2 2  2 2 -3] "integer indices" [0 1 2 0 2 3]
Material "diffuse" "float reflectance" 0.7
AttributeBegin
  AreaLightSource "diffuse" "blackbody L" 3000
  Shape "sphere" "float radius" 0.3
AttributeEnd
)");
  auto scene = build(desc, early_stop_options());
  ASSERT_TRUE(scene);
  const bool dependent[] = {false, true, true};  // grey floor, coloured wall, blackbody lamp
  for (int shape = 0; shape < 3; ++shape) {
    EXPECT_EQ(scene->shape(shape).wavelength_dependent, dependent[shape]) << "shape " << shape;
  }
}

}  // namespace
}  // namespace prism::worker
