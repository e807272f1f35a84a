#include "coordinator/local_render.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <vector>

#include "coordinator/outputs.h"
#include "services/base/status.h"
#include "services/scene/scene_loader.h"

namespace prism::coordinator {
namespace {

class LocalRenderTest : public testing::Test {
 protected:
  void SetUp() override {
    auto library = spectral::SpectrumLibrary::load_builtin();
    ASSERT_TRUE(library.ok()) << library.status();
    library_ = std::make_unique<spectral::SpectrumLibrary>(*std::move(library));
    scene::LoadOptions load = scene::with_library_names(*library_);
    auto loaded = scene::load_scene(
        std::filesystem::path(PRISM_SOURCE_DIR) / "scenes/cornell-two-lights.pbrt", load);
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    scene_ = std::make_unique<scene::SceneDescription>(std::move(loaded->description));
  }

  LocalRenderOptions options(int threads, int tile, std::uint64_t per_task) const {
    LocalRenderOptions o;
    o.render.bins = 16;
    o.render.max_depth = 3;
    o.render.seed = 11;
    o.width = 24;
    o.height = 20;
    o.spp = 4;
    o.tile_size = tile;
    o.threads = threads;
    o.samples_per_task = per_task;
    return o;
  }

  absl::StatusOr<LocalRenderResult> render(const LocalRenderOptions& o,
                                           const std::atomic<bool>* cancel = nullptr) {
    PRISM_ASSIGN_OR_RETURN(auto r, LocalRender::create(device_, *scene_, *library_, o));
    return r->render(cancel);
  }

  worker::EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<scene::SceneDescription> scene_;
};

bool same_bits(std::span<const float> a, std::span<const float> b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

TEST_F(LocalRenderTest, SplitTasksAreDeterministicAcrossThreadsAndTiles) {
  auto a = render(options(1, 8, 1));
  ASSERT_TRUE(a.ok()) << a.status();
  auto b = render(options(2, 32, 1));
  ASSERT_TRUE(b.ok()) << b.status();
  auto c = render(options(2, 4, 1));
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_TRUE(same_bits(a->image.data(), b->image.data()));
  EXPECT_TRUE(same_bits(a->image.data(), c->image.data()));
  EXPECT_EQ(a->stats.tasks, 3u * 3u * 4u);
  EXPECT_EQ(a->stats.samples, 24u * 20u * 4u);
  EXPECT_EQ(a->stats.counters.camera_rays, 24u * 20u * 4u);
  EXPECT_EQ(a->stats.counters.rays, b->stats.counters.rays);
  // One thread finishes a tile's ranges in order: one tile in flight at a time.
  EXPECT_EQ(a->stats.peak_tiles_in_flight, 1);

  // The same samples summed in one task: equal up to the order of the double additions.
  auto whole = render(options(2, 16, 0));
  ASSERT_TRUE(whole.ok()) << whole.status();
  double total = 0;
  for (std::size_t i = 0; i < whole->image.data().size(); ++i) {
    const float x = whole->image.data()[i], y = a->image.data()[i];
    ASSERT_NEAR(x, y, 1e-5 * std::fabs(y) + 1e-30) << i;
    total += x;
  }
  EXPECT_GT(total, 0.0);
}

TEST_F(LocalRenderTest, StatisticsDescribeTheImage) {
  auto r = render(options(2, 8, 2));
  ASSERT_TRUE(r.ok()) << r.status();
  const int bins = r->image.bins();
  ASSERT_EQ(r->statistics.mean.size(), std::size_t(bins));
  std::vector<double> mean(bins, 0.0);
  for (int y = 0; y < r->image.height(); ++y)
    for (int x = 0; x < r->image.width(); ++x)
      for (int b = 0; b < bins; ++b) mean[b] += r->image.value(x, y, b);
  for (int b = 0; b < bins; ++b) {
    mean[b] /= r->image.width() * r->image.height();
    EXPECT_NEAR(r->statistics.mean[b], mean[b], 1e-6 * mean[b] + 1e-30) << b;
    EXPECT_GE(r->statistics.standard_error[b], 0.0);
  }
  EXPECT_EQ(r->statistics.pixels_with_error, 24u * 20u);
}

TEST_F(LocalRenderTest, ProgressIsMonotoneAndEndsAtTheTotal) {
  LocalRenderOptions o = options(2, 8, 1);
  o.progress_interval_seconds = 0;
  std::vector<RenderProgress> reports;
  o.progress = [&](const RenderProgress& p) { reports.push_back(p); };
  auto r = render(o);
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_FALSE(reports.empty());
  for (std::size_t i = 1; i < reports.size(); ++i) {
    EXPECT_GE(reports[i].samples_done, reports[i - 1].samples_done);
    EXPECT_GE(reports[i].seconds, reports[i - 1].seconds);
  }
  EXPECT_EQ(reports.back().samples_done, 24u * 20u * 4u);
  EXPECT_EQ(reports.back().samples_total, 24u * 20u * 4u);
}

TEST_F(LocalRenderTest, CancelledRendersReturnNoImage) {
  std::atomic<bool> cancel{true};
  auto r = render(options(2, 8, 1), &cancel);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kCancelled);
}

TEST_F(LocalRenderTest, RefusesSizesOutOfRange) {
  LocalRenderOptions o = options(1, 8, 0);
  o.width = 0;
  EXPECT_EQ(render(o).status().code(), absl::StatusCode::kInvalidArgument);
  o = options(1, 2, 0);
  EXPECT_EQ(render(o).status().code(), absl::StatusCode::kInvalidArgument);
  o = options(1, 8, 0);
  o.spp = 0;
  EXPECT_EQ(render(o).status().code(), absl::StatusCode::kInvalidArgument);
  o = options(-1, 8, 0);
  EXPECT_EQ(render(o).status().code(), absl::StatusCode::kInvalidArgument);
}

// A sodium-like line lamp (588–590.6 nm) over a grey floor, with a dispersive BK7 sphere: the
// case where RGB made from bin averages depended on --bins (a bin's spectrum taken as flat).
constexpr char kLineLamp[] = R"(LookAt 0 2 -5  0 0.5 0  0 1 0
Camera "perspective" "float fov" 40
WorldBegin
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" [587 0 588 1 590.6 1 591.6 0] "float scale" 6
  Translate 0 3 0
  Rotate 90 1 0 0
  Shape "bilinearmesh" "point3 P" [-1 -1 0  1 -1 0  -1 1 0  1 1 0]
AttributeEnd
Material "diffuse" "rgb reflectance" [0.5 0.5 0.5]
Shape "trianglemesh" "point3 P" [-4 0 -4  4 0 -4  4 0 4  -4 0 4] "integer indices" [0 1 2 0 2 3]
Material "dielectric" "spectrum eta" "glass-BK7"
Translate 0 0.8 0
Shape "sphere" "float radius" 0.8
)";

class RgbOutputTest : public testing::Test {
 protected:
  void SetUp() override {
    auto library = spectral::SpectrumLibrary::load_builtin();
    ASSERT_TRUE(library.ok()) << library.status();
    library_ = std::make_unique<spectral::SpectrumLibrary>(*std::move(library));
    const std::filesystem::path file = std::filesystem::path(testing::TempDir()) / "line_lamp.pbrt";
    std::ofstream(file) << kLineLamp;
    auto loaded = scene::load_scene(file, scene::with_library_names(*library_));
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    scene_ = std::make_unique<scene::SceneDescription>(std::move(loaded->description));
  }

  absl::StatusOr<LocalRenderResult> render(worker::IntegratorKind integrator, int bins,
                                           std::uint64_t seed, std::uint64_t spp) {
    LocalRenderOptions o;
    o.render.integrator = integrator;
    o.render.bins = bins;
    o.render.max_depth = 5;
    o.render.seed = seed;
    if (integrator == worker::IntegratorKind::kGradient) {
      PRISM_ASSIGN_OR_RETURN(o.render.gradient_offset_bins,
                             worker::gradient_offset_bins(0.15, bins));
    }
    o.width = 24;
    o.height = 18;
    o.spp = spp;
    o.tile_size = 8;
    o.threads = 2;
    PRISM_ASSIGN_OR_RETURN(auto r, LocalRender::create(device_, *scene_, *library_, o));
    return r->render();
  }

  static std::array<double, 3> mean_rgb(const image::RgbImage& rgb) {
    std::array<double, 3> m{};
    for (int y = 0; y < rgb.height(); ++y) {
      for (int x = 0; x < rgb.width(); ++x) {
        for (int c = 0; c < 3; ++c) m[c] += rgb.value(x, y, c);
      }
    }
    for (double& v : m) v /= double(rgb.width()) * rgb.height();
    return m;
  }

  worker::EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<scene::SceneDescription> scene_;
};

// Every sample adds its X, Y, Z at its own wavelengths, and nothing that picks a path depends on
// the bins, so hero's and uniform's RGB are the same bits at 4, 16, 64 and 256 bins, while the
// RGB of the bin averages is not (at 4 bins the line's 2.6 nm sit in a 117 nm bin taken as flat).
TEST_F(RgbOutputTest, HeroAndUniformRgbDoNotDependOnTheBins) {
  for (auto integrator : {worker::IntegratorKind::kHero, worker::IntegratorKind::kUniform}) {
    auto reference = render(integrator, 256, 3, 16);
    ASSERT_TRUE(reference.ok()) << reference.status();
    const std::array<double, 3> mean = mean_rgb(reference->rgb);
    ASSERT_GT(mean[0], 0.0);
    // At 256 bins (1.8 nm) the bins' RGB of the same samples is nearly exact: the scale agrees.
    auto fine = to_linear_srgb(reference->image, spectral::ColorMatching::cie1931());
    ASSERT_TRUE(fine.ok());
    const std::array<double, 3> fine_mean = mean_rgb(*fine);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(fine_mean[c] / mean[c], 1.0, 0.01) << "channel " << c;
    for (int bins : {4, 16, 64}) {
      SCOPED_TRACE(bins);
      auto r = render(integrator, bins, 3, 16);
      ASSERT_TRUE(r.ok()) << r.status();
      EXPECT_TRUE(same_bits(r->rgb.data(), reference->rgb.data()));
    }
    auto coarse = render(integrator, 4, 3, 16);
    ASSERT_TRUE(coarse.ok());
    auto from_bins = to_linear_srgb(coarse->image, spectral::ColorMatching::cie1931());
    ASSERT_TRUE(from_bins.ok());
    const std::array<double, 3> binned = mean_rgb(*from_bins);
    double worst = 0;
    for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(binned[c] / mean[c] - 1));
    EXPECT_GT(worst, 0.2) << "the bins' RGB was expected to be off at 4 bins";
  }
}

// The gradient integrator's RGB is the samples' exact XYZ plus the reconstruction's change of
// the bins' RGB, whose expectation is zero: the image means at 4 and 256 bins agree within the
// noise measured over independent seeds.
TEST_F(RgbOutputTest, GradientRgbAgreesAcrossBinsWithinNoise) {
  constexpr int kSeeds = 8;
  std::array<std::array<double, 3>, 2> mean{}, square{};
  const int bins[2] = {4, 256};
  for (int i = 0; i < 2; ++i) {
    for (int seed = 0; seed < kSeeds; ++seed) {
      auto r = render(worker::IntegratorKind::kGradient, bins[i], 100 + seed, 32);
      ASSERT_TRUE(r.ok()) << r.status();
      const std::array<double, 3> m = mean_rgb(r->rgb);
      for (int c = 0; c < 3; ++c) {
        mean[i][c] += m[c] / kSeeds;
        square[i][c] += m[c] * m[c] / kSeeds;
      }
    }
  }
  for (int c = 0; c < 3; ++c) {
    double variance = 0;
    for (int i = 0; i < 2; ++i) {
      variance += (square[i][c] - mean[i][c] * mean[i][c]) * kSeeds / (kSeeds - 1) / kSeeds;
    }
    ASSERT_GT(variance, 0.0);
    const double z = (mean[0][c] - mean[1][c]) / std::sqrt(variance);
    EXPECT_LT(std::abs(z), 4.0) << "channel " << c << ": " << mean[0][c] << " at 4 bins, "
                                << mean[1][c] << " at 256";
  }
}

// Light through a dispersive interface into a chromatic absorbing medium, against Beer–Lambert:
// the camera looks along the axis of a BK7 slab 1 unit thick filled with an absorbing dye
// (piecewise-linear sigma_a, scale 1.5) at a flat emitter behind it. At (near) normal incidence
// every wavelength crosses the same length, so per wavelength
//     L(λ) = Le·(1 − R)²·τ / (1 − R²·τ²),  R = ((η − 1)/(η + 1))²,  τ = exp(−1.5·σ_a(λ)),
// the internal reflections retracing the axis. The emitter reflects nothing (with pbrt's
// default grey it would return the light the slab reflects, +1.3 % in the red). This is the case
// where pbrt-v4's volpath is biased (docs/conformance.md): after the first dispersive refraction
// terminates the secondary wavelengths it still averages their MIS ratios. Prism's hero, uniform
// and gradient must give L per bin within noise.
constexpr char kDyeSlab[] = R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 1
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
PixelFilter "box"
WorldBegin
MakeNamedMedium "dye" "string type" "homogeneous"
  "spectrum sigma_a" [360 5 480 5 540 3 590 0.5 640 0.15 830 0.15]
  "spectrum sigma_s" [360 0 830 0] "float scale" 1.5
AttributeBegin
  MediumInterface "dye" ""
  Material "dielectric" "spectrum eta" "glass-BK7"
  Shape "trianglemesh" "point3 P" [-2 -2 -0.5  2 -2 -0.5  2 2 -0.5  -2 2 -0.5]
    "integer indices" [0 2 1 0 3 2]
  Shape "trianglemesh" "point3 P" [-2 -2 0.5  2 -2 0.5  2 2 0.5  -2 2 0.5]
    "integer indices" [0 1 2 0 2 3]
AttributeEnd
AttributeBegin
  Material "diffuse" "rgb reflectance" [0 0 0]
  AreaLightSource "diffuse" "spectrum L" [360 1 830 1] "bool twosided" true
  Shape "trianglemesh" "point3 P" [-4 -4 3  4 -4 3  4 4 3  -4 4 3] "integer indices" [0 1 2 0 2 3]
AttributeEnd
)";

TEST(MediumBehindDispersiveGlassTest, EveryIntegratorGivesBeerLambertPerBin) {
  auto library = spectral::SpectrumLibrary::load_builtin();
  ASSERT_TRUE(library.ok()) << library.status();
  const std::filesystem::path file = std::filesystem::path(testing::TempDir()) / "dye_slab.pbrt";
  std::ofstream(file) << kDyeSlab;
  auto loaded = scene::load_scene(file, scene::with_library_names(*library));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const spectral::Ior* bk7 = library->find_ior("glass-BK7");
  ASSERT_NE(bk7, nullptr);
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  // pbrt-v4's light normalisation of the flat spectrum (scale 1).
  const double le = 1.0 / cmf.photometric_sum(spectral::Spectrum(spectral::ConstantSpectrum{1.0f}));
  auto sigma_a = [](double l) {
    const double x[] = {360, 480, 540, 590, 640, 830}, y[] = {5, 5, 3, 0.5, 0.15, 0.15};
    for (int i = 0; i < 5; ++i) {
      if (l <= x[i + 1]) return y[i] + (y[i + 1] - y[i]) * (l - x[i]) / (x[i + 1] - x[i]);
    }
    return 0.15;
  };
  auto radiance = [&](double l) {
    const double n = spectral::eta(*bk7, l);
    const double r = (n - 1) * (n - 1) / ((n + 1) * (n + 1));
    const double tau = std::exp(-1.5 * sigma_a(l));
    return le * (1 - r) * (1 - r) * tau / (1 - r * r * tau * tau);
  };
  spectral::WavelengthGrid grid = *spectral::WavelengthGrid::create(16);
  std::vector<double> expected(16);
  for (int b = 0; b < 16; ++b) {
    constexpr int kSteps = 2000;
    const double lo = grid.lower(b), hi = grid.upper(b);
    for (int i = 0; i < kSteps; ++i) expected[b] += radiance(lo + (i + 0.5) * (hi - lo) / kSteps);
    expected[b] /= kSteps;
  }

  worker::EmbreeDevice device;
  for (auto integrator : {worker::IntegratorKind::kUniform, worker::IntegratorKind::kHero,
                          worker::IntegratorKind::kGradient}) {
    SCOPED_TRACE(worker::name(integrator));
    LocalRenderOptions o;
    o.render.integrator = integrator;
    o.render.bins = 16;
    o.render.max_depth = 24;
    o.render.seed = 5;
    o.render.gradient_offset_bins = 2;
    o.width = 8;
    o.height = 8;
    o.spp = 512;
    o.tile_size = 8;
    o.threads = 2;
    auto r = LocalRender::create(device, loaded->description, *library, o);
    ASSERT_TRUE(r.ok()) << r.status();
    auto result = (*r)->render();
    ASSERT_TRUE(result.ok()) << result.status();
    // Per bin: the mean over the 64 pixels (independent estimates) and its standard error.
    for (int b = 0; b < 16; ++b) {
      double mean = 0, square = 0;
      for (int y = 0; y < 8; ++y) {
        for (int x = 0; x < 8; ++x) {
          const double v = result->image.value(x, y, b);
          mean += v / 64;
          square += v * v / 64;
        }
      }
      const double se = std::sqrt(std::max(0.0, square - mean * mean) / 63);
      EXPECT_NEAR(mean, expected[b], 4 * se + 1e-6 * expected[b])
          << "bin " << b << " (" << grid.lower(b) << "-" << grid.upper(b) << " nm): z "
          << (mean - expected[b]) / se;
    }
  }
}

// pbrt-v4's distant light with a target illuminance, on a grey diffuse floor at 30° from the
// light: every pixel's radiance is ρ/π·E·cos 30° spread over the flat spectrum, E the illuminance
// on a surface facing the light (pbrt-v4: scale·L normalised to one nit, times `illuminance`).
TEST(DistantLightTest, LightsAFloorAsItsIlluminanceSays) {
  auto library = spectral::SpectrumLibrary::load_builtin();
  ASSERT_TRUE(library.ok()) << library.status();
  const std::filesystem::path file = std::filesystem::path(testing::TempDir()) / "distant.pbrt";
  std::ofstream(file) << R"(LookAt 0 5 0  0 0 0  0 0 1
Camera "perspective" "float fov" 20
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
WorldBegin
LightSource "distant" "spectrum L" [360 1 830 1] "point3 from" [1 1.7320508 0]
  "point3 to" [0 0 0] "float illuminance" 3
Material "diffuse" "spectrum reflectance" [360 0.5 830 0.5]
Shape "trianglemesh" "point3 P" [-10 0 -10  10 0 -10  10 0 10  -10 0 10]
  "integer indices" [0 1 2 0 2 3]
)";
  auto loaded = scene::load_scene(file, scene::with_library_names(*library));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  const double expected =
      0.5 / M_PI * 3.0 / cmf.photometric_sum(spectral::Spectrum(spectral::ConstantSpectrum{1.0f})) *
      std::cos(M_PI / 6);
  worker::EmbreeDevice device;
  for (auto integrator : {worker::IntegratorKind::kUniform, worker::IntegratorKind::kHero,
                          worker::IntegratorKind::kGradient}) {
    SCOPED_TRACE(worker::name(integrator));
    LocalRenderOptions o;
    o.render.integrator = integrator;
    o.render.bins = 16;
    o.render.max_depth = 3;
    o.render.seed = 9;
    o.render.gradient_offset_bins = 2;
    o.width = 8;
    o.height = 8;
    o.spp = 256;
    o.threads = 2;
    auto r = LocalRender::create(device, loaded->description, *library, o);
    ASSERT_TRUE(r.ok()) << r.status();
    auto result = (*r)->render();
    ASSERT_TRUE(result.ok()) << result.status();
    for (int b = 0; b < 16; ++b) {
      double mean = 0, square = 0;
      for (int y = 0; y < 8; ++y) {
        for (int x = 0; x < 8; ++x) {
          const double v = result->image.value(x, y, b);
          mean += v / 64;
          square += v * v / 64;
        }
      }
      const double se = std::sqrt(std::max(0.0, square - mean * mean) / 63);
      EXPECT_NEAR(mean, expected, 4 * se + 1e-6 * expected) << "bin " << b;
    }
  }
  // The light needs a direction.
  std::ofstream(file) << "WorldBegin\nLightSource \"distant\" \"point3 from\" [1 1 1] "
                         "\"point3 to\" [1 1 1]\n";
  auto pointless = scene::load_scene(file, scene::with_library_names(*library));
  ASSERT_FALSE(pointless.ok());
  EXPECT_NE(pointless.status().message().find("distant.pbrt:2:13: distant light needs 'from' and "
                                              "'to' to differ"),
            std::string_view::npos)
      << pointless.status();
}

// A diffuse-transmission sheet (pbrt-v4's `diffusetransmission`, R 0.3, T 0.5) hanging in a
// constant environment: lit from both sides, it shows (R + T) times the sky's radiance, with no
// interreflection to count. Every integrator, per bin, within noise of the sky pixels' value.
TEST(DiffuseTransmissionTest, ASheetInTheSkyShowsReflectancePlusTransmittance) {
  auto library = spectral::SpectrumLibrary::load_builtin();
  ASSERT_TRUE(library.ok()) << library.status();
  const std::filesystem::path file = std::filesystem::path(testing::TempDir()) / "sheet.pbrt";
  std::ofstream(file) << R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 30
Film "spectral" "integer xresolution" 16 "integer yresolution" 16 "integer nbuckets" 8
PixelFilter "box"
WorldBegin
LightSource "infinite" "spectrum L" [360 1 830 1]
Material "diffusetransmission" "spectrum reflectance" [360 0.3 830 0.3]
  "spectrum transmittance" [360 0.5 830 0.5]
Shape "trianglemesh" "point3 P" [-1 -1 0  1 -1 0  1 1 0  -1 1 0] "integer indices" [0 1 2 0 2 3]
)";
  auto loaded = scene::load_scene(file, scene::with_library_names(*library));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  worker::EmbreeDevice device;
  for (auto integrator : {worker::IntegratorKind::kUniform, worker::IntegratorKind::kHero,
                          worker::IntegratorKind::kGradient}) {
    SCOPED_TRACE(worker::name(integrator));
    LocalRenderOptions o;
    o.render.integrator = integrator;
    o.render.bins = 8;
    o.render.max_depth = 4;
    o.render.seed = 2;
    o.render.gradient_offset_bins = 1;
    o.width = 16;
    o.height = 16;
    o.spp = 256;
    o.threads = 2;
    auto r = LocalRender::create(device, loaded->description, *library, o);
    ASSERT_TRUE(r.ok()) << r.status();
    auto result = (*r)->render();
    ASSERT_TRUE(result.ok()) << result.status();
    // The sheet (±1 at distance 5, fov 30) covers pixels 2.03..13.97: 4..11 are inside, columns
    // 0 and 15 are sky.
    for (int b = 0; b < 8; ++b) {
      double sheet = 0, sheet2 = 0, sky = 0, sky2 = 0;
      int n_sheet = 0, n_sky = 0;
      for (int y = 0; y < 16; ++y) {
        for (int x = 0; x < 16; ++x) {
          const double v = result->image.value(x, y, b);
          if (x >= 4 && x <= 11 && y >= 4 && y <= 11) {
            sheet += v;
            sheet2 += v * v;
            ++n_sheet;
          } else if (x == 0 || x == 15) {
            sky += v;
            sky2 += v * v;
            ++n_sky;
          }
        }
      }
      sheet /= n_sheet;
      sky /= n_sky;
      const double se_sheet =
          std::sqrt(std::max(0.0, sheet2 / n_sheet - sheet * sheet) / (n_sheet - 1));
      const double se_sky = std::sqrt(std::max(0.0, sky2 / n_sky - sky * sky) / (n_sky - 1));
      ASSERT_GT(sky, 0.0);
      EXPECT_NEAR(sheet, 0.8 * sky, 4 * std::hypot(se_sheet, 0.8 * se_sky) + 1e-6 * sky)
          << "bin " << b;
    }
  }
}

// A thin dielectric sheet (pbrt-v4's `thindielectric`, η 1.5) seen at normal incidence against
// a flat black-bodied emitter: it passes T' = (1 − R)/(1 + R) of the light, R = 0.04, so
// 0.923077 Le, at every wavelength and for every integrator. A dispersive BK7 ball beside it
// sends the gradient's offsets through the sheet diverged; the image stays finite.
TEST(ThinDielectricTest, ASheetPassesTheSlabTransmittance) {
  auto library = spectral::SpectrumLibrary::load_builtin();
  ASSERT_TRUE(library.ok()) << library.status();
  const std::filesystem::path file = std::filesystem::path(testing::TempDir()) / "thin.pbrt";
  std::ofstream(file) << R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 1
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 8
PixelFilter "box"
WorldBegin
AttributeBegin
  Material "thindielectric" "float eta" 1.5
  Shape "trianglemesh" "point3 P" [-2 -2 0  2 -2 0  2 2 0  -2 2 0] "integer indices" [0 1 2 0 2 3]
AttributeEnd
AttributeBegin
  Material "diffuse" "rgb reflectance" [0 0 0]
  AreaLightSource "diffuse" "spectrum L" [360 1 830 1] "bool twosided" true
  Shape "trianglemesh" "point3 P" [-4 -4 3  4 -4 3  4 4 3  -4 4 3] "integer indices" [0 1 2 0 2 3]
AttributeEnd
)";
  auto loaded = scene::load_scene(file, scene::with_library_names(*library));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  const double le = 1.0 / cmf.photometric_sum(spectral::Spectrum(spectral::ConstantSpectrum{1.0f}));
  const double expected = le * (1 - 0.04) / (1 + 0.04);
  worker::EmbreeDevice device;
  for (auto integrator : {worker::IntegratorKind::kUniform, worker::IntegratorKind::kHero,
                          worker::IntegratorKind::kGradient}) {
    SCOPED_TRACE(worker::name(integrator));
    LocalRenderOptions o;
    o.render.integrator = integrator;
    o.render.bins = 8;
    o.render.max_depth = 8;
    o.render.seed = 4;
    o.render.gradient_offset_bins = 1;
    o.width = 8;
    o.height = 8;
    o.spp = 256;
    o.threads = 2;
    auto r = LocalRender::create(device, loaded->description, *library, o);
    ASSERT_TRUE(r.ok()) << r.status();
    auto result = (*r)->render();
    ASSERT_TRUE(result.ok()) << result.status();
    for (int b = 0; b < 8; ++b) {
      double mean = 0, square = 0;
      for (int y = 0; y < 8; ++y) {
        for (int x = 0; x < 8; ++x) {
          const double v = result->image.value(x, y, b);
          mean += v / 64;
          square += v * v / 64;
        }
      }
      const double se = std::sqrt(std::max(0.0, square - mean * mean) / 63);
      EXPECT_NEAR(mean, expected, 4 * se + 1e-6 * expected) << "bin " << b;
    }
  }
  // Diverged offsets (after a dispersive ball) meeting the sheet: nothing non-finite.
  std::ofstream(file) << R"(LookAt 0 1 -4  0 0 0  0 1 0
Camera "perspective" "float fov" 40
Film "spectral" "integer xresolution" 16 "integer yresolution" 16 "integer nbuckets" 16
WorldBegin
LightSource "infinite" "spectrum L" [360 1 830 1]
AttributeBegin
  Material "dielectric" "spectrum eta" "glass-SF11"
  Translate 0 0 -1
  Shape "sphere" "float radius" 0.7
AttributeEnd
Material "thindielectric" "spectrum eta" "glass-BK7"
Shape "trianglemesh" "point3 P" [-2 -2 0  2 -2 0  2 2 0  -2 2 0] "integer indices" [0 1 2 0 2 3]
Material "diffuse" "rgb reflectance" [0.5 0.5 0.5]
Shape "trianglemesh" "point3 P" [-5 -1 -5  5 -1 -5  5 -1 5  -5 -1 5] "integer indices" [0 1 2 0 2 3]
)";
  auto mixed = scene::load_scene(file, scene::with_library_names(*library));
  ASSERT_TRUE(mixed.ok()) << mixed.status();
  LocalRenderOptions o;
  o.render.integrator = worker::IntegratorKind::kGradient;
  o.render.bins = 16;
  o.render.max_depth = 8;
  o.render.gradient_offset_bins = 2;
  o.width = 16;
  o.height = 16;
  o.spp = 64;
  o.threads = 2;
  auto r = LocalRender::create(device, mixed->description, *library, o);
  ASSERT_TRUE(r.ok()) << r.status();
  auto result = (*r)->render();
  ASSERT_TRUE(result.ok()) << result.status();
  for (float v : result->image.data()) ASSERT_TRUE(std::isfinite(v));
  EXPECT_EQ(result->stats.counters.non_finite, 0u);
  EXPECT_GT(result->stats.counters.gradient_divergences, 0u);
}

}  // namespace
}  // namespace prism::coordinator
