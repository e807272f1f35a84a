// The spectral domain Λ = [kLambdaMin, kLambdaMax] nm and its uniform output binning
// (docs/estimators.md §1). A WavelengthGrid of B bins (kMinBins..kMaxBins) has width w = 470/B nm;
// bin b covers the half-open interval [360 + b·w, 360 + (b+1)·w), except that λ = 830 belongs
// to the last bin so the whole closed domain is covered. A grid is an immutable value.
#pragma once

#include <cmath>

#include "absl/status/statusor.h"

namespace prism::spectral {

inline constexpr float kLambdaMin = 360.0f;  // nm
inline constexpr float kLambdaMax = 830.0f;  // nm
inline constexpr float kLambdaRange = kLambdaMax - kLambdaMin;

// λ wrapped into [360, 830) cyclically (period 470 nm), for wavelength shifts of gradient
// sampling (docs/estimators.md §5: the spectrum is cyclic). NaN stays NaN.
inline float wrap_wavelength(float lambda_nm) {
  float r = std::fmod(lambda_nm - kLambdaMin, kLambdaRange);
  if (r < 0.0f) r += kLambdaRange;
  // For λ just below 360 the sum rounds up to 830, which is outside [360, 830).
  const float out = kLambdaMin + r;
  return out >= kLambdaMax ? std::nextafter(kLambdaMax, 0.0f) : out;
}

class WavelengthGrid {
 public:
  static constexpr int kMinBins = 4;
  static constexpr int kMaxBins = 256;
  static constexpr int kDefaultBins = 64;

  // The default 64-bin grid.
  WavelengthGrid() : WavelengthGrid(kDefaultBins) {}

  // INVALID_ARGUMENT unless kMinBins <= bins <= kMaxBins.
  static absl::StatusOr<WavelengthGrid> create(int bins);

  int bins() const { return bins_; }
  float bin_width() const { return width_; }  // nm

  // Bounds and centre of bin b in nm; b must be in [0, bins()).
  float lower(int b) const;
  float upper(int b) const;
  float centre(int b) const;

  // The bin holding lambda_nm, or -1 when lambda_nm is outside [360, 830] or NaN. Inline: every
  // lane of every splat and light choice asks.
  int bin_of(float lambda_nm) const {
    if (!(lambda_nm >= kLambdaMin && lambda_nm <= kLambdaMax)) return -1;
    int b = static_cast<int>((lambda_nm - kLambdaMin) * static_cast<float>(bins_) / kLambdaRange);
    if (b >= bins_) b = bins_ - 1;
    // The division can round across a boundary; settle against the exact bounds lower() uses.
    if (b > 0 && lambda_nm < lower_unchecked(b)) --b;
    if (b + 1 < bins_ && lambda_nm >= lower_unchecked(b + 1)) ++b;
    return b;
  }

  // Bin index modulo bins(), for any integer (negative too): the spectrum is cyclic for
  // gradient sampling (docs/estimators.md §5), so b + k and b − k wrap around.
  int wrap(int b) const {
    const int r = b % bins_;
    return r < 0 ? r + bins_ : r;
  }

  friend bool operator==(const WavelengthGrid&, const WavelengthGrid&) = default;

 private:
  explicit WavelengthGrid(int bins)
      : bins_(bins), width_(kLambdaRange / static_cast<float>(bins)) {}
  float lower_unchecked(int b) const {
    return kLambdaMin + kLambdaRange * static_cast<float>(b) / static_cast<float>(bins_);
  }

  int bins_;
  float width_;
};

}  // namespace prism::spectral
