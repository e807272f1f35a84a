// Pearson chi-square goodness-of-fit for sampling tests (pbrt-v4 bsdfs_test.cpp, Mitsuba's
// ChiSquareTest): histogram a sampler's output into cells, integrate its claimed pdf over the
// same cells to get expected counts, and reject when the p-value falls below a threshold
// (1e-4 by default, Šidák-corrected when several tests run together). Cells with small
// expected counts are pooled so the chi-square approximation holds; any sample in a cell whose
// expected count is 0 is an immediate failure (p = 0), since the pdf claims it is impossible.
#pragma once

#include <span>
#include <string>

namespace prism::spectral::testing {

// The regularised upper incomplete gamma function Q(a, x) = Γ(a, x)/Γ(a), a > 0, x >= 0
// (series below a + 1, Lentz continued fraction above; relative accuracy ~1e-14).
double regularized_gamma_q(double a, double x);

// P(X >= statistic) for X ~ χ² with dof degrees of freedom (dof >= 1).
double chi_square_survival(double statistic, int dof);

struct ChiSquareResult {
  double statistic = 0.0;
  int dof = 0;
  double p_value = 1.0;
  int cells_used = 0;  // after pooling
  std::string note;    // why the test was decided without the statistic, if it was

  // One line for test failure output: statistic, dof, p-value and the note.
  std::string describe() const;
};

// observed and expected have the same length and (nearly) the same totals. Cells with
// expected < min_expected are merged into one pooled cell (dropped if it stays below
// min_expected); dof = cells_used − 1.
ChiSquareResult chi_square(std::span<const double> observed, std::span<const double> expected,
                           double min_expected = 5.0);

// The per-test threshold giving an overall false-rejection rate alpha over `tests` tests.
double sidak_threshold(double alpha, int tests);

}  // namespace prism::spectral::testing
