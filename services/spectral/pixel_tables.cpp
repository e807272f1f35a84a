#include "services/spectral/pixel_tables.h"

#include <string>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"

namespace prism::spectral {
namespace {

void append_u16(std::uint16_t v, std::string& out) {
  out.push_back(static_cast<char>(v & 0xffu));
  out.push_back(static_cast<char>(v >> 8));
}

std::uint16_t read_u16(const char* p) {
  return static_cast<std::uint16_t>(static_cast<unsigned char>(p[0]) |
                                    (static_cast<unsigned>(static_cast<unsigned char>(p[1])) << 8));
}

}  // namespace

std::uint64_t pixel_table_bytes(int width, int height, int cells) {
  if (width < 1 || height < 1 || cells < 1) return 0;
  return std::uint64_t(width) * std::uint64_t(height) * std::uint64_t(cells) * 2u;
}

void append_pixel_table(std::span<const std::uint16_t> cdf, std::string& out) {
  PRISM_CHECK(cdf.size() >= 2 && cdf.front() == 0 && cdf.back() == QuantisedWavelengthCdf::kTotal);
  for (std::size_t i = 1; i < cdf.size(); ++i) append_u16(cdf[i], out);
}

void append_default_pixel(int cells, std::string& out) {
  PRISM_CHECK(cells >= 1);
  out.append(std::size_t(cells) * 2u, '\0');
}

absl::StatusOr<PixelTables> PixelTables::decode(int width, int height, int cells,
                                                std::string_view bytes) {
  if (width < 1 || height < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("pixel tables need a non-empty tile, got ", width, "x", height));
  }
  if (cells < 1 || cells > WavelengthDistribution::kMaxCells) {
    return absl::InvalidArgumentError(absl::StrCat("pixel tables need 1 to ",
                                                   WavelengthDistribution::kMaxCells,
                                                   " cells per pixel, got ", cells));
  }
  const std::uint64_t want = pixel_table_bytes(width, height, cells);
  if (bytes.size() != want) {
    return absl::InvalidArgumentError(
        absl::StrCat("pixel tables of a ", width, "x", height, " tile with ", cells, " cells need ",
                     want, " bytes (width*height*cells*2), got ", bytes.size()));
  }
  PixelTables t;
  t.width_ = width;
  t.height_ = height;
  t.cells_ = cells;
  const std::size_t area = std::size_t(width) * std::size_t(height);
  const std::size_t stride = std::size_t(cells) + 1;
  t.values_.resize(area * stride);
  t.guide_stride_ = std::size_t(BinnedShape::guide_entries(cells));
  t.guides_.resize(area * t.guide_stride_);
  t.tables_.reserve(area);
  for (std::size_t p = 0; p < area; ++p) {
    const char* row = bytes.data() + p * std::size_t(cells) * 2u;
    std::uint16_t* v = t.values_.data() + p * stride;
    v[0] = 0;
    bool all_zero = true;
    for (int i = 0; i < cells; ++i) {
      v[i + 1] = read_u16(row + 2 * i);
      all_zero = all_zero && v[i + 1] == 0;
    }
    if (all_zero) {
      t.tables_.emplace_back(std::nullopt);
      ++t.default_pixels_;
      continue;
    }
    absl::StatusOr<QuantisedWavelengthCdf> cdf =
        QuantisedWavelengthCdf::create(std::span<const std::uint16_t>(v, stride));
    if (!cdf.ok()) {
      return absl::InvalidArgumentError(absl::StrCat(
          "pixel table of tile pixel (", p % std::size_t(width), ", ", p / std::size_t(width),
          ") is neither all zero (default distribution) nor a valid CDF: ",
          std::string(cdf.status().message())));
    }
    BinnedShape::build_guide(
        *cdf, std::span<std::uint16_t>(t.guides_.data() + p * t.guide_stride_, t.guide_stride_));
    t.tables_.emplace_back(*cdf);
  }
  return t;
}

std::size_t PixelTables::index(int x, int y) const {
  PRISM_CHECK(x >= 0 && x < width_ && y >= 0 && y < height_);
  return std::size_t(y) * std::size_t(width_) + std::size_t(x);
}

}  // namespace prism::spectral
