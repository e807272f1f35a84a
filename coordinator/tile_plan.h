// Splitting a job into tasks: the image into tiles and each pixel's samples into ranges.
// The plan is a pure function of (width, height, tile size, spp, samples per task), so a restarted
// coordinator, the embedded renderer and every test plan exactly the same tasks in the same
// order. Tiles are numbered in raster order (left to right, top to bottom); edge tiles are
// clipped to the image. Sample ranges are half-open and cover [0, spp) with no gaps.
#pragma once

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "services/image/tile.h"

namespace prism::coordinator {

struct TilePlanOptions {
  int width = 0;
  int height = 0;
  int tile_size = 32;                  // 4..1024
  std::uint64_t spp = 0;               // >= 1
  std::uint64_t samples_per_task = 0;  // 0: all of a pixel's samples in one task
  // One tile, the whole image, whatever tile_size says: a light-tracing job's task splats over
  // the whole film (worker/light_tracer.h), so its unit is a range of light-path batches.
  bool whole_image = false;
};

struct TilePlan {
  std::vector<image::TileRect> tiles;
  std::vector<image::SampleRange> ranges;  // the same split for every tile
  int tiles_x = 0;
  int tiles_y = 0;

  std::size_t task_count() const { return tiles.size() * ranges.size(); }
};

// INVALID_ARGUMENT with the offending value when a size is out of range.
absl::StatusOr<TilePlan> plan_tiles(const TilePlanOptions& options);

}  // namespace prism::coordinator
