// Tests of the pixel filters' importance sampling (pixel_filter.h): over a regular grid of
// sample numbers the weighted samples integrate any function g against the normalised filter,
// Σ w·g(o) / N → ∫ f·g / ∫ f, which is what makes a pixel's mean the filtered image (checked
// against direct quadrature of pbrt-v4's filter definitions); the unit box is the old jitter.
#include "worker/pixel_filter.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "tests/testing/test_dir.h"
#include "worker/render_scene.h"
#include "worker/tile_renderer.h"

namespace prism::worker {
namespace {

using scene::PixelFilterSpec;
using scene::PixelFilterType;

PixelFilterSpec spec(PixelFilterType type, double rx, double ry) {
  PixelFilterSpec s;
  s.type = type;
  s.x_radius = rx;
  s.y_radius = ry;
  return s;
}

// ∫∫ f·g / ∫∫ f by the midpoint rule on a fine grid over the support.
double quadrature(const PixelFilter& filter, double rx, double ry,
                  const std::function<double(double, double)>& g) {
  constexpr int kN = 1200;
  double num = 0, den = 0;
  for (int i = 0; i < kN; ++i) {
    const double x = -rx + (i + 0.5) * 2 * rx / kN;
    for (int j = 0; j < kN; ++j) {
      const double y = -ry + (j + 0.5) * 2 * ry / kN;
      const double f = filter.evaluate(x, y);
      num += f * g(x, y);
      den += f;
    }
  }
  return num / den;
}

// Σ w·g(offset) over a regular grid of (u0, u1): the sampler's own quadrature.
double weighted(const PixelFilter& filter, const std::function<double(double, double)>& g) {
  constexpr int kN = 1024;
  double sum = 0;
  for (int i = 0; i < kN; ++i) {
    for (int j = 0; j < kN; ++j) {
      const FilterSample s = filter.sample((i + 0.5f) / kN, (j + 0.5f) / kN);
      sum += double(s.weight) * g(s.x - 0.5, s.y - 0.5);
    }
  }
  return sum / (double(kN) * kN);
}

// Per axis, on a grid of 2^18 sample numbers, the weighted offsets integrate g against f/∫f to
// within the grid's own resolution.
TEST(PixelFilterTest, EachAxisIntegratesAgainstTheNormalisedFilter) {
  const std::function<double(double)> tests[] = {
      [](double) { return 1.0; }, [](double x) { return x * x; },
      [](double x) { return std::exp(0.7 * x); }, [](double x) { return x > 0.3 ? 1.0 : 0.0; }};
  for (auto [type, radius] :
       {std::pair{PixelFilterType::kBox, 1.0}, std::pair{PixelFilterType::kGaussian, 1.5},
        std::pair{PixelFilterType::kTriangle, 2.0}, std::pair{PixelFilterType::kMitchell, 2.0},
        std::pair{PixelFilterType::kLanczos, 4.0}}) {
    SCOPED_TRACE(int(type));
    auto filter = PixelFilter::create(spec(type, radius, radius));
    ASSERT_TRUE(filter.ok()) << filter.status();
    for (std::size_t t = 0; t < std::size(tests); ++t) {
      constexpr int kQ = 1 << 20;
      double num = 0, den = 0;
      for (int i = 0; i < kQ; ++i) {
        const double x = -radius + (i + 0.5) * 2 * radius / kQ;
        const double f = filter->evaluate_axis(0, x);
        num += f * tests[t](x);
        den += f;
      }
      constexpr int kN = 1 << 18;
      double got = 0, previous = -radius;
      for (int i = 0; i < kN; ++i) {
        double x = 0, w = 0;
        filter->sample_axis(0, (i + 0.5) / kN, &x, &w);
        got += w * tests[t](x);
        // An inverted CDF: the offset never decreases as u grows (a guide that sent u to the
        // wrong cell would break it).
        ASSERT_GE(x, previous) << "u = " << (i + 0.5) / kN;
        previous = x;
      }
      got /= kN;
      EXPECT_NEAR(got, num / den, 1e-4 * std::max(1.0, std::abs(num / den))) << "function " << t;
    }
  }
}

// The same in 2D through sample() on a 1024² grid (whose coarser steps miss some of the signed
// filters' narrowest cells: 1e-2).
TEST(PixelFilterTest, WeightedSamplesIntegrateAgainstTheNormalisedFilter) {
  const std::function<double(double, double)> tests[] = {
      [](double, double) { return 1.0; }, [](double x, double y) { return x * x + 0.5 * y * y; },
      [](double x, double y) { return std::exp(0.7 * x - 0.3 * y); },
      [](double x, double) { return x > 0.3 ? 1.0 : 0.0; },  // an edge
  };
  struct Case {
    PixelFilterType type;
    double rx, ry;
    const char* name;
  };
  for (const Case& c : {Case{PixelFilterType::kBox, 0.5, 0.5, "box"},
                        Case{PixelFilterType::kBox, 1.0, 0.75, "wide box"},
                        Case{PixelFilterType::kGaussian, 1.5, 1.5, "gaussian"},
                        Case{PixelFilterType::kTriangle, 2.0, 1.0, "triangle"},
                        Case{PixelFilterType::kMitchell, 2.0, 2.0, "mitchell"},
                        Case{PixelFilterType::kLanczos, 4.0, 4.0, "lanczos"}}) {
    SCOPED_TRACE(c.name);
    auto filter = PixelFilter::create(spec(c.type, c.rx, c.ry));
    ASSERT_TRUE(filter.ok()) << filter.status();
    for (std::size_t t = 0; t < std::size(tests); ++t) {
      const double want = quadrature(*filter, c.rx, c.ry, tests[t]);
      const double got = weighted(*filter, tests[t]);
      EXPECT_NEAR(got, want, 1e-2 * std::max(1.0, std::abs(want))) << "test function " << t;
    }
  }
}

// Mitchell and Lanczos have negative lobes: some samples carry negative weights, and offsets
// reach the whole support.
TEST(PixelFilterTest, NegativeLobesGiveSignedWeights) {
  auto lanczos = PixelFilter::create(spec(PixelFilterType::kLanczos, 4, 4));
  ASSERT_TRUE(lanczos.ok());
  int negative = 0;
  double reach = 0;
  for (int i = 0; i < 256; ++i) {
    const FilterSample s = lanczos->sample((i + 0.5f) / 256, 0.5f);
    negative += s.weight < 0 ? 1 : 0;
    reach = std::max(reach, std::abs(double(s.x) - 0.5));
  }
  EXPECT_GT(negative, 0);
  EXPECT_GT(reach, 3.5);
  EXPECT_LE(reach, 4.0);
}

// The unit box is the plain jittered pixel, bit for bit: a scene with PixelFilter "box" renders
// exactly as before filters were sampled.
TEST(PixelFilterTest, TheUnitBoxIsThePlainJitter) {
  auto box = PixelFilter::create(spec(PixelFilterType::kBox, 0.5, 0.5));
  ASSERT_TRUE(box.ok());
  EXPECT_TRUE(box->unit_box());
  for (float u : {0.0f, 0.25f, 0.999f}) {
    const FilterSample s = box->sample(u, 1.0f - u);
    EXPECT_EQ(s.x, u);
    EXPECT_EQ(s.y, 1.0f - u);
    EXPECT_EQ(s.weight, 1.0f);
  }
}

TEST(PixelFilterTest, RefusesParametersWithoutAFilter) {
  EXPECT_FALSE(PixelFilter::create(spec(PixelFilterType::kGaussian, 0, 1)).ok());
  PixelFilterSpec flat = spec(PixelFilterType::kGaussian, 1.5, 1.5);
  flat.sigma = 0;
  EXPECT_FALSE(PixelFilter::create(flat).ok());
}

// A rendered edge: the camera looks straight at an emitter that fills the right half of the view,
// its edge on the boundary between columns 7 and 8 of 16. Each column's value over a column deep
// inside the emitter is the share of the filter's mass on the emitting side, from pbrt-v4's
// formulas written out here (gaussian: exp(−x²/2σ²) − exp(−r²/2σ²); mitchell: its cubic, with
// the overshoot of its negative lobes), within 4 standard errors of the rows' spread.
TEST(PixelFilterTest, AnEdgeRendersAsTheFilterSaysWithinNoise) {
  auto library = spectral::SpectrumLibrary::load_builtin();
  ASSERT_TRUE(library.ok());
  EmbreeDevice device;
  auto gaussian = [](double x) {
    const double s = 0.5, r = 1.5;
    return std::abs(x) > r ? 0.0 : std::exp(-x * x / (2 * s * s)) - std::exp(-r * r / (2 * s * s));
  };
  auto mitchell = [](double x) {
    const double b = 1.0 / 3, c = 1.0 / 3;
    x = std::abs(x);  // radius 2: pbrt-v4 evaluates Mitchell1D(2x/2)
    if (x <= 1)
      return ((12 - 9 * b - 6 * c) * x * x * x + (-18 + 12 * b + 6 * c) * x * x + (6 - 2 * b)) / 6;
    if (x <= 2)
      return ((-b - 6 * c) * x * x * x + (6 * b + 30 * c) * x * x + (-12 * b - 48 * c) * x +
              (8 * b + 24 * c)) /
             6;
    return 0.0;
  };
  struct Case {
    const char* directive;
    std::function<double(double)> f;
    double radius;
  };
  for (const Case& c : {Case{"PixelFilter \"gaussian\"", gaussian, 1.5},
                        Case{"PixelFilter \"mitchell\"", mitchell, 2.0}}) {
    SCOPED_TRACE(c.directive);
    const std::filesystem::path file = prism::testing::test_dir() / "edge.pbrt";
    std::ofstream(file)
        << "LookAt 0 0 -10  0 0 0  0 1 0\nCamera \"perspective\" \"float fov\" 10\n"
        << "Film \"spectral\" \"integer xresolution\" 16 \"integer yresolution\" 8 "
           "\"integer nbuckets\" 4\n"
        << c.directive << "\nWorldBegin\n"
        << "AreaLightSource \"diffuse\" \"spectrum L\" [360 1 830 1] \"bool twosided\" true\n"
        << "Shape \"trianglemesh\" \"point3 P\" [0 -50 0  50 -50 0  50 50 0  0 50 0] "
           "\"integer indices\" [0 1 2 0 2 3]\n";
    auto loaded = scene::load_scene(file, scene::with_library_names(*library));
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    job::RenderOptions options;
    options.integrator = job::IntegratorKind::kUniform;
    options.bins = 4;
    options.max_depth = 0;
    auto rs = RenderScene::build(device, loaded->description, *library, options, 16, 8);
    ASSERT_TRUE(rs.ok()) << rs.status();
    auto result = TileRenderer(**rs).render({{0, 0, 16, 8}, {0, 4096}, 0}, nullptr);
    ASSERT_TRUE(result.ok()) << result.status();
    // Each pixel's mean over its bins.
    auto pixel = [&](int x, int y) {
      double sum = 0;
      for (int b = 0; b < 4; ++b) sum += result->sum(x, y, b);
      return sum / 4 / double(result->count(x, y));
    };
    double inside = 0;
    for (int y = 0; y < 8; ++y) inside += pixel(15, y) / 8;
    ASSERT_GT(inside, 0.0);
    double total = 0;
    for (int i = 0; i < 100000; ++i) total += c.f(-c.radius + (i + 0.5) * 2 * c.radius / 100000);
    for (int x = 4; x < 12; ++x) {
      // The emitter (world x > 0) covers film x > 8.
      double share = 0;
      for (int i = 0; i < 100000; ++i) {
        const double t = -c.radius + (i + 0.5) * 2 * c.radius / 100000;
        if (x + 0.5 + t > 8) share += c.f(t);
      }
      share /= total;
      double mean = 0, square = 0;
      for (int y = 0; y < 8; ++y) {
        const double v = pixel(x, y) / inside;
        mean += v / 8;
        square += v * v / 8;
      }
      const double se = std::sqrt(std::max(0.0, square - mean * mean) / 7) + 1e-4;
      EXPECT_NEAR(mean, share, 4 * se) << "column " << x;
    }
  }
}

}  // namespace
}  // namespace prism::worker
