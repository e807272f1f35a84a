#include "services/spectral/testing/chi_square.h"

#include <random>
#include <vector>

#include "gtest/gtest.h"

namespace prism::spectral::testing {
namespace {

TEST(ChiSquareTest, SurvivalMatchesTables) {
  // Upper 5 % and 0.01 % critical values of the chi-square distribution.
  EXPECT_NEAR(chi_square_survival(3.841458820694124, 1), 0.05, 1e-10);
  EXPECT_NEAR(chi_square_survival(18.307038053275146, 10), 0.05, 1e-10);
  EXPECT_NEAR(chi_square_survival(124.34211340400407, 100), 0.05, 1e-9);
  EXPECT_NEAR(chi_square_survival(15.136705226623606, 1), 1e-4, 1e-12);
  EXPECT_NEAR(chi_square_survival(2.0, 2), std::exp(-1.0), 1e-12);
  EXPECT_EQ(chi_square_survival(0.0, 5), 1.0);
  EXPECT_NEAR(regularized_gamma_q(1.0, 3.0), std::exp(-3.0), 1e-13);
}

TEST(ChiSquareTest, AcceptsAFairDieAndRejectsALoadedOne) {
  std::mt19937_64 rng(7);
  std::uniform_int_distribution<int> die(0, 5);
  std::vector<double> fair(6, 0.0), loaded(6, 0.0), expected(6, 10000.0);
  for (int i = 0; i < 60000; ++i) {
    fair[die(rng)] += 1;
    const int f = die(rng);
    loaded[f == 5 && (i % 10 == 0) ? 0 : f] += 1;
  }
  EXPECT_GT(chi_square(fair, expected).p_value, 1e-4);
  EXPECT_LT(chi_square(loaded, expected).p_value, 1e-4);
}

TEST(ChiSquareTest, PoolsSmallCellsAndFailsOnImpossibleSamples) {
  const std::vector<double> obs = {100, 98, 1, 2, 0};
  const std::vector<double> exp = {100, 100, 1.5, 1.5, 0};
  const ChiSquareResult r = chi_square(obs, exp);
  EXPECT_EQ(r.cells_used, 2);  // the two small cells pool to 3 < 5 and are dropped
  const std::vector<double> impossible = {100, 98, 1, 2, 1};
  EXPECT_EQ(chi_square(impossible, exp).p_value, 0.0);
  EXPECT_NEAR(sidak_threshold(0.01, 1), 0.01, 1e-15);
  EXPECT_LT(sidak_threshold(0.01, 10), 0.01 / 9.9);
}

}  // namespace
}  // namespace prism::spectral::testing
