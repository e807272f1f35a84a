// Error metrics between a test image and a reference, over spectral bins or RGB channels, for
// the whole image or a crop. Every metric averages over all values (pixels x channels) of the
// region:
//   MSE        mean (t - r)^2
//   relMSE     mean (t - r)^2 / (r^2 + 0.01)
//   SSIM       Wang et al. 2004 on each channel separately, then averaged over channels:
//              Gaussian window 11x11, sigma 1.5, normalised weights, evaluated where the window
//              fits entirely inside the region ("valid"); a region narrower or shorter than 11
//              uses a window of that side. K1 = 0.01, K2 = 0.03, C1 = (K1 L)^2, C2 = (K2 L)^2.
//              The data are HDR, so L is not a fixed 1 or 255: L is the largest |r| over the
//              region and all channels of the reference (L = 1 if the reference is all zero),
//              which makes SSIM invariant to scaling both images by the same factor.
//   non-finite fraction of test values that are NaN or infinite. Such values count as 0 in
//              the three metrics above, so one NaN does not hide the error of the rest.
// The reference must be finite everywhere in the region (INVALID_ARGUMENT otherwise).
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "services/image/tile.h"

namespace prism::image {

inline constexpr double kSsimK1 = 0.01;
inline constexpr double kSsimK2 = 0.03;
inline constexpr int kSsimWindow = 11;
inline constexpr double kSsimSigma = 1.5;
inline constexpr double kRelMseEpsilon = 0.01;

// A region of interest: top-left (x, y), size w x h pixels.
struct Crop {
  int x = 0;
  int y = 0;
  int w = 0;
  int h = 0;
};

// The crop as a TileRect; INVALID_ARGUMENT unless w, h >= 1 and it lies inside width x height.
absl::StatusOr<TileRect> crop_rect(const Crop& crop, int width, int height);

struct ErrorMetrics {
  double mse = 0.0;
  double rel_mse = 0.0;
  double ssim = 1.0;
  double nonfinite_fraction = 0.0;
  int channels = 0;
};

// Metrics of `test` against `reference` over the crop (whole image when absent).
// INVALID_ARGUMENT when sizes or bins differ, the crop is invalid or the reference is not finite.
absl::StatusOr<ErrorMetrics> compare_spectral(const SpectralImage& test,
                                              const SpectralImage& reference,
                                              const std::optional<Crop>& crop = std::nullopt);
absl::StatusOr<ErrorMetrics> compare_rgb(const RgbImage& test, const RgbImage& reference,
                                         const std::optional<Crop>& crop = std::nullopt);

struct Comparison {
  int width = 0;
  int height = 0;
  TileRect region;                       // the pixels compared
  std::optional<ErrorMetrics> spectral;  // both files spectral with the same wavelengths
  std::optional<ErrorMetrics> rgb;       // both files have R, G, B
};

// Loads two EXR files (spectral or plain RGB) and compares what both have: spectral bins when
// both are spectral, RGB when both have R, G, B. INVALID_ARGUMENT naming the files when the
// sizes, bin counts or wavelengths differ or when they have nothing in common; errors from
// reading either file are passed on.
absl::StatusOr<Comparison> compare_exr_files(const std::filesystem::path& test,
                                             const std::filesystem::path& reference,
                                             const std::optional<Crop>& crop = std::nullopt);

// Human-readable lines, e.g. "rgb       MSE 1.2e-05  relMSE 3.4e-04  SSIM 0.9876  non-finite 0".
std::string format_comparison_text(const Comparison& comparison);
// One JSON object: {"width":..,"height":..,"region":{"x0":..,"y0":..,"x1":..,"y1":..},
// "spectral":{"channels":..,"mse":..,"rel_mse":..,"ssim":..,"nonfinite_fraction":..}|null,
// "rgb":{...}|null}. Non-finite numbers are written as null.
std::string format_comparison_json(const Comparison& comparison);

}  // namespace prism::image
