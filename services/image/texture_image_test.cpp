#include "services/image/texture_image.h"

#include <gtest/gtest.h>
#include <png.h>

#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

namespace prism::image {
namespace {

// A PNG in memory, written by libpng's simplified API from `samples` (8 or 16 bits each, in the
// file's byte order handled by libpng) in `format`.
std::string png_bytes(int width, int height, png_uint_32 format, const void* samples) {
  png_image image;
  std::memset(&image, 0, sizeof(image));
  image.version = PNG_IMAGE_VERSION;
  image.width = png_uint_32(width);
  image.height = png_uint_32(height);
  image.format = format;
  png_alloc_size_t size = 0;
  EXPECT_TRUE(png_image_write_to_memory(&image, nullptr, &size, 0, samples, 0, nullptr));
  std::string out(size, '\0');
  EXPECT_TRUE(png_image_write_to_memory(&image, out.data(), &size, 0, samples, 0, nullptr));
  out.resize(size);
  return out;
}

// 16-bit samples are the file's values over 65535, in its encoding, as 8-bit ones are over 255
// (pbrt-v4's ReadPNG): libpng's simplified API had re-encoded them to sRGB bytes when asked for
// 8 bits, which decoded a 16-bit grey of 0.502 as if it were linear.
TEST(TextureImageTest, SixteenBitSamplesAreTheFilesValues) {
  const std::uint16_t grey[2] = {0x8080, 0xffff};
  auto decoded = decode_texture_image(png_bytes(2, 1, PNG_FORMAT_LINEAR_Y, grey), "grey16.png");
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  EXPECT_TRUE(decoded->eight_bit);  // in the file's encoding, for the texture to decode
  ASSERT_EQ(decoded->channels, 1);
  EXPECT_FLOAT_EQ(decoded->values[0], 32896.0f / 65535.0f);
  EXPECT_FLOAT_EQ(decoded->values[1], 1.0f);
}

// A texel's colour does not depend on its alpha (pbrt-v4 keeps the RGB channels); reading
// without alpha had composited it onto black.
TEST(TextureImageTest, AlphaIsDroppedNotCompositedOntoBlack) {
  const std::uint8_t rgba[8] = {255, 0, 0, 0, 128, 128, 128, 128};
  auto decoded = decode_texture_image(png_bytes(2, 1, PNG_FORMAT_RGBA, rgba), "rgba.png");
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  ASSERT_EQ(decoded->channels, 3);
  const std::vector<float> expected = {1.0f, 0.0f, 0.0f, 128 / 255.0f, 128 / 255.0f, 128 / 255.0f};
  EXPECT_EQ(decoded->values, expected);
  const std::uint8_t ga[4] = {200, 0, 60, 255};
  auto grey = decode_texture_image(png_bytes(2, 1, PNG_FORMAT_GA, ga), "ga.png");
  ASSERT_TRUE(grey.ok()) << grey.status();
  EXPECT_EQ(grey->values, (std::vector<float>{200 / 255.0f, 60 / 255.0f}));
}

}  // namespace
}  // namespace prism::image
