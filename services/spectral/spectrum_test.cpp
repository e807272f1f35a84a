#include "services/spectral/spectrum.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "gtest/gtest.h"

namespace prism::spectral {
namespace {

PiecewiseLinearSpectrum triangle() {
  // 0 at 400, 2 at 500, 0 at 600.
  const std::vector<double> l = {400, 500, 600}, v = {0, 2, 0};
  return *PiecewiseLinearSpectrum::create(l, v, "triangle");
}

TEST(PiecewiseLinearSpectrumTest, EvaluatesInterpolatesAndIsZeroOutside) {
  const PiecewiseLinearSpectrum t = triangle();
  EXPECT_FLOAT_EQ(t(400.0f), 0.0f);
  EXPECT_FLOAT_EQ(t(450.0f), 1.0f);
  EXPECT_FLOAT_EQ(t(500.0f), 2.0f);
  EXPECT_FLOAT_EQ(t(575.0f), 0.5f);
  EXPECT_FLOAT_EQ(t(600.0f), 0.0f);
  EXPECT_EQ(t(399.0f), 0.0f);
  EXPECT_EQ(t(601.0f), 0.0f);
  EXPECT_FLOAT_EQ(t.slope(450.0f), 0.02f);
  EXPECT_FLOAT_EQ(t.slope(550.0f), -0.02f);
  EXPECT_EQ(t.slope(700.0f), 0.0f);
  EXPECT_FLOAT_EQ(t.max_value(), 2.0f);
}

TEST(PiecewiseLinearSpectrumTest, RefusesBadTables) {
  const std::vector<double> one = {500};
  EXPECT_FALSE(PiecewiseLinearSpectrum::create(one, one, "x").ok());
  const std::vector<double> l = {400, 400, 500}, v = {1, 2, 3};
  EXPECT_FALSE(PiecewiseLinearSpectrum::create(l, v, "x").ok());
  const std::vector<double> l2 = {400, 500}, v2 = {1, NAN};
  EXPECT_FALSE(PiecewiseLinearSpectrum::create(l2, v2, "x").ok());
  const std::vector<double> v3 = {1, 2, 3};
  EXPECT_FALSE(PiecewiseLinearSpectrum::create(l2, v3, "x").ok());
  const std::vector<double> l4 = {500, 400};
  EXPECT_FALSE(PiecewiseLinearSpectrum::create(l4, l4, "x").ok());
}

TEST(PiecewiseLinearSpectrumTest, ExactIntegralsAndBinAverages) {
  const PiecewiseLinearSpectrum t = triangle();
  EXPECT_NEAR(t.integral(0, 1000), 200.0, 1e-9);
  EXPECT_NEAR(t.integral(400, 500), 100.0, 1e-9);
  EXPECT_NEAR(t.integral(450, 550), 150.0, 1e-9);  // 1..2..1 over 100 nm
  EXPECT_NEAR(t.integral(420, 430), 0.5 * (0.4 + 0.6) * 10, 1e-9);
  EXPECT_NEAR(t.integral(590, 700), 0.5 * 0.2 * 10, 1e-9);
  EXPECT_EQ(t.integral(700, 800), 0.0);
  EXPECT_NEAR(t.bin_average(450, 550), 1.5, 1e-12);
  // Against a fine midpoint rule on an irregular table.
  const std::vector<double> l = {361.5, 377.25, 402, 530.125, 600, 829};
  const std::vector<double> v = {0.3, 1.7, 0.2, 4.0, 2.5, 0.1};
  const PiecewiseLinearSpectrum s = *PiecewiseLinearSpectrum::create(l, v, "irregular");
  for (auto [a, b] : {std::pair{360.0, 830.0}, {380.0, 381.0}, {400.5, 612.25}, {530.0, 530.5}}) {
    double sum = 0.0;
    const int n = 200000;
    for (int i = 0; i < n; ++i) {
      sum += s(static_cast<float>(a + (i + 0.5) * (b - a) / n));
    }
    EXPECT_NEAR(s.integral(a, b), sum * (b - a) / n, 1e-4 * (b - a)) << a << ".." << b;
    EXPECT_NEAR(integrate(Spectrum(s), a, b), s.integral(a, b), 1e-12);
  }
}

TEST(BlackbodySpectrumTest, PeakIsOneAtWiensWavelength) {
  for (double t : {2856.0, 4000.0, 5000.0, 6504.0, 10000.0}) {
    const BlackbodySpectrum b = *BlackbodySpectrum::create(t);
    const double peak = b.peak_wavelength_nm();
    EXPECT_NEAR(peak, 2.897771955e6 / t, 1e-9);
    EXPECT_NEAR(b.value(peak), 1.0, 1e-12);
    EXPECT_LT(b.value(peak - 1.0), 1.0);
    EXPECT_LT(b.value(peak + 1.0), 1.0);
    EXPECT_NEAR(b.derivative(peak), 0.0, 1e-9);
  }
  EXPECT_EQ(max_value(Spectrum(*BlackbodySpectrum::create(3000))), 1.0f);
}

TEST(BlackbodySpectrumTest, DerivativeMatchesCentralDifferences) {
  for (double t : {500.0, 1500.0, 2856.0, 6500.0, 20000.0}) {
    const BlackbodySpectrum b = *BlackbodySpectrum::create(t);
    for (double l = 360.0; l <= 830.0; l += 23.5) {
      const double h = 1e-3;
      const double fd = (b.value(l + h) - b.value(l - h)) / (2 * h);
      EXPECT_NEAR(b.derivative(l), fd, 1e-7 * std::abs(fd) + 1e-14) << t << " K " << l << " nm";
    }
  }
}

TEST(BlackbodySpectrumTest, RefusesNonPositiveTemperature) {
  EXPECT_FALSE(BlackbodySpectrum::create(0.0).ok());
  EXPECT_FALSE(BlackbodySpectrum::create(-100.0).ok());
  EXPECT_FALSE(BlackbodySpectrum::create(NAN).ok());
  EXPECT_FALSE(BlackbodySpectrum::create(INFINITY).ok());
}

TEST(SpectrumTest, QuadratureOfSmoothSpectra) {
  const Spectrum b = *BlackbodySpectrum::create(3000.0);
  double sum = 0.0;
  const int n = 470000;
  for (int i = 0; i < n; ++i) {
    sum += std::get<BlackbodySpectrum>(b).value(360.0 + (i + 0.5) * 470.0 / n);
  }
  EXPECT_NEAR(integrate(b, 360, 830), sum * 470.0 / n, 1e-7 * sum * 470.0 / n);
  const Spectrum r = RgbAlbedoSpectrum{{1.5f, -2.0f, 0.3f}};
  sum = 0.0;
  for (int i = 0; i < n; ++i) sum += eval(r, static_cast<float>(360.0 + (i + 0.5) * 470.0 / n));
  EXPECT_NEAR(integrate(r, 360, 830), sum * 470.0 / n, 1e-5);
}

TEST(SpectrumTest, DispatchSampleMaxAndConstancy) {
  const Spectrum c = ConstantSpectrum{0.25f};
  const Spectrum t = triangle();
  SampledWavelengths w(3);
  w.set(0, 450, 1);
  w.set(1, 500, 1);
  w.set(2, 900, 1);
  const SampledSpectrum st = sample(t, w);
  EXPECT_FLOAT_EQ(st[0], 1.0f);
  EXPECT_FLOAT_EQ(st[1], 2.0f);
  EXPECT_EQ(st[2], 0.0f);
  EXPECT_EQ(st[3], 0.0f);
  EXPECT_EQ(sample(c, w)[1], 0.25f);
  EXPECT_EQ(sample(c, w)[5], 0.0f);
  EXPECT_EQ(eval(c, 123.0f), 0.25f);
  EXPECT_NEAR(integrate(c, 400, 500), 25.0, 1e-12);
  EXPECT_TRUE(is_constant(c));
  EXPECT_FALSE(is_constant(t));
  EXPECT_TRUE(is_constant(Spectrum(RgbAlbedoSpectrum{{0, 0, 1.0f}})));
  EXPECT_FALSE(is_constant(Spectrum(RgbAlbedoSpectrum{{0, 1.0f, 0}})));
  EXPECT_FALSE(is_constant(Spectrum(*BlackbodySpectrum::create(5000))));
  EXPECT_EQ(max_value(c), 0.25f);
  EXPECT_EQ(max_value(t), 2.0f);
  // Sigmoid max over Λ: a downward parabola peaking inside.
  const SigmoidPolynomial p{-4.0f, 4.0f, 0.0f};  // vertex at t = 0.5 with value 1
  EXPECT_FLOAT_EQ(max_value(Spectrum(RgbAlbedoSpectrum{p})), SigmoidPolynomial::sigmoid(1.0f));
}

TEST(SigmoidPolynomialTest, ValuesBoundedAndNmCoefficientsAgree) {
  const SigmoidPolynomial p{30.0f, -25.0f, 3.0f};
  const auto nm = p.nm_coefficients();
  for (float l = 360.0f; l <= 830.0f; l += 7.0f) {
    const float v = p(l);
    EXPECT_GE(v, 0.0f);
    EXPECT_LE(v, 1.0f);
    const double x = (nm[0] * l + nm[1]) * l + nm[2];
    EXPECT_NEAR(v, 0.5 + x / (2 * std::sqrt(1 + x * x)), 2e-5);
  }
  EXPECT_EQ(SigmoidPolynomial::sigmoid(INFINITY), 1.0f);
  EXPECT_EQ(SigmoidPolynomial::sigmoid(-INFINITY), 0.0f);
}

}  // namespace
}  // namespace prism::spectral

namespace prism::spectral {
namespace {

// Uniformly spaced tables take a direct index; the result must equal interpolation found by a
// plain search, exactly, including at and next to every sample.
TEST(PiecewiseLinearSpectrumTest, UniformTablesEvaluateExactlyLikeTheSearch) {
  std::vector<double> l, v;
  for (int i = 0; i <= 80; ++i) {
    l.push_back(380.0 + 5.0 * i);
    v.push_back(std::sin(0.37 * i) + 1.5);
  }
  const PiecewiseLinearSpectrum s = *PiecewiseLinearSpectrum::create(l, v, "uniform");
  auto reference = [&](float x) -> float {
    std::vector<float> lf(l.begin(), l.end());
    if (!(x >= lf.front() && x <= lf.back())) return 0.0f;
    size_t i = size_t(std::upper_bound(lf.begin(), lf.end(), x) - lf.begin());
    if (i == lf.size()) return float(v.back());
    float t = (x - lf[i - 1]) / (lf[i] - lf[i - 1]);
    return float(v[i - 1]) + t * (float(v[i]) - float(v[i - 1]));
  };
  for (int k = 0; k <= 40000; ++k) {
    float x = 380.0f + 400.0f * float(k) / 40000.0f;
    ASSERT_EQ(s(x), reference(x)) << x;
    ASSERT_EQ(s(std::nextafter(x, 0.0f)), reference(std::nextafter(x, 0.0f))) << x;
    ASSERT_EQ(s(std::nextafter(x, 1e9f)), reference(std::nextafter(x, 1e9f))) << x;
  }
}

}  // namespace
}  // namespace prism::spectral
