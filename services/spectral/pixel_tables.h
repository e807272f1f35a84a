// Per-pixel wavelength tables of one tile (algorithms.md §4): what a prepass or final-pass task
// carries in PdfTable.quantised_cdf, and the worker's decoded, read-only form of it.
//
// Wire layout (specified here; types.proto's PdfTable points here): pixels in row-major
// order over the tile, tile-local index p = y·width + x. Pixel p occupies the bytes
// [2·cells·p, 2·cells·(p + 1)): `cells` unsigned 16-bit little-endian integers q_1 … q_N, the
// quantised CDF of a QuantisedWavelengthCdf over N = cells uniform cells of [360, 830] nm with
// q_0 = 0 left out (it is always 0) and q_N = 65535. A pixel whose N values are all 0 (never a
// valid CDF, whose last value is 65535) carries no table: it uses the job's default wavelength
// distribution, and prepasses skip it (the fallback of §4). Total size width·height·cells·2.
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
// the pixel's decoded table, behind one trivially copyable value (so a trace function can take
// it by value whichever it is). Converts implicitly from a WavelengthDistribution, so code that
// passes the job's distribution keeps compiling. A table alone is uniform inside its cells; a
// table with `within` (what PixelTables::view gives: the job's default distribution) has the
// table's cell masses and within's shape inside each cell
// (QuantisedWavelengthCdf::sample_within), so a table learned per bin keeps the emitters' lines.
// The referenced objects must outlive the view.
class WavelengthPdfView {
 public:
  WavelengthPdfView(const WavelengthDistribution& distribution)  // NOLINT: implicit on purpose
      : distribution_(&distribution) {}
  explicit WavelengthPdfView(const QuantisedWavelengthCdf& table) : table_(&table) {}
  WavelengthPdfView(const QuantisedWavelengthCdf& table, const WavelengthDistribution& within)
      : distribution_(&within), table_(&table) {}

  WavelengthSample sample(double u) const {
    if (table_ == nullptr) return distribution_->sample(u);
    return distribution_ != nullptr ? table_->sample_within(u, *distribution_) : table_->sample(u);
  }
  float pdf(float lambda_nm) const {
    if (table_ == nullptr) return distribution_->pdf(lambda_nm);
    return distribution_ != nullptr ? table_->pdf_within(lambda_nm, *distribution_)
                                    : table_->pdf(lambda_nm);
  }
  double cdf(float lambda_nm) const {
    if (table_ == nullptr) return distribution_->cdf(lambda_nm);
    return distribution_ != nullptr ? table_->cdf_within(lambda_nm, *distribution_)
                                    : table_->cdf(lambda_nm);
  }
  // CMIS lanes (algorithms.md §2), exactly as the underlying density's sample_lanes.
  SampledWavelengths sample_lanes(double u, int lanes) const {
    if (table_ == nullptr) return distribution_->sample_lanes(u, lanes);
    return distribution_ != nullptr ? table_->sample_lanes_within(u, lanes, *distribution_)
                                    : table_->sample_lanes(u, lanes);
  }
  bool is_pixel_table() const { return table_ != nullptr; }

 private:
  const WavelengthDistribution* distribution_ = nullptr;
  const QuantisedWavelengthCdf* table_ = nullptr;
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
  // The density tile-local pixel (x, y) samples with: its table's cell masses with
  // `job_default`'s shape inside each cell, or `job_default` (the RenderScene's
  // wavelength_pdf()) when it has none.
  WavelengthPdfView view(int x, int y, const WavelengthDistribution& job_default) const {
    const QuantisedWavelengthCdf* t = table(x, y);
    return t != nullptr ? WavelengthPdfView(*t, job_default) : WavelengthPdfView(job_default);
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
  std::vector<std::optional<QuantisedWavelengthCdf>> tables_;
};

}  // namespace prism::spectral
