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
#include "services/spectral/binned_shape.h"
#include "services/spectral/pixel_tables.h"
#include "services/spectral/testing/chi_square.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::coordinator {
namespace {

using image::SpectralImage;
using spectral::WavelengthDistribution;

// Distance in units in the last place between two finite floats of the same sign.
std::int64_t ulps(float a, float b) {
  std::int32_t ia, ib;
  std::memcpy(&ia, &a, 4);
  std::memcpy(&ib, &b, 4);
  return std::abs(std::int64_t{ia} - std::int64_t{ib});
}

TEST(PrepassScheduleTest, SampleScaledDividesTheSamplesOfEarlierPassesByEight) {
  auto s = prepass_schedule(job::PrepassParameters{}, 320, 200);
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->size(), 2u);
  EXPECT_EQ((*s)[0].index, 1);
  EXPECT_EQ((*s)[0].spp, 16u);
  EXPECT_EQ((*s)[1].spp, 128u);
  for (const PrepassPass& p : *s) {
    EXPECT_EQ(p.width, 320);
    EXPECT_EQ(p.height, 200);
    EXPECT_EQ(p.scale, 1.0);
  }
  job::PrepassParameters four;
  four.passes = 4;
  s = prepass_schedule(four, 8, 8);
  ASSERT_TRUE(s.ok());
  std::vector<std::uint32_t> spp;
  for (const PrepassPass& p : *s) spp.push_back(p.spp);
  EXPECT_EQ(spp, (std::vector<std::uint32_t>{1, 2, 16, 128}));  // 128/8³ rounds to 0: 1
  four.passes = 8;
  s = prepass_schedule(four, 8, 8);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ((*s)[0].spp, 1u);
  EXPECT_EQ((*s)[7].spp, 128u);
  EXPECT_FALSE(prepass_schedule(job::PrepassParameters{}, 0, 8).ok());
  job::PrepassParameters bad;
  bad.passes = 0;
  EXPECT_FALSE(prepass_schedule(bad, 8, 8).ok());
}

TEST(PrepassScheduleTest, ImageScaledQuartersThePixelsOfEarlierPasses) {
  job::PrepassParameters p;
  p.image_scaled = true;
  p.passes = 3;
  auto s = prepass_schedule(p, 101, 50);
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->size(), 3u);
  EXPECT_EQ((*s)[0].scale, 0.25);
  EXPECT_EQ((*s)[0].width, 26);   // ⌈101/4⌉
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
      guides.set(
          x, y,
          side == 0 ? GuideFeatures{0.2f, 0, 0, 1, 0.2f} : GuideFeatures{0.7f, 0, 0, 1, 0.8f});
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

// Default bin masses D_b over 32 bins, zero in bins 0..3 and 28..31 (no emitter there).
}  // namespace
}  // namespace prism::coordinator
