// Splitting a job into tasks: the image into tiles and each pixel's samples into ranges.
// The plan is a pure function of (width, height, tile size, spp, samples per task), so a restarted
// coordinator, the embedded renderer and every test plan exactly the same tasks in the same
// order. Tiles are numbered in raster order (left to right, top to bottom); edge tiles are
// clipped to the image. Sample ranges are half-open and cover [0, spp) with no gaps.
#pragma once

#include <cstdint>
#include <functional>
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

// The band of rows [y0, y0 + rows) of a width x height x bins image assembled from its finished
// tiles, for streaming an output a row of tiles at a time (FinishedTiles, SpectralSpool):
// `tile_values(t)` gives tile t's values, its rect's pixels row-major with `bins` per pixel.
// `band` is resized to width x rows x bins. INTERNAL when no row of tiles starts at y0 or its
// height is not `rows`.
absl::Status assemble_band(
    const TilePlan& plan, int width, int bins, int y0, int rows,
    const std::function<absl::StatusOr<const float*>(std::size_t)>& tile_values,
    std::vector<float>* band);

}  // namespace prism::coordinator
