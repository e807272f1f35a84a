#include "coordinator/tile_finaliser.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::coordinator {

TileFinaliser mean_finaliser() {
  return [](const image::TileResult& merged) -> absl::StatusOr<image::SpectralImage> {
    return image::finalise(merged);
  };
}

TileFinaliser reconstructing_finaliser(std::shared_ptr<const PoissonSolver> solver,
                                       PoissonNorm norm) {
  PRISM_CHECK(solver != nullptr);
  return [solver = std::move(solver),
          norm](const image::TileResult& merged) -> absl::StatusOr<image::SpectralImage> {
    const image::TileRect& rect = merged.rect();
    if (!merged.has_gradients()) {
      return absl::InvalidArgumentError(absl::StrCat(
          "tile ", image::to_string(rect), " has no gradients to reconstruct a gradient job from"));
    }
    if (merged.bins() != solver->bins()) {
      return absl::InvalidArgumentError(absl::StrCat("tile ", image::to_string(rect), " has ",
                                                     merged.bins(), " bins, the solver ",
                                                     solver->bins()));
    }
    const image::SpectralImage primal = image::finalise(merged);
    const image::SpectralImage gradient = image::finalise_gradients(merged);
    PRISM_ASSIGN_OR_RETURN(
        image::SpectralImage out,
        image::SpectralImage::create(rect.width(), rect.height(), merged.bins()));
    const std::size_t row = static_cast<std::size_t>(rect.width()) * merged.bins();
    for (int y = 0; y < rect.height(); ++y) {
      const std::size_t o = static_cast<std::size_t>(y) * row;
      absl::Status solved =
          solver->solve_pixels(norm, primal.data().subspan(o, row), gradient.data().subspan(o, row),
                               out.data().subspan(o, row), rect.y0 + y);
      if (!solved.ok()) {
        // solve_pixels names (index in the row, image row); the row starts at the tile's x0.
        return absl::Status(solved.code(),
                            absl::StrCat("tile ", image::to_string(rect), " (pixel x = ", rect.x0,
                                         " + index): ", solved.message()));
      }
    }
    return out;
  };
}

}  // namespace prism::coordinator
