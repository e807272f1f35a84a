#include "services/spectral/spectrum.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/spectral/absl_string_view.h"

namespace prism::spectral {
namespace {

// Physical constants (CODATA 2018, exact SI definitions).
constexpr double kPlanck = 6.62607015e-34;   // J·s
constexpr double kLightSpeed = 299792458.0;  // m/s
constexpr double kBoltzmann = 1.380649e-23;  // J/K
constexpr double kWienB = 2.897771955e-3;    // m·K

// Unnormalised Planck radiance at λ (m); only ratios are used, so the 2hc² factor is kept for
// readability rather than need.
double planck(double lambda_m, double t) {
  const double x = kPlanck * kLightSpeed / (lambda_m * kBoltzmann * t);
  return 2.0 * kPlanck * kLightSpeed * kLightSpeed / (std::pow(lambda_m, 5) * std::expm1(x));
}

template <typename F>
double gauss_legendre(const F& f, double a, double b) {
  static constexpr double kNodes[5] = {0.0, -0.5384693101056831, 0.5384693101056831,
                                       -0.9061798459386640, 0.9061798459386640};
  static constexpr double kWeights[5] = {0.5688888888888889, 0.4786286704993665, 0.4786286704993665,
                                         0.2369268850561891, 0.2369268850561891};
  if (!(b > a)) return 0.0;
  const int pieces = std::max(1, static_cast<int>(std::ceil((b - a) / 2.0)));
  const double h = (b - a) / pieces;
  double sum = 0.0;
  for (int p = 0; p < pieces; ++p) {
    const double mid = a + (p + 0.5) * h;
    double s = 0.0;
    for (int k = 0; k < 5; ++k) s += kWeights[k] * f(mid + 0.5 * h * kNodes[k]);
    sum += 0.5 * h * s;
  }
  return sum;
}

}  // namespace

absl::StatusOr<PiecewiseLinearSpectrum> PiecewiseLinearSpectrum::create(
    std::span<const double> lambda_nm, std::span<const double> values,
    std::string_view source_name) {
  if (lambda_nm.size() != values.size()) {
    return absl::InvalidArgumentError(absl::StrCat(to_absl(source_name), ": ", lambda_nm.size(),
                                                   " wavelengths but ", values.size(), " values"));
  }
  if (lambda_nm.size() < 2) {
    return absl::InvalidArgumentError(
        absl::StrCat(to_absl(source_name), ": a tabulated spectrum needs at least 2 samples"));
  }
  PiecewiseLinearSpectrum s;
  s.lambda_.reserve(lambda_nm.size());
  s.value_.reserve(values.size());
  for (size_t i = 0; i < lambda_nm.size(); ++i) {
    if (!std::isfinite(lambda_nm[i]) || lambda_nm[i] <= 0.0) {
      return absl::InvalidArgumentError(absl::StrCat(to_absl(source_name), ": sample ", i + 1,
                                                     ": wavelength ", lambda_nm[i],
                                                     " nm is not a positive finite number"));
    }
    if (!std::isfinite(values[i])) {
      return absl::InvalidArgumentError(
          absl::StrCat(to_absl(source_name), ": sample ", i + 1, ": value is not finite"));
    }
    const float l = static_cast<float>(lambda_nm[i]);
    if (i > 0 && !(l > s.lambda_.back())) {
      return absl::InvalidArgumentError(absl::StrCat(
          to_absl(source_name), ": wavelengths must be strictly increasing, but sample ", i + 1,
          " (", lambda_nm[i], " nm) follows ", lambda_nm[i - 1], " nm"));
    }
    s.lambda_.push_back(l);
    s.value_.push_back(static_cast<float>(values[i]));
  }
  // Most tables (CIE data, lamps) are uniformly spaced; then the segment of λ is found by
  // division instead of a binary search, which is the hot path of shading.
  const float step = (s.lambda_.back() - s.lambda_.front()) / float(s.lambda_.size() - 1);
  bool uniform = step > 0;
  for (size_t i = 0; uniform && i < s.lambda_.size(); ++i) {
    uniform = std::abs(s.lambda_[i] - (s.lambda_.front() + float(i) * step)) <= 1e-3f * step;
  }
  s.inverse_step_ = uniform ? 1.0f / step : 0.0f;
  // Outside the table the spectrum is 0, so 0 bounds it too.
  s.max_ = std::max(0.0f, *std::max_element(s.value_.begin(), s.value_.end()));
  s.min_ = std::min(0.0f, *std::min_element(s.value_.begin(), s.value_.end()));
  return s;
}

absl::StatusOr<PiecewiseLinearSpectrum> PiecewiseLinearSpectrum::from_csv(const CsvTable& table,
                                                                          std::string_view column) {
  const int c = table.column_index(column);
  if (c < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(table.source_name(), ": no column named '", to_absl(column), "'"));
  }
  if (c == 0) {
    return absl::InvalidArgumentError(absl::StrCat(table.source_name(), ": column '",
                                                   to_absl(column),
                                                   "' is the wavelength column, not a spectrum"));
  }
  auto lambda = table.numeric_column(0);
  if (!lambda.ok()) return lambda.status();
  auto values = table.numeric_column(c);
  if (!values.ok()) return values.status();
  for (int r = 1; r < table.row_count(); ++r) {
    if (!((*lambda)[r] > (*lambda)[r - 1])) {
      return absl::InvalidArgumentError(absl::StrCat(table.source_name(), ":", table.line_of_row(r),
                                                     ": wavelengths must be strictly increasing (",
                                                     (*lambda)[r], " nm after ", (*lambda)[r - 1],
                                                     " nm)"));
    }
  }
  return create(*lambda, *values,
                absl::StrCat(table.source_name(), " column '", to_absl(column), "'"));
}

absl::StatusOr<PiecewiseLinearSpectrum> PiecewiseLinearSpectrum::from_csv_text(
    std::string_view text, std::string_view source_name, std::string_view column) {
  auto table = parse_csv_table(text, source_name);
  if (!table.ok()) return table.status();
  return from_csv(*table, column);
}

float PiecewiseLinearSpectrum::slope(float lambda_nm) const {
  if (!(lambda_nm >= lambda_.front() && lambda_nm <= lambda_.back())) return 0.0f;
  size_t i = static_cast<size_t>(std::upper_bound(lambda_.begin(), lambda_.end(), lambda_nm) -
                                 lambda_.begin());
  if (i == lambda_.size()) i = lambda_.size() - 1;
  return (value_[i] - value_[i - 1]) / (lambda_[i] - lambda_[i - 1]);
}

double PiecewiseLinearSpectrum::integral(double a_nm, double b_nm) const {
  PRISM_CHECK(a_nm <= b_nm);
  const double lo = std::max<double>(a_nm, lambda_.front());
  const double hi = std::min<double>(b_nm, lambda_.back());
  if (!(hi > lo)) return 0.0;
  size_t i = static_cast<size_t>(
      std::upper_bound(lambda_.begin(), lambda_.end(), static_cast<float>(lo)) - lambda_.begin());
  i = std::clamp<size_t>(i, 1, lambda_.size() - 1);
  // upper_bound on the float-rounded bound may land one segment late.
  while (i > 1 && lambda_[i - 1] > lo) --i;
  double sum = 0.0;
  for (; i < lambda_.size() && lambda_[i - 1] < hi; ++i) {
    const double x0 = lambda_[i - 1], x1 = lambda_[i];
    const double y0 = value_[i - 1], y1 = value_[i];
    const double s0 = std::max(lo, x0), s1 = std::min(hi, x1);
    if (!(s1 > s0)) continue;
    const double slope = (y1 - y0) / (x1 - x0);
    const double f0 = y0 + slope * (s0 - x0), f1 = y0 + slope * (s1 - x0);
    sum += 0.5 * (f0 + f1) * (s1 - s0);
  }
  return sum;
}

double PiecewiseLinearSpectrum::bin_average(double a_nm, double b_nm) const {
  PRISM_CHECK(a_nm < b_nm);
  return integral(a_nm, b_nm) / (b_nm - a_nm);
}

absl::StatusOr<BlackbodySpectrum> BlackbodySpectrum::create(double temperature_k) {
  if (!std::isfinite(temperature_k) || temperature_k <= 0.0) {
    return absl::InvalidArgumentError(absl::StrCat(
        "blackbody temperature must be a finite number of kelvin > 0, got ", temperature_k));
  }
  return BlackbodySpectrum(temperature_k);
}

BlackbodySpectrum::BlackbodySpectrum(double t) : temperature_(t) {
  inv_peak_ = 1.0 / planck(kWienB / t, t);
}

double BlackbodySpectrum::peak_wavelength_nm() const {
  return kWienB / temperature_ * 1e9;
}

double BlackbodySpectrum::value(double lambda_nm) const {
  if (!(lambda_nm > 0.0)) return 0.0;
  return planck(lambda_nm * 1e-9, temperature_) * inv_peak_;
}

// dB/dλ = B · (−5/λ + x/λ · eˣ/(eˣ − 1)) with x = hc/(λkT), from differentiating λ⁻⁵/(eˣ − 1).
double BlackbodySpectrum::derivative(double lambda_nm) const {
  if (!(lambda_nm > 0.0)) return 0.0;
  const double x = kPlanck * kLightSpeed / (lambda_nm * 1e-9 * kBoltzmann * temperature_);
  // eˣ/(eˣ − 1) written so that it cannot overflow for large x (cold bodies, short λ).
  const double ratio = -1.0 / std::expm1(-x);
  return value(lambda_nm) * (-5.0 + x * ratio) / lambda_nm;
}

float eval(const Spectrum& s, float lambda_nm) {
  return std::visit([lambda_nm](const auto& k) { return k(lambda_nm); }, s);
}

SampledSpectrum sample(const Spectrum& s, const SampledWavelengths& lambdas) {
  return std::visit(
      [&lambdas](const auto& k) {
        SampledSpectrum out;
        for (int i = 0; i < lambdas.count(); ++i) out[i] = k(lambdas.lambda(i));
        return out;
      },
      s);
}

namespace {

struct IntegrateVisitor {
  double a, b;
  double operator()(const ConstantSpectrum& c) const { return c.value * (b - a); }
  double operator()(const PiecewiseLinearSpectrum& p) const { return p.integral(a, b); }
  double operator()(const BlackbodySpectrum& bb) const {
    return gauss_legendre([&bb](double l) { return bb.value(l); }, a, b);
  }
  double operator()(const RgbAlbedoSpectrum& r) const { return smooth(r, a, b); }
  double operator()(const RgbUnboundedSpectrum& r) const { return smooth(r, a, b); }
  // The illuminant table has kinks at its samples: integrate piece by piece between them so
  // the quadrature only ever sees a smooth integrand.
  double operator()(const RgbIlluminantSpectrum& r) const {
    double sum = 0.0, lo = a;
    for (float knot : r.illuminant->lambdas()) {
      if (knot <= lo) continue;
      if (knot >= b) break;
      sum += smooth(r, lo, knot);
      lo = knot;
    }
    return sum + smooth(r, lo, b);
  }
  template <typename K>
  static double smooth(const K& k, double lo, double hi) {
    return gauss_legendre([&k](double l) { return k(static_cast<float>(l)); }, lo, hi);
  }
};

}  // namespace

double integrate(const Spectrum& s, double a_nm, double b_nm) {
  PRISM_CHECK(a_nm <= b_nm);
  return std::visit(IntegrateVisitor{a_nm, b_nm}, s);
}

float max_value(const Spectrum& s) {
  struct Visitor {
    float operator()(const ConstantSpectrum& c) const { return c.value; }
    float operator()(const PiecewiseLinearSpectrum& p) const { return p.max_value(); }
    float operator()(const BlackbodySpectrum&) const { return 1.0f; }
    float operator()(const RgbAlbedoSpectrum& r) const { return r.polynomial.max_value(); }
    float operator()(const RgbUnboundedSpectrum& r) const {
      return r.scale * r.polynomial.max_value();
    }
    float operator()(const RgbIlluminantSpectrum& r) const {
      return r.scale * r.polynomial.max_value() * r.illuminant->max_value();
    }
  };
  return std::visit(Visitor{}, s);
}

bool is_constant(const Spectrum& s) {
  if (std::holds_alternative<ConstantSpectrum>(s)) return true;
  if (const auto* r = std::get_if<RgbAlbedoSpectrum>(&s)) {
    return r->polynomial.c0 == 0.0f && r->polynomial.c1 == 0.0f;
  }
  if (const auto* r = std::get_if<RgbUnboundedSpectrum>(&s)) {
    return r->polynomial.c0 == 0.0f && r->polynomial.c1 == 0.0f;
  }
  return false;
}

}  // namespace prism::spectral
