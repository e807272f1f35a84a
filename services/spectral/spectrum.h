// Spectral distributions as a closed set of value types dispatched through std::variant.
// Wavelengths are in nm; a spectrum may be queried at any λ > 0 but Prism only asks inside
// Λ = [360, 830]. Every kind is immutable after construction and evaluation never allocates.
//   ConstantSpectrum        the same value everywhere.
//   PiecewiseLinearSpectrum a table (λ strictly increasing, finite values) interpolated
//                           linearly; 0 outside the table, as in pbrt-v4.
//   BlackbodySpectrum       Planck's law at T kelvin, divided by its value at Wien's peak
//                           wavelength so the maximum is exactly 1 (pbrt-v4 semantics).
//   RgbAlbedoSpectrum       a sigmoid polynomial (Jakob–Hanika), values in [0, 1]; built by
//                           RgbUplift from an RGB reflectance.
//   RgbUnboundedSpectrum    scale × sigmoid polynomial, for RGB values above 1 (media
//                           coefficients); pbrt-v4's RGBUnboundedSpectrum.
//   RgbIlluminantSpectrum   scale × sigmoid polynomial × the colour space's illuminant (D65 for
//                           sRGB), for RGB emission; pbrt-v4's RGBIlluminantSpectrum.
#pragma once

#include <algorithm>
#include <memory>
#include <span>
#include <string_view>
#include <variant>
#include <vector>

#include "absl/status/statusor.h"
#include "services/spectral/csv_table.h"
#include "services/spectral/sampled.h"
#include "services/spectral/sigmoid_polynomial.h"

namespace prism::spectral {

struct ConstantSpectrum {
  float value = 0.0f;
  float operator()(float) const { return value; }
};

class PiecewiseLinearSpectrum {
 public:
  // INVALID_ARGUMENT (prefixed with source_name) unless there are >= 2 samples of equal count,
  // wavelengths are finite, positive and strictly increasing, and values are finite.
  static absl::StatusOr<PiecewiseLinearSpectrum> create(std::span<const double> lambda_nm,
                                                        std::span<const double> values,
                                                        std::string_view source_name);
  // From a table whose first column holds wavelengths in nm and `column` the values.
  static absl::StatusOr<PiecewiseLinearSpectrum> from_csv(const CsvTable& table,
                                                          std::string_view column);
  // Parses CSV text (see csv_table.h) and takes `column`.
  static absl::StatusOr<PiecewiseLinearSpectrum> from_csv_text(std::string_view text,
                                                               std::string_view source_name,
                                                               std::string_view column);

  // Linear interpolation; 0 outside [lambda_min(), lambda_max()]. O(log n), no allocation.
  float operator()(float lambda_nm) const;
  // d/dλ of the interpolant (per nm): the slope of the segment holding λ (the right-hand one at a
  // sample), 0 outside the table.
  float slope(float lambda_nm) const;
  // Exact ∫_a^b of the interpolant (0 outside the table) in value·nm; a <= b.
  double integral(double a_nm, double b_nm) const;
  // integral(a, b) / (b − a): the exact bin average; requires a < b.
  double bin_average(double a_nm, double b_nm) const;
  float max_value() const { return max_; }
  float min_value() const { return min_; }

  float lambda_min() const { return lambda_.front(); }
  float lambda_max() const { return lambda_.back(); }
  std::span<const float> lambdas() const { return lambda_; }
  std::span<const float> values() const { return value_; }

 private:
  PiecewiseLinearSpectrum() = default;
  // Index of the first sample strictly greater than lambda_nm (lambda_nm inside the table).
  size_t upper_index(float lambda_nm) const;
  std::vector<float> lambda_;
  std::vector<float> value_;
  float inverse_step_ = 0.0f;  // 1 / spacing when the samples are uniformly spaced, else 0
  float max_ = 0.0f;
  float min_ = 0.0f;
};

// Inline: every shading point evaluates a few of these per lane.
inline size_t PiecewiseLinearSpectrum::upper_index(float lambda_nm) const {
  if (inverse_step_ > 0.0f) {
    // The guess from the uniform spacing is exact but for rounding next to a sample; one step
    // each way makes it equal to the binary search's answer.
    size_t i = static_cast<size_t>((lambda_nm - lambda_.front()) * inverse_step_) + 1;
    i = std::min(i, lambda_.size());
    while (i < lambda_.size() && lambda_[i] <= lambda_nm) ++i;
    while (i > 1 && lambda_[i - 1] > lambda_nm) --i;
    return i;
  }
  return static_cast<size_t>(std::upper_bound(lambda_.begin(), lambda_.end(), lambda_nm) -
                             lambda_.begin());
}

inline float PiecewiseLinearSpectrum::operator()(float lambda_nm) const {
  if (!(lambda_nm >= lambda_.front() && lambda_nm <= lambda_.back())) return 0.0f;
  // First sample strictly greater than λ; λ == last sample is the end of the last segment.
  size_t i = upper_index(lambda_nm);
  if (i == lambda_.size()) return value_.back();
  const float t = (lambda_nm - lambda_[i - 1]) / (lambda_[i] - lambda_[i - 1]);
  return value_[i - 1] + t * (value_[i] - value_[i - 1]);
}

class BlackbodySpectrum {
 public:
  // INVALID_ARGUMENT unless temperature_k is finite and > 0.
  static absl::StatusOr<BlackbodySpectrum> create(double temperature_k);

  float operator()(float lambda_nm) const { return static_cast<float>(value(lambda_nm)); }
  // The normalised Planck curve and its derivative (per nm), in double precision.
  double value(double lambda_nm) const;
  double derivative(double lambda_nm) const;
  double temperature() const { return temperature_; }
  // Wien's displacement law: λ_max = b / T, b = 2.897771955e-3 m·K.
  double peak_wavelength_nm() const;

 private:
  explicit BlackbodySpectrum(double t);
  double temperature_;
  double inv_peak_;
};

struct RgbAlbedoSpectrum {
  SigmoidPolynomial polynomial;
  float operator()(float lambda_nm) const { return polynomial(lambda_nm); }
};

struct RgbUnboundedSpectrum {
  float scale = 0.0f;
  SigmoidPolynomial polynomial;
  float operator()(float lambda_nm) const { return scale * polynomial(lambda_nm); }
};

// The illuminant is shared, immutable and never null (RgbUplift builds these).
struct RgbIlluminantSpectrum {
  float scale = 0.0f;
  SigmoidPolynomial polynomial;
  std::shared_ptr<const PiecewiseLinearSpectrum> illuminant;
  float operator()(float lambda_nm) const {
    return scale * polynomial(lambda_nm) * (*illuminant)(lambda_nm);
  }
};

using Spectrum = std::variant<ConstantSpectrum, PiecewiseLinearSpectrum, BlackbodySpectrum,
                              RgbAlbedoSpectrum, RgbUnboundedSpectrum, RgbIlluminantSpectrum>;

// The spectrum's value at lambda_nm.
float eval(const Spectrum& s, float lambda_nm);

// The spectrum at each of the wavelengths' count() lanes; lanes beyond are 0.
SampledSpectrum sample(const Spectrum& s, const SampledWavelengths& lambdas);

// ∫_a^b s(λ) dλ (value·nm), a <= b. Exact for constant and piecewise-linear spectra; 5-point
// Gauss–Legendre on sub-intervals of at most 2 nm for the smooth kinds, split at the
// illuminant's samples for RGB illuminants (relative error far below float precision).
double integrate(const Spectrum& s, double a_nm, double b_nm);

// The largest value: the table maximum, 1 for a blackbody (its normalised peak), the maximum
// over Λ for the RGB kinds (for an illuminant: scale × polynomial max × illuminant max, a bound).
// An upper bound of eval over Λ.
float max_value(const Spectrum& s);

// True when the value does not depend on λ (a constant, or an albedo or unbounded RGB spectrum
// with a flat polynomial).
bool is_constant(const Spectrum& s);

}  // namespace prism::spectral
