#include "services/image/png.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace prism::image {
namespace {

namespace fs = std::filesystem;

TEST(PngPreview, ExposureSrgbAndClampOnKnownValues) {
  EXPECT_EQ(preview_byte(0.0f, 0.0f), 0);
  EXPECT_EQ(preview_byte(1.0f, 0.0f), 255);
  EXPECT_EQ(preview_byte(7.0f, 0.0f), 255);  // clamped
  EXPECT_EQ(preview_byte(-1.0f, 0.0f), 0);
  EXPECT_EQ(preview_byte(std::numeric_limits<float>::quiet_NaN(), 0.0f), 0);
  EXPECT_EQ(preview_byte(std::numeric_limits<float>::infinity(), 0.0f), 0);
  // sRGB(0.5) = 1.055 * 0.5^(1/2.4) - 0.055 = 0.735357 -> 187.52 -> 188.
  EXPECT_EQ(preview_byte(0.5f, 0.0f), 188);
  EXPECT_EQ(preview_byte(0.25f, 1.0f), 188);  // +1 stop doubles
  EXPECT_EQ(preview_byte(1.0f, -1.0f), 188);  // -1 stop halves
  EXPECT_EQ(preview_byte(0.6f, 1.0f), 255);   // 1.2 after exposure, clamped
  // Linear segment: 12.92 * 0.001 * 255 = 3.29 -> 3.
  EXPECT_EQ(preview_byte(0.001f, 0.0f), 3);
  // 0.18 (mid grey): 1.055 * 0.18^(1/2.4) - 0.055 = 0.461356 -> 117.65 -> 118.
  EXPECT_EQ(preview_byte(0.18f, 0.0f), 118);
}

TEST(PngPreview, FileRoundTripOfEightBitValues) {
  fs::path dir = fs::temp_directory_path() / ("prism_png_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  auto rgb = RgbImage::create(3, 2);
  ASSERT_TRUE(rgb.ok());
  rgb->value(0, 0, 0) = 0.5f;
  rgb->value(1, 0, 1) = 2.0f;
  rgb->value(2, 1, 2) = 0.25f;
  rgb->value(2, 1, 0) = 0.001f;
  fs::path path = dir / "preview.png";
  ASSERT_TRUE(write_png_preview(path, *rgb, 1.0f).ok());
  auto png = read_png(path);
  ASSERT_TRUE(png.ok()) << png.status();
  EXPECT_EQ(png->width, 3);
  EXPECT_EQ(png->height, 2);
  EXPECT_EQ(png->channels, 3);
  EXPECT_EQ(png->bytes, to_preview(*rgb, 1.0f).bytes);
  auto at = [&](int x, int y, int c) { return png->bytes[(y * 3 + x) * 3 + c]; };
  EXPECT_EQ(at(0, 0, 0), 255);  // 0.5 at +1 stop = 1.0
  EXPECT_EQ(at(1, 0, 1), 255);  // clamped
  EXPECT_EQ(at(2, 1, 2), 188);  // 0.25 at +1 stop = 0.5
  EXPECT_EQ(at(2, 1, 0), 7);    // 0.002 linear segment: 6.59 -> 7
  EXPECT_EQ(at(0, 1, 0), 0);

  // Failure leaves no file.
  EXPECT_FALSE(write_png_preview(dir / "missing" / "p.png", *rgb).ok());
  EXPECT_FALSE(fs::exists(dir / "missing" / "p.png"));
  EXPECT_EQ(read_png(dir / "none.png").status().code(), absl::StatusCode::kNotFound);
  std::FILE* f = std::fopen((dir / "bad.png").c_str(), "wb");
  std::fputs("definitely not a png", f);
  std::fclose(f);
  EXPECT_EQ(read_png(dir / "bad.png").status().code(), absl::StatusCode::kInvalidArgument);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace prism::image
