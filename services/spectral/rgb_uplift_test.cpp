#include "services/spectral/rgb_uplift.h"

#include <cmath>
#include <random>
#include <thread>
#include <vector>

#include "gtest/gtest.h"

namespace prism::spectral {
namespace {

class RgbUpliftTest : public ::testing::Test {
 protected:
  const ColorMatching cmf_storage_ = ColorMatching::cie1931();
  const RgbUplift uplift_storage_{cmf_storage_};
  const ColorMatching* cmf_ = &cmf_storage_;
  const RgbUplift* uplift_ = &uplift_storage_;
};

double max_error(const Rgb& a, const Rgb& b) {
  return std::max({std::abs(a.r - b.r), std::abs(a.g - b.g), std::abs(a.b - b.b)});
}

TEST_F(RgbUpliftTest, RoundTripOfRandomInGamutColours) {
  std::mt19937_64 rng(20261122);
  std::uniform_real_distribution<double> u(0.05, 0.95);
  double worst = 0.0;
  for (int i = 0; i < 200; ++i) {
    const Rgb rgb = {u(rng), u(rng), u(rng)};
    auto p = uplift_->fit(rgb);
    ASSERT_TRUE(p.ok()) << p.status();
    const Rgb back = uplift_->to_rgb(*p);
    const Rgb target = {static_cast<float>(rgb.r), static_cast<float>(rgb.g),
                        static_cast<float>(rgb.b)};
    worst = std::max(worst, max_error(back, target));
    ASSERT_LT(max_error(back, target), 1e-3) << rgb.r << " " << rgb.g << " " << rgb.b << " → "
                                             << back.r << " " << back.g << " " << back.b;
    for (float l = 360.0f; l <= 830.0f; l += 1.0f) {
      const float v = (*p)(l);
      ASSERT_GE(v, 0.0f);
      ASSERT_LE(v, 1.0f);
    }
  }
  RecordProperty("worst_round_trip_error", std::to_string(worst));
}

TEST_F(RgbUpliftTest, RoundTripThroughTheColourPipeline) {
  // Independent of to_rgb(): reflectance × D65 through ColorMatching, normalised by D65's Y.
  const PiecewiseLinearSpectrum d65 = cie_d65();
  const double d65_y = cmf_->to_xyz(Spectrum(d65)).y;
  for (const Rgb rgb :
       {Rgb{0.8, 0.2, 0.1}, Rgb{0.1, 0.6, 0.3}, Rgb{0.2, 0.3, 0.9}, Rgb{0.9, 0.9, 0.1}}) {
    const RgbAlbedoSpectrum s = *uplift_->albedo(rgb);
    Xyz xyz;
    for (int l = 360; l <= 830; ++l) {
      const Xyz c = cmf_->cmf(static_cast<float>(l));
      const double v = s(static_cast<float>(l)) * d65(static_cast<float>(l));
      xyz.x += c.x * v;
      xyz.y += c.y * v;
      xyz.z += c.z * v;
    }
    const double k = 1.0 / (kCieYIntegral * d65_y);
    const Rgb back = xyz_to_linear_srgb({xyz.x * k, xyz.y * k, xyz.z * k});
    EXPECT_LT(max_error(back, rgb), 1e-3);
  }
}

TEST_F(RgbUpliftTest, GamutCornersGiveBoundedBestFits) {
  // Saturated corners need unbounded coefficients for an exact match; the fit is the closest
  // sigmoid spectrum and must stay finite, bounded and close in colour.
  for (const Rgb rgb : {Rgb{1, 0, 0}, Rgb{0, 1, 0}, Rgb{0, 0, 1}, Rgb{1, 1, 0}, Rgb{0, 1, 1},
                        Rgb{1, 0, 1}, Rgb{0.99, 0.01, 0.5}}) {
    const SigmoidPolynomial p = *uplift_->fit(rgb);
    ASSERT_TRUE(std::isfinite(p.c0) && std::isfinite(p.c1) && std::isfinite(p.c2));
    for (float l = 360.0f; l <= 830.0f; l += 1.0f) {
      ASSERT_GE(p(l), 0.0f);
      ASSERT_LE(p(l), 1.0f);
    }
    EXPECT_LT(max_error(uplift_->to_rgb(p), rgb), 0.1) << rgb.r << " " << rgb.g << " " << rgb.b;
  }
}

TEST_F(RgbUpliftTest, UnboundedAndIlluminantSpectra) {
  for (const Rgb rgb : {Rgb{2.0, 0.5, 0.1}, Rgb{0.3, 0.3, 7.0}, Rgb{0.04, 0.02, 0.01}}) {
    const RgbUnboundedSpectrum u = *uplift_->unbounded(rgb);
    const Rgb back = uplift_->to_rgb(u.polynomial);
    const double m = 2.0 * std::max({rgb.r, rgb.g, rgb.b});
    EXPECT_FLOAT_EQ(u.scale, static_cast<float>(m));
    EXPECT_LT(max_error({back.r * m, back.g * m, back.b * m}, rgb), 1e-3 * m);
  }
  const RgbUnboundedSpectrum zero = *uplift_->unbounded({0, 0, 0});
  EXPECT_EQ(zero(500.0f), 0.0f);
  EXPECT_FALSE(uplift_->unbounded({-1, 0, 0}).ok());
  // White emission is the D65 table itself; a coloured emitter has that colour times D65's.
  const PiecewiseLinearSpectrum d65 = cie_d65();
  const RgbIlluminantSpectrum white = *uplift_->illuminant({1, 1, 1});
  for (float l : {380.0f, 555.0f, 700.0f}) EXPECT_NEAR(white(l), d65(l), 1e-4f * d65(l));
  const Rgb rgb = {4.0, 1.0, 0.25};
  const Spectrum e = *uplift_->illuminant(rgb);
  const double d65_y = cmf_->to_xyz(Spectrum(d65)).y;
  const Xyz xyz = cmf_->to_xyz(e);
  const Rgb back = xyz_to_linear_srgb({xyz.x / d65_y, xyz.y / d65_y, xyz.z / d65_y});
  EXPECT_LT(max_error(back, rgb), 1e-2);
  EXPECT_GE(max_value(e), eval(e, 450.0f));
  double sum = 0.0;
  const int n = 300000;
  for (int i = 0; i < n; ++i) sum += eval(e, static_cast<float>(400.0 + (i + 0.5) * 300.0 / n));
  EXPECT_NEAR(integrate(e, 400.0, 700.0), sum * 300.0 / n, 1e-5 * sum * 300.0 / n);
  EXPECT_FALSE(is_constant(e));
  EXPECT_TRUE(is_constant(Spectrum(*uplift_->unbounded({3, 3, 3}))));
}

TEST_F(RgbUpliftTest, GreysAreExactConstants) {
  const SigmoidPolynomial black = *uplift_->fit({0, 0, 0});
  const SigmoidPolynomial white = *uplift_->fit({1, 1, 1});
  const SigmoidPolynomial grey = *uplift_->fit({0.5, 0.5, 0.5});
  const SigmoidPolynomial g2 = *uplift_->fit({0.2, 0.2, 0.2});
  for (float l = 360.0f; l <= 830.0f; l += 10.0f) {
    EXPECT_EQ(black(l), 0.0f);
    EXPECT_EQ(white(l), 1.0f);
    EXPECT_EQ(grey(l), 0.5f);
    EXPECT_NEAR(g2(l), 0.2f, 1e-6f);
  }
  EXPECT_TRUE(is_constant(Spectrum(RgbAlbedoSpectrum{grey})));
}

TEST_F(RgbUpliftTest, RefusesOutOfRangeInput) {
  EXPECT_EQ(uplift_->fit({1.2, 0.5, 0.5}).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(uplift_->fit({-0.1, 0.5, 0.5}).ok());
  EXPECT_FALSE(uplift_->fit({NAN, 0.5, 0.5}).ok());
  EXPECT_FALSE(uplift_->albedo({0.5, INFINITY, 0.5}).ok());
}

TEST_F(RgbUpliftTest, CacheReturnsIdenticalCoefficientsAcrossThreads) {
  const Rgb rgb = {0.31, 0.62, 0.17};
  const SigmoidPolynomial first = *uplift_->fit(rgb);
  const size_t size = uplift_->cache_size();
  EXPECT_EQ(*uplift_->fit(rgb), first);
  EXPECT_EQ(uplift_->cache_size(), size);
  std::vector<std::thread> threads;
  std::vector<SigmoidPolynomial> results(4);
  const Rgb other = {0.7, 0.15, 0.45};
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] { results[t] = *uplift_->fit(t % 2 ? rgb : other); });
  }
  for (auto& th : threads) th.join();
  EXPECT_EQ(results[1], first);
  EXPECT_EQ(results[3], first);
  EXPECT_EQ(results[0], results[2]);
  EXPECT_EQ(uplift_->cache_size(), size + 1);
}

}  // namespace
}  // namespace prism::spectral
