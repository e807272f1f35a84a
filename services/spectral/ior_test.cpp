#include "services/spectral/ior.h"

#include <cmath>
#include <vector>

#include "gtest/gtest.h"
#include "services/spectral/named_spectra.h"

namespace prism::spectral {
namespace {

TEST(IorTest, CauchyMatchesHandComputedValues) {
  // n = 1.5046 + 0.0042/λ² + 1e-4/λ⁴ at λ = 0.5 µm: 1.5046 + 0.0168 + 0.0016 = 1.5230.
  const std::vector<double> a = {1.5046, 0.0042, 1e-4};
  const Ior ior = *CauchyIor::create(a);
  EXPECT_NEAR(eta(ior, 500.0), 1.5230, 1e-12);
  // dn/dλ = −2B/λ³ − 4C/λ⁵ = −0.0672 − 0.0128 = −0.08 per µm = −8e-5 per nm.
  EXPECT_NEAR(deta_dlambda(ior, 500.0), -8e-5, 1e-15);
  EXPECT_TRUE(is_dispersive(ior));
  const std::vector<double> one = {1.33};
  EXPECT_FALSE(is_dispersive(Ior(*CauchyIor::create(one))));
  EXPECT_FALSE(CauchyIor::create(std::vector<double>{}).ok());
  const std::vector<double> negative = {-2.0};
  EXPECT_FALSE(CauchyIor::create(negative).ok());
}

TEST(IorTest, CauchyDerivativeMatchesCentralDifferencesForManyTerms) {
  const std::vector<double> a = {1.45, 0.0035, 2e-4, -1e-5, 3e-6, 1e-7};
  const Ior ior = *CauchyIor::create(a);
  for (double l = 360.0; l <= 830.0; l += 10.0) {
    const double h = 1e-2;
    const double fd = (eta(ior, l + h) - eta(ior, l - h)) / (2 * h);
    EXPECT_NEAR(deta_dlambda(ior, l), fd, 1e-6 * std::abs(fd) + 1e-12) << l;
  }
}

TEST(IorTest, ConstantIsNotDispersive) {
  const Ior c = ConstantIor{1.5};
  EXPECT_EQ(eta(c, 400), 1.5);
  EXPECT_EQ(deta_dlambda(c, 400), 0.0);
  EXPECT_FALSE(is_dispersive(c));
}

TEST(IorTest, SellmeierBk7AndValidation) {
  const std::vector<double> b = {1.03961212, 0.231792344, 1.01046945};
  const std::vector<double> c = {0.00600069867, 0.0200179144, 103.560653};
  const Ior bk7 = *SellmeierIor::create(0.0, b, c);
  EXPECT_NEAR(eta(bk7, 587.56), 1.5168, 1e-4);
  EXPECT_TRUE(is_dispersive(bk7));
  const std::vector<double> two = {1.0, 2.0};
  EXPECT_FALSE(SellmeierIor::create(0.0, b, two).ok());
  const std::vector<double> one_b = {1.0}, pole = {0.25};  // resonance at 500 nm
  EXPECT_FALSE(SellmeierIor::create(0.0, one_b, pole).ok());
}

TEST(IorTest, TabulatedClampsAndUsesInterpolantSlope) {
  const std::vector<double> l = {400, 500, 600}, v = {1.6, 1.5, 1.45};
  const Ior t = *TabulatedIor::create(*PiecewiseLinearSpectrum::create(l, v, "t"));
  EXPECT_NEAR(eta(t, 450), 1.55, 1e-6);
  EXPECT_NEAR(eta(t, 300), 1.6, 1e-6);
  EXPECT_NEAR(eta(t, 800), 1.45, 1e-6);
  EXPECT_NEAR(deta_dlambda(t, 450), -0.001, 1e-7);
  EXPECT_NEAR(deta_dlambda(t, 550), -0.0005, 1e-7);
  EXPECT_EQ(deta_dlambda(t, 700), 0.0);
  EXPECT_TRUE(is_dispersive(t));
  const std::vector<double> zero = {1.0, 0.0, 1.0};
  EXPECT_FALSE(TabulatedIor::create(*PiecewiseLinearSpectrum::create(l, zero, "z")).ok());
}

TEST(IorTest, EveryNamedIorDerivativeMatchesCentralDifferences) {
  const SpectrumLibrary lib = *SpectrumLibrary::load_builtin();
  int checked = 0;
  for (const std::string& name : lib.names()) {
    const Ior* ior = lib.find_ior(name);
    if (ior == nullptr) continue;
    ++checked;
    if (const auto* tab = std::get_if<TabulatedIor>(ior)) {
      // Within each segment the interpolant is linear: compare at segment midpoints with a step
      // that stays inside the segment.
      const auto ls = tab->table().lambdas();
      for (size_t i = 1; i < ls.size(); ++i) {
        const double mid = 0.5 * (ls[i - 1] + ls[i]);
        if (mid < 360 || mid > 830) continue;
        const double h = 0.25 * (ls[i] - ls[i - 1]);
        const double fd = (eta(*ior, mid + h) - eta(*ior, mid - h)) / (2 * h);
        EXPECT_NEAR(deta_dlambda(*ior, mid), fd, 1e-6 + 1e-4 * std::abs(fd)) << name << " " << mid;
      }
      continue;
    }
    for (double l = 360.0; l <= 830.0; l += 10.0) {
      const double h = 1e-2;
      const double fd = (eta(*ior, l + h) - eta(*ior, l - h)) / (2 * h);
      EXPECT_NEAR(deta_dlambda(*ior, l), fd, 1e-6 * std::abs(fd) + 1e-11) << name << " " << l;
      EXPECT_GT(eta(*ior, l), 0.0) << name;
    }
  }
  EXPECT_GE(checked, 35);
}

TEST(IorTest, PbrtGlassNamesAgreeWithPbrtTables) {
  const SpectrumLibrary lib = *SpectrumLibrary::load_builtin();
  for (const char* name : {"glass-BK7", "glass-BAF10", "glass-FK51A", "glass-LASF9", "glass-F5",
                           "glass-F10", "glass-F11"}) {
    const Ior* sellmeier = lib.find_ior(name);
    const Ior* table = lib.find_ior(std::string("pbrt-v4-") + name);
    ASSERT_NE(sellmeier, nullptr) << name;
    ASSERT_NE(table, nullptr) << name;
    EXPECT_TRUE(std::holds_alternative<SellmeierIor>(*sellmeier));
    double worst = 0.0;
    for (double l = 400.0; l <= 780.0; l += 1.0) {
      worst = std::max(worst, std::abs(eta(*sellmeier, l) - eta(*table, l)));
    }
    // pbrt-v4's tables match these glasses' n_d; the dense flints drift by up to 4e-4 in the blue.
    EXPECT_LT(worst, 5e-4) << name;
  }
  EXPECT_NEAR(eta(*lib.find_ior("glass-BK7"), 587.6), 1.5168, 1e-4);
  EXPECT_NEAR(eta(*lib.find_ior("glass-N-BK7"), 587.56), 1.5168, 1e-4);
  EXPECT_NEAR(eta(*lib.find_ior("glass-fused-silica"), 587.56), 1.45846, 1e-4);
  EXPECT_NEAR(eta(*lib.find_ior("water"), 587.56), 1.3334, 1e-4);
  EXPECT_NEAR(eta(*lib.find_ior("diamond"), 587.56), 2.41749, 1e-4);
  EXPECT_NEAR(eta(*lib.find_ior("glass-N-SF11"), 587.56), 1.78472, 1e-4);
}

}  // namespace
}  // namespace prism::spectral
