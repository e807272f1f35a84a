#include "coordinator/tile_plan.h"

#include <algorithm>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"

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

absl::Status assemble_band(
    const TilePlan& plan, int width, int bins, int y0, int rows,
    const std::function<absl::StatusOr<const float*>(std::size_t)>& tile_values,
    std::vector<float>* band) {
  band->resize(std::size_t(width) * std::size_t(rows) * std::size_t(bins));
  bool covered = false;
  for (std::size_t t = 0; t < plan.tiles.size(); ++t) {
    const image::TileRect& rect = plan.tiles[t];
    if (rect.y0 != y0) continue;
    if (rect.height() != rows) {
      return absl::InternalError(absl::StrCat("band of ", rows, " rows at y ", y0,
                                              " does not match tile ", to_string(rect)));
    }
    covered = true;
    PRISM_ASSIGN_OR_RETURN(const float* values, tile_values(t));
    const std::size_t row_values = std::size_t(rect.width()) * std::size_t(bins);
    for (int y = 0; y < rect.height(); ++y) {
      std::memcpy(band->data() + (std::size_t(y) * width + rect.x0) * bins,
                  values + std::size_t(y) * row_values, row_values * sizeof(float));
    }
  }
  if (!covered) return absl::InternalError(absl::StrCat("no row of tiles starts at y ", y0));
  return absl::OkStatus();
}

}  // namespace prism::coordinator
