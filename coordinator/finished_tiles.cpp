#include "coordinator/finished_tiles.h"

#include <algorithm>
#include <cstring>
#include <optional>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/status.h"
#include "services/image/tile_codec.h"

namespace prism::coordinator {

namespace fs = std::filesystem;

absl::StatusOr<FinishedTiles> FinishedTiles::open(fs::path dir, TilePlan plan, int width,
                                                  int bins) {
  if (plan.tiles.empty() || width < 1 || bins < 1 || bins > image::kMaxChannels) {
    return absl::InvalidArgumentError(
        absl::StrCat("finished tiles need a plan with tiles, width ", width, " and bins ", bins));
  }
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    return absl::InternalError(
        absl::StrCat("cannot create the tile directory ", dir.string(), ": ", ec.message()));
  }
  return FinishedTiles(std::move(dir), std::move(plan), width, bins);
}

fs::path FinishedTiles::path_of(int tile) const {
  return dir_ / absl::StrCat(tile, ".tile");
}

absl::Status FinishedTiles::put(int tile, const image::TileResult& merged) const {
  if (tile < 0 || static_cast<std::size_t>(tile) >= plan_.tiles.size() ||
      merged.rect() != plan_.tiles[static_cast<std::size_t>(tile)] || merged.bins() != bins_) {
    return absl::InvalidArgumentError(absl::StrCat("tile ", tile, " (", to_string(merged.rect()),
                                                   ") is not a tile of this job's plan"));
  }
  const std::string bytes = image::serialise_tile(merged);
  return base::write_file_atomic(path_of(tile), std::span<const char>(bytes));
}

bool FinishedTiles::has(int tile) const {
  std::error_code ec;
  return fs::is_regular_file(path_of(tile), ec);
}

absl::StatusOr<image::TileResult> FinishedTiles::get(int tile) const {
  const fs::path path = path_of(tile);
  auto fail = [&](const std::string& why) {
    return absl::DataLossError(absl::StrCat("finished tile ", path.string(), ": ", why));
  };
  if (tile < 0 || static_cast<std::size_t>(tile) >= plan_.tiles.size()) {
    return fail("not a tile of the plan");
  }
  absl::StatusOr<std::string> bytes = base::read_file(path);
  if (!bytes.ok()) return fail(std::string(bytes.status().message()));
  absl::StatusOr<image::TileResult> result = image::parse_tile(*bytes);
  if (!result.ok()) return fail(std::string(result.status().message()));
  if (result->rect() != plan_.tiles[static_cast<std::size_t>(tile)] || result->bins() != bins_) {
    return fail(absl::StrCat("holds ", to_string(result->rect()), " with ", result->bins(),
                             " bins, not this job's tile"));
  }
  return result;
}

image::SpectralRows FinishedTiles::rows(TileFinaliser finalise, std::vector<float>* buffer) const {
  return [this, finalise = std::move(finalise), buffer](int y0,
                                                        int rows) -> absl::StatusOr<const float*> {
    std::optional<image::SpectralImage> values;
    PRISM_RETURN_IF_ERROR(assemble_band(
        plan_, width_, bins_, y0, rows,
        [&](std::size_t t) -> absl::StatusOr<const float*> {
          PRISM_ASSIGN_OR_RETURN(image::TileResult merged, get(static_cast<int>(t)));
          PRISM_ASSIGN_OR_RETURN(values, finalise(merged));
          return values->data().data();
        },
        buffer));
    return buffer->data();
  };
}

absl::Status FinishedTiles::remove() const {
  std::error_code ec;
  fs::remove_all(dir_, ec);
  if (ec) {
    return absl::InternalError(
        absl::StrCat("cannot remove the tile directory ", dir_.string(), ": ", ec.message()));
  }
  return absl::OkStatus();
}

}  // namespace prism::coordinator
