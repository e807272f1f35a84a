#include "worker/environment_map.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "worker/equal_area.h"

namespace prism::worker {
namespace {

TEST(EqualAreaMap, RoundTripsAndLandsOnTheSphere) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  for (int i = 0; i < 10000; ++i) {
    const Point2f p{u01(rng), u01(rng)};
    const Vec3f d = equal_area_square_to_sphere(p);
    EXPECT_NEAR(length(d), 1.0f, 1e-5f);
    const Point2f q = equal_area_sphere_to_square(d);
    EXPECT_NEAR(q.x, p.x, 2e-5f) << p.x << " " << p.y;
    EXPECT_NEAR(q.y, p.y, 2e-5f) << p.x << " " << p.y;
  }
  // The centre is +z, the corners −z (pbrt-v4's layout).
  EXPECT_NEAR(equal_area_square_to_sphere({0.5f, 0.5f}).z, 1.0f, 1e-6f);
  EXPECT_NEAR(equal_area_square_to_sphere({0.0f, 0.0f}).z, -1.0f, 1e-6f);
  EXPECT_NEAR(equal_area_square_to_sphere({1.0f, 0.5f}).x, 1.0f, 1e-6f);
}

// Equal area: uniform points of the square are uniform on the sphere. Each of 8 octants and 4
// latitude bands of equal area gets 1/32 of the points (a chi-square test, 31 dof).
TEST(EqualAreaMap, UniformSquareIsUniformSphere) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  constexpr int kN = 320000;
  int counts[32] = {};
  for (int i = 0; i < kN; ++i) {
    const Vec3f d = equal_area_square_to_sphere({u01(rng), u01(rng)});
    const int octant = (d.x > 0) + 2 * (d.y > 0) + 4 * (d.z > 0);
    // |z| bands of equal area within a hemisphere: |z| in [0, .25), [.25, .5), [.5, .75), [.75, 1].
    const int band = std::min(3, int(std::abs(d.z) * 4));
    ++counts[octant * 4 + band];
  }
  double chi2 = 0;
  const double expected = kN / 32.0;
  for (int c : counts) chi2 += (c - expected) * (c - expected) / expected;
  EXPECT_LT(chi2, 61.1);  // the 0.999 quantile of chi-square with 31 dof
}

class EnvironmentMapTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    cmf_ = new spectral::ColorMatching(spectral::ColorMatching::cie1931());
    uplift_ = new spectral::RgbUplift(*cmf_);
  }
  static void TearDownTestSuite() {
    delete uplift_;
    delete cmf_;
  }
  static spectral::ColorMatching* cmf_;
  static spectral::RgbUplift* uplift_;
};
spectral::ColorMatching* EnvironmentMapTest::cmf_ = nullptr;
spectral::RgbUplift* EnvironmentMapTest::uplift_ = nullptr;

// A 4x4 map with one black texel: texels are drawn in proportion to their mean RGB (a
// chi-square test), the returned density is pdf(w), and a direction looks up its own texel.
TEST_F(EnvironmentMapTest, SamplesTexelsByBrightnessWithTheDensityItReports) {
  scene::TextureImage image;
  image.width = image.height = 4;
  image.channels = 3;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  for (int i = 0; i < 16 * 3; ++i) image.values.push_back(0.1f + 2 * u01(rng));
  for (int c = 0; c < 3; ++c) image.values[5 * 3 + c] = 0;  // texel (1, 1) is black
  // A rotation, so light and world frames differ.
  auto light_to_world = *scene::Transform::rotate(90, {1, 0, 0});
  auto map = EnvironmentMap::create(image, light_to_world, *uplift_);
  ASSERT_TRUE(map.ok()) << map.status();

  double weight[16], total = 0;
  for (int i = 0; i < 16; ++i) {
    weight[i] = (image.values[3 * i] + image.values[3 * i + 1] + image.values[3 * i + 2]) / 3;
    total += weight[i];
  }
  constexpr int kN = 160000;
  int counts[16] = {};
  for (int i = 0; i < kN; ++i) {
    auto s = (*map)->sample({u01(rng), u01(rng)});
    ASSERT_TRUE(s.has_value());
    EXPECT_NEAR(length(s->w), 1.0f, 1e-5f);
    EXPECT_NEAR(s->pdf, (*map)->pdf(s->w), 1e-4f * s->pdf);
    // The texel the direction falls in, found by the inverse map in light space.
    const scene::Vec3 l = light_to_world.inverse().apply_vector({s->w.x, s->w.y, s->w.z});
    const Point2f uv = equal_area_sphere_to_square({float(l[0]), float(l[1]), float(l[2])});
    const int texel = std::min(3, int(uv.y * 4)) * 4 + std::min(3, int(uv.x * 4));
    ++counts[texel];
    EXPECT_NEAR(s->pdf, weight[texel] / total * 16 / (4 * kPi), 1e-3 * s->pdf);
  }
  EXPECT_EQ(counts[5], 0);
  double chi2 = 0;
  for (int i = 0; i < 16; ++i) {
    if (i == 5) continue;
    const double expected = kN * weight[i] / total;
    chi2 += (counts[i] - expected) * (counts[i] - expected) / expected;
  }
  EXPECT_LT(chi2, 37.7);  // the 0.999 quantile of chi-square with 14 dof

  // The radiance towards a texel's centre is that texel's RGB illuminant spectrum.
  spectral::SampledWavelengths w(3);
  w.set(0, 450, 1.0f / 470);
  w.set(1, 550, 1.0f / 470);
  w.set(2, 650, 1.0f / 470);
  for (int texel : {0, 5, 10, 15}) {
    const Vec3f light_dir =
        equal_area_square_to_sphere({(float(texel % 4) + 0.5f) / 4, (float(texel / 4) + 0.5f) / 4});
    const scene::Vec3 wd = light_to_world.apply_vector({light_dir.x, light_dir.y, light_dir.z});
    const auto got = (*map)->radiance({float(wd[0]), float(wd[1]), float(wd[2])}, w);
    auto want = uplift_->illuminant(
        {image.values[3 * texel], image.values[3 * texel + 1], image.values[3 * texel + 2]});
    ASSERT_TRUE(want.ok());
    for (int s = 0; s < 3; ++s) EXPECT_NEAR(got[s], (*want)(w.lambda(s)), 1e-5f * (1 + got[s]));
  }
}

}  // namespace
}  // namespace prism::worker

namespace prism::worker {
namespace {

// The illuminance `illuminance` normalises: a constant map of luminance 1 gives π on a patch
// facing light-space +z (not pbrt-v4's π/2) at any size; a map lit only by texels whose
// centres are below the horizon gives only the upper parts of the texels the horizon cuts.
TEST_F(EnvironmentMapTest, UpperHemisphereIlluminanceIsTheCosineWeightedIntegral) {
  // 1 and 3: a texel holds the whole upper hemisphere, or a corner of its diamond, with all its
  // own corners below the horizon (the 1x1 map was said to be black above the horizon).
  for (int n : {1, 3, 4, 16, 64}) {
    scene::TextureImage image;
    image.width = image.height = n;
    image.channels = 1;
    image.values.assign(size_t(n) * size_t(n), 1.0f);
    auto map = EnvironmentMap::create(image, scene::Transform(), *uplift_);
    ASSERT_TRUE(map.ok()) << map.status();
    EXPECT_NEAR((*map)->upper_hemisphere_illuminance(), M_PI, 0.002 * M_PI) << n;

    // Light only where z <= 0: the square outside the inner diamond |u-½| + |v-½| <= ½.
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        const Vec3f w = equal_area_square_to_sphere(
            Point2f{(float(x) + 0.5f) / float(n), (float(y) + 0.5f) / float(n)});
        image.values[size_t(y * n + x)] = w.z > 0 ? 0.0f : 1.0f;
      }
    map = EnvironmentMap::create(image, scene::Transform(), *uplift_);
    ASSERT_TRUE(map.ok());
    // Texels cut by the horizon still contribute their upper part, a share that shrinks with
    // the texel size.
    if (n >= 4) {
      EXPECT_LT((*map)->upper_hemisphere_illuminance(), (n == 4 ? 0.3 : 1.3 / n) * M_PI) << n;
    }
  }
}

}  // namespace
}  // namespace prism::worker
