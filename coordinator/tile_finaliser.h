// How a finished tile's merged sums become its output values. Every job divides the sums by the
// sample counts (image::finalise); a gradient job (docs/estimators.md §5) then reconstructs each
// pixel from its mean primal I and mean gradient G with the screened Poisson solve (poisson.h).
// Pixels are independent, so a tile is finalised as soon as its last sample range is merged, in the
// farm and in `prism render` alike, and the result does not depend on the tiling, except with
// the variance-weighted norm: its variances are pooled over each pixel's 3×3 block within the
// tile, so pixels on a tile's edge pool fewer (the tile size is part of the job, so the same
// job still gives the same bytes).
#pragma once

#include <functional>
#include <memory>

#include "absl/status/statusor.h"
#include "coordinator/poisson.h"
#include "services/image/tile.h"

namespace prism::coordinator {

// A merged tile result (samples [0, spp)) to its rect-sized output image. Errors are the
// reconstruction's (a non-finite I or G names the pixel in image coordinates and the bin).
using TileFinaliser = std::function<absl::StatusOr<image::SpectralImage>(const image::TileResult&)>;

// image::finalise.
TileFinaliser mean_finaliser();
// Means of I and G, then the reconstruction of every pixel with `solver` (whose bins must be
// the tiles'; INVALID_ARGUMENT otherwise) in `norm`. A tile without gradients is refused with
// INVALID_ARGUMENT, and so is one without halves for job::PoissonNorm::kWeighted, which
// reconstructs each pixel's even and odd samples apart, each with per-sample variances from the
// other half and the 3×3 block around it, so that no weight depends on the values it weighs
// (unbiased).
TileFinaliser reconstructing_finaliser(std::shared_ptr<const PoissonSolver> solver,
                                       job::PoissonNorm norm);

}  // namespace prism::coordinator
