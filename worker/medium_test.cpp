#include "worker/medium.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "services/spectral/testing/chi_square.h"
#include "worker/sampler.h"
#include "worker/testing/sphere_histogram.h"

namespace prism::worker {
namespace {

using testing::cell_of;
using testing::expected_counts;

constexpr int kSamplesPerTest = 200000;

class PhaseFunctionTest : public ::testing::TestWithParam<float> {};

TEST_P(PhaseFunctionTest, SamplingMatchesTheDensity) {
  const HenyeyGreenstein hg(GetParam());
  const Vec3f wo = normalize(Vec3f(0.3f, -0.4f, 0.8f));
  auto expected =
      expected_counts([&](const Vec3f& wi) { return double(hg.p(wo, wi)); }, kSamplesPerTest);
  std::vector<double> observed(expected.size(), 0.0);
  for (std::uint32_t i = 0; i < kSamplesPerTest; ++i) {
    Sampler s(job::SamplerKind::kIndependent, SampleKey{17, 0, 0, 0, i});
    Point2f u;
    s.get2d(u.x, u.y);
    float pdf = 0;
    Vec3f wi = hg.sample(wo, u, &pdf);
    ASSERT_NEAR(length(wi), 1.0f, 1e-5f);
    ASSERT_NEAR(pdf, hg.p(wo, wi), 2e-3f * std::max(1.0f, pdf)) << "g " << hg.g();
    observed[cell_of(wi)] += 1;
  }
  auto result = spectral::testing::chi_square(observed, expected, 5.0);
  EXPECT_GT(result.p_value, 1e-5) << "g " << hg.g() << ": " << result.describe();
}

// ∫ p dω = 1 (p depends on μ = cos θ only: 2π ∫ p(μ) dμ, midpoint rule fine enough for g = 0.9).
TEST_P(PhaseFunctionTest, IntegratesToOne) {
  const HenyeyGreenstein hg(GetParam());
  const Vec3f wo(0, 0, 1);
  constexpr int kN = 400000;
  double sum = 0;
  for (int i = 0; i < kN; ++i) {
    double mu = -1 + (i + 0.5) * 2.0 / kN;
    Vec3f wi(float(std::sqrt(1 - mu * mu)), 0, float(mu));
    sum += hg.p(wo, wi);
  }
  EXPECT_NEAR(sum * 2.0 / kN * 2 * kPi, 1.0, 1e-4) << "g " << hg.g();
}

INSTANTIATE_TEST_SUITE_P(AsymmetryValues, PhaseFunctionTest,
                         ::testing::Values(-0.7f, 0.0f, 0.3f, 0.9f));

// pbrt-v4's convention: wo and wi both point away, so forward scattering (g > 0) sends wi
// near −wo.
TEST(PhaseFunctionConventionTest, ForwardScatteringContinuesTheRay) {
  HenyeyGreenstein hg(0.8f);
  Vec3f wo(0, 0, 1);
  EXPECT_GT(hg.p(wo, -wo), 100 * hg.p(wo, wo));
  double mean_cos = 0;
  constexpr int kN = 100000;
  for (std::uint32_t i = 0; i < kN; ++i) {
    Sampler s(job::SamplerKind::kSobol, SampleKey{2, 0, 0, 0, i});
    Point2f u;
    s.get2d(u.x, u.y);
    float pdf;
    mean_cos += dot(hg.sample(wo, u, &pdf), -wo);
  }
  // The mean cosine of the deflection is g.
  EXPECT_NEAR(mean_cos / kN, 0.8, 2e-3);
}

// The hero's distance follows σ·exp(−σt) on [0, t_max), and it passes with probability
// exp(−σ t_max).
TEST(FreeFlightTest, HeroDistanceDistribution) {
  const float sigma = 0.8f, t_max = 2.5f;
  constexpr int kCells = 40;
  constexpr int kN = 200000;
  std::vector<double> observed(kCells + 1, 0.0), expected(kCells + 1, 0.0);
  for (int c = 0; c < kCells; ++c) {
    double a = t_max * c / kCells, b = t_max * (c + 1) / kCells;
    expected[c] = kN * (std::exp(-sigma * a) - std::exp(-sigma * b));
  }
  expected[kCells] = kN * std::exp(-sigma * t_max);
  SampledSpectrum sigma_t;
  sigma_t[0] = sigma;
  sigma_t[1] = 0.3f;
  for (std::uint32_t i = 0; i < kN; ++i) {
    Sampler s(job::SamplerKind::kIndependent, SampleKey{5, 0, 0, 0, i});
    FreeFlight ff = sample_free_flight(sigma_t, t_max, s.get1d(), 2);
    if (ff.scattered) {
      ASSERT_GE(ff.t, 0.0f);
      ASSERT_LT(ff.t, t_max);
      observed[std::min(kCells - 1, int(ff.t / t_max * kCells))] += 1;
      ASSERT_FLOAT_EQ(ff.transmittance[0], std::exp(-sigma * ff.t));
      ASSERT_FLOAT_EQ(ff.pdf[0], sigma * std::exp(-sigma * ff.t));
      ASSERT_FLOAT_EQ(ff.pdf[1], 0.3f * std::exp(-0.3f * ff.t));
    } else {
      observed[kCells] += 1;
      ASSERT_EQ(ff.t, t_max);
      ASSERT_FLOAT_EQ(ff.pdf[0], std::exp(-sigma * t_max));
      ASSERT_FLOAT_EQ(ff.pdf[1], std::exp(-0.3f * t_max));
    }
    for (int lane = 2; lane < spectral::kMaxLanes; ++lane) {
      ASSERT_EQ(ff.pdf[lane], 0.0f);
      ASSERT_EQ(ff.transmittance[lane], 0.0f);
    }
  }
  auto result = spectral::testing::chi_square(observed, expected, 5.0);
  EXPECT_GT(result.p_value, 1e-5) << result.describe();

  // The probability of passing, by exact quadrature over u.
  constexpr int kQ = 1000000;
  int passed = 0;
  for (int i = 0; i < kQ; ++i) {
    passed += sample_free_flight(sigma_t, t_max, (i + 0.5f) / kQ, 1).scattered ? 0 : 1;
  }
  EXPECT_NEAR(double(passed) / kQ, std::exp(-sigma * t_max), 2e-6);
}

// The spectral MIS identity the integrator relies on. With C lanes and the CMIS rotation each
// wavelength is the hero equally often, so for lane s
//   Σ_h E_{o ~ p_h}[ f_s(o) / Σ_k p_k(o) ] = ∫ f_s(o) do,
// over outcomes o (a scattering distance t, or "passed"). Taking f_s = p_s(t)·h(t) for scatter
// (σ_t,s·T_s(t) times a smooth test function, the shape of an in-scattering estimate) and
// f_s = T_s(t_max) for passing, the right-hand sides are ∫_0^t_max σ_s e^{−σ_s t} h(t) dt and
// T_s(t_max). Expectations over u are computed by midpoint quadrature, so the test is exact up
// to quadrature error. A lane with σ_t = 0 (which as hero always passes) is included.
TEST(FreeFlightTest, SpectralMisIsUnbiasedForEveryLane) {
  constexpr int kC = 4;
  const float sigmas[kC] = {0.3f, 1.7f, 0.0f, 0.9f};
  const float t_max = 1.5f;
  auto h = [](double t) { return 1.0 + t * t; };
  double scatter[kC] = {}, pass[kC] = {};
  constexpr int kQ = 400000;
  for (int hero = 0; hero < kC; ++hero) {
    // Lane `hero` moved into lane 0; position[s] is where wavelength s sits.
    SampledSpectrum sigma_t;
    int position[kC];
    for (int s = 0; s < kC; ++s) {
      position[s] = s == hero ? 0 : (s == 0 ? hero : s);
      sigma_t[position[s]] = sigmas[s];
    }
    for (int i = 0; i < kQ; ++i) {
      FreeFlight ff = sample_free_flight(sigma_t, t_max, (i + 0.5f) / kQ, kC);
      double total = 0;
      for (int k = 0; k < kC; ++k) total += ff.pdf[k];
      ASSERT_GT(total, 0.0);
      for (int s = 0; s < kC; ++s) {
        const int p = position[s];
        if (ff.scattered) {
          scatter[s] += ff.pdf[p] * h(ff.t) / total / kQ;
        } else {
          pass[s] += ff.transmittance[p] / total / kQ;
        }
      }
    }
  }
  for (int s = 0; s < kC; ++s) {
    // ∫_0^t_max σ e^{−σt} (1 + t²) dt by Simpson's rule.
    constexpr int kM = 20000;
    double integral = 0;
    for (int j = 0; j <= kM; ++j) {
      double t = t_max * j / kM;
      double w = (j == 0 || j == kM) ? 1 : (j % 2 ? 4 : 2);
      integral += w * sigmas[s] * std::exp(-sigmas[s] * t) * h(t);
    }
    integral *= t_max / kM / 3;
    EXPECT_NEAR(scatter[s], integral, 1e-4 * std::max(1.0, integral)) << "lane " << s;
    EXPECT_NEAR(pass[s], std::exp(-sigmas[s] * t_max), 1e-4) << "lane " << s;
  }
}

TEST(FreeFlightTest, VacuumHeroPassesEvenAnInfiniteSegment) {
  SampledSpectrum sigma_t;
  sigma_t[1] = 0.5f;
  FreeFlight ff = sample_free_flight(sigma_t, INFINITY, 0.3f, 2);
  EXPECT_FALSE(ff.scattered);
  EXPECT_EQ(ff.transmittance[0], 1.0f);
  EXPECT_EQ(ff.pdf[0], 1.0f);
  EXPECT_EQ(ff.transmittance[1], 0.0f);
  EXPECT_EQ(ff.pdf[1], 0.0f);
  EXPECT_FALSE(ff.pdf.has_non_finite());
  EXPECT_FALSE(ff.transmittance.has_non_finite());
}

class HomogeneousMediumTest : public ::testing::Test {
 protected:
  void SetUp() override {
    library_ =
        std::make_unique<spectral::SpectrumLibrary>(*spectral::SpectrumLibrary::load_builtin());
    cmf_ = std::make_unique<spectral::ColorMatching>(spectral::ColorMatching::cie1931());
    uplift_ = std::make_unique<spectral::RgbUplift>(*cmf_);
  }
  absl::StatusOr<HomogeneousMedium> create(scene::HomogeneousMedium m) {
    return HomogeneousMedium::create(scene::Medium{"fog", m, {"media.pbrt", 4, 2}}, *library_,
                                     *uplift_);
  }
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<spectral::ColorMatching> cmf_;
  std::unique_ptr<spectral::RgbUplift> uplift_;
};

TEST_F(HomogeneousMediumTest, CoefficientsAndFlags) {
  SampledWavelengths lambda(3);
  lambda.set(0, 450, 1);
  lambda.set(1, 550, 1);
  lambda.set(2, 650, 1);

  auto grey = create({scene::SpectrumConstant{0.5}, scene::SpectrumConstant{2}, 3.0, 0.2});
  ASSERT_TRUE(grey.ok()) << grey.status();
  EXPECT_FALSE(grey->chromatic());
  EXPECT_TRUE(grey->scattering());
  EXPECT_FLOAT_EQ(grey->sigma_a(lambda)[2], 1.5f);
  EXPECT_FLOAT_EQ(grey->sigma_s(lambda)[0], 6.0f);
  EXPECT_EQ(grey->sigma_s(lambda)[3], 0.0f);
  EXPECT_FLOAT_EQ(grey->phase().g(), 0.2f);

  auto ink = create({scene::SpectrumRgb{0.9, 0.2, 0.05}, scene::SpectrumConstant{0}, 1.0, 0.0});
  ASSERT_TRUE(ink.ok()) << ink.status();
  EXPECT_TRUE(ink->chromatic());
  EXPECT_FALSE(ink->scattering());
  SampledSpectrum a = ink->sigma_a(lambda);
  EXPECT_GT(a[2], a[0]);  // absorbs red most: an RGB of (0.9, 0.2, 0.05)
  EXPECT_TRUE(ink->sigma_s(lambda).is_zero());

  auto table = create({scene::SpectrumConstant{0},
                       scene::SpectrumTabulated{{400, 700}, {0.1, 0.2}, "inline"}, 2.0, 0.0});
  ASSERT_TRUE(table.ok());
  EXPECT_TRUE(table->chromatic());
  EXPECT_TRUE(table->scattering());
  EXPECT_NEAR(table->sigma_s(lambda)[1], 2 * 0.15f, 1e-6f);

  auto off = create({scene::SpectrumConstant{1}, scene::SpectrumConstant{1}, 0.0, 0.0});
  ASSERT_TRUE(off.ok());
  EXPECT_FALSE(off->scattering());
}

TEST_F(HomogeneousMediumTest, BadParametersCarryTheMediumLocation) {
  for (const scene::HomogeneousMedium& m : {
           scene::HomogeneousMedium{scene::SpectrumConstant{1}, scene::SpectrumConstant{1}, 1, 1.0},
           scene::HomogeneousMedium{scene::SpectrumConstant{-1}, scene::SpectrumConstant{1}, 1, 0},
           scene::HomogeneousMedium{scene::SpectrumConstant{1},
                                    scene::SpectrumNamed{"no-such-spectrum"}, 1, 0},
           scene::HomogeneousMedium{scene::SpectrumConstant{1}, scene::SpectrumConstant{1}, -2, 0},
       }) {
    auto r = create(m);
    ASSERT_FALSE(r.ok());
    EXPECT_TRUE(absl::StartsWith(r.status().message(), "media.pbrt:4:2: medium \"fog\""))
        << r.status();
  }
}

}  // namespace
}  // namespace prism::worker
