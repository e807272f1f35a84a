#include "coordinator/convergence.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "tests/testing/test_dir.h"

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
  ConvergenceTracker tracker(4);
  // Pixel 0 saw 1 and 3 (mean 2, variance 2, of the mean 1); pixel 1 saw 2 and 2.
  ConvergencePoint first = tracker.add(result({0, 0, 2, 1}, {{2, 4, 10}, {2, 4, 8}}), 1.5);
  EXPECT_EQ(first.samples, 4u);
  EXPECT_DOUBLE_EQ(first.seconds, 1.5);
  EXPECT_DOUBLE_EQ(first.relative_error, std::sqrt(1.0) / 4.0);
  // Pixel 0 then sees a 2: n 3, Σ 6, Σ² 14, variance 1, of the mean 1/3; its mean stays 2.
  ConvergencePoint second = tracker.add(result({0, 0, 2, 1}, {{1, 2, 4}, {0, 0, 0}}), 2.0);
  EXPECT_EQ(second.samples, 5u);
  EXPECT_NEAR(second.relative_error, std::sqrt(1.0 / 3.0) / 4.0, 1e-15);
  // A pixel with one sample adds its mean but no variance.
  ConvergenceTracker single(1);
  EXPECT_EQ(single.add(result({0, 0, 1, 1}, {{1, 5, 25}}), 0).relative_error, 0.0);
}

// A tile's per-pixel sums go once its pixels have every sample, and the estimate is the one a
// tracker that keeps everything gives.
TEST(ConvergenceTest, OnlyTilesStillRenderingKeepTheirPixels) {
  ConvergenceTracker bounded(2);
  ConvergenceTracker keeping(1000);
  const std::vector<std::pair<image::TileRect, std::vector<std::array<double, 3>>>> results = {
      {{0, 0, 2, 1}, {{1, 1, 1}, {1, 3, 9}}},    // tile A, first sample
      {{2, 0, 4, 1}, {{2, 4, 10}, {2, 6, 20}}},  // tile B, both samples: done at once
      {{0, 0, 2, 1}, {{1, 2, 4}, {1, 2, 4}}},    // tile A, second sample: done
  };
  const std::size_t in_flight[] = {1, 1, 0};
  for (std::size_t i = 0; i < results.size(); ++i) {
    const auto& [rect, pixels] = results[i];
    const ConvergencePoint a = bounded.add(result(rect, pixels), double(i));
    const ConvergencePoint b = keeping.add(result(rect, pixels), double(i));
    EXPECT_EQ(bounded.tiles_in_flight(), in_flight[i]) << i;
    EXPECT_EQ(a.samples, b.samples);
    EXPECT_DOUBLE_EQ(a.relative_error, b.relative_error) << i;
  }
  EXPECT_GT(bounded.relative_error(), 0.0);
  EXPECT_EQ(keeping.tiles_in_flight(), 2u);
}

TEST(ConvergenceTest, ALongSeriesIsThinnedKeepingItsEnds) {
  std::vector<ConvergencePoint> points;
  for (int i = 0; i <= int(kMaxConvergencePoints); ++i)
    append_point(points, {double(i), std::uint64_t(i), 1.0 / (i + 1)});
  EXPECT_LE(points.size(), kMaxConvergencePoints);
  EXPECT_EQ(points.front().samples, 0u);
  EXPECT_EQ(points.back().samples, std::uint64_t(kMaxConvergencePoints));
}

bool same(const std::vector<ConvergencePoint>& a, const std::vector<ConvergencePoint>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].seconds != b[i].seconds || a[i].samples != b[i].samples ||
        a[i].relative_error != b[i].relative_error) {
      return false;
    }
  }
  return true;
}

// The series on disk: what is appended reads back bit for bit after a reopen; a torn tail (a
// crash mid-record) or a stale record that is not a later point ends the series there, and the
// next append overwrites it; a finished job's rewrite is the thinned series.
TEST(ConvergenceLogTest, PointsSurviveAReopenAndATornTailIsOverwritten) {
  const std::filesystem::path path = testing::fresh_dir("convergence_log") / "job";
  const std::vector<ConvergencePoint> points = {
      {0.5, 16, 0.25}, {1.25, 32, 0.125}, {2.0, 48, 1.0 / 3.0}};
  {
    std::vector<ConvergencePoint> none;
    auto log = ConvergenceLog::open(path, &none);
    ASSERT_TRUE(log.ok()) << log.status();
    EXPECT_TRUE(none.empty());
    for (const ConvergencePoint& p : points) ASSERT_TRUE(log->append(p).ok());
  }
  std::vector<ConvergencePoint> read;
  {
    auto log = ConvergenceLog::open(path, &read);
    ASSERT_TRUE(log.ok()) << log.status();
  }
  EXPECT_TRUE(same(read, points));
  EXPECT_TRUE(same(read_convergence(path), points));

  // A torn record, then a whole but stale one (fewer samples).
  std::ofstream(path, std::ios::binary | std::ios::app) << std::string(10, '\x7f');
  EXPECT_TRUE(same(read_convergence(path), points));
  {
    auto log = ConvergenceLog::open(path, &read);
    ASSERT_TRUE(log.ok());
    EXPECT_TRUE(same(read, points));
    ASSERT_TRUE(log->append({3.0, 64, 0.2}).ok());
  }
  EXPECT_EQ(std::filesystem::file_size(path), 4u * 24u) << "the torn tail is overwritten";
  std::vector<ConvergencePoint> four = points;
  four.push_back({3.0, 64, 0.2});
  EXPECT_TRUE(same(read_convergence(path), four));
  std::ofstream(path, std::ios::binary | std::ios::app) << std::string(24, '\0');
  EXPECT_TRUE(same(read_convergence(path), four));

  // A long series reads back thinned, and the rewrite keeps exactly that.
  std::vector<ConvergencePoint> long_series;
  {
    auto log = ConvergenceLog::open(path, &read);
    ASSERT_TRUE(log.ok());
    long_series = read;
    for (std::uint64_t k = 5; k < 5000; ++k) {
      const ConvergencePoint p{double(k), 16 * k, 1.0 / double(k)};
      ASSERT_TRUE(log->append(p).ok());
      append_point(long_series, p);
    }
  }
  const std::vector<ConvergencePoint> thinned = read_convergence(path);
  EXPECT_LE(thinned.size(), kMaxConvergencePoints);
  EXPECT_TRUE(same(thinned, long_series));
  ASSERT_TRUE(write_convergence(path, thinned).ok());
  EXPECT_EQ(std::filesystem::file_size(path), thinned.size() * 24u);
  EXPECT_TRUE(same(read_convergence(path), thinned));
  EXPECT_TRUE(read_convergence(path.string() + ".missing").empty());
}

}  // namespace
}  // namespace prism::coordinator
