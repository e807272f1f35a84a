// PNG previews of linear RGB renders, via libpng's simplified API (no setjmp/longjmp).
//
// A preview value is computed per channel from the linear value v as
//   v' = v * 2^exposure_stops;  non-finite or negative -> 0;  v' > 1 -> 1;
//   s  = sRGB transfer(v')  (12.92 v' below 0.0031308, else 1.055 v'^(1/2.4) - 0.055);
//   byte = round(255 s).
// Files are 8-bit RGB, no alpha, and written atomically (complete under their name or absent).
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include "absl/status/statusor.h"
#include "services/image/tile.h"

namespace prism::image {

// 8-bit interleaved image as stored in a PNG: bytes[(y*width + x)*channels + c].
struct Png8 {
  int width = 0;
  int height = 0;
  int channels = 0;  // 3 (RGB) for what Prism writes; 1..4 as read
  std::vector<std::uint8_t> bytes;
};

// The 8-bit value of one linear channel value under the pipeline above.
std::uint8_t preview_byte(float linear, float exposure_stops);

// Applies the pipeline above to every pixel.
Png8 to_preview(const RgbImage& rgb, float exposure_stops);

// Writes the preview PNG; INTERNAL naming the file when libpng or the file system fails.
absl::Status write_png_preview(const std::filesystem::path& path, const RgbImage& rgb,
                               float exposure_stops = 0.0f);

// Reads any PNG as 8-bit samples in its own channel count (gray, gray+alpha, RGB, RGBA;
// 16-bit files are reduced to 8 bits). NOT_FOUND when missing; INVALID_ARGUMENT naming the
// file when it is not a valid PNG or is larger than kMaxImageValues.
absl::StatusOr<Png8> read_png(const std::filesystem::path& path);

}  // namespace prism::image
