#include "services/spectral/testing/chi_square.h"

#include <cmath>
#include <limits>

#include "absl/strings/str_format.h"
#include "services/base/check.h"

namespace prism::spectral::testing {
namespace {

constexpr double kEps = 1e-15;
constexpr int kMaxIterations = 100000;

// P(a, x) by its power series; converges quickly for x < a + 1.
double gamma_p_series(double a, double x) {
  double term = 1.0 / a, sum = term;
  for (int n = 1; n < kMaxIterations; ++n) {
    term *= x / (a + n);
    sum += term;
    if (std::abs(term) < std::abs(sum) * kEps) break;
  }
  return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

// Q(a, x) by its continued fraction (modified Lentz); converges quickly for x >= a + 1.
double gamma_q_fraction(double a, double x) {
  constexpr double kTiny = std::numeric_limits<double>::min() / kEps;
  double b = x + 1.0 - a;
  double c = 1.0 / kTiny;
  double d = 1.0 / b;
  double h = d;
  for (int i = 1; i < kMaxIterations; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1.0) < kEps) break;
  }
  return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

}  // namespace

double regularized_gamma_q(double a, double x) {
  PRISM_CHECK(a > 0.0 && x >= 0.0);
  if (x == 0.0) return 1.0;
  if (x < a + 1.0) return 1.0 - gamma_p_series(a, x);
  return gamma_q_fraction(a, x);
}

double chi_square_survival(double statistic, int dof) {
  PRISM_CHECK(dof >= 1);
  if (!(statistic > 0.0)) return 1.0;
  return regularized_gamma_q(0.5 * dof, 0.5 * statistic);
}

ChiSquareResult chi_square(std::span<const double> observed, std::span<const double> expected,
                           double min_expected) {
  PRISM_CHECK(observed.size() == expected.size());
  ChiSquareResult r;
  double pooled_obs = 0.0, pooled_exp = 0.0;
  for (size_t i = 0; i < observed.size(); ++i) {
    if (expected[i] <= 0.0) {
      if (observed[i] > 0.0) {
        r.p_value = 0.0;
        r.statistic = std::numeric_limits<double>::infinity();
        r.note = absl::StrFormat("%g samples in cell %d whose expected count is 0", observed[i],
                                 static_cast<int>(i));
        return r;
      }
      continue;
    }
    if (expected[i] < min_expected) {
      pooled_obs += observed[i];
      pooled_exp += expected[i];
      continue;
    }
    const double d = observed[i] - expected[i];
    r.statistic += d * d / expected[i];
    ++r.cells_used;
  }
  if (pooled_exp >= min_expected) {
    const double d = pooled_obs - pooled_exp;
    r.statistic += d * d / pooled_exp;
    ++r.cells_used;
  }
  r.dof = r.cells_used - 1;
  if (r.dof < 1) {
    r.p_value = 1.0;
    r.note = "too few cells with enough expected samples for a chi-square test";
    return r;
  }
  r.p_value = chi_square_survival(r.statistic, r.dof);
  return r;
}

std::string ChiSquareResult::describe() const {
  std::string s = absl::StrFormat("chi2 = %.3f, dof = %d, cells = %d, p = %.3g", statistic, dof,
                                  cells_used, p_value);
  if (!note.empty()) s += "; " + note;
  return s;
}

double sidak_threshold(double alpha, int tests) {
  PRISM_CHECK(tests >= 1 && alpha > 0.0 && alpha < 1.0);
  return 1.0 - std::pow(1.0 - alpha, 1.0 / tests);
}

}  // namespace prism::spectral::testing
