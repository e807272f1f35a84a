// Gathering's filter (gather.h) on synthetic images with known answers: a noisy rainbow whose
// offsets all agree comes out closer to the clean one, offsets that cancel (two caustics
// crossing) leave the image as it is, pixels without offsets are never touched, and another
// surface's pixels along the line lend nothing.
#include "coordinator/gather.h"

#include <gtest/gtest.h>

#include <random>
#include <vector>

namespace prism::coordinator {
namespace {

constexpr int kW = 40, kH = 12, kBins = 16;
constexpr double kBinWidth = 470.0 / kBins;

// A rainbow on a flat floor: bin b lit in column 8 + b (one pixel per bin), every row; the sky
// (no guides) nowhere. `noise`: each lit value is scaled by an independent factor, mean 1, as a
// few samples per pixel would. Offsets: each lit pixel's events moved by +1 pixel per bin width.
struct Rainbow {
  image::SpectralImage image = *image::SpectralImage::create(kW, kH, kBins);
  image::SpectralImage clean = *image::SpectralImage::create(kW, kH, kBins);
  std::vector<std::uint64_t> counts = std::vector<std::uint64_t>(kW * kH, 16);
  std::vector<double> offsets = std::vector<double>(kW * kH * image::kOffsetValues, 0.0);
  std::vector<float> depth = std::vector<float>(kW * kH, 0.5f * 16);
  std::vector<float> normals = std::vector<float>(kW * kH * 3, 0.0f);

  Rainbow(double noise, double dx_per_nm, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::gamma_distribution<double> factor(1.0 / (noise * noise), noise * noise);
    for (int p = 0; p < kW * kH; ++p) normals[std::size_t(p) * 3 + 1] = 16.0f;  // up, summed
    for (int y = 0; y < kH; ++y) {
      for (int b = 0; b < kBins; ++b) {
        const int x = 8 + b;
        clean.value(x, y, b) = 1.0f;
        image.value(x, y, b) = noise > 0 ? float(factor(rng)) : 1.0f;
        add_event(x, y, image.value(x, y, b) * kBinWidth, dx_per_nm);
      }
    }
  }
  void add_event(int x, int y, double w, double dx) {
    double* o = &offsets[(std::size_t(y) * kW + x) * image::kOffsetValues];
    const double n = 16;  // the sums are over the pixel's samples
    o[0] += n * w;
    o[1] += n * w * dx;
    o[3] += n * w * dx * dx;
  }
  GatherInputs inputs() const { return {&image, counts, offsets, depth, normals}; }
};

double squared_error(const image::SpectralImage& a, const image::SpectralImage& b) {
  double sum = 0;
  for (std::size_t i = 0; i < a.data().size(); ++i) {
    const double d = double(a.data()[i]) - b.data()[i];
    sum += d * d;
  }
  return sum;
}

TEST(GatherTest, ANoisyRainbowComesOutCloserToTheCleanOne) {
  const Rainbow r(0.8, 1.0 / kBinWidth, 7);
  GatherStats stats;
  auto out = gather_filter(r.inputs(), 3 * kBinWidth, &stats);
  ASSERT_TRUE(out.ok()) << out.status();
  EXPECT_LT(squared_error(*out, r.clean), 0.5 * squared_error(r.image, r.clean));
  EXPECT_EQ(stats.pixels_incoherent, 0u);
  EXPECT_GT(stats.pixels_filtered, std::uint64_t(kBins * kH));
  // The filter moves energy along the rainbow only: nothing lands in a bin that the rainbow has
  // nowhere near its column.
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      for (int b = 0; b < kBins; ++b) {
        if (std::abs((x - 8) - b) > 4) {
          EXPECT_EQ(out->value(x, y, b), 0.0f) << x << "," << b;
        }
      }
    }
  }
  // A clean rainbow is a fixed point up to the ends of the spectrum.
  const Rainbow exact(0.0, 1.0 / kBinWidth, 7);
  auto same = gather_filter(exact.inputs(), 3 * kBinWidth);
  ASSERT_TRUE(same.ok());
  for (int y = 0; y < kH; ++y) {
    for (int b = 3; b < kBins - 3; ++b) EXPECT_NEAR(same->value(8 + b, y, b), 1.0f, 1e-6f);
  }
}

TEST(GatherTest, OffsetsThatDisagreeLeaveTheImageAlone) {
  Rainbow r(0.8, 1.0 / kBinWidth, 9);
  // A second caustic through the same pixels, as strong, moving the other way.
  for (int y = 0; y < kH; ++y) {
    for (int b = 0; b < kBins; ++b) {
      r.add_event(8 + b, y, r.image.value(8 + b, y, b) * kBinWidth, -1.0 / kBinWidth);
    }
  }
  GatherStats stats;
  auto out = gather_filter(r.inputs(), 3 * kBinWidth, &stats);
  ASSERT_TRUE(out.ok());
  EXPECT_TRUE(std::ranges::equal(out->data(), r.image.data()));
  EXPECT_GT(stats.pixels_incoherent, 0u);
  EXPECT_EQ(stats.pixels_filtered, 0u);
}

TEST(GatherTest, PixelsWithoutOffsetsOrOnAnotherSurfaceAreLeftAlone) {
  Rainbow r(0.8, 1.0 / kBinWidth, 11);
  std::fill(r.offsets.begin(), r.offsets.end(), 0.0);
  auto untouched = gather_filter(r.inputs(), 3 * kBinWidth);
  ASSERT_TRUE(untouched.ok());
  EXPECT_TRUE(std::ranges::equal(untouched->data(), r.image.data()));

  // Columns 16 and beyond are another surface, twice as far: what the near pixels become must
  // not depend on anything there (the rainbow runs across the edge).
  auto near_part = [&](double far_scale) {
    Rainbow split(0.8, 1.0 / kBinWidth, 11);
    for (int y = 0; y < kH; ++y) {
      for (int x = 16; x < kW; ++x) {
        split.depth[std::size_t(y) * kW + x] = 1.0f * 16;
        for (int b = 0; b < kBins; ++b) split.image.value(x, y, b) *= float(far_scale);
      }
    }
    auto out = gather_filter(split.inputs(), 3 * kBinWidth);
    EXPECT_TRUE(out.ok());
    std::vector<float> near;
    for (int y = 0; y < kH; ++y) {
      for (int x = 0; x < 16; ++x) {
        for (int b = 0; b < kBins; ++b) near.push_back(out->value(x, y, b));
      }
    }
    return near;
  };
  const std::vector<float> near = near_part(1.0);
  EXPECT_EQ(near_part(5.0), near);
  // ... while on one surface the far columns do reach them.
  auto joined = [&](double scale) {
    Rainbow r2(0.8, 1.0 / kBinWidth, 11);
    for (int y = 0; y < kH; ++y) {
      for (int x = 16; x < kW; ++x) {
        for (int b = 0; b < kBins; ++b) r2.image.value(x, y, b) *= float(scale);
      }
    }
    return gather_filter(r2.inputs(), 3 * kBinWidth)->value(15, 3, 7);
  };
  EXPECT_NE(joined(1.0), joined(5.0));
}

TEST(GatherTest, BadInputsAreRefused) {
  const Rainbow r(0.0, 0.0, 1);
  GatherInputs in = r.inputs();
  in.offsets = in.offsets.subspan(1);
  EXPECT_EQ(gather_filter(in, 10).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(gather_filter(r.inputs(), 0).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace prism::coordinator
