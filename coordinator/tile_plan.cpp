#include "coordinator/tile_plan.h"

#include <algorithm>

#include "absl/strings/str_cat.h"

namespace prism::coordinator {
namespace {

// Tiles of tile_size in raster order, the last row and column cut at the image's edge.
void plan_grid(const TilePlanOptions& options, TilePlan& plan) {
  plan.tiles_x = (options.width + options.tile_size - 1) / options.tile_size;
  plan.tiles_y = (options.height + options.tile_size - 1) / options.tile_size;
  plan.tiles.reserve(static_cast<std::size_t>(plan.tiles_x) * plan.tiles_y);
  for (int ty = 0; ty < plan.tiles_y; ++ty) {
    for (int tx = 0; tx < plan.tiles_x; ++tx) {
      int x0 = tx * options.tile_size, y0 = ty * options.tile_size;
      plan.tiles.push_back({x0, y0, std::min(x0 + options.tile_size, options.width),
                            std::min(y0 + options.tile_size, options.height)});
    }
  }
}

}  // namespace

absl::StatusOr<TilePlan> plan_tiles(const TilePlanOptions& options) {
  if (options.width < 1 || options.height < 1 || options.width > image::kMaxImageSide ||
      options.height > image::kMaxImageSide) {
    return absl::InvalidArgumentError(
        absl::StrCat("image size ", options.width, "x", options.height, " is out of range"));
  }
  if (options.tile_size < 4 || options.tile_size > 1024) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile size ", options.tile_size, " is out of range 4..1024"));
  }
  if (options.spp < 1) return absl::InvalidArgumentError("spp must be at least 1");
  TilePlan plan;
  if (options.whole_image) {
    plan.tiles_x = plan.tiles_y = 1;
    plan.tiles.push_back({0, 0, options.width, options.height});
  } else {
    plan_grid(options, plan);
  }
  std::uint64_t per_task = options.samples_per_task == 0 ? options.spp : options.samples_per_task;
  for (std::uint64_t s0 = 0; s0 < options.spp; s0 += per_task) {
    plan.ranges.push_back({s0, std::min(s0 + per_task, options.spp)});
  }
  return plan;
}

}  // namespace prism::coordinator
