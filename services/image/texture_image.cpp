#include "services/image/texture_image.h"

#include <ImfArray.h>
#include <ImfIO.h>
#include <ImfRgbaFile.h>
#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <stdexcept>

#include "absl/strings/str_cat.h"

namespace prism::image {
namespace {

absl::Status bad(std::string_view name, std::string_view why) {
  return absl::InvalidArgumentError(
      absl::StrCat("image \"", std::string(name), "\": ", std::string(why)));
}

absl::StatusOr<TextureImageData> decode_png(std::string_view bytes, std::string_view name) {
  png_image image;
  std::memset(&image, 0, sizeof(image));
  image.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_memory(&image, bytes.data(), bytes.size())) {
    std::string message = image.message;
    png_image_free(&image);
    return bad(name, absl::StrCat("not a readable PNG: ", message));
  }
  const bool colour = (image.format & PNG_FORMAT_FLAG_COLOR) != 0;
  const bool alpha = (image.format & PNG_FORMAT_FLAG_ALPHA) != 0;
  // libpng's simplified API reports 16-bit files as linear; read them as 16-bit, since asking
  // for 8 bits would re-encode them to sRGB bytes (2x too bright once decoded as sRGB again).
  const bool sixteen = (image.format & PNG_FORMAT_FLAG_LINEAR) != 0;
  // The alpha channel is read and dropped: asking for no alpha composites the colour onto
  // black, and pbrt-v4 keeps a texel's colour whatever its alpha.
  image.format = (colour ? PNG_FORMAT_FLAG_COLOR : 0u) | (alpha ? PNG_FORMAT_FLAG_ALPHA : 0u) |
                 (sixteen ? PNG_FORMAT_FLAG_LINEAR : 0u);
  const int channels = colour ? 3 : 1;
  const int stored = channels + (alpha ? 1 : 0);
  const long texels = long(image.width) * long(image.height);
  if (image.width < 1 || image.height < 1 || texels > kMaxTextureTexels) {
    png_image_free(&image);
    return bad(name,
               absl::StrCat("is ", image.width, "x", image.height, ", outside the supported size"));
  }
  std::vector<std::uint8_t> raw(std::size_t(texels) * stored * (sixteen ? 2 : 1));
  if (!png_image_finish_read(&image, nullptr, raw.data(), 0, nullptr)) {
    std::string message = image.message;
    png_image_free(&image);
    return bad(name, absl::StrCat("damaged PNG: ", message));
  }
  png_image_free(&image);
  // Values as stored, in the file's encoding (the texture's `encoding` decodes them), 8- and
  // 16-bit alike, as pbrt-v4's ReadPNG has them.
  TextureImageData out{int(image.width), int(image.height), channels, true, {}};
  out.values.resize(std::size_t(texels) * channels);
  for (std::size_t t = 0; t < std::size_t(texels); ++t) {
    for (int c = 0; c < channels; ++c) {
      const std::size_t at = t * std::size_t(stored) + std::size_t(c);
      float v;
      if (sixteen) {
        std::uint16_t sample;
        std::memcpy(&sample, raw.data() + 2 * at, 2);
        v = float(sample) / 65535.0f;
        if (alpha) {
          // libpng premultiplies 16-bit output by alpha; undone where alpha is not 0 (a texel of
          // alpha 0 has lost its colour there).
          std::uint16_t a;
          std::memcpy(&a, raw.data() + 2 * (t * std::size_t(stored) + std::size_t(channels)), 2);
          v = a > 0 ? std::min(1.0f, float(sample) / float(a)) : 0.0f;
        }
      } else {
        v = float(raw[at]) / 255.0f;
      }
      out.values[t * std::size_t(channels) + std::size_t(c)] = v;
    }
  }
  return out;
}

// OpenEXR reads through this stream so that a file in memory needs no temporary copy on disk.
class MemoryStream : public Imf::IStream {
 public:
  MemoryStream(std::string_view bytes, const std::string& name)
      : Imf::IStream(name.c_str()), bytes_(bytes) {}
  bool isMemoryMapped() const override { return false; }
  bool read(char c[], int n) override {
    if (n < 0 || position_ + std::uint64_t(n) > bytes_.size()) {
      throw std::runtime_error("unexpected end of file");
    }
    std::memcpy(c, bytes_.data() + position_, std::size_t(n));
    position_ += std::uint64_t(n);
    return position_ < bytes_.size();
  }
  std::uint64_t tellg() override { return position_; }
  void seekg(std::uint64_t pos) override { position_ = pos; }
  void clear() override {}

 private:
  std::string_view bytes_;
  std::uint64_t position_ = 0;
};

absl::StatusOr<TextureImageData> decode_exr(std::string_view bytes, std::string_view name) {
  try {
    MemoryStream stream(bytes, std::string(name));
    Imf::RgbaInputFile file(stream);
    const Imath::Box2i window = file.dataWindow();
    const long width = long(window.max.x) - window.min.x + 1;
    const long height = long(window.max.y) - window.min.y + 1;
    if (width < 1 || height < 1 || width * height > kMaxTextureTexels) {
      return bad(name, absl::StrCat("is ", width, "x", height, ", outside the supported size"));
    }
    const Imf::RgbaChannels present = file.channels();
    const bool colour = (present & Imf::WRITE_RGB) != 0;
    if (!colour && (present & Imf::WRITE_Y) == 0) return bad(name, "has no R, G, B or Y channels");
    Imf::Array2D<Imf::Rgba> pixels(height, width);
    file.setFrameBuffer(&pixels[0][0] - window.min.x - window.min.y * width, 1, std::size_t(width));
    file.readPixels(window.min.y, window.max.y);
    TextureImageData out{int(width), int(height), colour ? 3 : 1, false, {}};
    out.values.reserve(std::size_t(width * height * out.channels));
    for (long y = 0; y < height; ++y) {
      for (long x = 0; x < width; ++x) {
        const Imf::Rgba& p = pixels[y][x];
        if (colour) {
          out.values.insert(out.values.end(), {float(p.r), float(p.g), float(p.b)});
        } else {
          out.values.push_back(float(p.r));  // Y-only files are read back as grey in r, g, b
        }
      }
    }
    for (float v : out.values) {
      if (!std::isfinite(v)) return bad(name, "holds a non-finite value");
    }
    return out;
  } catch (const std::exception& e) {
    return bad(name, absl::StrCat("not a readable OpenEXR file: ", e.what()));
  }
}

}  // namespace

absl::StatusOr<TextureImageData> decode_texture_image(std::string_view bytes,
                                                      std::string_view name) {
  static constexpr unsigned char kPng[] = {0x89, 'P', 'N', 'G'};
  static constexpr unsigned char kExr[] = {0x76, 0x2f, 0x31, 0x01};
  if (bytes.size() >= 4 && std::memcmp(bytes.data(), kPng, 4) == 0) return decode_png(bytes, name);
  if (bytes.size() >= 4 && std::memcmp(bytes.data(), kExr, 4) == 0) return decode_exr(bytes, name);
  return bad(name, "is neither a PNG nor an OpenEXR file (Prism reads those two formats)");
}

}  // namespace prism::image
