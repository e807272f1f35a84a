// Differential splatting's line (differential_splat.h) against exact answers: one synthetic
// splat on a floor whose line runs onto a raised block. The fragments that land where the camera
// sees the block weigh nothing, the rest carry the whole splat, each in the bin of its own
// wavelength, and a line of no length is the point.
#include "worker/differential_splat.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <numeric>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "tests/testing/test_dir.h"
#include "worker/embree_device.h"
#include "worker/light.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

constexpr int kWidth = 64, kHeight = 32, kBins = 16;

// Looking straight down at the floor y = 0; a diffuse block 1 high covers x > 0.
constexpr char kScene[] = R"(LookAt 0 6 0  0 0 0  0 0 1
Camera "perspective" "float fov" 40
Film "spectral" "integer xresolution" 64 "integer yresolution" 32 "integer nbuckets" 16
PixelFilter "box"
WorldBegin
LightSource "point" "point3 from" [0 3 0] "blackbody I" 3000
Material "diffuse"
Shape "trianglemesh" "point3 P" [-20 0 -20  20 0 -20  20 0 20  -20 0 20]
  "integer indices" [0 1 2 0 2 3]
Shape "trianglemesh" "point3 P" [0 1 -20  20 1 -20  20 1 20  0 1 20]
  "integer indices" [0 1 2 0 2 3]
)";

class DifferentialSplatTest : public ::testing::Test {
 protected:
  void SetUp() override { build(kBins); }
  void build(int bins) {
    library_ =
        std::make_unique<spectral::SpectrumLibrary>(*spectral::SpectrumLibrary::load_builtin());
    const fs::path file = prism::testing::test_dir() / "block.pbrt";
    std::ofstream(file) << kScene;
    auto loaded = scene::load_scene(file, scene::with_library_names(*library_));
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    job::RenderOptions options;
    options.bins = bins;
    options.integrator = job::IntegratorKind::kLight;
    auto built =
        RenderScene::build(device_, loaded->description, *library_, options, kWidth, kHeight);
    ASSERT_TRUE(built.ok()) << built.status();
    scene_ = std::move(*built);
  }

  // A splat from the floor point p whose position moves by dp per nm, at 550 nm.
  LightSplat floor_splat(const Vec3f& p, const Vec3f& dp) const {
    const Camera& camera = scene_->camera();
    auto c = camera.connect(p, 0.0f);
    EXPECT_TRUE(c.has_value());
    LightSplat s;
    s.raster = c->raster;
    s.lambda = 550.0f;
    s.bin = scene_->grid().bin_of(s.lambda);
    s.value = 2.0f;
    const spectral::Rgb bar = scene_->cmf().srgb(s.lambda);
    const float energy = s.value * scene_->grid().bin_width();
    s.rgb[0] = float(bar.r * energy);
    s.rgb[1] = float(bar.g * energy);
    s.rgb[2] = float(bar.b * energy);
    s.position = p;
    s.normal = {0, 1, 0};
    s.position_per_nm = dp;
    s.raster_per_nm = camera.raster_differential(p, dp);
    s.has_differential = true;
    return s;
  }

  EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<RenderScene> scene_;
};

struct Image {
  int bins = kBins;
  std::vector<double> values = std::vector<double>(std::size_t(kWidth) * kHeight * bins, 0.0);
  std::vector<double> rgb = std::vector<double>(std::size_t(kWidth) * kHeight * 3, 0.0);
  FilteredSums sums() { return {kWidth, kHeight, bins, values, rgb}; }
  double pixel(int x, int y) const {
    double total = 0;
    for (int b = 0; b < bins; ++b) total += values[(std::size_t(y) * kWidth + x) * bins + b];
    return total;
  }
  double total() const { return std::accumulate(values.begin(), values.end(), 0.0); }
};

TEST_F(DifferentialSplatTest, TheReceiverImageSeesTheFloorAndTheBlock) {
  const ReceiverImage receivers(*scene_);
  int floor = 0, block = 0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const ReceiverImage::Pixel& g = receivers.at(x, y);
      ASSERT_TRUE(g.valid);
      EXPECT_NEAR(std::abs(g.normal.y), 1.0f, 1e-6f);
      const float height = g.position.y;
      EXPECT_TRUE(std::abs(height) < 1e-4f || std::abs(height - 1.0f) < 1e-4f) << height;
      (height > 0.5f ? block : floor)++;
      // One pixel is d = 2·tan(20°)/32 wide on the plane one unit down (fov spans the 32
      // rows), and its cone widens with the distance along its ray.
      const double d = 2.0 * std::tan(20.0 * 3.14159265358979 / 180.0) / 32;
      const double sx = (x + 0.5 - kWidth / 2) * d, sy = (y + 0.5 - kHeight / 2) * d;
      const double depth = 6.0 - height;
      EXPECT_NEAR(g.footprint, depth * d * std::sqrt(1 + sx * sx + sy * sy), 1e-4) << x << "," << y;
    }
  }
  EXPECT_GT(floor, kWidth * kHeight / 3);
  EXPECT_GT(block, kWidth * kHeight / 3);
}

TEST_F(DifferentialSplatTest, ALineKeepsItsEnergyOnItsOwnSurfaceOnly) {
  const ReceiverImage receivers(*scene_);
  DifferentialSplatter splatter(*scene_, receivers);
  // From x = -1 on the floor, ±100 nm moves ±2 along x: the line reaches x = 1, over the block.
  const LightSplat s = floor_splat({-1.0f, 0.0f, 0.3f}, {0.02f, 0.0f, 0.0f});
  Image image;
  FilteredSums sums = image.sums();
  ASSERT_TRUE(splatter.splat(s, 100.0, 0.5, sums));
  // The whole splat lands (every fragment is on the film), scaled.
  EXPECT_NEAR(image.total(), 0.5 * s.value, 1e-9 * s.value);
  int lit = 0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const double v = image.pixel(x, y);
      if (receivers.at(x, y).position.y > 0.5f) {
        EXPECT_LT(v, 1e-12) << "the block at pixel " << x << "," << y;
      } else if (v > 0) {
        ++lit;
      }
    }
  }
  // Floor x from -3 to 0 at depth 6: 3 / (6·2·tan 20° / 32) ≈ 22 pixels of line.
  EXPECT_GE(lit, 18);
  // Each point of the line carries its own wavelength, 550 nm + 50 nm per unit of x from -1:
  // 455 nm at x = -2.9, 580 nm at x = -0.4 (each pixel spans ±2.5 nm, inside one bin).
  const Camera& camera = scene_->camera();
  auto left = camera.connect({-2.9f, 0.0f, 0.3f}, 0.0f);
  auto right = camera.connect({-0.4f, 0.0f, 0.3f}, 0.0f);
  ASSERT_TRUE(left && right);
  auto brightest_bin = [&](Point2f raster) {
    const std::size_t p = std::size_t(int(raster.y)) * kWidth + std::size_t(int(raster.x));
    int best = 0;
    for (int b = 1; b < kBins; ++b) {
      if (image.values[p * kBins + b] > image.values[p * kBins + best]) best = b;
    }
    return best;
  };
  EXPECT_EQ(brightest_bin(left->raster), scene_->grid().bin_of(455.0f));
  EXPECT_EQ(brightest_bin(right->raster), scene_->grid().bin_of(580.0f));
}

TEST_F(DifferentialSplatTest, ALineOfNoLengthIsThePoint) {
  const ReceiverImage receivers(*scene_);
  DifferentialSplatter splatter(*scene_, receivers);
  const LightSplat s = floor_splat({-1.0f, 0.0f, 0.3f}, {0.02f, 0.0f, 0.0f});
  LightSplat point = s;
  point.has_differential = false;
  Image line, dot;
  FilteredSums line_sums = line.sums(), dot_sums = dot.sums();
  splatter.splat(s, 1e-4, 1.0, line_sums);
  EXPECT_FALSE(splatter.splat(point, 100.0, 1.0, dot_sums));
  for (std::size_t i = 0; i < dot.values.size(); ++i) {
    EXPECT_NEAR(line.values[i], dot.values[i], 1e-6 * s.value) << i;
  }
  for (std::size_t i = 0; i < dot.rgb.size(); ++i) {
    EXPECT_NEAR(line.rgb[i], dot.rgb[i], 1e-5 * std::abs(dot.rgb[i]) + 1e-12) << i;
  }
}

// With its light named, a line shares the splat's energy in proportion to the lamp's spectrum
// (a 3000 K blackbody here): with 4 bins of 117.5 nm, what each bin receives of a line over
// 450..650 nm is ∫ Le over the bin's part of that range, over ∫ Le over all of it (the fragments,
// about 3 nm apart, sample Le by the midpoint rule).
TEST_F(DifferentialSplatTest, ALineSharesItsEnergyLikeItsLampsSpectrum) {
  build(4);
  const ReceiverImage receivers(*scene_);
  DifferentialSplatter splatter(*scene_, receivers);
  LightSplat s = floor_splat({-2.2f, 0.0f, 0.3f}, {0.02f, 0.0f, 0.0f});
  s.light = 0;
  Image image;
  image.bins = 4;
  image.values.assign(std::size_t(kWidth) * kHeight * 4, 0.0);
  FilteredSums sums = image.sums();
  ASSERT_TRUE(splatter.splat(s, 100.0, 1.0, sums));
  EXPECT_NEAR(image.total(), s.value, 1e-9 * s.value);
  const spectral::Spectrum& le = light_spectrum(scene_->lights()[0]);
  auto integral = [&](double a, double b) {
    double sum = 0;
    for (int i = 0; i < 1000; ++i) sum += spectral::eval(le, float(a + (b - a) * (i + 0.5) / 1000));
    return sum * (b - a) / 1000;
  };
  const double all = integral(450, 650);
  const double expected[4] = {integral(450, 477.5) / all, integral(477.5, 595) / all,
                              integral(595, 650) / all, 0.0};
  for (int b = 0; b < 4; ++b) {
    double in_bin = 0;
    for (std::size_t p = 0; p < std::size_t(kWidth) * kHeight; ++p)
      in_bin += image.values[p * 4 + b];
    EXPECT_NEAR(in_bin / s.value, expected[b], 0.03) << "bin " << b;
  }
  // A flat share would give the red part (595..650) 55/200 = 0.275; the 3000 K lamp gives more.
  EXPECT_GT(expected[2], 0.3);
}

TEST_F(DifferentialSplatTest, WavelengthsOutsideTheGridShortenTheLine) {
  const ReceiverImage receivers(*scene_);
  DifferentialSplatter splatter(*scene_, receivers);
  LightSplat s = floor_splat({-1.5f, 0.0f, 0.3f}, {0.01f, 0.0f, 0.0f});
  s.lambda = 370.0f;  // ±100 nm would reach 270 nm: the line runs from 360 nm only
  s.bin = scene_->grid().bin_of(s.lambda);
  Image image;
  FilteredSums sums = image.sums();
  ASSERT_TRUE(splatter.splat(s, 100.0, 1.0, sums));
  EXPECT_NEAR(image.total(), s.value, 1e-9 * s.value);
  // 360 nm is 10 nm below: the line starts 0.1 units left of the point and runs 1 unit right.
  // Nothing lands beyond its start (a pixel of margin), and something lands near its far end.
  const Camera& camera = scene_->camera();
  auto beyond = camera.connect({-1.5f - 0.1f - 0.15f, 0.0f, 0.3f}, 0.0f);
  auto far_end = camera.connect({-1.5f + 0.95f, 0.0f, 0.3f}, 0.0f);
  ASSERT_TRUE(beyond && far_end);
  const int y = int(beyond->raster.y);
  const int step = beyond->raster.x < s.raster.x ? -1 : 1;
  for (int x = int(beyond->raster.x); x >= 0 && x < kWidth; x += step) {
    EXPECT_EQ(image.pixel(x, y), 0.0) << x;
  }
  EXPECT_GT(image.pixel(int(far_end->raster.x), int(far_end->raster.y)), 0.0);
}

}  // namespace
}  // namespace prism::worker
