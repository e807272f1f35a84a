#include "services/spectral/sampled.h"

#include <limits>

#include "gtest/gtest.h"

namespace prism::spectral {
namespace {

SampledSpectrum make(std::initializer_list<float> values) {
  SampledSpectrum s;
  int i = 0;
  for (float v : values) s[i++] = v;
  return s;
}

TEST(SampledSpectrumTest, Arithmetic) {
  const SampledSpectrum a = make({1, 2, 3, 4});
  const SampledSpectrum b(2.0f);
  EXPECT_EQ(a + b, make({3, 4, 5, 6, 2, 2, 2, 2}));
  EXPECT_EQ(a - b, make({-1, 0, 1, 2, -2, -2, -2, -2}));
  EXPECT_EQ(a * b, make({2, 4, 6, 8}));  // unused lanes stay 0
  EXPECT_EQ(a * 2.0f, make({2, 4, 6, 8}));
  EXPECT_EQ(2.0f * a, make({2, 4, 6, 8}));
  EXPECT_EQ(a / 2.0f, make({0.5f, 1, 1.5f, 2}));
  EXPECT_EQ(-a, make({-1, -2, -3, -4}));
  SampledSpectrum c = a;
  c += b;
  c -= b;
  c *= b;
  c /= b;
  EXPECT_EQ(c, a);
  EXPECT_EQ(a + 1.0f, make({2, 3, 4, 5, 1, 1, 1, 1}));
  EXPECT_EQ(SampledSpectrum(3.0f)[7], 3.0f);
}

TEST(SampledSpectrumTest, SafeDivisionAndNonFinite) {
  const SampledSpectrum a = make({1, 2, 3, 4});
  const SampledSpectrum pdf = make({0.5f, 0.0f, 1.0f, 2.0f});
  const SampledSpectrum q = safe_div(a, pdf);
  EXPECT_EQ(q, make({2, 0, 3, 2}));
  EXPECT_FALSE(q.has_non_finite());
  EXPECT_TRUE((a / pdf).has_non_finite());
  SampledSpectrum n = a;
  n[2] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_TRUE(n.has_non_finite());
}

TEST(SampledSpectrumTest, ReductionsAndFunctions) {
  const SampledSpectrum a = make({1, 4, 9, 16});
  EXPECT_EQ(a.max_value(4), 16.0f);
  EXPECT_EQ(a.min_value(4), 1.0f);
  EXPECT_EQ(a.min_value(5), 0.0f);
  EXPECT_FLOAT_EQ(a.average(4), 7.5f);
  EXPECT_EQ(sqrt(a), make({1, 2, 3, 4}));
  EXPECT_EQ(clamp(a, 2.0f, 10.0f), make({2, 4, 9, 10, 2, 2, 2, 2}));
  EXPECT_FLOAT_EQ(exp(make({0, 1}))[1], std::exp(1.0f));
  EXPECT_FLOAT_EQ(exp(make({0, 1}))[0], 1.0f);
  EXPECT_TRUE(SampledSpectrum().is_zero());
  EXPECT_FALSE(a.is_zero());
  EXPECT_EQ(max(a, make({2, 2, 2, 20})), make({2, 4, 9, 20}));
  EXPECT_EQ(min(a, make({2, 2, 2, 20})), make({1, 2, 2, 16}));
}

TEST(SampledWavelengthsTest, HeroAndTermination) {
  SampledWavelengths w(4);
  EXPECT_EQ(w.count(), 4);
  for (int i = 0; i < 4; ++i) w.set(i, 400.0f + 100.0f * i, 0.01f * (i + 1));
  EXPECT_EQ(w.hero(), 400.0f);
  EXPECT_EQ(w.live_count(), 4);
  EXPECT_FALSE(w.secondary_terminated());
  EXPECT_EQ(w.pdf_spectrum(), make({0.01f, 0.02f, 0.03f, 0.04f}));
  w.terminate_secondary();
  EXPECT_EQ(w.live_count(), 1);
  EXPECT_TRUE(w.live(0));
  EXPECT_FALSE(w.live(3));
  EXPECT_TRUE(w.secondary_terminated());
  EXPECT_EQ(w.live_mask(), make({1, 0, 0, 0}));
  EXPECT_EQ(w.pdf(2), 0.03f);  // lane pdfs are kept; see terminate_secondary()
  EXPECT_EQ(SampledWavelengths(1).live_count(), 1);
  EXPECT_EQ(SampledWavelengths(kMaxLanes).count(), kMaxLanes);
}

}  // namespace
}  // namespace prism::spectral
