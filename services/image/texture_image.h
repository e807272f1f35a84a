// Images read as texture data for pbrt-v4's `imagemap` textures and image-based lights: PNG
// (8 or 16 bit; gray, gray+alpha, RGB, RGBA) and OpenEXR (any R, G, B or Y channels), decoded
// from bytes already in memory, because a scene's files come from a bundle as well as from disk.
// Values are returned as written: 8-bit samples as byte/255 still in the file's encoding (the
// scene says how to decode them), EXR samples as the linear floats they are. Alpha is dropped;
// gray stays one channel.
#pragma once

#include <string_view>
#include <vector>

#include "absl/status/statusor.h"

namespace prism::image {

struct TextureImageData {
  int width = 0;
  int height = 0;
  int channels = 0;        // 1 (gray) or 3 (RGB)
  bool eight_bit = false;  // PNG (8 or 16 bits): values are sample/max in the file's encoding;
                           // EXR: linear
  // values[(y * width + x) * channels + c]; row 0 is the top of the image.
  std::vector<float> values;
};

// Decodes a PNG or an OpenEXR file by its signature. INVALID_ARGUMENT naming `name` for
// anything else, a damaged file, no colour channels, or more than kMaxTextureTexels texels.
inline constexpr long kMaxTextureTexels = 1L << 28;
absl::StatusOr<TextureImageData> decode_texture_image(std::string_view bytes,
                                                      std::string_view name);

}  // namespace prism::image
