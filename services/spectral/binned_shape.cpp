#include "services/spectral/binned_shape.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::spectral {
namespace {

constexpr double kUnits = QuantisedWavelengthCdf::kTotal;
constexpr double kBelowOne = 0x1.fffffffffffffp-1;  // the largest double below 1
constexpr double kInvUnits = 1.0 / kUnits;

double cyclic_offset(double u, int lane, int lanes) {
  const double v = u + static_cast<double>(lane) / lanes;
  return v >= 1.0 ? v - 1.0 : v;
}

}  // namespace

absl::StatusOr<BinnedShape> BinnedShape::create(const WavelengthDistribution& shape, int bins) {
  if (bins < 1 || bins > WavelengthDistribution::kMaxCells) {
    return absl::InvalidArgumentError(absl::StrCat("a binned wavelength shape needs 1 to ",
                                                   WavelengthDistribution::kMaxCells, " bins, got ",
                                                   bins));
  }
  BinnedShape s;
  s.bins_ = bins;
  s.cells_ = shape.cells();
  const int n = s.cells_;
  s.cell_cdf_.resize(std::size_t(n) + 1);
  s.cell_density_.resize(std::size_t(n));
  const double cell_width = double{kLambdaRange} / n;
  for (int c = 0; c <= n; ++c) s.cell_cdf_[c] = shape.cell_cdf(c);
  s.cell_width_ = cell_width;
  s.cell_scale_ = double(n) / double{kLambdaRange};
  s.bin_scale_ = double(bins) / double{kLambdaRange};
  s.cell_lower_.resize(std::size_t(n));
  for (int c = 0; c < n; ++c) s.cell_lower_[c] = uniform_cell_lower(c, n);
  s.float_ranges(n, s.cell_scale_, s.cell_first_, s.cell_last_);
  s.float_ranges(bins, s.bin_scale_, s.bin_first_, s.bin_last_);
  s.inv_cell_mass_.resize(std::size_t(n));
  for (int c = 0; c < n; ++c) {
    s.cell_density_[c] = shape.cell_mass(c) / cell_width;
    const double mass = s.cell_cdf_[c + 1] - s.cell_cdf_[c];
    s.inv_cell_mass_[c] = mass > 0.0 ? 1.0 / mass : 0.0;
  }

  // The default CDF at a bin edge, in double: the cell holding the edge, linear inside it.
  auto cdf_at = [&](double lambda) {
    if (lambda >= double{kLambdaMax}) return 1.0;
    const int c = std::min(n - 1, int((lambda - double{kLambdaMin}) * n / double{kLambdaRange}));
    const double t = std::clamp((lambda - uniform_cell_lower(c, n)) / cell_width, 0.0, 1.0);
    return s.cell_cdf_[c] + t * (s.cell_cdf_[c + 1] - s.cell_cdf_[c]);
  };
  s.bin_mass_.resize(std::size_t(bins));
  s.inv_bin_mass_.resize(std::size_t(bins));
  s.bin_cdf_.resize(std::size_t(bins));
  s.first_cell_.resize(std::size_t(bins));
  s.bin_lower_.resize(std::size_t(bins));
  s.last_cell_.resize(std::size_t(bins));
  for (int b = 0; b < bins; ++b) {
    const double lo = uniform_cell_lower(b, bins), hi = uniform_cell_lower(b + 1, bins);
    const double p0 = cdf_at(lo), p1 = b + 1 == bins ? 1.0 : cdf_at(hi);
    s.bin_cdf_[b] = p0;
    s.bin_lower_[b] = lo;
    s.bin_mass_[b] = std::max(0.0, p1 - p0);
    s.inv_bin_mass_[b] = s.bin_mass_[b] > 0.0 ? 1.0 / s.bin_mass_[b] : 0.0;
    s.first_cell_[b] = std::min(n - 1, int((lo - double{kLambdaMin}) * n / double{kLambdaRange}));
    const int last = int(std::ceil((hi - double{kLambdaMin}) * n / double{kLambdaRange})) - 1;
    s.last_cell_[b] = std::clamp(last, s.first_cell_[b], n - 1);
  }
  // The cell guide: thresholds computed exactly as sample() computes v, so the cell holding v
  // lies between the guide entries around it.
  s.cell_guide_.resize(std::size_t(bins) * (kCellGuide + 1));
  for (int b = 0; b < bins; ++b) {
    int c = s.first_cell_[b];
    for (int k = 0; k <= kCellGuide; ++k) {
      const double v = s.bin_cdf_[b] + (double(k) / kCellGuide) * s.bin_mass_[b];
      while (c < s.last_cell_[b] && s.cell_cdf_[c + 1] <= v) ++c;
      s.cell_guide_[std::size_t(b) * (kCellGuide + 1) + k] = c;
    }
  }
  return s;
}

namespace {

// The uniform cell of n holding λ by one multiplication, as bin_of and cell_of look it up.
int index_of(float lambda_nm, double scale, int n) {
  const int i = int((double(lambda_nm) - double{kLambdaMin}) * scale);
  return std::clamp(i, 0, n - 1);
}

}  // namespace

void BinnedShape::float_ranges(int n, double scale, std::vector<float>& first,
                               std::vector<float>& last) {
  uniform_cell_floats(
      n, [scale, n](float lambda) { return index_of(lambda, scale, n); }, first, last);
}

int BinnedShape::bin_of(float lambda_nm) const {
  return index_of(lambda_nm, bin_scale_, bins_);
}

int BinnedShape::cell_of(float lambda_nm) const {
  return index_of(lambda_nm, cell_scale_, cells_);
}

float BinnedShape::settle(float lambda, int b, int c) const {
  // Clamped into the floats that bin_of maps to b and cell_of to c: the two ranges overlap
  // wherever the sample can land (it came from a positive mass of that cell in that bin).
  float lo = bin_first_[b], hi = bin_last_[b];
  if (c >= 0) {
    lo = std::max(lo, cell_first_[c]);
    hi = std::min(hi, cell_last_[c]);
  }
  return std::clamp(lambda, lo, std::max(lo, hi));
}

float BinnedShape::density(int table_units, int b, int c) const {
  if (inv_bin_mass_[b] == 0.0) {
    return static_cast<float>(table_units * kInvUnits * bin_scale_);
  }
  return static_cast<float>(table_units * kInvUnits * inv_bin_mass_[b] * cell_density_[c]);
}

WavelengthSample BinnedShape::sample(const QuantisedWavelengthCdf& table, double u,
                                     const std::uint16_t* guide) const {
  PRISM_CHECK(table.cells() == bins_);
  const std::span<const std::uint16_t> q = table.values();
  const double x = std::clamp(u, 0.0, kBelowOne) * kUnits;
  // The bin b with q[b] <= x < q[b+1]: it has positive mass. q[i] <= x exactly when q[i] <= ⌊x⌋
  // (integers). Branch-free halving (a conditional move per step), since which half holds x is a
  // coin toss a branch predictor cannot learn; the guide narrows the range first.
  const int below = int(x);
  const std::uint16_t* first = q.data();
  int count = bins_;  // search q[first..first + count) for the last value <= ⌊x⌋
  if (guide != nullptr) {
    const int j = int(std::int64_t{below} * bins_ / QuantisedWavelengthCdf::kTotal);
    first = q.data() + guide[j];
    count = guide[j + 1] - guide[j] + 1;
  }
  while (count > 1) {
    const int half = count / 2;
    first = int(first[half]) <= below ? first + half : first;
    count -= half;
  }
  const int b = int(first - q.data());
  const int units = q[b + 1] - q[b];
  const double frac = std::clamp((x - q[b]) / units, 0.0, 1.0);
  if (inv_bin_mass_[b] == 0.0) {
    const double w = double{kLambdaRange} / bins_;
    const float lambda = settle(static_cast<float>(bin_lower_[b] + frac * w), b, -1);
    return {lambda, density(units, b, cell_of(lambda))};
  }
  // The default's CDF value of the same fraction of the bin's default mass, then its cell among
  // the few that overlap the bin: the largest c with cdf[c] <= v, which has positive mass.
  const double v = bin_cdf_[b] + frac * bin_mass_[b];
  const int k = std::min(kCellGuide - 1, int(frac * kCellGuide));
  const int* cells = cell_guide_.data() + std::size_t(b) * (kCellGuide + 1);
  const double* cell = cell_cdf_.data() + cells[k];
  int span = cells[k + 1] - cells[k] + 1;  // search for the last cdf value <= v
  while (span > 1) {
    const int half = span / 2;
    cell = cell[half] <= v ? cell + half : cell;
    span -= half;
  }
  int c = int(cell - cell_cdf_.data());
  // Only rounding (v at the very top of the bin) can leave c on a zero-mass cell: take the
  // nearest cell below with mass, at its top.
  while (c > first_cell_[b] && !(cell_cdf_[c + 1] > cell_cdf_[c])) --c;
  const double t = std::clamp((v - cell_cdf_[c]) * inv_cell_mass_[c], 0.0, 1.0);
  const float lambda = settle(static_cast<float>(cell_lower_[c] + t * cell_width_), b, c);
  return {lambda, density(units, b, c)};
}

float BinnedShape::pdf(const QuantisedWavelengthCdf& table, float lambda_nm) const {
  PRISM_CHECK(table.cells() == bins_);
  if (!(lambda_nm >= kLambdaMin && lambda_nm <= kLambdaMax)) return 0.0f;
  const int b = bin_of(lambda_nm);
  const std::span<const std::uint16_t> q = table.values();
  const int units = q[b + 1] - q[b];
  if (units == 0) return 0.0f;
  return density(units, b, cell_of(lambda_nm));
}

double BinnedShape::cdf(const QuantisedWavelengthCdf& table, float lambda_nm) const {
  PRISM_CHECK(table.cells() == bins_);
  if (!(lambda_nm >= kLambdaMin)) return 0.0;
  if (lambda_nm >= kLambdaMax) return 1.0;
  const std::span<const std::uint16_t> q = table.values();
  const int b = bin_of(lambda_nm);
  const double below = q[b] * kInvUnits, units = (q[b + 1] - q[b]) * kInvUnits;
  double within;  // fraction of bin b's mass below λ
  if (inv_bin_mass_[b] == 0.0) {
    within = (double(lambda_nm) - bin_lower_[b]) * bin_scale_;
  } else {
    const int c = cell_of(lambda_nm);
    const double t = (double(lambda_nm) - cell_lower_[c]) / cell_width_;
    const double p = cell_cdf_[c] + std::clamp(t, 0.0, 1.0) * (cell_cdf_[c + 1] - cell_cdf_[c]);
    within = (p - bin_cdf_[b]) * inv_bin_mass_[b];
  }
  return below + units * std::clamp(within, 0.0, 1.0);
}

SampledWavelengths BinnedShape::sample_lanes(const QuantisedWavelengthCdf& table, double u,
                                             int lanes, const std::uint16_t* guide) const {
  SampledWavelengths w(lanes);
  for (int s = 0; s < lanes; ++s) {
    const WavelengthSample x = sample(table, cyclic_offset(u, s, lanes), guide);
    w.set(s, x.lambda, x.pdf);
  }
  return w;
}

void BinnedShape::build_guide(const QuantisedWavelengthCdf& table, std::span<std::uint16_t> guide) {
  const int n = table.cells();
  PRISM_CHECK(guide.size() == std::size_t(n) + 1);
  const std::span<const std::uint16_t> q = table.values();
  int b = 0;
  for (int j = 0; j <= n; ++j) {
    const int value = int(std::int64_t{j} * QuantisedWavelengthCdf::kTotal / n);
    while (b + 1 < n && q[b + 1] <= value) ++b;  // the last bin whose lower CDF value <= value
    guide[j] = std::uint16_t(b);
  }
}

}  // namespace prism::spectral
