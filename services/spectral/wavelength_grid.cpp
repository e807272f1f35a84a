#include "services/spectral/wavelength_grid.h"

#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"

namespace prism::spectral {

absl::StatusOr<WavelengthGrid> WavelengthGrid::create(int bins) {
  if (bins < kMinBins || bins > kMaxBins) {
    return absl::InvalidArgumentError(absl::StrCat("spectral bin count must be between ", kMinBins,
                                                   " and ", kMaxBins, ", got ", bins));
  }
  return WavelengthGrid(bins);
}

// Bounds are computed from the integer index rather than accumulated, so upper(b) == lower(b+1)
// bit for bit and bin_of(lower(b)) == b.
float WavelengthGrid::lower(int b) const {
  PRISM_CHECK(b >= 0 && b < bins_);
  return lower_unchecked(b);
}

float WavelengthGrid::upper(int b) const {
  PRISM_CHECK(b >= 0 && b < bins_);
  return b + 1 == bins_
             ? kLambdaMax
             : kLambdaMin + kLambdaRange * static_cast<float>(b + 1) / static_cast<float>(bins_);
}

float WavelengthGrid::centre(int b) const {
  return 0.5f * (lower(b) + upper(b));
}

}  // namespace prism::spectral
