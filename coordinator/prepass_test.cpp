#include "coordinator/prepass.h"

#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "services/spectral/pixel_tables.h"
#include "services/spectral/testing/chi_square.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::coordinator {
namespace {

using image::SpectralImage;
using spectral::WavelengthDistribution;

bool has(const absl::Status& s, const std::string& text) {
  return std::string(s.message()).find(text) != std::string::npos;
}

// Distance in units in the last place between two finite floats of the same sign.
std::int64_t ulps(float a, float b) {
  std::int32_t ia, ib;
  std::memcpy(&ia, &a, 4);
  std::memcpy(&ib, &b, 4);
  return std::abs(std::int64_t{ia} - std::int64_t{ib});
}

TEST(PrepassParametersTest, ValidateNamesTheBadField) {
  EXPECT_TRUE(PrepassParameters{}.validate().ok());
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  struct Case {
    PrepassParameters p;
    const char* field;
  };
  std::vector<Case> cases;
  auto with = [](auto edit) {
    PrepassParameters p;
    edit(p);
    return p;
  };
  cases.push_back({with([](auto& p) { p.passes = 0; }), "passes"});
  cases.push_back({with([](auto& p) { p.passes = 9; }), "passes"});
  cases.push_back({with([](auto& p) { p.spp = 0; }), "spp"});
  cases.push_back({with([](auto& p) { p.epsilon = 0.0; }), "epsilon"});
  cases.push_back({with([](auto& p) { p.epsilon = 1.0; }), "epsilon"});
  cases.push_back({with([=](auto& p) { p.epsilon = nan; }), "epsilon"});
  cases.push_back({with([](auto& p) { p.fallback = -1e-9; }), "fallback"});
  cases.push_back({with([=](auto& p) { p.fallback = inf; }), "fallback"});
  cases.push_back({with([](auto& p) { p.sigma_s = 0.0; }), "sigma_s"});
  cases.push_back({with([=](auto& p) { p.sigma_s = inf; }), "sigma_s"});
  cases.push_back({with([](auto& p) { p.sigma_s = 1000.0; }), "sigma_s"});
  cases.push_back({with([](auto& p) { p.sigma_r = -0.015; }), "sigma_r"});
  cases.push_back({with([=](auto& p) { p.sigma_r = nan; }), "sigma_r"});
  for (const Case& c : cases) {
    const absl::Status s = c.p.validate();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << c.field;
    EXPECT_TRUE(has(s, std::string("prepass ") + c.field + " is")) << s;
  }
  // Edges that are allowed.
  EXPECT_TRUE(with([](auto& p) { p.fallback = 0.0; }).validate().ok());
  EXPECT_TRUE(with([](auto& p) { p.passes = 8; }).validate().ok());
}

TEST(PrepassScheduleTest, SampleScaledQuartersTheSamplesOfEarlierPasses) {
  auto s = prepass_schedule(PrepassParameters{}, 320, 200);
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->size(), 2u);
  EXPECT_EQ((*s)[0].index, 1);
  EXPECT_EQ((*s)[0].spp, 32u);
  EXPECT_EQ((*s)[1].spp, 128u);
  for (const PrepassPass& p : *s) {
    EXPECT_EQ(p.width, 320);
    EXPECT_EQ(p.height, 200);
    EXPECT_EQ(p.scale, 1.0);
  }
  PrepassParameters four;
  four.passes = 4;
  s = prepass_schedule(four, 8, 8);
  ASSERT_TRUE(s.ok());
  std::vector<std::uint32_t> spp;
  for (const PrepassPass& p : *s) spp.push_back(p.spp);
  EXPECT_EQ(spp, (std::vector<std::uint32_t>{2, 8, 32, 128}));
  four.passes = 8;  // 128 / 4^7 rounds to 0: at least one sample
  s = prepass_schedule(four, 8, 8);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ((*s)[0].spp, 1u);
  EXPECT_EQ((*s)[7].spp, 128u);
  EXPECT_FALSE(prepass_schedule(PrepassParameters{}, 0, 8).ok());
  PrepassParameters bad;
  bad.passes = 0;
  EXPECT_FALSE(prepass_schedule(bad, 8, 8).ok());
}

TEST(PrepassScheduleTest, ImageScaledQuartersThePixelsOfEarlierPasses) {
  PrepassParameters p;
  p.image_scaled = true;
  p.passes = 3;
  auto s = prepass_schedule(p, 101, 50);
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->size(), 3u);
  EXPECT_EQ((*s)[0].scale, 0.25);
  EXPECT_EQ((*s)[0].width, 26);  // ⌈101/4⌉
  EXPECT_EQ((*s)[0].height, 13);  // ⌈50/4⌉
  EXPECT_EQ((*s)[1].width, 51);
  EXPECT_EQ((*s)[1].height, 25);
  EXPECT_EQ((*s)[2].width, 101);
  EXPECT_EQ((*s)[2].height, 50);
  EXPECT_EQ((*s)[2].scale, 1.0);
  for (const PrepassPass& q : *s) EXPECT_EQ(q.spp, 128u);
  p.passes = 8;
  s = prepass_schedule(p, 3, 1);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ((*s)[0].width, 1);
  EXPECT_EQ((*s)[0].height, 1);
}

TEST(GuideImageTest, AddTileStoresMeanGuidesAndMarksPixelsWithoutSamples) {
  auto tile = image::TileResult::create({2, 1, 4, 3}, {0, 2}, 3, {false, true, {}});
  ASSERT_TRUE(tile.ok());
  const std::vector<double> spectrum = {1.0, 2.0, 3.0};
  for (int s = 0; s < 2; ++s) {
    tile->add_sample(2, 1, spectrum);
    tile->add_guides(2, 1, 0.25f + 0.5f * s, 0.0f, 1.0f, 0.0f, 0.5f);
    tile->add_sample(3, 2, spectrum);
    tile->add_guides(3, 2, 0.5f, 1.0f, 0.0f, 0.0f, 0.25f * s);
  }
  auto guides = GuideImage::create(5, 4);
  ASSERT_TRUE(guides.ok());
  ASSERT_TRUE(guides->add_tile(*tile).ok());
  EXPECT_TRUE(guides->valid(2, 1));
  EXPECT_EQ(guides->at(2, 1).depth, 0.5f);
  EXPECT_EQ(guides->at(2, 1).ny, 1.0f);
  EXPECT_EQ(guides->at(2, 1).albedo, 0.5f);
  EXPECT_EQ(guides->at(3, 2).nx, 1.0f);
  EXPECT_EQ(guides->at(3, 2).albedo, 0.125f);
  EXPECT_FALSE(guides->valid(3, 1));  // no samples
  EXPECT_FALSE(guides->valid(0, 0));  // never written

  auto plain = image::TileResult::create({0, 0, 2, 2}, {0, 1}, 3);
  EXPECT_EQ(guides->add_tile(*plain).code(), absl::StatusCode::kInvalidArgument);
  auto outside = image::TileResult::create({4, 3, 6, 4}, {0, 1}, 3, {false, true, {}});
  EXPECT_EQ(guides->add_tile(*outside).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(GuideImage::create(0, 3).ok());
}

GuideImage random_guides(int w, int h, std::mt19937_64& rng) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  GuideImage g = *GuideImage::create(w, h);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      // Smooth-ish so that many neighbours have non-negligible range weights.
      g.set(x, y, {0.3f + 0.001f * x, 0.0f, 0.01f * u(rng), 1.0f, 0.5f + 0.01f * u(rng)});
    }
  }
  return g;
}

TEST(BilateralFilterTest, ConstantInputStaysConstantAtBordersAndAroundHoles) {
  constexpr int kW = 23, kH = 17, kBins = 6;
  std::mt19937_64 rng(1);
  GuideImage guides = random_guides(kW, kH, rng);
  SpectralImage img = *SpectralImage::create(kW, kH, kBins);
  const float values[kBins] = {0.0f, 1.0f, 0.1f, 3.3e-7f, 12345.678f, 0.7f};
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x)
      for (int b = 0; b < kBins; ++b) img.value(x, y, b) = values[b];
  // A hole without samples and a pixel with a NaN bin: both ignored by their neighbours.
  GuideImage holed = *GuideImage::create(kW, kH);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x)
      if (!(x == 5 && y == 5)) holed.set(x, y, guides.at(x, y));
  img.value(9, 9, 1) = std::numeric_limits<float>::quiet_NaN();
  for (double sigma_s : {0.5, 1.75, 4.0}) {
    auto out = filter_estimate(img, holed, sigma_s, 0.015);
    ASSERT_TRUE(out.ok()) << out.status();
    for (int y = 0; y < kH; ++y) {
      for (int x = 0; x < kW; ++x) {
        for (int b = 0; b < kBins; ++b) {
          const float v = out->value(x, y, b);
          if ((x == 5 && y == 5) || (x == 9 && y == 9)) {
            ASSERT_EQ(v, 0.0f) << x << "," << y;  // unusable pixels are left at zero
          } else {
            ASSERT_LE(ulps(v, values[b]), 1) << x << "," << y << " bin " << b << ": " << v;
          }
        }
      }
    }
  }
}

TEST(BilateralFilterTest, SharpGuideEdgeIsKept) {
  constexpr int kW = 20, kH = 12, kBins = 4;
  std::mt19937_64 rng(2);
  std::normal_distribution<float> noise(0.0f, 0.1f);
  SpectralImage img = *SpectralImage::create(kW, kH, kBins);
  GuideImage guides = *GuideImage::create(kW, kH);
  GuideImage no_edge = *GuideImage::create(kW, kH);
  // Left: a near wall, albedo 0.2, value ≈ 1. Right: a far wall, albedo 0.8, value ≈ 10.
  float lo[2] = {1e30f, 1e30f}, hi[2] = {-1e30f, -1e30f};
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const int side = x < kW / 2 ? 0 : 1;
      guides.set(x, y, side == 0 ? GuideFeatures{0.2f, 0, 0, 1, 0.2f}
                                 : GuideFeatures{0.7f, 0, 0, 1, 0.8f});
      no_edge.set(x, y, {0.2f, 0, 0, 1, 0.2f});
      for (int b = 0; b < kBins; ++b) {
        const float v = (side == 0 ? 1.0f : 10.0f) * (1.0f + noise(rng));
        img.value(x, y, b) = v;
        lo[side] = std::min(lo[side], v);
        hi[side] = std::max(hi[side], v);
      }
    }
  }
  auto out = filter_estimate(img, guides, 1.75, 0.015);
  ASSERT_TRUE(out.ok()) << out.status();
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const int side = x < kW / 2 ? 0 : 1;
      for (int b = 0; b < kBins; ++b) {
        // A convex combination of its own region only: within that region's range.
        const float v = out->value(x, y, b);
        ASSERT_GE(v, lo[side] * (1 - 1e-6f)) << x << "," << y;
        ASSERT_LE(v, hi[side] * (1 + 1e-6f)) << x << "," << y;
      }
    }
  }
  // The columns on either side of the edge keep their region's level (noise averaged down).
  double left = 0.0, right = 0.0;
  for (int y = 0; y < kH; ++y)
    for (int b = 0; b < kBins; ++b) {
      left += out->value(kW / 2 - 1, y, b);
      right += out->value(kW / 2, y, b);
    }
  EXPECT_NEAR(left / (kH * kBins), 1.0, 0.05);
  EXPECT_NEAR(right / (kH * kBins), 10.0, 0.5);
  // Without the guide edge the same filter blurs across: the property above is not vacuous.
  auto blurred = filter_estimate(img, no_edge, 1.75, 0.015);
  ASSERT_TRUE(blurred.ok());
  EXPECT_GT(blurred->value(kW / 2 - 1, kH / 2, 0), 2.0f);
}

TEST(BilateralFilterTest, MatchesADirectEvaluationOfEquation9) {
  constexpr int kW = 9, kH = 7, kBins = 3;
  constexpr double kSigmaS = 1.3, kSigmaR = 0.05;
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  SpectralImage img = *SpectralImage::create(kW, kH, kBins);
  GuideImage guides = *GuideImage::create(kW, kH);
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      guides.set(x, y, {0.1f * u(rng), 0.1f * u(rng), 0.0f, 1.0f, 0.05f * u(rng)});
      for (int b = 0; b < kBins; ++b) img.value(x, y, b) = u(rng) - 0.2f;
    }
  }
  auto out = filter_estimate(img, guides, kSigmaS, kSigmaR);
  ASSERT_TRUE(out.ok());
  const int r = int(std::ceil(3 * kSigmaS));
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      double acc[kBins] = {0, 0, 0}, wsum = 0;
      const GuideFeatures& c = guides.at(x, y);
      for (int ny = 0; ny < kH; ++ny) {
        for (int nx = 0; nx < kW; ++nx) {
          if (std::abs(nx - x) > r || std::abs(ny - y) > r) continue;
          const GuideFeatures& n = guides.at(nx, ny);
          const double f[5] = {c.depth - n.depth, c.nx - n.nx, c.ny - n.ny, c.nz - n.nz,
                               c.albedo - n.albedo};
          double d2 = 0;
          for (double v : f) d2 += v * v;
          const double s2 = double((nx - x) * (nx - x) + (ny - y) * (ny - y));
          const double wgt =
              std::exp(-s2 / (2 * kSigmaS * kSigmaS)) * std::exp(-d2 / (2 * kSigmaR * kSigmaR));
          for (int b = 0; b < kBins; ++b) acc[b] += wgt * img.value(nx, ny, b);
          wsum += wgt;
        }
      }
      for (int b = 0; b < kBins; ++b) {
        ASSERT_NEAR(out->value(x, y, b), acc[b] / wsum, 1e-6) << x << "," << y << "," << b;
      }
    }
  }
}

TEST(BilateralFilterTest, SameBytesWithOneThreadOrMany) {
  constexpr int kW = 40, kH = 33, kBins = 16;
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  GuideImage guides = random_guides(kW, kH, rng);
  SpectralImage img = *SpectralImage::create(kW, kH, kBins);
  for (float& v : img.data()) v = u(rng);
  auto many = filter_estimate(img, guides, 1.75, 0.015);
  absl::StatusOr<SpectralImage> one = absl::UnknownError("not run");
  tbb::task_arena arena(1);
  arena.execute([&] { one = filter_estimate(img, guides, 1.75, 0.015); });
  ASSERT_TRUE(many.ok() && one.ok());
  ASSERT_EQ(0, std::memcmp(many->data().data(), one->data().data(), many->data().size_bytes()));
}

TEST(BilateralFilterTest, RefusesMismatchedInputs) {
  SpectralImage img = *SpectralImage::create(4, 4, 2);
  GuideImage guides = *GuideImage::create(4, 5);
  EXPECT_EQ(filter_estimate(img, guides, 1.75, 0.015).status().code(),
            absl::StatusCode::kInvalidArgument);
  GuideImage ok = *GuideImage::create(4, 4);
  EXPECT_FALSE(filter_estimate(img, ok, 0.0, 0.015).ok());
  EXPECT_FALSE(filter_estimate(img, ok, 1.75, -1.0).ok());
}

// An emitter mixture over 32 bins that is zero in bins 0..3 and 28..31 (no emitter there).
WavelengthDistribution partial_emitters(int bins = 32) {
  std::vector<double> w(static_cast<size_t>(bins), 0.0);
  for (int b = 4; b < bins - 4; ++b) w[b] = 1.0 + 0.5 * std::sin(0.7 * b) + (b == 13 ? 30.0 : 0.0);
  return *WavelengthDistribution::from_table(w);
}

int quantised_units(std::span<const std::uint16_t> cdf, int b) { return cdf[b + 1] - cdf[b]; }

TEST(PrepassTablesTest, EveryBinWhereAnEmitterEmitsKeepsPositiveQuantisedMass) {
  constexpr int kBins = 32, kW = 6, kH = 1;
  const WavelengthDistribution e = partial_emitters(kBins);
  const WavelengthDistribution sensor = *WavelengthDistribution::visible(kBins);
  SpectralImage img = *SpectralImage::create(kW, kH, kBins);
  // 0: all energy in one bin outside the emitters' support; 1: one huge spike inside it;
  // 2: zero in every support bin, tiny outside; 3: negative and positive noise; 4: all zero;
  // 5: a NaN.
  img.value(0, 0, 1) = 5.0f;
  img.value(1, 0, 20) = 1e30f;
  img.value(1, 0, 21) = 1e-30f;
  img.value(2, 0, 0) = 1e-20f;
  img.value(2, 0, 31) = 1e-20f;
  std::mt19937_64 rng(6);
  std::normal_distribution<float> n(0.0f, 1.0f);
  for (int b = 0; b < kBins; ++b) img.value(3, 0, b) = n(rng);
  img.value(5, 0, 7) = std::numeric_limits<float>::quiet_NaN();
  PrepassParameters params;
  params.fallback = 0.0;
  for (const WavelengthDistribution* s : {static_cast<const WavelengthDistribution*>(nullptr),
                                          &sensor}) {
    auto tables = build_tables(img, params, e, s);
    ASSERT_TRUE(tables.ok()) << tables.status();
    const int support = kBins - 8;
    const int floor_units = int(std::floor(65535.0 * params.epsilon / support)) - 1;
    for (int x = 0; x < kW; ++x) {
      ASSERT_NE(tables->source(x, 0), PixelSource::kMatchesDefault) << x;
      std::span<const std::uint16_t> cdf = tables->cdf(x, 0);
      ASSERT_EQ(cdf.size(), size_t(kBins) + 1);
      ASSERT_EQ(cdf.back(), 65535);
      for (int b = 0; b < kBins; ++b) {
        if (e.cell_mass(b) > 0.0) {
          EXPECT_GE(quantised_units(cdf, b), floor_units) << "pixel " << x << " bin " << b;
        }
      }
    }
    EXPECT_EQ(tables->source(4, 0), PixelSource::kNoEstimate);
    EXPECT_EQ(tables->source(5, 0), PixelSource::kNoEstimate);
    EXPECT_EQ(tables->source(0, 0), PixelSource::kLearned);
    // Outside the support only the estimate gives mass: bin 1 of pixel 0 and the tiny bins of
    // pixel 2 (kept positive by quantisation), nothing elsewhere.
    EXPECT_GT(quantised_units(tables->cdf(0, 0), 1), 60000);
    EXPECT_EQ(quantised_units(tables->cdf(0, 0), 0), 0);
    EXPECT_EQ(quantised_units(tables->cdf(1, 0), 30), 0);
    EXPECT_GT(quantised_units(tables->cdf(2, 0), 0), 0);
    EXPECT_GT(quantised_units(tables->cdf(2, 0), 31), 0);
    EXPECT_GT(quantised_units(tables->cdf(1, 0), 21), 0);
  }
}

// The table of a learned pixel is r_def = ε·p_ε + (1 − ε)·s·x/Σ(s·x), quantised; of a pixel
// without estimate the same with x = E, which is the job's default (sensor × emitters, mixed).
TEST(PrepassTablesTest, TablesAreTheQuantisedDefensiveMixture) {
  constexpr int kBins = 32;
  const WavelengthDistribution e = partial_emitters(kBins);
  const WavelengthDistribution sensor = *WavelengthDistribution::visible(kBins);
  SpectralImage img = *SpectralImage::create(2, 1, kBins);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> u(-0.2f, 1.0f);
  for (int b = 0; b < kBins; ++b) img.value(0, 0, b) = u(rng);
  PrepassParameters params;
  auto tables = build_tables(img, params, e, &sensor);
  ASSERT_TRUE(tables.ok());
  std::vector<double> x(kBins), want(kBins);
  double sx = 0;
  for (int b = 0; b < kBins; ++b) {
    x[b] = std::max(0.0f, img.value(0, 0, b)) * sensor.cell_mass(b);
    sx += x[b];
  }
  for (int b = 0; b < kBins; ++b) {
    want[b] = params.epsilon * (e.cell_mass(b) > 0 ? 1.0 / (kBins - 8) : 0.0) +
              (1 - params.epsilon) * x[b] / sx;
  }
  const std::vector<std::uint16_t> oracle = WavelengthDistribution::from_table(want)->quantise();
  const WavelengthDistribution def =
      *WavelengthDistribution::product(sensor, e)->mix_defensive(params.epsilon, e);
  const std::vector<std::uint16_t> default_q = def.quantise();
  for (int b = 0; b < kBins; ++b) {
    // Within one unit: the oracle's floating-point sums may round a remainder differently.
    EXPECT_NEAR(quantised_units(tables->cdf(0, 0), b), oracle[b + 1] - oracle[b], 1) << b;
    EXPECT_NEAR(quantised_units(tables->cdf(1, 0), b), default_q[b + 1] - default_q[b], 1) << b;
  }
  EXPECT_EQ(tables->source(1, 0), PixelSource::kNoEstimate);
}

TEST(PrepassTablesTest, FallbackHoldsForTheEmitterMixtureAtAnyScaleOnly) {
  constexpr int kBins = 32;
  // Positive everywhere, so that perturbations below keep the spectrum non-negative.
  std::vector<double> ew(kBins);
  for (int b = 0; b < kBins; ++b) ew[b] = 1.0 + 0.5 * std::sin(0.3 * b);
  const WavelengthDistribution e = *WavelengthDistribution::from_table(ew);
  PrepassParameters params;  // h = 2e-4
  const double delta_in = std::sqrt(0.8 * params.fallback);
  const double delta_out = std::sqrt(1.25 * params.fallback);
  const float scales[] = {1e-6f, 1.0f, 3.7f, 1e8f};
  SpectralImage img = *SpectralImage::create(4, 4, kBins);
  // Row 0: c·E. Row 1: E at unit mean plus ±δ (zero-sum, so the mean stays 1 and the mean
  // squared difference is exactly δ²) with δ² = 0.8h. Row 2: the same with δ² = 1.25h.
  // Row 3: a different spectrum (E reversed).
  for (int x = 0; x < 4; ++x) {
    for (int b = 0; b < kBins; ++b) {
      const double unit = e.cell_mass(b) * kBins;
      const double sign = b % 2 == 0 ? 1.0 : -1.0;
      img.value(x, 0, b) = float(scales[x] * e.cell_mass(b));
      img.value(x, 1, b) = float(scales[x] * (unit + sign * delta_in));
      img.value(x, 2, b) = float(scales[x] * (unit + sign * delta_out));
      img.value(x, 3, b) = float(scales[x] * e.cell_mass(kBins - 1 - b));
    }
  }
  auto tables = build_tables(img, params, e, nullptr);
  ASSERT_TRUE(tables.ok());
  for (int x = 0; x < 4; ++x) {
    EXPECT_EQ(tables->source(x, 0), PixelSource::kMatchesDefault) << x;
    EXPECT_EQ(tables->source(x, 1), PixelSource::kMatchesDefault) << x;
    EXPECT_EQ(tables->source(x, 2), PixelSource::kLearned) << x;
    EXPECT_EQ(tables->source(x, 3), PixelSource::kLearned) << x;
    for (std::uint16_t q : tables->cdf(x, 0)) EXPECT_EQ(q, 0);  // no table
  }
  EXPECT_EQ(tables->count(PixelSource::kMatchesDefault), 8);
  EXPECT_DOUBLE_EQ(tables->fallback_fraction(), 0.5);

  // A pixel that fell back stays so in later passes whatever its (skipped) estimate says; the
  // filter ignores it as a neighbour.
  SpectralImage next = *SpectralImage::create(4, 4, kBins);
  for (float& v : next.data()) v = 1.0f;
  auto later = build_tables(next, params, e, nullptr, &*tables);
  ASSERT_TRUE(later.ok());
  EXPECT_EQ(later->source(0, 0), PixelSource::kMatchesDefault);
  EXPECT_EQ(later->source(0, 2), PixelSource::kLearned);
  GuideImage g = *GuideImage::create(4, 4);
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x) g.set(x, y, {});
  for (int b = 0; b < kBins; ++b) next.value(1, 0, b) = 1e9f;  // skipped: must not leak
  auto filtered = filter_estimate(next, g, 1.75, 0.015, &*tables);
  ASSERT_TRUE(filtered.ok());
  EXPECT_LE(ulps(filtered->value(1, 2, 0), 1.0f), 1);
  EXPECT_EQ(filtered->value(1, 0, 0), 0.0f);
  // With h = 0 only an exact match could fall back.
  params.fallback = 0.0;
  EXPECT_EQ(build_tables(img, params, e, nullptr)->source(1, 1), PixelSource::kLearned);
}

TEST(PrepassTablesTest, RefusesMismatchedInputs) {
  SpectralImage img = *SpectralImage::create(2, 2, 16);
  const WavelengthDistribution e16 = *WavelengthDistribution::flat(16);
  const WavelengthDistribution e8 = *WavelengthDistribution::flat(8);
  EXPECT_TRUE(build_tables(img, {}, e16, nullptr).ok());
  absl::Status s = build_tables(img, {}, e8, nullptr).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(has(s, "emitter mixture has 8 cells")) << s;
  EXPECT_FALSE(build_tables(img, {}, e16, &e8).ok());
  PrepassParameters bad;
  bad.epsilon = 2.0;
  EXPECT_TRUE(has(build_tables(img, bad, e16, nullptr).status(), "epsilon"));
  SpectralImage other = *SpectralImage::create(3, 2, 16);
  auto prev = build_tables(other, {}, e16, nullptr);
  EXPECT_FALSE(build_tables(img, {}, e16, nullptr, &*prev).ok());
}

// Pipeline tables through the wire: encode a tile, decode it as a worker would, and check
// every pixel's table bytes and that CMIS lanes sample the decoded (quantised) pdf.
TEST(PrepassTablesTest, TilesRoundTripAndSampleTheirQuantisedPdf) {
  constexpr int kW = 7, kH = 5, kBins = 64;
  const WavelengthDistribution e = partial_emitters(kBins);
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  SpectralImage img = *SpectralImage::create(kW, kH, kBins);
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      for (int b = 0; b < kBins; ++b) img.value(x, y, b) = u(rng) * u(rng) * u(rng);
      if (x == 1) {  // very peaked: a narrow line
        for (int b = 0; b < kBins; ++b) img.value(x, y, b) = b == 10 + y ? 1e4f : 1e-6f;
      }
      if (x == 2 && y == 2) {
        for (int b = 0; b < kBins; ++b) img.value(x, y, b) = float(e.cell_mass(b) * 7.0);
      }
    }
  }
  auto tables = build_tables(img, {}, e, nullptr);
  ASSERT_TRUE(tables.ok());
  ASSERT_EQ(tables->source(2, 2), PixelSource::kMatchesDefault);
  const image::TileRect rect{1, 1, 5, 4};
  auto bytes = tables->encode_tile(rect);
  ASSERT_TRUE(bytes.ok());
  ASSERT_EQ(bytes->size(), spectral::pixel_table_bytes(4, 3, kBins));
  auto decoded = spectral::PixelTables::decode(4, 3, kBins, *bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  EXPECT_EQ(decoded->default_pixels(), 1);
  EXPECT_TRUE(decoded->uses_default(1, 1));  // image pixel (2, 2)

  constexpr int kSamples = 60000;
  const double threshold = spectral::testing::sidak_threshold(1e-4, 5 * 4);
  int tested = 0;
  for (int ty = 0; ty < 3; ++ty) {
    for (int tx = 0; tx < 4; ++tx) {
      const spectral::QuantisedWavelengthCdf* q = decoded->table(tx, ty);
      if (q == nullptr) continue;
      const std::span<const std::uint16_t> cdf = tables->cdf(rect.x0 + tx, rect.y0 + ty);
      for (int b = 0; b < kBins; ++b) {
        ASSERT_EQ(q->cell_pdf(b), float(double(cdf[b + 1] - cdf[b]) / 65535.0 /
                                        (spectral::kLambdaRange / kBins)));
      }
      // The peaked column (image x = 1, tile x = 0) and two ordinary pixels.
      if (!(tx == 0 || (tx == 2 && ty == 1) || (tx == 3 && ty == 2))) continue;
      ++tested;
      for (int lane = 0; lane < 4; ++lane) {
        std::vector<double> observed(kBins, 0.0), expected(kBins, 0.0);
        std::uniform_real_distribution<double> v(0.0, 1.0);
        for (int i = 0; i < kSamples; ++i) {
          const spectral::SampledWavelengths s = q->sample_lanes(v(rng), 4);
          ASSERT_EQ(s.pdf(lane), q->pdf(s.lambda(lane)));
          const int c = std::min(kBins - 1, int((s.lambda(lane) - spectral::kLambdaMin) /
                                                (spectral::kLambdaRange / kBins)));
          observed[c] += 1.0;
        }
        for (int b = 0; b < kBins; ++b) expected[b] = double(kSamples) * (cdf[b + 1] - cdf[b]) / 65535.0;
        const auto r = spectral::testing::chi_square(observed, expected);
        EXPECT_GT(r.p_value, threshold) << tx << "," << ty << " lane " << lane << ": "
                                        << r.describe();
      }
    }
  }
  EXPECT_EQ(tested, 5);
  EXPECT_FALSE(tables->encode_tile({5, 3, 8, 5}).ok());
  EXPECT_FALSE(tables->encode_tile({2, 2, 2, 4}).ok());
}

TEST(PrepassTablesTest, UpsamplingTakesThePixelHoldingEachCentre) {
  constexpr int kBins = 8;
  SpectralImage img = *SpectralImage::create(2, 3, kBins);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 2; ++x) img.value(x, y, (x + 2 * y) % kBins) = 1.0f;
  const WavelengthDistribution e = *WavelengthDistribution::flat(kBins);
  auto low = build_tables(img, {}, e, nullptr);
  ASSERT_TRUE(low.ok());
  auto high = upsample_tables(*low, 5, 7);
  ASSERT_TRUE(high.ok());
  for (int y = 0; y < 7; ++y) {
    for (int x = 0; x < 5; ++x) {
      const int sx = int((x + 0.5) * 2 / 5), sy = int((y + 0.5) * 3 / 7);
      const auto a = high->cdf(x, y), b = low->cdf(sx, sy);
      ASSERT_TRUE(std::equal(a.begin(), a.end(), b.begin())) << x << "," << y;
      ASSERT_EQ(high->source(x, y), low->source(sx, sy));
    }
  }
  EXPECT_FALSE(upsample_tables(*low, 0, 4).ok());
}

}  // namespace
}  // namespace prism::coordinator
