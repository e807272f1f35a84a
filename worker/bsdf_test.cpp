#include "worker/bsdf.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "services/spectral/testing/chi_square.h"
#include "worker/fresnel.h"
#include "worker/sampler.h"
#include "worker/testing/sphere_histogram.h"

namespace prism::worker {
namespace {

constexpr int kLanes = 4;

// Lane `lane` moved into lane 0 (the hero), so sampling uses that lane's parameters.
SampledSpectrum with_hero(SampledSpectrum s, int lane) {
  std::swap(s[0], s[lane]);
  return s;
}

Vec3f direction(float theta_deg, float phi_deg) {
  float t = theta_deg * kPi / 180, p = phi_deg * kPi / 180;
  return {std::sin(t) * std::cos(p), std::sin(t) * std::sin(p), std::cos(t)};
}

using testing::cell_of;
using testing::expected_counts;
using testing::kCells;
using testing::spectrum_of;

constexpr int kSamplesPerTest = 250000;

struct Case {
  std::string name;
  Bsdf bsdf;
  std::function<Bsdf(int hero_lane)> with_lane_as_hero;
};

std::vector<Case> rough_cases() {
  std::vector<Case> cases;
  SampledSpectrum refl = spectrum_of({0.8f, 0.5f, 0.2f, 0.9f});
  cases.push_back({"diffuse", DiffuseBsdf(refl, kLanes),
                   [=](int lane) { return Bsdf(DiffuseBsdf(with_hero(refl, lane), kLanes)); }});
  // Each lane picks its side by its own R/(R + T): the lanes' densities differ.
  SampledSpectrum r = spectrum_of({0.3f, 0.5f, 0.1f, 0.6f});
  SampledSpectrum t = spectrum_of({0.6f, 0.2f, 0.8f, 0.3f});
  cases.push_back({"diffuse transmission", DiffuseTransmissionBsdf(r, t, kLanes), [=](int lane) {
                     return Bsdf(
                         DiffuseTransmissionBsdf(with_hero(r, lane), with_hero(t, lane), kLanes));
                   }});
  for (float alpha : {0.05f, 0.3f, 0.8f}) {
    for (SampledSpectrum eta :
         {spectrum_of({1.5f, 1.52f, 1.55f, 1.6f}), spectrum_of({1.02f, 1.025f, 1.03f, 1.035f}),
          spectrum_of({2.4f, 2.45f, 2.5f, 2.42f})}) {
      TrowbridgeReitz d(alpha, alpha * 0.7f);
      cases.push_back(
          {"rough dielectric alpha " + std::to_string(alpha) + " eta " + std::to_string(eta[0]),
           DielectricBsdf(eta, kLanes, true, d),
           [=](int lane) { return Bsdf(DielectricBsdf(with_hero(eta, lane), kLanes, true, d)); }});
    }
    SampledSpectrum eta = spectrum_of({0.2f, 0.5f, 1.1f, 0.15f});
    SampledSpectrum k = spectrum_of({3.9f, 2.9f, 2.6f, 3.5f});
    TrowbridgeReitz d(alpha, alpha);
    cases.push_back({"rough conductor alpha " + std::to_string(alpha),
                     ConductorBsdf(eta, k, kLanes, d), [=](int lane) {
                       return Bsdf(
                           ConductorBsdf(with_hero(eta, lane), with_hero(k, lane), kLanes, d));
                     }});
  }
  return cases;
}

// For each non-specular BSDF, each lane and several incident directions (including grazing and
// from below the surface): samples drawn with that lane as hero follow pdf()[lane] of the
// original BSDF (chi-square, reject at p < 1e-5 per test). One test per BSDF so ctest can run
// them in parallel.
class BsdfSamplingTest : public ::testing::TestWithParam<int> {};

TEST_P(BsdfSamplingTest, MatchesPdfPerLane) {
  const Case c = rough_cases()[GetParam()];
  for (float theta : {0.0f, 45.0f, 85.0f, 135.0f, 179.0f}) {
    Vec3f wo = direction(theta, 30);
    auto expected = expected_counts([&](const Vec3f& wi) { return worker::pdf(c.bsdf, wo, wi); },
                                    kLanes, kSamplesPerTest);
    for (int lane = 0; lane < kLanes; ++lane) {
      Bsdf hero = c.with_lane_as_hero(lane);
      std::vector<double> observed(kCells, 0.0);
      for (std::uint32_t i = 0; i < kSamplesPerTest; ++i) {
        Sampler s(job::SamplerKind::kIndependent, SampleKey{99, 0, std::uint32_t(lane), 0, i});
        float uc = s.get1d();
        Point2f u;
        s.get2d(u.x, u.y);
        auto bs = worker::sample(hero, wo, uc, u);
        if (bs) observed[cell_of(bs->wi)] += 1;
      }
      auto result = spectral::testing::chi_square(observed, expected[lane], 5.0);
      EXPECT_GT(result.p_value, 1e-5)
          << c.name << " theta " << theta << " lane " << lane << ": " << result.describe();
    }
  }
}

INSTANTIATE_TEST_SUITE_P(AllRoughBsdfs, BsdfSamplingTest,
                         ::testing::Range(0, int(rough_cases().size())));

// Nearly index-matched rough glass (η − 1 = 5e-4) has a transmission lobe far too narrow to
// bin, but must stay finite: every sample's f and pdf are finite and agree with eval()/pdf().
TEST(BsdfTest, NearlyIndexMatchedRoughGlassStaysFinite) {
  SampledSpectrum eta = spectrum_of({1.0005f, 1.001f, 1.0002f, 1.0f});
  for (float alpha : {0.01f, 0.05f, 0.5f}) {
    DielectricBsdf bsdf(eta, kLanes, true, TrowbridgeReitz(alpha, alpha));
    for (float theta : {0.0f, 30.0f, 89.9f, 120.0f}) {
      Vec3f wo = direction(theta, 0);
      for (std::uint32_t i = 0; i < 20000; ++i) {
        Sampler s(job::SamplerKind::kIndependent, SampleKey{8, 0, 0, 0, i});
        float uc = s.get1d();
        Point2f u;
        s.get2d(u.x, u.y);
        auto bs = bsdf.sample(wo, uc, u);
        if (!bs) continue;
        ASSERT_FALSE(bs->f.has_non_finite()) << alpha << " " << theta;
        ASSERT_FALSE(bs->pdf.has_non_finite()) << alpha << " " << theta;
        ASSERT_TRUE(is_finite(bs->wi));
        ASSERT_GT(bs->pdf[0], 0.0f);
      }
    }
  }
}

// sample() reports exactly what eval() and pdf() say for the direction it drew.
TEST(BsdfTest, SampleAgreesWithEvalAndPdf) {
  for (const Case& c : rough_cases()) {
    Vec3f wo = direction(60, 10);
    for (std::uint32_t i = 0; i < 2000; ++i) {
      Sampler s(job::SamplerKind::kIndependent, SampleKey{5, 0, 0, 0, i});
      float uc = s.get1d();
      Point2f u;
      s.get2d(u.x, u.y);
      auto bs = worker::sample(c.bsdf, wo, uc, u);
      if (!bs) continue;
      SampledSpectrum f = worker::eval(c.bsdf, wo, bs->wi);
      SampledSpectrum p = worker::pdf(c.bsdf, wo, bs->wi);
      for (int lane = 0; lane < kLanes; ++lane) {
        ASSERT_NEAR(bs->f[lane], f[lane], 1e-4f * std::max(1.0f, f[lane])) << c.name;
        ASSERT_NEAR(bs->pdf[lane], p[lane], 1e-4f * std::max(1.0f, p[lane])) << c.name;
      }
    }
  }
}

// Smooth dielectric: the event probabilities are the hero's Fresnel terms; reflection keeps
// every lane with its own Fresnel probability, dispersive refraction keeps only the hero.
TEST(BsdfTest, SmoothDielectricEventsAndLanes) {
  SampledSpectrum eta = spectrum_of({1.5f, 1.52f, 1.55f, 1.6f});
  DielectricBsdf bsdf(eta, kLanes, true, TrowbridgeReitz(0, 0));
  for (float theta : {0.0f, 60.0f, 89.0f, 120.0f, 150.0f}) {
    Vec3f wo = direction(theta, 0);
    float r0 = fresnel_dielectric(wo.z, eta[0]);
    constexpr int kN = 200000;
    int reflected = 0;
    for (int i = 0; i < kN; ++i) {
      float uc = (i + 0.5f) / kN;
      auto bs = bsdf.sample(wo, uc, {0.5f, 0.5f});
      ASSERT_TRUE(bs.has_value());
      ASSERT_TRUE(bs->specular);
      if (!bs->transmission) {
        ++reflected;
        for (int lane = 0; lane < kLanes; ++lane) {
          ASSERT_FLOAT_EQ(bs->pdf[lane], fresnel_dielectric(wo.z, eta[lane]));
        }
      } else {
        ASSERT_TRUE(bs->hero_only);
        ASSERT_EQ(bs->pdf[1], 0.0f);
        // Snell's law holds for the hero.
        float sin_o = std::sqrt(1 - wo.z * wo.z), sin_i = std::sqrt(1 - bs->wi.z * bs->wi.z);
        float etap = wo.z > 0 ? eta[0] : 1 / eta[0];
        ASSERT_NEAR(sin_o, etap * sin_i, 1e-4f);
        ASSERT_LT(bs->wi.z * wo.z, 0.0f);
      }
    }
    EXPECT_NEAR(double(reflected) / kN, r0, 1e-4) << "theta " << theta;
  }
}

// White furnace for a single scattering event: ∫ f cos dω = albedo, estimated by sampling,
// agrees with the directly integrated value; a conductor with k = 0, η = 1 would be black, while
// Fresnel ≤ 1 keeps every albedo ≤ 1 (energy conservation).
TEST(BsdfTest, AlbedoNeverExceedsOne) {
  for (const Case& c : rough_cases()) {
    for (float theta : {10.0f, 70.0f, 89.0f}) {
      Vec3f wo = direction(theta, 0);
      double sum[kLanes] = {};
      constexpr int kN = 100000;
      for (std::uint32_t i = 0; i < kN; ++i) {
        Sampler s(job::SamplerKind::kSobol, SampleKey{1, 0, 0, 0, i});
        float uc = s.get1d();
        Point2f u;
        s.get2d(u.x, u.y);
        auto bs = worker::sample(c.bsdf, wo, uc, u);
        if (!bs || bs->pdf[0] == 0) continue;
        // The hero's own estimator of its albedo.
        sum[0] += bs->f[0] * abs_cos_theta(bs->wi) / bs->pdf[0];
      }
      EXPECT_LE(sum[0] / kN, 1.0 + 1e-2) << c.name << " theta " << theta;
    }
  }
}

// Diffuse transmission's hero estimator of its albedo is R + T in every sample (the side is
// chosen in proportion to R and T, the direction by the cosine), and it transmits a fraction
// T/(R + T) of them, to the side opposite wo.
TEST(BsdfTest, DiffuseTransmissionAlbedoIsReflectancePlusTransmittance) {
  DiffuseTransmissionBsdf bsdf(spectrum_of({0.3f, 0.5f, 0.1f, 0.6f}),
                               spectrum_of({0.5f, 0.2f, 0.8f, 0.3f}), kLanes);
  for (float theta : {30.0f, 150.0f}) {
    const Vec3f wo = direction(theta, 20);
    int transmitted = 0;
    constexpr int kN = 20000;
    for (std::uint32_t i = 0; i < kN; ++i) {
      Sampler s(job::SamplerKind::kIndependent, SampleKey{4, 0, 0, 0, i});
      const float uc = s.get1d();
      Point2f u;
      s.get2d(u.x, u.y);
      auto bs = bsdf.sample(wo, uc, u);
      ASSERT_TRUE(bs);
      EXPECT_NEAR(bs->f[0] * abs_cos_theta(bs->wi) / bs->pdf[0], 0.8, 1e-5);
      EXPECT_EQ(bs->transmission, !same_hemisphere(wo, bs->wi));
      transmitted += bs->transmission ? 1 : 0;
    }
    // Binomial: 0.625 of 20000, standard deviation 0.0034.
    EXPECT_NEAR(double(transmitted) / kN, 0.625, 4 * 0.0034) << "theta " << theta;
  }
}

// A thin dielectric slab: at normal incidence R' = 2R/(1 + R) (R = ((η−1)/(η+1))², every
// internal bounce summed); reflection mirrors, transmission goes straight through, every lane
// follows either event with its own probability, and the events' frequencies follow R'.
TEST(BsdfTest, ThinDielectricSumsItsInternalBounces) {
  const SampledSpectrum eta = spectrum_of({1.5f, 1.52f, 1.55f, 2.4f});
  ThinDielectricBsdf bsdf(eta, kLanes);
  for (int lane = 0; lane < kLanes; ++lane) {
    const double r = std::pow((eta[lane] - 1.0) / (eta[lane] + 1.0), 2);
    EXPECT_NEAR(bsdf.reflectance(lane, 1.0f), 2 * r / (1 + r), 1e-6) << lane;
    EXPECT_NEAR(bsdf.reflectance(lane, -1.0f), 2 * r / (1 + r), 1e-6) << lane;
  }
  const Vec3f wo = direction(40, 15);
  int reflected = 0;
  constexpr int kN = 20000;
  for (std::uint32_t i = 0; i < kN; ++i) {
    auto bs = bsdf.sample(wo, (i + 0.5f) / kN, {0.5f, 0.5f});
    ASSERT_TRUE(bs);
    EXPECT_TRUE(bs->specular);
    EXPECT_FALSE(bs->hero_only);
    if (bs->transmission) {
      EXPECT_EQ(bs->wi, -wo);
    } else {
      EXPECT_EQ(bs->wi, Vec3f(-wo.x, -wo.y, wo.z));
      ++reflected;
    }
    for (int lane = 0; lane < kLanes; ++lane) {
      const float r = bsdf.reflectance(lane, wo.z);
      EXPECT_FLOAT_EQ(bs->pdf[lane], bs->transmission ? 1 - r : r);
      EXPECT_FLOAT_EQ(bs->f[lane] * abs_cos_theta(bs->wi), bs->pdf[lane]);
    }
  }
  EXPECT_NEAR(double(reflected) / kN, bsdf.reflectance(0, wo.z), 1.0 / kN + 1e-6);
}

TEST(BsdfTest, DiffuseAlbedoIsReflectance) {
  DiffuseBsdf bsdf(spectrum_of({0.25f, 1.0f, 0.5f, 0.75f}), kLanes);
  Vec3f wo = direction(40, 0);
  double sum[kLanes] = {};
  constexpr int kN = 4096;
  for (std::uint32_t i = 0; i < kN; ++i) {
    Sampler s(job::SamplerKind::kSobol, SampleKey{3, 0, 0, 0, i});
    Point2f u;
    s.get2d(u.x, u.y);
    auto bs = bsdf.sample(wo, 0, u);
    ASSERT_TRUE(bs);
    for (int l = 0; l < kLanes; ++l) sum[l] += bs->f[l] * abs_cos_theta(bs->wi) / bs->pdf[l];
  }
  EXPECT_NEAR(sum[0] / kN, 0.25, 1e-5);
  EXPECT_NEAR(sum[1] / kN, 1.0, 1e-5);
}

TEST(BsdfTest, FresnelLimits) {
  EXPECT_NEAR(fresnel_dielectric(1.0f, 1.5f), 0.04f, 1e-6f);
  EXPECT_FLOAT_EQ(fresnel_dielectric(1.0f, 1.0f), 0.0f);
  // From inside glass beyond the critical angle (41.8°): total internal reflection.
  EXPECT_FLOAT_EQ(fresnel_dielectric(-std::cos(50 * kPi / 180), 1.5f), 1.0f);
  EXPECT_NEAR(fresnel_dielectric(0.0f, 1.5f), 1.0f, 1e-6f);
  // A conductor with k = 0 is a dielectric.
  EXPECT_NEAR(fresnel_complex(0.7f, 1.5f, 0.0f), fresnel_dielectric(0.7f, 1.5f), 1e-6f);
  // Normal incidence on a conductor: ((n-1)² + k²) / ((n+1)² + k²).
  EXPECT_NEAR(fresnel_complex(1.0f, 0.2f, 3.9f), (0.64f + 15.21f) / (1.44f + 15.21f), 1e-5f);
  // A vanishing index (η = k = 0, as a scene may give it) reflects everything, without a NaN;
  // a small one approaches that limit.
  for (float c : {0.0f, 0.3f, 0.7f, 1.0f}) {
    EXPECT_EQ(fresnel_complex(c, 0.0f, 0.0f), 1.0f) << c;
    EXPECT_NEAR(fresnel_complex(c, 1e-3f, 0.0f), 1.0f, 1e-2f) << c;
  }
}

}  // namespace
}  // namespace prism::worker
