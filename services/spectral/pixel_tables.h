// Per-pixel wavelength tables of one tile (docs/estimators.md §4): what a prepass or final-pass
// task carries in PdfTable.quantised_cdf, and the worker's decoded, read-only form of it.
//
// Wire layout (specified here; types.proto's PdfTable points here): pixels in row-major
// order over the tile, tile-local index p = y·width + x. Pixel p occupies the bytes
// [2·cells·p, 2·cells·(p + 1)): `cells` unsigned 16-bit little-endian integers q_1 … q_N, the
// quantised CDF of a QuantisedWavelengthCdf over N = cells uniform cells of [360, 830] nm with
// q_0 = 0 left out (it is always 0) and q_N = 65535. A pixel whose N values are all 0 (never a
// valid CDF, whose last value is 65535) carries no table: it uses the job's default wavelength
// distribution, and prepasses skip it (the fallback of §4). Total size width·height·cells·2.
// A table gives bin masses only: inside each of its cells (the job's bins) the worker samples
// with the shape of the job's default distribution (binned_shape.h).
//
// Decoding validates every table once and restores q_0, so the worker samples and evaluates
// each pixel's QuantisedWavelengthCdf from exactly the integers the coordinator quantised:
// sample_lanes(u, C) and pdf(λ) give the same numbers on every machine. Lookups do not
// allocate; the views stay valid while the PixelTables lives (also after it is moved).
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "absl/status/statusor.h"
#include "services/base/check.h"
#include "services/spectral/binned_shape.h"
#include "services/spectral/wavelength_distribution.h"

namespace prism::spectral {

// Bytes of a tile's tables: width·height·cells·2.
std::uint64_t pixel_table_bytes(int width, int height, int cells);

// Appends one pixel's table in the wire layout. `cdf` holds a quantised CDF's cells + 1 values
// (cdf[0] == 0 and cdf.back() == 65535, PRISM_CHECK); cdf[0] is not written.
void append_pixel_table(std::span<const std::uint16_t> cdf, std::string& out);
// Appends the all-zero row of a pixel that uses the job's default distribution.
void append_default_pixel(int cells, std::string& out);

// One pixel's wavelength density as an integrator uses it: the job's default distribution, or
// the pixel's decoded table of bin masses with the default's shape inside each bin
// (binned_shape.h), behind one trivially copyable value (so a trace function can take it by
// value whichever it is). Converts implicitly from a WavelengthDistribution, so code that
// passes the job's distribution keeps compiling. The referenced objects must outlive the view.
class WavelengthPdfView {
 public:
  WavelengthPdfView(const WavelengthDistribution& distribution)  // NOLINT: implicit on purpose
      : distribution_(&distribution) {}
  // `table` must have shape.bins() cells; `guide` is null or its BinnedShape::build_guide.
  WavelengthPdfView(const QuantisedWavelengthCdf& table, const BinnedShape& shape,
                    const std::uint16_t* guide = nullptr)
      : table_(&table), shape_(&shape), guide_(guide) {}
  // The same density sampled from its composite CDF (one search per lane; binned_shape.h):
  // samples agree with the table's view to rounding, densities exactly.
  explicit WavelengthPdfView(const CompositeCdf& composite)
      : table_(&composite.table()), shape_(&composite.shape()), composite_(&composite) {}

  WavelengthSample sample(double u) const {
    if (composite_ != nullptr) return composite_->sample(u);
    return table_ != nullptr ? shape_->sample(*table_, u, guide_) : distribution_->sample(u);
  }
  float pdf(float lambda_nm) const {
    return table_ != nullptr ? shape_->pdf(*table_, lambda_nm) : distribution_->pdf(lambda_nm);
  }
  double cdf(float lambda_nm) const {
    return table_ != nullptr ? shape_->cdf(*table_, lambda_nm) : distribution_->cdf(lambda_nm);
  }
  // CMIS lanes (docs/estimators.md §2), exactly as the underlying density's sample_lanes.
  SampledWavelengths sample_lanes(double u, int lanes) const {
    if (composite_ != nullptr) return composite_->sample_lanes(u, lanes);
    return table_ != nullptr ? shape_->sample_lanes(*table_, u, lanes, guide_)
                             : distribution_->sample_lanes(u, lanes);
  }
  bool is_pixel_table() const { return table_ != nullptr; }

 private:
  const WavelengthDistribution* distribution_ = nullptr;
  const QuantisedWavelengthCdf* table_ = nullptr;
  const BinnedShape* shape_ = nullptr;
  const std::uint16_t* guide_ = nullptr;
  const CompositeCdf* composite_ = nullptr;
};
static_assert(std::is_trivially_copyable_v<WavelengthPdfView>);

class PixelTables {
 public:
  // Decodes a tile's tables. INVALID_ARGUMENT, with the expected and actual sizes or the first
  // bad pixel, when width or height is < 1, cells is outside 1..WavelengthDistribution::kMaxCells,
  // bytes.size() != pixel_table_bytes(width, height, cells), or a pixel's row is neither all
  // zero nor a valid CDF (non-decreasing, ending at 65535).
  static absl::StatusOr<PixelTables> decode(int width, int height, int cells,
                                            std::string_view bytes);

  PixelTables(PixelTables&&) = default;
  PixelTables& operator=(PixelTables&&) = default;
  // The views point into values_; a copy would point into the original.
  PixelTables(const PixelTables&) = delete;
  PixelTables& operator=(const PixelTables&) = delete;

  int width() const { return width_; }
  int height() const { return height_; }
  int cells() const { return cells_; }

  // The table of tile-local pixel (x, y) (in range, PRISM_CHECK), or nullptr when the pixel uses
  // the job's default distribution.
  const QuantisedWavelengthCdf* table(int x, int y) const {
    const std::optional<QuantisedWavelengthCdf>& t = tables_[index(x, y)];
    return t ? &*t : nullptr;
  }
  bool uses_default(int x, int y) const { return table(x, y) == nullptr; }
  // The density tile-local pixel (x, y) samples with: its table's bin masses with the default's
  // shape inside each bin, or `job_default` (the RenderScene's wavelength_pdf()) when it has
  // none. `shape` is job_default cut at the tables' cells (shape.bins() == cells(), PRISM_CHECK).
  WavelengthPdfView view(int x, int y, const WavelengthDistribution& job_default,
                         const BinnedShape& shape) const {
    PRISM_CHECK(shape.bins() == cells_);
    const QuantisedWavelengthCdf* t = table(x, y);
    return t != nullptr ? WavelengthPdfView(*t, shape, guides_.data() + index(x, y) * guide_stride_)
                        : WavelengthPdfView(job_default);
  }
  // Pixels without a table.
  std::int64_t default_pixels() const { return default_pixels_; }

 private:
  PixelTables() = default;
  std::size_t index(int x, int y) const;

  int width_ = 0;
  int height_ = 0;
  int cells_ = 0;
  std::int64_t default_pixels_ = 0;
  std::vector<std::uint16_t> values_;  // per pixel cells + 1 values, q_0 restored
  std::size_t guide_stride_ = 0;       // BinnedShape::guide_entries(cells)
  std::vector<std::uint16_t> guides_;  // per pixel guide_stride_ values (BinnedShape::build_guide)
  std::vector<std::optional<QuantisedWavelengthCdf>> tables_;
};

}  // namespace prism::spectral
