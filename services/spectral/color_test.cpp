#include "services/spectral/color.h"

#include <cmath>
#include <string>

#include "gtest/gtest.h"
#include "services/spectral/named_spectra.h"

namespace prism::spectral {
namespace {

class ColorTest : public ::testing::Test {
 protected:
  const ColorMatching cmf_storage_ = ColorMatching::cie1931();
  const SpectrumLibrary lib_storage_ = *SpectrumLibrary::load_builtin();
  const ColorMatching* cmf_ = &cmf_storage_;
  const SpectrumLibrary* lib_ = &lib_storage_;
};

TEST_F(ColorTest, YIntegralMatchesPbrt) {
  EXPECT_NEAR(cmf_->y_sum(), kCieYIntegral, 1e-3);
  EXPECT_NEAR(cmf_->cmf(555.0f).y, 1.0, 1e-9);
  EXPECT_EQ(cmf_->cmf(359.0f).y, 0.0);
  EXPECT_GT(cmf_->cmf(830.0f).x, 0.0);
  // Between samples the CMFs are linear.
  EXPECT_NEAR(cmf_->cmf(555.5f).y, 0.5 * (cmf_->cmf(555.0f).y + cmf_->cmf(556.0f).y), 1e-7);
}

TEST_F(ColorTest, D65NormalisedToUnitYIsSrgbAndAcescgWhite) {
  const Spectrum d65 = cie_d65();
  Xyz xyz = cmf_->to_xyz(d65);
  xyz = {xyz.x / xyz.y, 1.0, xyz.z / xyz.y};
  const Rgb srgb = xyz_to_linear_srgb(xyz);
  EXPECT_NEAR(srgb.r, 1.0, 1e-3);
  EXPECT_NEAR(srgb.g, 1.0, 1e-3);
  EXPECT_NEAR(srgb.b, 1.0, 1e-3);
  const Rgb aces = xyz_to_acescg(xyz);
  EXPECT_NEAR(aces.r, 1.0, 1e-3);
  EXPECT_NEAR(aces.g, 1.0, 1e-3);
  EXPECT_NEAR(aces.b, 1.0, 1e-3);
  // The ideal D65 white maps to (1, 1, 1) to rounding.
  const Rgb w = xyz_to_acescg({0.3127 / 0.3290, 1.0, (1 - 0.3127 - 0.3290) / 0.3290});
  EXPECT_NEAR(w.r, 1.0, 1e-9);
  EXPECT_NEAR(w.g, 1.0, 1e-9);
  EXPECT_NEAR(w.b, 1.0, 1e-9);
}

TEST_F(ColorTest, MatricesAreInversesAndMatchPublishedSrgb) {
  const Rgb rgb = {0.2, 0.5, 0.9};
  const Rgb back = xyz_to_linear_srgb(linear_srgb_to_xyz(rgb));
  EXPECT_NEAR(back.r, rgb.r, 1e-12);
  EXPECT_NEAR(back.g, rgb.g, 1e-12);
  EXPECT_NEAR(back.b, rgb.b, 1e-12);
  // IEC 61966-2-1 (as rounded by Lindbloom): R row of XYZ → sRGB.
  const Rgb r = xyz_to_linear_srgb({1, 0, 0});
  EXPECT_NEAR(r.r, 3.2404542, 1e-3);
  EXPECT_NEAR(r.g, -0.9692660, 1e-3);
  EXPECT_NEAR(r.b, 0.0556434, 1e-3);
  // A neutral of any brightness stays neutral in ACEScg (the adaptation maps white to white).
  const Rgb grey = xyz_to_acescg(linear_srgb_to_xyz({0.18, 0.18, 0.18}));
  EXPECT_NEAR(grey.r, 0.18, 1e-9);
  EXPECT_NEAR(grey.g, 0.18, 1e-9);
  EXPECT_NEAR(grey.b, 0.18, 1e-9);
  // sRGB's primaries lie inside AP1's gamut: pure sRGB red has no negative ACEScg component.
  const Rgb red = xyz_to_acescg(linear_srgb_to_xyz({1.0, 0.0, 0.0}));
  EXPECT_GT(red.r, 0.5);
  EXPECT_GE(red.g, 0.0);
  EXPECT_GE(red.b, 0.0);
}

TEST_F(ColorTest, PhotometricSumIsPbrtsLightNormalisation) {
  EXPECT_NEAR(cmf_->photometric_sum(ConstantSpectrum{1.0f}), cmf_->y_sum(), 1e-9);
  const Spectrum d65 = cie_d65();
  EXPECT_NEAR(cmf_->photometric_sum(d65) / kCieYIntegral, cmf_->to_xyz(d65).y, 1e-12);
}

TEST_F(ColorTest, SrgbTransferFunction) {
  EXPECT_EQ(srgb_encode(0.0), 0.0);
  EXPECT_NEAR(srgb_encode(1.0), 1.0, 1e-12);
  EXPECT_NEAR(srgb_encode(0.18), 0.4613561, 1e-6);
  EXPECT_NEAR(srgb_encode(0.0031308), 0.0031308 * 12.92, 1e-7);
  for (double v = 0.0; v <= 1.0; v += 0.01) EXPECT_NEAR(srgb_decode(srgb_encode(v)), v, 1e-12);
  EXPECT_NEAR(srgb_encode(-0.18), -0.4613561, 1e-6);
}

TEST_F(ColorTest, BinWeightsIntegrateBinAverages) {
  const Spectrum d65 = cie_d65();
  const Xyz reference = cmf_->to_xyz(d65);
  for (int bins : {4, 16, 64, 256}) {
    const WavelengthGrid grid = *WavelengthGrid::create(bins);
    const XyzBinWeights w = cmf_->bin_weights(grid);
    ASSERT_EQ(static_cast<int>(w.weights().size()), bins);
    std::vector<float> ones(bins, 1.0f), avg(bins);
    // A constant 1: Σ weights = ∫ CMF / kCieYIntegral exactly (trapezoid of the 1 nm table).
    EXPECT_NEAR(w.to_xyz(ones).y, 1.0, 1e-5);
    for (int b = 0; b < bins; ++b) {
      avg[b] = static_cast<float>(integrate(d65, grid.lower(b), grid.upper(b)) / grid.bin_width());
    }
    if (bins < 16) continue;  // 117 nm bins are too coarse to compare colours
    const Xyz binned = w.to_xyz(avg);
    // Binning smooths the spectrum; with 64+ bins the colour is within 0.5 % of the 1 nm sum.
    const double tol = bins >= 64 ? 5e-3 : 5e-2;
    EXPECT_NEAR(binned.y / reference.y, 1.0, tol) << bins;
    EXPECT_NEAR(binned.x / reference.x, 1.0, tol) << bins;
    EXPECT_NEAR(binned.z / reference.z, 1.0, tol) << bins;
  }
}

// sRGB (D65, 8-bit encoded) of the ColorChecker Classic 24 patches, as published by X-Rite for
// the post-2014 formulation and tabulated in the Wikipedia article "ColorChecker"
// (en.wikipedia.org/wiki/ColorChecker, "sRGB" column). Ohta's spectra are a different
// measurement of the same chart, so agreement is to within a few counts; data/README reports
// <= 10/255 per channel, which is the tolerance used here (the largest difference, 10, is the
// red channel of patch 13 "blue"; dark skin gives (116, 79, 63) as data/README states).
struct Patch {
  const char* name;
  int r, g, b;
};
constexpr Patch kPublished[24] = {
    {"dark-skin", 115, 82, 68},   {"light-skin", 194, 150, 130},  {"blue-sky", 98, 122, 157},
    {"foliage", 87, 108, 67},     {"blue-flower", 133, 128, 177}, {"bluish-green", 103, 189, 170},
    {"orange", 214, 126, 44},     {"purplish-blue", 80, 91, 166}, {"moderate-red", 193, 90, 99},
    {"purple", 94, 60, 108},      {"yellow-green", 157, 188, 64}, {"orange-yellow", 224, 163, 46},
    {"blue", 56, 61, 150},        {"green", 70, 148, 73},         {"red", 175, 54, 60},
    {"yellow", 231, 199, 31},     {"magenta", 187, 86, 149},      {"cyan", 8, 133, 161},
    {"white-9.5", 243, 243, 242}, {"neutral-8", 200, 200, 200},   {"neutral-6.5", 160, 160, 160},
    {"neutral-5", 122, 122, 121}, {"neutral-3.5", 85, 85, 85},    {"black-2", 52, 52, 52}};

TEST_F(ColorTest, ColorCheckerUnderD65MatchesPublishedSrgb) {
  const PiecewiseLinearSpectrum d65 = cie_d65();
  const double d65_y = cmf_->to_xyz(Spectrum(d65)).y;
  int worst = 0;
  for (const Patch& p : kPublished) {
    const Spectrum* refl = lib_->find_spectrum(std::string("colorchecker-") + p.name);
    ASSERT_NE(refl, nullptr) << p.name;
    Xyz xyz;
    for (int l = 360; l <= 830; ++l) {
      const Xyz c = cmf_->cmf(static_cast<float>(l));
      const double v = eval(*refl, static_cast<float>(l)) * d65(static_cast<float>(l));
      xyz.x += c.x * v;
      xyz.y += c.y * v;
      xyz.z += c.z * v;
    }
    const double scale = 1.0 / (kCieYIntegral * d65_y);
    xyz = {xyz.x * scale, xyz.y * scale, xyz.z * scale};
    const Rgb lin = xyz_to_linear_srgb(xyz);
    auto to8 = [](double v) {
      return static_cast<int>(std::lround(255.0 * std::clamp(srgb_encode(v), 0.0, 1.0)));
    };
    const int r = to8(lin.r), g = to8(lin.g), b = to8(lin.b);
    EXPECT_LE(std::abs(r - p.r), 10) << p.name << " R " << r;
    EXPECT_LE(std::abs(g - p.g), 10) << p.name << " G " << g;
    EXPECT_LE(std::abs(b - p.b), 10) << p.name << " B " << b;
    worst = std::max({worst, std::abs(r - p.r), std::abs(g - p.g), std::abs(b - p.b)});
  }
  RecordProperty("worst_channel_difference_255", worst);
}

}  // namespace
}  // namespace prism::spectral
