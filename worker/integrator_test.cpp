#include "worker/integrator.h"

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/testing/chi_square.h"
#include "worker/testing/bin_stats.h"
#include "worker/tile_renderer.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

const fs::path kTestData = fs::path(PRISM_SOURCE_DIR) / "worker" / "testdata";

class IntegratorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    library_ = new spectral::SpectrumLibrary(*spectral::SpectrumLibrary::load_builtin());
    device_ = new EmbreeDevice();
  }
  static void TearDownTestSuite() {
    delete device_;
    delete library_;
  }

  static scene::SceneDescription load(const std::string& name) {
    scene::LoadOptions options;
    auto loaded = scene::load_scene(kTestData / name, options);
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    return loaded->description;
  }

  static std::unique_ptr<RenderScene> build(const scene::SceneDescription& desc,
                                            const RenderOptions& options) {
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

  static spectral::SpectrumLibrary* library_;
  static EmbreeDevice* device_;
};

spectral::SpectrumLibrary* IntegratorTest::library_ = nullptr;
EmbreeDevice* IntegratorTest::device_ = nullptr;

using testing::BinStats;
using testing::bin_stats;

// Two-sample z statistics per bin between independent renders.
struct Agreement {
  double max_z = 0;        // largest |a − b| / combined standard error
  double chi2_p_value = 1; // Σ z² against chi-square with one degree of freedom per bin
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
  for (IntegratorKind kind : {IntegratorKind::kUniform, IntegratorKind::kHero}) {
    RenderOptions options;
    options.integrator = kind;
    options.bins = 8;
    options.max_depth = 100;
    options.seed = 11;
    auto scene = build(desc, options);
    ASSERT_TRUE(scene);
    auto stats = bin_stats(render(*scene, kind == IntegratorKind::kUniform ? 1024 : 256));
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
      RenderOptions options;
      options.integrator = IntegratorKind::kUniform;
      options.bins = 16;
      options.max_depth = 8;
      options.seed = 1;
      auto scene = build(load("unbiased.pbrt"), options);
      return bin_stats(render(*scene, 4096));
    }();
    return stats;
  }
  static BinStats run(const RenderOptions& overrides) {
    RenderOptions options = overrides;
    options.bins = 16;
    options.max_depth = 8;
    auto scene = build(load("unbiased.pbrt"), options);
    return bin_stats(render(*scene, 1024));
  }
};

// `hero` with every wavelength pdf option agrees with the single-wavelength tracer per bin.
TEST_F(AgreementTest, HeroAgreesWithUniformForEveryWavelengthPdf) {
  const BinStats& ref = reference();
  std::uint64_t seed = 100;
  for (SpectralPdfKind sensor : {SpectralPdfKind::kFlat, SpectralPdfKind::kVisible}) {
    for (EmitterPdfKind emitter : {EmitterPdfKind::kUniform, EmitterPdfKind::kEmitters}) {
      RenderOptions options;
      options.integrator = IntegratorKind::kHero;
      options.spectral_pdf = sensor;
      options.emitter_pdf = emitter;
      options.seed = seed++;
      expect_agreement(run(options), ref,
                       "sensor " + std::to_string(int(sensor)) + " emitter " +
                           std::to_string(int(emitter)));
    }
  }
  for (double se : ref.standard_error) EXPECT_GT(se, 0.0);
}

// Emitter selection with and without the spectral unit-emission factor, for every base pmf,
// stays unbiased.
TEST_F(AgreementTest, EmitterSelectionVariantsAgreeWithUniform) {
  const BinStats& ref = reference();
  std::uint64_t seed = 200;
  for (LightSelectionKind base :
       {LightSelectionKind::kUniform, LightSelectionKind::kPower, LightSelectionKind::kSpatial}) {
    for (bool spectral_factor : {true, false}) {
      RenderOptions options;
      options.integrator = IntegratorKind::kHero;
      options.light_selection = base;
      options.spectral_light_selection = spectral_factor;
      options.seed = seed++;
      expect_agreement(run(options), ref,
                       "base " + std::to_string(int(base)) + " spectral factor " +
                           std::to_string(spectral_factor));
    }
  }
}

// The uniform tracer with a non-uniform wavelength pdf and independent samples also agrees
// (checks the 1/p(λ) weighting and the sampler choice).
TEST_F(AgreementTest, UniformWithVisiblePdfAndIndependentSamplerAgrees) {
  RenderOptions options;
  options.integrator = IntegratorKind::kUniform;
  options.spectral_pdf = SpectralPdfKind::kVisible;
  options.sampler = SamplerKind::kIndependent;
  options.seed = 300;
  expect_agreement(run(options), reference(), "uniform, visible pdf, independent sampler");
}

TEST_F(IntegratorTest, OutputDoesNotDependOnThreadsOrTiles) {
  auto desc = load("unbiased.pbrt");
  RenderOptions options;
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
  const fs::path file = fs::path(::testing::TempDir()) / name;
  std::ofstream(file) << text;
  scene::LoadOptions options;
  auto loaded = scene::load_scene(file, options);
  EXPECT_TRUE(loaded.ok()) << loaded.status();
  return loaded.ok() ? loaded->description : scene::SceneDescription();
}

RenderOptions direct_light_options(std::uint64_t seed) {
  RenderOptions options;
  options.integrator = IntegratorKind::kUniform;
  options.sampler = SamplerKind::kIndependent;
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
  auto run = [&](LightSelectionKind base, std::uint64_t seed) {
    RenderOptions options = direct_light_options(seed);
    options.light_selection = base;
    auto scene = build(desc, options);
    return bin_stats(render(*scene, 1024));
  };
  BinStats uniform = run(LightSelectionKind::kUniform, 400);
  BinStats power = run(LightSelectionKind::kPower, 401);
  expect_agreement(uniform, power, "sphere light on a floor, uniform vs power selection");
  for (double m : uniform.mean) EXPECT_GT(m, 0.0);
}

}  // namespace
}  // namespace prism::worker
