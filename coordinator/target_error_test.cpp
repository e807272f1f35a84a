#include "coordinator/target_error.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <vector>

namespace prism::coordinator {
namespace {

// A tile's result over samples [s0, s1): sample i of pixel p has R = G = B = value(p, i) (so its
// luminance is the value), and one bin holding it too.
image::TileResult result(const image::TileRect& rect, std::uint64_t s0, std::uint64_t s1,
                         const std::function<double(int, std::uint64_t)>& value) {
  image::TileBuffers buffers;
  buffers.rgb = true;
  image::TileResult r = *image::TileResult::create(rect, {s0, s1}, 4, buffers);
  std::span<double> rgb = r.mutable_rgb_sums(), squares = r.mutable_rgb_squares();
  int p = 0;
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x, ++p) {
      for (std::uint64_t i = s0; i < s1; ++i) {
        const double v = value(p, i);
        const double spectrum[4] = {v, 0, 0, 0};
        r.add_sample(x, y, spectrum);
        for (int c = 0; c < 3; ++c) {
          rgb[std::size_t(p) * 3 + c] += v;
          squares[std::size_t(p) * 3 + c] += v * v;
        }
      }
    }
  }
  return r;
}

TilePlan two_tiles() {
  TilePlan plan;
  plan.tiles = {{0, 0, 4, 4}, {4, 0, 8, 4}};
  plan.ranges = {{0, 8}};
  plan.tiles_x = 2;
  plan.tiles_y = 1;
  return plan;
}

// Tile 0 is constant (no error at all); tile 1 alternates 0 and 2 (mean 1, sample variance 1),
// so after n samples its pixels' relative standard error is sqrt(1 / (n − 1)).
double steady(int, std::uint64_t) {
  return 1.0;
}
double alternating(int, std::uint64_t i) {
  return i % 2 == 0 ? 0.0 : 2.0;
}

TEST(TargetErrorTest, RoundsDoubleUpToTheMaximum) {
  EXPECT_EQ(target_error_rounds(16, 100), (std::vector<std::uint64_t>{16, 32, 64, 100}));
  EXPECT_EQ(target_error_rounds(16, 16), (std::vector<std::uint64_t>{16}));
  EXPECT_EQ(target_error_rounds(16, 64), (std::vector<std::uint64_t>{16, 32, 64}));
  const TilePlan round = plan_round(two_tiles(), 16, 40, 10);
  EXPECT_EQ(round.tiles, two_tiles().tiles);
  ASSERT_EQ(round.ranges.size(), 3u);
  EXPECT_EQ(round.ranges[0], (image::SampleRange{16, 26}));
  EXPECT_EQ(round.ranges[2], (image::SampleRange{36, 40}));
  EXPECT_EQ(plan_round(two_tiles(), 16, 40, 0).ranges.size(), 1u);
}

// Per pixel: the steady tile stops after round 1; the alternating one runs until
// sqrt(1/(n − 1)) <= 0.1, which 64 samples miss (0.126) and 128 meet (0.0887).
TEST(TargetErrorTest, EachTileStopsWhenEveryPixelMeetsTheTarget) {
  const TilePlan plan = two_tiles();
  auto tracker = TargetErrorTracker::create({0.1, false, 1024}, plan, 8);
  ASSERT_TRUE(tracker.ok()) << tracker.status();
  std::vector<std::vector<int>> finished;
  while (!tracker->finished()) {
    const image::SampleRange s = tracker->round_samples();
    if (tracker->active(0)) {
      ASSERT_TRUE(tracker->add(0, result(plan.tiles[0], s.s0, s.s1, steady)).ok());
    }
    if (tracker->active(1)) {
      ASSERT_TRUE(tracker->add(1, result(plan.tiles[1], s.s0, s.s1, alternating)).ok());
    }
    auto done = tracker->finish_round();
    ASSERT_TRUE(done.ok()) << done.status();
    for (int t : *done) EXPECT_EQ(tracker->sum(t).samples().s0, 0u);
    finished.push_back(*done);
  }
  ASSERT_EQ(finished.size(), 5u);  // 8, 16, 32, 64, 128
  EXPECT_EQ(finished[0], std::vector<int>{0});
  EXPECT_EQ(finished[4], std::vector<int>{1});
  EXPECT_EQ(tracker->sum(1).samples(), (image::SampleRange{0, 128}));
  const TargetErrorOutcome o = tracker->outcome();
  EXPECT_TRUE(o.met);
  EXPECT_EQ(o.rounds, 5);
  EXPECT_EQ(o.rounds_planned, 8);  // 8 .. 1024
  EXPECT_EQ(o.min_spp, 8u);
  EXPECT_EQ(o.max_spp, 128u);
  EXPECT_DOUBLE_EQ(o.mean_spp, (8.0 + 128.0) / 2);
  EXPECT_EQ(o.samples, 16u * 8 + 16u * 128);
  EXPECT_NEAR(o.pixel_max, std::sqrt(1.0 / 127), 1e-12);
  EXPECT_NEAR(o.pixel_p99, std::sqrt(1.0 / 127), 1e-12);
  EXPECT_NEAR(o.pixel_mean, std::sqrt(1.0 / 127) / 2, 1e-12);
  // The image's mean luminance 1 over 32 pixels, 16 of them with standard error sqrt(1/127).
  EXPECT_NEAR(o.image_error, std::sqrt(16.0 / 127) / 32, 1e-12);
}

// max_spp stops an unmet target, and says so; the image scope stops every tile together.
TEST(TargetErrorTest, MaxSppStopsAndTheImageScopeStopsTogether) {
  const TilePlan plan = two_tiles();
  auto run = [&](job::TargetError target) {
    auto tracker = TargetErrorTracker::create(target, plan, 8);
    EXPECT_TRUE(tracker.ok()) << tracker.status();
    std::vector<std::vector<int>> rounds;
    while (!tracker->finished()) {
      const image::SampleRange s = tracker->round_samples();
      for (int t = 0; t < 2; ++t) {
        if (!tracker->active(t)) continue;
        EXPECT_TRUE(
            tracker->add(t, result(plan.tiles[t], s.s0, s.s1, t == 0 ? steady : alternating)).ok());
      }
      rounds.push_back(*tracker->finish_round());
    }
    return std::pair{rounds, tracker->outcome()};
  };
  auto [capped, capped_outcome] = run({0.01, false, 32});
  EXPECT_EQ(capped.size(), 3u);
  EXPECT_EQ(capped.back(), std::vector<int>{1});
  EXPECT_FALSE(capped_outcome.met);
  EXPECT_EQ(capped_outcome.max_spp, 32u);
  // Image scope: sqrt(16/(n − 1))/32 <= 0.02 first at n = 64 (0.0157; at 32 it is 0.0225).
  auto [image, image_outcome] = run({0.02, true, 1024});
  ASSERT_EQ(image.size(), 4u);
  EXPECT_EQ(image.back(), (std::vector<int>{0, 1}));
  EXPECT_TRUE(image_outcome.met);
  EXPECT_EQ(image_outcome.min_spp, 64u);
  EXPECT_NEAR(image_outcome.image_error, std::sqrt(16.0 / 63) / 32, 1e-12);
}

// Pixels far darker than the image are held to a tenth of its mean, not to their own value: a
// black pixel with no error meets any target, and one at a thousandth of the image's brightness
// with the same absolute error as a bright one does not need a thousand times more samples.
TEST(TargetErrorTest, DarkPixelsAreMeasuredAgainstTheImage) {
  const TilePlan plan = two_tiles();
  auto tracker = TargetErrorTracker::create({0.1, false, 64}, plan, 8);
  ASSERT_TRUE(tracker.ok());
  // Tile 0 bright and exact (mean 10); tile 1 near black: 0.01 ± 0.01.
  ASSERT_TRUE(
      tracker->add(0, result(plan.tiles[0], 0, 8, [](int, std::uint64_t) { return 10.0; })).ok());
  ASSERT_TRUE(tracker
                  ->add(1, result(plan.tiles[1], 0, 8,
                                  [](int, std::uint64_t i) { return i % 2 == 0 ? 0.0 : 0.02; }))
                  .ok());
  auto done = tracker->finish_round();
  ASSERT_TRUE(done.ok());
  // se = 0.01/sqrt(7) = 0.0038, against 10 % of the mean 5.005: 0.0075 relative.
  EXPECT_EQ(*done, (std::vector<int>{0, 1}));
  EXPECT_NEAR(tracker->outcome().pixel_max, 0.01 / std::sqrt(7.0) / (0.1 * 5.005), 1e-9);
}

TEST(TargetErrorTest, MisuseIsRefused) {
  const TilePlan plan = two_tiles();
  EXPECT_FALSE(TargetErrorTracker::create({0, false, 64}, plan, 8).ok());
  EXPECT_FALSE(TargetErrorTracker::create({2, false, 64}, plan, 8).ok());
  EXPECT_FALSE(TargetErrorTracker::create({0.1, false, 4}, plan, 8).ok());
  EXPECT_FALSE(TargetErrorTracker::create({0.1, false, 64}, plan, 1).ok());
  auto tracker = TargetErrorTracker::create({0.1, false, 64}, plan, 8);
  ASSERT_TRUE(tracker.ok());
  EXPECT_FALSE(tracker->add(0, result(plan.tiles[0], 0, 16, steady)).ok());  // not round 1's
  EXPECT_FALSE(tracker->add(0, result(plan.tiles[1], 0, 8, steady)).ok());   // not its rect
  EXPECT_FALSE(tracker->add(2, result(plan.tiles[0], 0, 8, steady)).ok());
  ASSERT_TRUE(tracker->add(0, result(plan.tiles[0], 0, 8, steady)).ok());
  EXPECT_EQ(tracker->add(0, result(plan.tiles[0], 0, 8, steady)).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(tracker->finish_round().status().code(), absl::StatusCode::kFailedPrecondition);
  image::TileResult plain = *image::TileResult::create(plan.tiles[1], {0, 8}, 4);
  EXPECT_EQ(tracker->add(1, plain).code(), absl::StatusCode::kFailedPrecondition);
}

}  // namespace
}  // namespace prism::coordinator
