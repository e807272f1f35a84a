#include "services/spectral/wavelength_distribution.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "absl/strings/str_cat.h"
#include "services/base/cdf_guide.h"
#include "services/base/check.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::spectral {

double uniform_cell_lower(int c, int n) {
  return double{kLambdaMin} + double{kLambdaRange} * c / n;
}

int uniform_cell_of(float lambda_nm, int n) {
  if (!(lambda_nm >= kLambdaMin && lambda_nm <= kLambdaMax)) return -1;
  const int c = static_cast<int>((static_cast<double>(lambda_nm) - double{kLambdaMin}) * n /
                                 double{kLambdaRange});
  return std::min(c, n - 1);
}

void uniform_cell_floats(int n, absl::FunctionRef<int(float)> index, std::vector<float>& first,
                         std::vector<float>& last) {
  first.assign(std::size_t(n), kLambdaMax);
  last.assign(std::size_t(n), kLambdaMin);
  // Walk each edge's float neighbourhood: the first float of cell i is the smallest float whose
  // index is i; cells are contiguous, so the last float of cell i − 1 is the float before it.
  first[0] = kLambdaMin;
  last[std::size_t(n) - 1] = kLambdaMax;
  for (int i = 1; i < n; ++i) {
    float edge = static_cast<float>(uniform_cell_lower(i, n));
    while (index(edge) >= i) edge = std::nextafter(edge, 0.0f);
    while (index(edge) < i) edge = std::nextafter(edge, kLambdaMax);
    first[i] = edge;
    last[i - 1] = std::nextafter(edge, 0.0f);
  }
}

namespace {

constexpr double kMin = kLambdaMin;
constexpr double kRange = kLambdaRange;

double cell_lower(int c, int n) {
  return uniform_cell_lower(c, n);
}

int cell_index(float lambda_nm, int n) {
  return uniform_cell_of(lambda_nm, n);
}

absl::Status check_cells(int cells) {
  if (cells < 1 || cells > WavelengthDistribution::kMaxCells) {
    return absl::InvalidArgumentError(absl::StrCat("a wavelength distribution needs 1 to ",
                                                   WavelengthDistribution::kMaxCells,
                                                   " cells, got ", cells));
  }
  return absl::OkStatus();
}

struct Inverted {
  float lambda;
  int cell;
};

// Inverts a piecewise-linear CDF given by cdf_at(0..n) (non-decreasing, cdf_at(0) = 0,
// cdf_at(n) = 1). The chosen cell c satisfies cdf(c) <= u < cdf(c+1), so it has positive mass;
// the returned float λ is nudged, if rounding moved it, until cell_index(λ) == c, which is what
// makes sample() and pdf() agree exactly. With a guide (guide_cells below), the search starts in
// the cells that u's guide interval can reach; the cell found is the same.
// Per cell of n uniform cells: its lower edge (cell_lower) and the first and last float that
// cell_index maps to it, so that a λ is settled into its cell by one clamp.
struct CellFloats {
  std::span<const double> lower;
  std::span<const float> first, last;
};

template <typename CdfAt>
Inverted invert(int n, double u, const CdfAt& cdf_at, std::span<const int> guide = {},
                const CellFloats* floats = nullptr) {
  u = std::clamp(u, 0.0, 0x1.fffffffffffffp-1);  // the largest double below 1
  // The last c in [0, n) with cdf(c) <= u, by branch-free halving: which half holds u is a coin
  // toss that a branch predictor cannot learn, and a conditional move costs less than the
  // mispredictions.
  int c = 0, count = n;
  if (!guide.empty()) {
    const std::size_t j = static_cast<std::size_t>(u * double(guide.size() - 1));
    c = guide[j];
    count = guide[j + 1] - c + 1;
  }
  while (count > 1) {
    const int half = count / 2;
    c = cdf_at(c + half) <= u ? c + half : c;
    count -= half;
  }
  const double c0 = cdf_at(c), c1 = cdf_at(c + 1);
  const double t = std::clamp((u - c0) / (c1 - c0), 0.0, 1.0);
  if (floats != nullptr) {
    // cell_index is non-decreasing in λ, so the nudging below ends on the cell's first or last
    // float: the clamp gives the same λ.
    const float lambda = static_cast<float>(floats->lower[c] + t * (kRange / n));
    return {std::clamp(lambda, floats->first[c], floats->last[c]), c};
  }
  float lambda = static_cast<float>(cell_lower(c, n) + t * (kRange / n));
  lambda = std::clamp(lambda, kLambdaMin, kLambdaMax);
  while (cell_index(lambda, n) > c) lambda = std::nextafter(lambda, 0.0f);
  while (cell_index(lambda, n) < c) lambda = std::nextafter(lambda, kLambdaMax);
  return {lambda, c};
}

template <typename CdfAt>
double eval_cdf(int n, float lambda_nm, const CdfAt& cdf_at) {
  if (!(lambda_nm >= kLambdaMin)) return 0.0;
  if (lambda_nm >= kLambdaMax) return 1.0;
  const int c = cell_index(lambda_nm, n);
  const double w = kRange / n;
  const double t = std::clamp((lambda_nm - cell_lower(c, n)) / w, 0.0, 1.0);
  return cdf_at(c) + t * (cdf_at(c + 1) - cdf_at(c));
}

// sample()'s search guide: base::build_cdf_guide's, 2^m + 1 entries for 2^m >= 4n (u·2^m exact),
// entry j the last cell c with cdf(c) <= j/2^m (n − 1 for the last). The cell u falls in, for
// j/2^m <= u < (j+1)/2^m, lies in [guide[j], guide[j+1]]. Four entries per cell rather than two:
// a default lane 7 % faster (prism-bench-wavelength-sampling, 5.75 -> 5.33 ns), and the binned
// shape's search inside a bin, which uses it, 9 %. (sample() keeps its own halving search: the
// guided search's two comparisons made a default lane slower, 7.5 ns.)
std::vector<int> guide_cells(const std::vector<double>& cdf) {
  std::vector<double> with_sentinel(cdf);
  with_sentinel.push_back(1.0);
  std::vector<int> guide;
  base::build_cdf_guide(std::span<const double>(with_sentinel), guide);
  return guide;
}

// The CellFloats tables of n cells. Every cell holds at least one float (PRISM_CHECK): true for
// any n up to kMaxCells, whose cells are 0.029 nm wide against a float spacing of 6e-5 nm.
void cell_floats(int n, std::vector<double>& lower, std::vector<float>& first,
                 std::vector<float>& last) {
  lower.resize(std::size_t(n));
  for (int c = 0; c < n; ++c) lower[c] = cell_lower(c, n);
  uniform_cell_floats(
      n, [n](float lambda) { return cell_index(lambda, n); }, first, last);
  for (int c = 0; c < n; ++c) PRISM_CHECK(first[c] <= last[c]);
}

double cyclic_offset(double u, int lane, int lanes) {
  double v = u + static_cast<double>(lane) / lanes;
  return v >= 1.0 ? v - 1.0 : v;
}

// Hero lanes from one number: lane s samples u + s/lanes (mod 1).
template <typename Distribution>
SampledWavelengths sample_cyclic_lanes(const Distribution& d, double u, int lanes) {
  SampledWavelengths w(lanes);
  for (int s = 0; s < lanes; ++s) {
    const WavelengthSample x = d.sample(cyclic_offset(u, s, lanes));
    w.set(s, x.lambda, x.pdf);
  }
  return w;
}

}  // namespace

WavelengthDistribution::WavelengthDistribution(std::vector<double> weights) {
  const int n = static_cast<int>(weights.size());
  cdf_.resize(weights.size() + 1);
  cdf_[0] = 0.0;
  for (int i = 0; i < n; ++i) cdf_[i + 1] = cdf_[i] + weights[i];
  const double total = cdf_[n];
  PRISM_CHECK(total > 0.0 && std::isfinite(total));
  for (double& c : cdf_) c /= total;
  cdf_[n] = 1.0;
  // Masses are taken from the stored CDF, not from the weights, so that a weight too small to
  // move the running sum counts as zero for pdf() exactly as it does for sample().
  mass_.resize(weights.size());
  pdf_.resize(weights.size());
  const double w = kRange / n;
  for (int i = 0; i < n; ++i) {
    mass_[i] = cdf_[i + 1] - cdf_[i];
    pdf_[i] = static_cast<float>(mass_[i] / w);
  }
  guide_ = guide_cells(cdf_);
  cell_floats(n, lower_, first_, last_);
}

absl::StatusOr<WavelengthDistribution> WavelengthDistribution::flat(int cells) {
  if (auto s = check_cells(cells); !s.ok()) return s;
  return WavelengthDistribution(std::vector<double>(static_cast<size_t>(cells), 1.0));
}

absl::StatusOr<WavelengthDistribution> WavelengthDistribution::visible(int cells) {
  if (auto s = check_cells(cells); !s.ok()) return s;
  constexpr double kA = 0.0072, kCentre = 538.0;
  std::vector<double> w(static_cast<size_t>(cells));
  for (int i = 0; i < cells; ++i) {
    const double lo = cell_lower(i, cells), hi = cell_lower(i + 1, cells);
    w[i] = (std::tanh(kA * (hi - kCentre)) - std::tanh(kA * (lo - kCentre))) / kA;
  }
  return WavelengthDistribution(std::move(w));
}

absl::StatusOr<WavelengthDistribution> WavelengthDistribution::emitters(
    std::span<const Spectrum> spectra, int cells) {
  if (auto s = check_cells(cells); !s.ok()) return s;
  if (spectra.empty()) {
    return absl::InvalidArgumentError(
        "an emitter wavelength distribution needs at least one emitter spectrum");
  }
  std::vector<double> sum(static_cast<size_t>(cells), 0.0), one(static_cast<size_t>(cells));
  for (size_t j = 0; j < spectra.size(); ++j) {
    double total = 0.0;
    for (int i = 0; i < cells; ++i) {
      one[i] = integrate(spectra[j], cell_lower(i, cells), cell_lower(i + 1, cells));
      if (!(one[i] >= 0.0) || !std::isfinite(one[i])) {
        return absl::InvalidArgumentError(
            absl::StrCat("emitter spectrum ", j, " is negative or not finite near ",
                         cell_lower(i, cells), " nm; emission must be >= 0"));
      }
      total += one[i];
    }
    if (!(total > 0.0)) {
      return absl::InvalidArgumentError(absl::StrCat(
          "emitter spectrum ", j, " emits nothing in 360–830 nm; remove it or fix its spectrum"));
    }
    for (int i = 0; i < cells; ++i) sum[i] += one[i] / total;
  }
  return WavelengthDistribution(std::move(sum));
}

absl::StatusOr<WavelengthDistribution> WavelengthDistribution::from_table(
    std::span<const double> weights) {
  if (auto s = check_cells(static_cast<int>(weights.size())); !s.ok()) return s;
  double total = 0.0;
  for (size_t i = 0; i < weights.size(); ++i) {
    if (!std::isfinite(weights[i]) || weights[i] < 0.0) {
      return absl::InvalidArgumentError(absl::StrCat(
          "wavelength table weight ", i, " is ", weights[i], "; weights must be finite and >= 0"));
    }
    total += weights[i];
  }
  if (!(total > 0.0) || !std::isfinite(total)) {
    return absl::InvalidArgumentError(
        "wavelength table weights are all zero (or overflow): no wavelength could be sampled");
  }
  return WavelengthDistribution(std::vector<double>(weights.begin(), weights.end()));
}

absl::StatusOr<WavelengthDistribution> WavelengthDistribution::product(
    const WavelengthDistribution& a, const WavelengthDistribution& b) {
  if (a.cells() != b.cells()) {
    return absl::InvalidArgumentError(absl::StrCat("cannot multiply wavelength distributions with ",
                                                   a.cells(), " and ", b.cells(), " cells"));
  }
  std::vector<double> w(static_cast<size_t>(a.cells()));
  for (int i = 0; i < a.cells(); ++i) w[i] = a.mass_[i] * b.mass_[i];
  if (std::accumulate(w.begin(), w.end(), 0.0) <= 0.0) {
    return absl::InvalidArgumentError(
        "the sensor and emitter wavelength distributions do not overlap: their product is zero");
  }
  return WavelengthDistribution(std::move(w));
}

absl::StatusOr<WavelengthDistribution> WavelengthDistribution::mix_defensive(
    double epsilon, const WavelengthDistribution& support) const {
  if (!(epsilon >= 0.0 && epsilon <= 1.0)) {
    return absl::InvalidArgumentError(
        absl::StrCat("defensive mixture weight must be in [0, 1], got ", epsilon));
  }
  if (support.cells() != cells()) {
    return absl::InvalidArgumentError(absl::StrCat("defensive support has ", support.cells(),
                                                   " cells, the distribution ", cells()));
  }
  int count = 0;
  for (double m : support.mass_) count += m > 0.0 ? 1 : 0;
  if (count == 0) return absl::InvalidArgumentError("defensive support is empty");
  std::vector<double> w(mass_.size());
  for (size_t i = 0; i < w.size(); ++i) {
    w[i] = (1.0 - epsilon) * mass_[i] + (support.mass_[i] > 0.0 ? epsilon / count : 0.0);
  }
  return WavelengthDistribution(std::move(w));
}

double WavelengthDistribution::cell_width() const {
  return kRange / cells();
}

int WavelengthDistribution::cell_of(float lambda_nm) const {
  return cell_index(lambda_nm, cells());
}

WavelengthSample WavelengthDistribution::sample(double u) const {
  const CellFloats floats{lower_, first_, last_};
  const Inverted r = invert(
      cells(), u, [this](int i) { return cdf_[i]; }, guide_, &floats);
  return {r.lambda, pdf_[r.cell]};
}

float WavelengthDistribution::pdf(float lambda_nm) const {
  const int c = cell_index(lambda_nm, cells());
  return c < 0 ? 0.0f : pdf_[c];
}

double WavelengthDistribution::cdf(float lambda_nm) const {
  return eval_cdf(cells(), lambda_nm, [this](int i) { return cdf_[i]; });
}

SampledWavelengths WavelengthDistribution::sample_lanes(double u, int lanes) const {
  return sample_cyclic_lanes(*this, u, lanes);
}

std::vector<std::uint16_t> WavelengthDistribution::quantise() const {
  QuantiseScratch scratch;
  std::vector<std::uint16_t> cdf(mass_.size() + 1);
  quantise_masses(mass_, cdf, scratch);
  return cdf;
}

void WavelengthDistribution::quantise_weights(std::span<const double> weights,
                                              std::span<std::uint16_t> cdf_out,
                                              QuantiseScratch& scratch) {
  const int n = static_cast<int>(weights.size());
  PRISM_CHECK(n >= 1 && n <= kMaxCells);
  PRISM_CHECK(cdf_out.size() == weights.size() + 1);
  // The same arithmetic as the constructor, so the masses (and hence the bytes) are those of
  // from_table(weights).
  scratch.cdf.resize(weights.size() + 1);
  scratch.mass.resize(weights.size());
  std::vector<double>& cdf = scratch.cdf;
  cdf[0] = 0.0;
  for (int i = 0; i < n; ++i) {
    PRISM_CHECK(weights[i] >= 0.0 && std::isfinite(weights[i]));
    cdf[i + 1] = cdf[i] + weights[i];
  }
  const double total = cdf[n];
  PRISM_CHECK(total > 0.0 && std::isfinite(total));
  for (double& c : cdf) c /= total;
  cdf[n] = 1.0;
  for (int i = 0; i < n; ++i) scratch.mass[i] = cdf[i + 1] - cdf[i];
  quantise_masses(scratch.mass, cdf_out, scratch);
}

void WavelengthDistribution::quantise_masses(std::span<const double> mass,
                                             std::span<std::uint16_t> cdf,
                                             QuantiseScratch& scratch) {
  constexpr double kTotal = QuantisedWavelengthCdf::kTotal;
  const int n = static_cast<int>(mass.size());
  scratch.units.assign(mass.size(), 0);
  scratch.remainder.assign(mass.size(), 0.0);
  std::vector<std::int64_t>& q = scratch.units;
  std::vector<double>& remainder = scratch.remainder;
  std::int64_t sum = 0;
  for (int i = 0; i < n; ++i) {
    if (mass[i] <= 0.0) continue;
    const double m = mass[i] * kTotal;
    q[i] = std::max<std::int64_t>(1, static_cast<std::int64_t>(std::floor(m)));
    remainder[i] = m - static_cast<double>(q[i]);
    sum += q[i];
  }
  // Largest remainders first gets each cell within one unit of its exact share; cells raised
  // to the minimum of 1 are paid for by the largest cells. Ties go to the lower index. The
  // deficit is normally below the number of positive cells, so each of the `deficit` largest
  // gets one unit and a selection (linear, no allocation) replaces sorting.
  std::vector<int>& order = scratch.order;
  order.clear();
  for (int i = 0; i < n; ++i) {
    if (mass[i] > 0.0) order.push_back(i);
  }
  const auto before = [&](int a, int b) {
    return remainder[a] > remainder[b] || (remainder[a] == remainder[b] && a < b);
  };
  const std::int64_t deficit = static_cast<std::int64_t>(kTotal) - sum;
  if (deficit > 0 && deficit <= static_cast<std::int64_t>(order.size())) {
    std::nth_element(order.begin(), order.begin() + (deficit - 1), order.end(), before);
    for (std::int64_t k = 0; k < deficit; ++k) ++q[order[k]];
    sum += deficit;
  } else if (deficit > 0) {
    std::sort(order.begin(), order.end(), before);
    for (size_t k = 0; sum < static_cast<std::int64_t>(kTotal); k = (k + 1) % order.size()) {
      ++q[order[k]];
      ++sum;
    }
  }
  while (sum > static_cast<std::int64_t>(kTotal)) {
    const int big = static_cast<int>(std::max_element(q.begin(), q.end()) - q.begin());
    PRISM_CHECK(q[big] > 1);
    --q[big];
    --sum;
  }
  std::int64_t running = 0;
  cdf[0] = 0;
  for (int i = 0; i < n; ++i) {
    running += q[i];
    cdf[i + 1] = static_cast<std::uint16_t>(running);
  }
  PRISM_CHECK(running == static_cast<std::int64_t>(kTotal));
}

absl::StatusOr<QuantisedWavelengthCdf> QuantisedWavelengthCdf::create(
    std::span<const std::uint16_t> cdf) {
  if (cdf.size() < 2 || cdf.size() > static_cast<size_t>(WavelengthDistribution::kMaxCells) + 1) {
    return absl::InvalidArgumentError(absl::StrCat("a quantised wavelength CDF needs 2 to ",
                                                   WavelengthDistribution::kMaxCells + 1,
                                                   " values, got ", cdf.size()));
  }
  if (cdf.front() != 0 || cdf.back() != kTotal) {
    return absl::InvalidArgumentError(absl::StrCat("a quantised wavelength CDF must run from 0 to ",
                                                   kTotal, ", got ", cdf.front(), " to ",
                                                   cdf.back()));
  }
  for (size_t i = 1; i < cdf.size(); ++i) {
    if (cdf[i] < cdf[i - 1]) {
      return absl::InvalidArgumentError(
          absl::StrCat("quantised wavelength CDF decreases at entry ", i));
    }
  }
  return QuantisedWavelengthCdf(cdf);
}

float QuantisedWavelengthCdf::cell_pdf(int i) const {
  const int n = cells();
  return static_cast<float>(static_cast<double>(cdf_[i + 1] - cdf_[i]) / kTotal / (kRange / n));
}

WavelengthSample QuantisedWavelengthCdf::sample(double u) const {
  const Inverted r =
      invert(cells(), u, [this](int i) { return static_cast<double>(cdf_[i]) / kTotal; });
  return {r.lambda, cell_pdf(r.cell)};
}

float QuantisedWavelengthCdf::pdf(float lambda_nm) const {
  const int c = cell_index(lambda_nm, cells());
  return c < 0 ? 0.0f : cell_pdf(c);
}

double QuantisedWavelengthCdf::cdf(float lambda_nm) const {
  return eval_cdf(cells(), lambda_nm,
                  [this](int i) { return static_cast<double>(cdf_[i]) / kTotal; });
}

SampledWavelengths QuantisedWavelengthCdf::sample_lanes(double u, int lanes) const {
  return sample_cyclic_lanes(*this, u, lanes);
}

}  // namespace prism::spectral
