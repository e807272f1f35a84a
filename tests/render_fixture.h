// A test fixture for whole renders through the embedded pipeline (LocalRender): scenes written
// from text and loaded as `prism render` loads them, rendered by any integrator, and per-bin
// means over chosen pixels with their standard errors (the pixels are independent estimates).
// Shared by the known-answer and the numerical-stability tests.
#pragma once

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>

#include "coordinator/local_render.h"
#include "services/base/status.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/color.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/wavelength_grid.h"
#include "tests/testing/test_dir.h"

namespace prism::coordinator {

inline constexpr job::IntegratorKind kIntegrators[] = {
    job::IntegratorKind::kUniform, job::IntegratorKind::kHero, job::IntegratorKind::kGradient};

// `Base`: ::testing::Test, or ::testing::TestWithParam<...> for parameterised suites.
template <typename Base = ::testing::Test>
class RenderFixtureBase : public Base {
 protected:
  static void SetUpTestSuite() {
    library_ = new spectral::SpectrumLibrary(*spectral::SpectrumLibrary::load_builtin());
    device_ = new worker::EmbreeDevice();
  }
  static void TearDownTestSuite() {
    delete device_;
    delete library_;
  }

  // The scene `text`, written to a file named `name` and loaded as `prism render` loads it.
  static absl::StatusOr<scene::SceneDescription> load(const std::string& name,
                                                      const std::string& text) {
    const std::filesystem::path file = prism::testing::test_dir() / name;
    std::ofstream(file) << text;
    PRISM_ASSIGN_OR_RETURN(scene::LoadedScene loaded,
                           scene::load_scene(file, scene::with_library_names(*library_)));
    return std::move(loaded.description);
  }

  // The scene's film resolution and bins, `spp` samples, 2 threads; `adjust` may change the
  // options before the render is built.
  static absl::StatusOr<LocalRenderResult> render(
      const scene::SceneDescription& scene, job::IntegratorKind integrator, std::uint64_t spp,
      std::uint64_t seed, int max_depth,
      const std::function<void(LocalRenderOptions&)>& adjust = nullptr) {
    LocalRenderOptions o;
    o.render.integrator = integrator;
    o.render.bins = scene.film.bins.value_or(16);
    o.render.max_depth = max_depth;
    o.render.seed = seed;
    o.render.gradient_offset_bins = std::max(1, o.render.bins / 8);
    o.width = scene.film.x_resolution;
    o.height = scene.film.y_resolution;
    o.spp = spp;
    o.threads = 2;
    if (adjust) adjust(o);
    PRISM_ASSIGN_OR_RETURN(auto r, LocalRender::create(*device_, scene, *library_, o));
    return r->render();
  }

  struct Mean {
    double mean = 0, standard_error = 0;
  };
  // Bin b's mean over the pixels `in` accepts, and its standard error.
  static Mean pixel_mean(const image::SpectralImage& image, int b,
                         const std::function<bool(int, int)>& in = nullptr) {
    double sum = 0, square = 0;
    int n = 0;
    for (int y = 0; y < image.height(); ++y) {
      for (int x = 0; x < image.width(); ++x) {
        if (in && !in(x, y)) continue;
        const double v = image.value(x, y, b);
        sum += v;
        square += v * v;
        ++n;
      }
    }
    const double mean = sum / n;
    return {mean, std::sqrt(std::max(0.0, square / n - mean * mean) / (n - 1))};
  }

  // Every integrator's image, per bin, against expected(lower, upper nm of the bin).
  static void expect_every_integrator(const scene::SceneDescription& scene, std::uint64_t spp,
                                      int max_depth,
                                      const std::function<double(double, double)>& expected) {
    for (job::IntegratorKind integrator : kIntegrators) {
      SCOPED_TRACE(job::name(integrator));
      auto result = render(scene, integrator, spp, 5, max_depth);
      ASSERT_TRUE(result.ok()) << result.status();
      const spectral::WavelengthGrid grid = *spectral::WavelengthGrid::create(result->image.bins());
      for (int b = 0; b < grid.bins(); ++b) {
        const double want = expected(grid.lower(b), grid.upper(b));
        const Mean got = pixel_mean(result->image, b);
        EXPECT_NEAR(got.mean, want, 4 * got.standard_error + 1e-6 * want)
            << "bin " << b << " (" << grid.lower(b) << "-" << grid.upper(b) << " nm): z "
            << (got.mean - want) / got.standard_error;
      }
    }
  }

  // The view expect_sheet_over_sky looks through (16 x 16, fov 30, box filter, 8 bins) in a
  // constant sky of unit flat radiance, then `world`: the sheet's material and shape.
  static std::string sky_scene(const std::string& world) {
    return R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 30
Film "spectral" "integer xresolution" 16 "integer yresolution" 16 "integer nbuckets" 8
PixelFilter "box"
WorldBegin
LightSource "infinite" "spectrum L" [360 1 830 1]
)" + world;
  }

  // A 2 x 2 sheet at distance 5 filling the middle of a 16 x 16, fov 30 film in a constant sky
  // (box filter): for every integrator and bin, the sheet's pixels (4..11, fully inside: it
  // covers 2.03..13.97) show `ratio` times the sky's (columns 0 and 15).
  static void expect_sheet_over_sky(const scene::SceneDescription& scene, double ratio,
                                    std::uint64_t seed) {
    for (job::IntegratorKind integrator : kIntegrators) {
      SCOPED_TRACE(job::name(integrator));
      auto result = render(scene, integrator, 256, seed, 4);
      ASSERT_TRUE(result.ok()) << result.status();
      for (int b = 0; b < result->image.bins(); ++b) {
        const Mean sheet = pixel_mean(
            result->image, b, [](int x, int y) { return x >= 4 && x <= 11 && y >= 4 && y <= 11; });
        const Mean sky = pixel_mean(result->image, b, [](int x, int) { return x == 0 || x == 15; });
        ASSERT_GT(sky.mean, 0.0);
        EXPECT_NEAR(
            sheet.mean, ratio * sky.mean,
            4 * std::hypot(sheet.standard_error, ratio * sky.standard_error) + 1e-6 * sky.mean)
            << "bin " << b;
      }
    }
  }

  // pbrt-v4's normalisation of a flat emission spectrum: 1 / Σ_1nm ȳ.
  static double unit_flat_emission() {
    const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
    return 1.0 / cmf.photometric_sum(spectral::Spectrum(spectral::ConstantSpectrum{1.0f}));
  }

  static inline spectral::SpectrumLibrary* library_ = nullptr;
  static inline worker::EmbreeDevice* device_ = nullptr;
};

using RenderFixture = RenderFixtureBase<>;
}  // namespace prism::coordinator
