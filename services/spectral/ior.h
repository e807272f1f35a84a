// Real index of refraction n(λ) as a closed set of value types (std::variant). Wavelengths are
// vacuum wavelengths in nm at the interface; the dispersion formulas use µm internally, as their
// coefficient tables do. Every kind gives n(λ) and its exact derivative dn/dλ per nm (needed by
// spectral ray differentials and gradient shifts, docs/estimators.md §5–6). Evaluation is double
// precision so finite differences and Jacobians are meaningful, and never allocates.
//   ConstantIor   n fixed; dn/dλ = 0.
//   CauchyIor     n = Σ_k a_k / λ^(2k), λ in µm (a_0 = A, a_1 = B in µm², …), any term count.
//   SellmeierIor  n² = 1 + A0 + Σ_k B_k λ² / (λ² − C_k), λ in µm, C_k in µm² (the layout of
//                 data/dispersion/sellmeier_coefficients.csv), up to kMaxTerms terms.
//   TabulatedIor  linear interpolation of a table, clamped to the end values outside it (an IOR
//                 of 0 would be unphysical); dn/dλ is the slope of the interpolant, 0 outside.
#pragma once

#include <array>
#include <span>
#include <string_view>
#include <variant>
#include <vector>

#include "absl/status/statusor.h"
#include "services/spectral/spectrum.h"

namespace prism::spectral {

struct ConstantIor {
  double value = 1.0;
  double eta(double) const { return value; }
  double derivative(double) const { return 0.0; }
};

class CauchyIor {
 public:
  // INVALID_ARGUMENT unless at least one coefficient is given, all are finite, and n > 0 over Λ.
  static absl::StatusOr<CauchyIor> create(std::span<const double> coefficients);
  double eta(double lambda_nm) const;
  double derivative(double lambda_nm) const;
  std::span<const double> coefficients() const { return a_; }

 private:
  std::vector<double> a_;
};

class SellmeierIor {
 public:
  static constexpr int kMaxTerms = 4;
  // INVALID_ARGUMENT unless b.size() == c.size() (1..kMaxTerms), all finite, C_k >= 0, and
  // n² > 0 and no pole (λ² = C_k) in Λ.
  static absl::StatusOr<SellmeierIor> create(double a0, std::span<const double> b,
                                             std::span<const double> c_um2);
  double eta(double lambda_nm) const;
  double derivative(double lambda_nm) const;

 private:
  double a0_ = 0.0;
  int terms_ = 0;
  std::array<double, kMaxTerms> b_{};
  std::array<double, kMaxTerms> c_{};
};

class TabulatedIor {
 public:
  // INVALID_ARGUMENT unless every table value is > 0.
  static absl::StatusOr<TabulatedIor> create(PiecewiseLinearSpectrum table);
  double eta(double lambda_nm) const;
  double derivative(double lambda_nm) const;
  const PiecewiseLinearSpectrum& table() const { return table_; }

 private:
  explicit TabulatedIor(PiecewiseLinearSpectrum t) : table_(std::move(t)) {}
  PiecewiseLinearSpectrum table_;
};

using Ior = std::variant<ConstantIor, CauchyIor, SellmeierIor, TabulatedIor>;

// n(λ), dimensionless, for λ in nm (> 0).
double eta(const Ior& ior, double lambda_nm);
// dn/dλ in 1/nm.
double deta_dlambda(const Ior& ior, double lambda_nm);
// False only when n does not depend on λ (a constant, a one-term Cauchy, a flat table).
bool is_dispersive(const Ior& ior);
// n sampled at 1 nm over Λ as a piecewise-linear spectrum (what `spectrum eta "glass-BK7"`
// needs); for a TabulatedIor its own table.
PiecewiseLinearSpectrum to_spectrum(const Ior& ior);

}  // namespace prism::spectral
