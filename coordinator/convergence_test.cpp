#include "coordinator/convergence.h"

#include <gtest/gtest.h>

#include <cmath>

namespace prism::coordinator {
namespace {

// A result for `rect` whose pixels carry (count, Σg, Σg²) in their green channel.
image::TileResult result(const image::TileRect& rect,
                         const std::vector<std::array<double, 3>>& pixels) {
  image::TileBuffers buffers;
  buffers.rgb = true;
  auto r = image::TileResult::create(rect, {0, 4}, 4, buffers);
  EXPECT_TRUE(r.ok()) << r.status();
  for (std::size_t p = 0; p < pixels.size(); ++p) {
    r->mutable_counts()[p] = std::uint64_t(pixels[p][0]);
    r->mutable_rgb_sums()[p * 3 + 1] = pixels[p][1];
    r->mutable_rgb_squares()[p * 3 + 1] = pixels[p][2];
  }
  return *std::move(r);
}

TEST(ConvergenceTest, TheEstimateIsTheImageMeansRelativeStandardError) {
  ConvergenceTracker tracker(2, 1);
  // Pixel 0 saw 1 and 3 (mean 2, variance 2, of the mean 1); pixel 1 saw 2 and 2.
  ConvergencePoint first = tracker.add(result({0, 0, 2, 1}, {{2, 4, 10}, {2, 4, 8}}), 1.5);
  EXPECT_EQ(first.samples, 4u);
  EXPECT_DOUBLE_EQ(first.seconds, 1.5);
  EXPECT_DOUBLE_EQ(first.relative_error, std::sqrt(1.0) / 4.0);
  // Pixel 0 then sees a 2: n 3, Σ 6, Σ² 14, variance 1, of the mean 1/3; its mean stays 2.
  ConvergencePoint second = tracker.add(result({0, 0, 1, 1}, {{1, 2, 4}}), 2.0);
  EXPECT_EQ(second.samples, 5u);
  EXPECT_NEAR(second.relative_error, std::sqrt(1.0 / 3.0) / 4.0, 1e-15);
  // A pixel with one sample adds its mean but no variance.
  ConvergenceTracker single(1, 1);
  EXPECT_EQ(single.add(result({0, 0, 1, 1}, {{1, 5, 25}}), 0).relative_error, 0.0);
}

TEST(ConvergenceTest, ALongSeriesIsThinnedKeepingItsEnds) {
  std::vector<ConvergencePoint> points;
  for (int i = 0; i <= int(kMaxConvergencePoints); ++i)
    append_point(points, {double(i), std::uint64_t(i), 1.0 / (i + 1)});
  EXPECT_LE(points.size(), kMaxConvergencePoints);
  EXPECT_EQ(points.front().samples, 0u);
  EXPECT_EQ(points.back().samples, std::uint64_t(kMaxConvergencePoints));
}

}  // namespace
}  // namespace prism::coordinator
