#include "services/spectral/binned_shape.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/cdf_guide.h"
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

// CMIS lanes (docs/estimators.md §2): lane s is sample_at((u + s/C) mod 1).
template <typename SampleAt>
SampledWavelengths rotated_lanes(double u, int lanes, const SampleAt& sample_at) {
  SampledWavelengths w(lanes);
  for (int s = 0; s < lanes; ++s) {
    const WavelengthSample x = sample_at(cyclic_offset(u, s, lanes));
    w.set(s, x.lambda, x.pdf);
  }
  return w;
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
  // The pieces: each bin's overlaps with the default cells, in λ order.
  s.bin_piece_.resize(std::size_t(bins) + 1);
  for (int b = 0; b < bins; ++b) {
    s.bin_piece_[b] = int(s.piece_cell_.size());
    const double lo = s.bin_lower_[b], hi = uniform_cell_lower(b + 1, bins);
    for (int c = s.first_cell_[b]; c <= s.last_cell_[b]; ++c) {
      const double a = std::max(lo, s.cell_lower_[c]);
      const double z = std::min(hi, uniform_cell_lower(c + 1, n));
      if (!(z > a)) continue;
      double fraction = 0.0;
      if (a == lo) {
        fraction = 0.0;
      } else if (s.inv_bin_mass_[b] == 0.0) {
        fraction = std::clamp((a - lo) / (hi - lo), 0.0, 1.0);
      } else {
        const double t = std::clamp((a - s.cell_lower_[c]) / cell_width, 0.0, 1.0);
        const double below = s.cell_cdf_[c] + t * (s.cell_cdf_[c + 1] - s.cell_cdf_[c]);
        fraction = std::clamp((below - s.bin_cdf_[b]) * s.inv_bin_mass_[b], 0.0, 1.0);
      }
      const float first = std::max(s.bin_first_[b], s.cell_first_[c]);
      s.piece_cell_.push_back(c);
      s.piece_lower_.push_back(a);
      s.piece_width_.push_back(z - a);
      s.piece_fraction_.push_back(fraction);
      s.piece_first_.push_back(first);
      s.piece_last_.push_back(std::max(first, std::min(s.bin_last_[b], s.cell_last_[c])));
    }
  }
  s.bin_piece_[bins] = int(s.piece_cell_.size());
  // A piece over a cell without default mass in a bin with some has no mass either: its fraction
  // is the next piece's (1 at the bin's end) exactly, so that rounding cannot leave it a sliver of
  // mass with a zero density.
  for (int b = 0; b < bins; ++b) {
    if (s.inv_bin_mass_[b] == 0.0) continue;
    for (int k = s.bin_piece_[b + 1] - 1; k >= s.bin_piece_[b]; --k) {
      if (s.inv_cell_mass_[s.piece_cell_[k]] != 0.0) continue;
      s.piece_fraction_[k] = k + 1 < s.bin_piece_[b + 1] ? s.piece_fraction_[k + 1] : 1.0;
    }
  }
  PRISM_CHECK(s.piece_cell_.size() < 65536);  // at most cells + bins <= 2·kMaxCells
  const std::span<const int> search = shape.search_guide();
  s.cell_search_guide_.assign(search.begin(), search.end());
  const int intervals = guide_entries(bins) - 1;  // a power of two up to 2^16
  while ((65536 >> s.guide_shift_) > intervals) ++s.guide_shift_;
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
  // min and max rather than std::clamp: no branches, and hi < lo cannot reach it.
  return std::min(std::max(lambda, lo), std::max(lo, hi));
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
    const int j = below >> guide_shift_;
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
  // The default's CDF value of the same fraction of the bin's default mass, then its cell: the
  // largest c with cdf[c] <= v among the cells that overlap the bin, which has positive mass.
  // The guided search looks over all cells (v lies in the bin's CDF range, so only rounding at
  // the bin's edges can find a cell outside it; the clamp brings it back).
  const double v = bin_cdf_[b] + frac * bin_mass_[b];
  int lo = first_cell_[b], span = last_cell_[b] - lo + 1;
  if (guide != nullptr) {
    const double g = double(cell_search_guide_.size() - 1);
    const std::size_t j = static_cast<std::size_t>(std::min(v, kBelowOne) * g);
    lo = cell_search_guide_[j];
    span = cell_search_guide_[j + 1] - lo + 1;
  }
  const double* cell = cell_cdf_.data() + lo;
  while (span > 1) {
    const int half = span / 2;
    cell = cell[half] <= v ? cell + half : cell;
    span -= half;
  }
  int c = std::clamp(int(cell - cell_cdf_.data()), first_cell_[b], last_cell_[b]);
  // Only rounding (v at the very top of the bin) can leave c on a zero-mass cell: take the
  // nearest cell below with mass, at its top.
  while (inv_cell_mass_[c] == 0.0 && c > first_cell_[b]) --c;
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
  return rotated_lanes(u, lanes, [&](double v) { return sample(table, v, guide); });
}

int BinnedShape::guide_entries(int bins) {
  int g = 1;
  while (g < 2 * bins && g < 65536) g *= 2;
  return g + 1;
}

void BinnedShape::build_guide(const QuantisedWavelengthCdf& table, std::span<std::uint16_t> guide) {
  const int n = table.cells();
  PRISM_CHECK(guide.size() == std::size_t(guide_entries(n)));
  const int g = int(guide.size()) - 1;
  const int width = 65536 / g;  // units per interval, 2^(16 − m)
  const std::span<const std::uint16_t> q = table.values();
  int b = 0;
  for (int j = 0; j < g; ++j) {
    const int value = j * width;
    while (b + 1 < n && q[b + 1] <= value) ++b;  // the last bin whose lower CDF value <= value
    guide[j] = std::uint16_t(b);
  }
  guide[g] = std::uint16_t(n - 1);
}

void CompositeCdf::assign(const BinnedShape& shape, const QuantisedWavelengthCdf& table) {
  PRISM_CHECK(table.cells() == shape.bins());
  shape_ = &shape;
  table_ = &table;
  const std::span<const std::uint16_t> q = table.values();
  const std::size_t count = shape.piece_cell_.size();
  cdf_.resize(count + 2);
  pieces_.resize(count);
  Piece* pieces = pieces_.data();
  const double* fraction = shape.piece_fraction_.data();
  const int* cell = shape.piece_cell_.data();
  for (int b = 0; b < shape.bins_; ++b) {
    const int units = q[b + 1] - q[b];
    const int k0 = shape.bin_piece_[b], k1 = shape.bin_piece_[b + 1];
    // In integer units first: a fraction of 0 or 1 lands exactly on the bin's edges q[b] and
    // q[b + 1], which the neighbouring bins' pieces reach the same way.
    for (int k = k0; k < k1; ++k) cdf_[std::size_t(k)] = (q[b] + fraction[k] * units) * kInvUnits;
    // BinnedShape::density's arithmetic, its per-bin factor taken out of the loop.
    if (shape.inv_bin_mass_[b] == 0.0) {
      const float density = static_cast<float>(units * kInvUnits * shape.bin_scale_);
      for (int k = k0; k < k1; ++k) pieces[k].pdf = density;
    } else {
      const double factor = units * kInvUnits * shape.inv_bin_mass_[b];
      for (int k = k0; k < k1; ++k) {
        pieces[k].pdf = static_cast<float>(factor * shape.cell_density_[cell[k]]);
      }
    }
  }
  cdf_[count] = 1.0;
  cdf_[count + 1] = 1.0;  // base::build_cdf_guide's sentinel
  // Per piece its edges and floats, and nanometres per unit of u inside it (0 for the pieces
  // without mass, never sampled).
  const double* width = shape.piece_width_.data();
  for (std::size_t k = 0; k < count; ++k) {
    const double mass = cdf_[k + 1] - cdf_[k];
    Piece& p = pieces[k];
    p.lower = shape.piece_lower_[k];
    p.slope = mass > 0.0 ? width[k] / mass : 0.0;
    p.first = shape.piece_first_[k];
    p.last = shape.piece_last_[k];
  }
  // The guide: 2^m >= four intervals of u per piece (services/base/cdf_guide.h).
  base::build_cdf_guide(std::span<const double>(cdf_), guide_);
}

WavelengthSample CompositeCdf::sample(double u) const {
  u = std::clamp(u, 0.0, kBelowOne);
  // The last piece k with cdf[k] <= u, which has positive mass (cdf[k + 1] > u).
  const int k =
      base::guided_cell(std::span<const double>(cdf_), std::span<const std::uint16_t>(guide_), u);
  const Piece& p = pieces_[std::size_t(k)];
  // Linear inside the piece; the clamp to its floats also absorbs any rounding past its edges.
  const float lambda = static_cast<float>(p.lower + (u - cdf_[std::size_t(k)]) * p.slope);
  return {std::min(std::max(lambda, p.first), p.last), p.pdf};
}

SampledWavelengths CompositeCdf::sample_lanes(double u, int lanes) const {
  return rotated_lanes(u, lanes, [this](double v) { return sample(v); });
}

}  // namespace prism::spectral
