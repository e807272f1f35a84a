#include "services/image/png.h"

#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/check.h"

namespace prism::image {
namespace {

float srgb_transfer(float v) {
  return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

png_uint_32 format_for_channels(int channels) {
  switch (channels) {
    case 1:
      return PNG_FORMAT_GRAY;
    case 2:
      return PNG_FORMAT_GA;
    case 3:
      return PNG_FORMAT_RGB;
    default:
      return PNG_FORMAT_RGBA;
  }
}

}  // namespace

std::uint8_t preview_byte(float linear, float exposure_stops) {
  float v = linear * std::exp2(exposure_stops);
  if (!std::isfinite(v) || v < 0.0f) v = 0.0f;
  if (v > 1.0f) v = 1.0f;
  float s = std::clamp(srgb_transfer(v), 0.0f, 1.0f);
  return static_cast<std::uint8_t>(std::lround(255.0f * s));
}

Png8 to_preview(const RgbImage& rgb, float exposure_stops) {
  Png8 out{rgb.width(), rgb.height(), 3, std::vector<std::uint8_t>(rgb.data().size())};
  std::span<const float> data = rgb.data();
  for (std::size_t i = 0; i < data.size(); ++i)
    out.bytes[i] = preview_byte(data[i], exposure_stops);
  return out;
}

absl::Status write_png_preview(const std::filesystem::path& path, const RgbImage& rgb,
                               float exposure_stops) {
  Png8 preview = to_preview(rgb, exposure_stops);
  return base::write_via_temp(path, [&](const std::filesystem::path& temp) -> absl::Status {
    png_image image;
    std::memset(&image, 0, sizeof(image));
    image.version = PNG_IMAGE_VERSION;
    image.width = static_cast<png_uint_32>(preview.width);
    image.height = static_cast<png_uint_32>(preview.height);
    image.format = PNG_FORMAT_RGB;
    // Speed over size (libpng's fast zlib settings): a 4096x4096 preview took 2.3 s.
    image.flags = PNG_IMAGE_FLAG_FAST;
    int ok = png_image_write_to_file(&image, temp.c_str(), /*convert_to_8bit=*/0,
                                     preview.bytes.data(), /*row_stride=*/0, nullptr);
    if (!ok) {
      std::string message = image.message;
      png_image_free(&image);
      return absl::InternalError(absl::StrCat("cannot write PNG ", path.string(), ": ", message));
    }
    png_image_free(&image);
    return absl::OkStatus();
  });
}

absl::StatusOr<Png8> read_png(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return absl::NotFoundError(absl::StrCat("PNG file not found: ", path.string()));
  }
  png_image image;
  std::memset(&image, 0, sizeof(image));
  image.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&image, path.c_str())) {
    std::string message = image.message;
    png_image_free(&image);
    return absl::InvalidArgumentError(
        absl::StrCat("cannot read PNG ", path.string(), ": ", message));
  }
  int channels = static_cast<int>(PNG_IMAGE_SAMPLE_CHANNELS(image.format));
  image.format = format_for_channels(channels);
  std::uint64_t values = std::uint64_t(image.width) * image.height * channels;
  if (image.width < 1 || image.height < 1 || image.width > std::uint32_t(kMaxImageSide) ||
      image.height > std::uint32_t(kMaxImageSide) || values > kMaxImageValues) {
    png_image_free(&image);
    return absl::InvalidArgumentError(absl::StrCat("PNG ", path.string(), " is ", image.width, "x",
                                                   image.height, ", outside the supported size"));
  }
  Png8 out{static_cast<int>(image.width), static_cast<int>(image.height), channels,
           std::vector<std::uint8_t>(values)};
  if (!png_image_finish_read(&image, nullptr, out.bytes.data(), 0, nullptr)) {
    std::string message = image.message;
    png_image_free(&image);
    return absl::InvalidArgumentError(
        absl::StrCat("cannot read PNG ", path.string(), ": ", message));
  }
  png_image_free(&image);
  return out;
}

}  // namespace prism::image
