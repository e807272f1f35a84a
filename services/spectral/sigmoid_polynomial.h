// The Jakob–Hanika (2019) reflectance model: s(λ) = S(c0·t² + c1·t + c2) with the sigmoid
// S(x) = 1/2 + x / (2·√(1 + x²)), so 0 <= s <= 1 for every λ. The polynomial variable is the
// normalised wavelength t = (λ − 360 nm) / 470 nm (t ∈ [0, 1] over Λ), which keeps the fitted
// coefficients well conditioned; nm_coefficients() converts them to λ in nm. c2 = ±inf with
// c0 = c1 = 0 encodes the exact constants 0 and 1.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>

namespace prism::spectral {

struct SigmoidPolynomial {
  float c0 = 0.0f;
  float c1 = 0.0f;
  float c2 = 0.0f;

  static float sigmoid(float x) {
    if (std::isinf(x)) return x > 0.0f ? 1.0f : 0.0f;
    return 0.5f + x / (2.0f * std::sqrt(1.0f + x * x));
  }

  // Value at lambda_nm, in [0, 1].
  float operator()(float lambda_nm) const {
    const float t = (lambda_nm - 360.0f) * (1.0f / 470.0f);
    return sigmoid((c0 * t + c1) * t + c2);
  }

  // The largest value over Λ = [360, 830] nm: S is increasing, so it is S at the polynomial's
  // largest value, found at an end of [0, 1] or at the vertex.
  float max_value() const {
    float m = std::max(sigmoid(c2), sigmoid(c0 + c1 + c2));
    if (c0 != 0.0f) {
      const float t = -c1 / (2.0f * c0);
      if (t > 0.0f && t < 1.0f) m = std::max(m, sigmoid((c0 * t + c1) * t + c2));
    }
    return m;
  }

  // {a, b, c} with s(λ) = S(a·λ² + b·λ + c) for λ in nm.
  std::array<double, 3> nm_coefficients() const {
    const double s = 470.0, o = 360.0;
    const double a = c0 / (s * s);
    return {a, -2.0 * o * a + c1 / s, a * o * o - c1 * o / s + c2};
  }

  friend bool operator==(const SigmoidPolynomial&, const SigmoidPolynomial&) = default;
};

}  // namespace prism::spectral
