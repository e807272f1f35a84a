#include "services/spectral/ior.h"

#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::spectral {

absl::StatusOr<CauchyIor> CauchyIor::create(std::span<const double> coefficients) {
  if (coefficients.empty()) {
    return absl::InvalidArgumentError("a Cauchy IOR needs at least one coefficient (A)");
  }
  for (double a : coefficients) {
    if (!std::isfinite(a)) {
      return absl::InvalidArgumentError("Cauchy IOR coefficients must be finite");
    }
  }
  CauchyIor ior;
  ior.a_.assign(coefficients.begin(), coefficients.end());
  for (double l = kLambdaMin; l <= kLambdaMax; l += 1.0) {
    if (!(ior.eta(l) > 0.0)) {
      return absl::InvalidArgumentError(absl::StrCat("Cauchy IOR is not positive at ", l,
                                                     " nm: check the coefficient units "
                                                     "(λ is in µm, so B is in µm²)"));
    }
  }
  return ior;
}

// Horner in u = 1/λ² (λ in µm): n = a0 + u·(a1 + u·(a2 + …)).
double CauchyIor::eta(double lambda_nm) const {
  const double l = lambda_nm * 1e-3;
  const double u = 1.0 / (l * l);
  double n = 0.0;
  for (size_t k = a_.size(); k-- > 0;) n = n * u + a_[k];
  return n;
}

// dn/dλ = Σ_k −2k·a_k·λ^(−2k−1) per µm; ×1e-3 converts to per nm.
double CauchyIor::derivative(double lambda_nm) const {
  const double l = lambda_nm * 1e-3;
  const double u = 1.0 / (l * l);
  double d = 0.0;
  double upow = u;
  for (size_t k = 1; k < a_.size(); ++k) {
    d += -2.0 * static_cast<double>(k) * a_[k] * upow / l;
    upow *= u;
  }
  return d * 1e-3;
}

absl::StatusOr<SellmeierIor> SellmeierIor::create(double a0, std::span<const double> b,
                                                  std::span<const double> c_um2) {
  if (b.size() != c_um2.size() || b.empty() || b.size() > kMaxTerms) {
    return absl::InvalidArgumentError(absl::StrCat("a Sellmeier IOR needs 1 to ", kMaxTerms,
                                                   " (B, C) pairs, got ", b.size(), " B and ",
                                                   c_um2.size(), " C coefficients"));
  }
  SellmeierIor ior;
  if (!std::isfinite(a0)) return absl::InvalidArgumentError("Sellmeier A0 must be finite");
  ior.a0_ = a0;
  ior.terms_ = static_cast<int>(b.size());
  for (size_t k = 0; k < b.size(); ++k) {
    if (!std::isfinite(b[k]) || !std::isfinite(c_um2[k]) || c_um2[k] < 0.0) {
      return absl::InvalidArgumentError(
          absl::StrCat("Sellmeier term ", k + 1, ": B and C must be finite and C (µm²) >= 0"));
    }
    const double lo = kLambdaMin * 1e-3, hi = kLambdaMax * 1e-3;
    if (c_um2[k] >= lo * lo && c_um2[k] <= hi * hi) {
      return absl::InvalidArgumentError(absl::StrCat(
          "Sellmeier term ", k + 1, ": C = ", c_um2[k],
          " µm² puts a resonance inside 360–830 nm; C is in µm² (a wavelength squared)"));
    }
    ior.b_[k] = b[k];
    ior.c_[k] = c_um2[k];
  }
  for (double l = kLambdaMin; l <= kLambdaMax; l += 1.0) {
    if (!(ior.eta(l) > 0.0)) {
      return absl::InvalidArgumentError(
          absl::StrCat("Sellmeier IOR: n² is not positive at ", l, " nm"));
    }
  }
  return ior;
}

double SellmeierIor::eta(double lambda_nm) const {
  const double l2 = lambda_nm * lambda_nm * 1e-6;
  double n2 = 1.0 + a0_;
  for (int k = 0; k < terms_; ++k) n2 += b_[k] * l2 / (l2 - c_[k]);
  return std::sqrt(n2);
}

// d(n²)/dλ = Σ_k −2·B_k·C_k·λ / (λ² − C_k)² (λ in µm), and dn/dλ = d(n²)/dλ / (2n).
double SellmeierIor::derivative(double lambda_nm) const {
  const double l = lambda_nm * 1e-3;
  const double l2 = l * l;
  double dn2 = 0.0;
  for (int k = 0; k < terms_; ++k) {
    const double d = l2 - c_[k];
    dn2 += -2.0 * b_[k] * c_[k] * l / (d * d);
  }
  return dn2 / (2.0 * eta(lambda_nm)) * 1e-3;
}

absl::StatusOr<TabulatedIor> TabulatedIor::create(PiecewiseLinearSpectrum table) {
  if (!(table.min_value() >= 0.0f)) {
    return absl::InvalidArgumentError("a tabulated IOR must not have negative values");
  }
  for (float v : table.values()) {
    if (!(v > 0.0f)) {
      return absl::InvalidArgumentError("a tabulated IOR must be > 0 at every sample");
    }
  }
  return TabulatedIor(std::move(table));
}

double TabulatedIor::eta(double lambda_nm) const {
  const float l =
      std::clamp(static_cast<float>(lambda_nm), table_.lambda_min(), table_.lambda_max());
  return table_(l);
}

double TabulatedIor::derivative(double lambda_nm) const {
  const float l = static_cast<float>(lambda_nm);
  if (l < table_.lambda_min() || l > table_.lambda_max()) return 0.0;
  return table_.slope(l);
}

double eta(const Ior& ior, double lambda_nm) {
  return std::visit([lambda_nm](const auto& k) { return k.eta(lambda_nm); }, ior);
}

double deta_dlambda(const Ior& ior, double lambda_nm) {
  return std::visit([lambda_nm](const auto& k) { return k.derivative(lambda_nm); }, ior);
}

bool is_dispersive(const Ior& ior) {
  struct Visitor {
    bool operator()(const ConstantIor&) const { return false; }
    bool operator()(const CauchyIor& c) const {
      for (size_t k = 1; k < c.coefficients().size(); ++k) {
        if (c.coefficients()[k] != 0.0) return true;
      }
      return false;
    }
    bool operator()(const SellmeierIor&) const { return true; }
    bool operator()(const TabulatedIor& t) const {
      for (float v : t.table().values()) {
        if (v != t.table().values().front()) return true;
      }
      return false;
    }
  };
  return std::visit(Visitor{}, ior);
}

PiecewiseLinearSpectrum to_spectrum(const Ior& ior) {
  if (const auto* t = std::get_if<TabulatedIor>(&ior)) return t->table();
  constexpr int kSamples = static_cast<int>(kLambdaMax - kLambdaMin) + 1;
  std::vector<double> lambda(kSamples), value(kSamples);
  for (int i = 0; i < kSamples; ++i) {
    lambda[i] = kLambdaMin + i;
    value[i] = eta(ior, lambda[i]);
  }
  auto s = PiecewiseLinearSpectrum::create(lambda, value, "IOR");
  PRISM_CHECK(s.ok());
  return *std::move(s);
}

}  // namespace prism::spectral
