#include "coordinator/tile_plan.h"

#include <gtest/gtest.h>

#include <vector>

namespace prism::coordinator {
namespace {

TEST(TilePlanTest, TilesCoverEveryPixelExactlyOnceInRasterOrder) {
  for (auto [w, h, t] : {std::tuple{100, 37, 16}, std::tuple{64, 64, 32}, std::tuple{5, 3, 4}}) {
    auto plan = plan_tiles({w, h, t, 10, 0});
    ASSERT_TRUE(plan.ok()) << plan.status();
    std::vector<int> hits(w * h, 0);
    for (const auto& tile : plan->tiles) {
      EXPECT_LE(tile.width(), t);
      for (int y = tile.y0; y < tile.y1; ++y)
        for (int x = tile.x0; x < tile.x1; ++x) ++hits[y * w + x];
    }
    for (int hit : hits) ASSERT_EQ(hit, 1);
    for (std::size_t i = 1; i < plan->tiles.size(); ++i) {
      const auto& a = plan->tiles[i - 1];
      const auto& b = plan->tiles[i];
      EXPECT_TRUE(a.y0 < b.y0 || (a.y0 == b.y0 && a.x0 < b.x0));
    }
    EXPECT_EQ(plan->tiles.size(), std::size_t(plan->tiles_x * plan->tiles_y));
  }
}

TEST(TilePlanTest, SampleRangesCoverSppWithoutGaps) {
  auto plan = plan_tiles({32, 32, 16, 100, 32});
  ASSERT_TRUE(plan.ok());
  std::vector<image::SampleRange> expected = {{0, 32}, {32, 64}, {64, 96}, {96, 100}};
  EXPECT_EQ(plan->ranges, expected);
  EXPECT_EQ(plan->task_count(), 4u * 4u);
  auto whole = plan_tiles({32, 32, 16, 100, 0});
  ASSERT_TRUE(whole.ok());
  EXPECT_EQ(whole->ranges, (std::vector<image::SampleRange>{{0, 100}}));
}

TEST(TilePlanTest, RefusesOutOfRangeSizes) {
  EXPECT_EQ(plan_tiles({0, 10, 16, 1, 0}).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(plan_tiles({10, 10, 2, 1, 0}).status().message(),
            "tile size 2 is out of range 4..1024");
  EXPECT_EQ(plan_tiles({10, 10, 16, 0, 0}).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace prism::coordinator
