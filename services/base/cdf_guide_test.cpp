#include "services/base/cdf_guide.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

namespace prism::base {
namespace {

// The last cell c < cells with cdf[c] <= u by a plain scan: the answer the guided search must give.
int scanned_cell(const std::vector<double>& cdf, double u) {
  const int cells = int(cdf.size()) - 2;
  int c = 0;
  while (c + 1 < cells && cdf[std::size_t(c) + 1] <= u) ++c;
  return c;
}

// A CDF of `cells` cells with the sentinel: random masses, some cells empty, some far thinner
// than a guide interval (so that intervals span many cells), one holding most of the mass.
std::vector<double> random_cdf(int cells, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<double> mass(static_cast<std::size_t>(cells));
  for (double& m : mass) {
    const double r = uniform(rng);
    m = r < 0.2 ? 0.0 : r < 0.5 ? 1e-6 * uniform(rng) : uniform(rng);
  }
  mass[static_cast<std::size_t>(cells / 2)] += 10.0;
  double total = 0;
  for (double m : mass) total += m;
  std::vector<double> cdf(static_cast<std::size_t>(cells) + 2, 0.0);
  for (int c = 0; c < cells; ++c) {
    // (Kept <= 1: the sum's rounding must not make the CDF decrease at its end.)
    cdf[std::size_t(c) + 1] = std::min(1.0, cdf[std::size_t(c)] + mass[c] / total);
  }
  cdf[std::size_t(cells)] = cdf[std::size_t(cells) + 1] = 1.0;
  return cdf;
}

template <typename Index>
void expect_scanned_cells(int cells, std::mt19937_64& rng) {
  const std::vector<double> cdf = random_cdf(cells, rng);
  std::vector<Index> guide;
  build_cdf_guide(std::span<const double>(cdf), guide);
  const int entries = cdf_guide_entries(cells);
  ASSERT_EQ(guide.size(), std::size_t(entries) + 1);
  EXPECT_GE(entries, 4 * cells);
  EXPECT_EQ(entries & (entries - 1), 0);  // a power of two
  // Every guide entry is the scan's answer at its interval's start.
  for (int j = 0; j <= entries; ++j) {
    ASSERT_EQ(int(guide[std::size_t(j)]), scanned_cell(cdf, std::min(double(j) / entries, 1.0)))
        << cells << " cells, entry " << j;
  }
  // Random u, every CDF value and its neighbours, every interval's edges.
  std::vector<double> us = {0.0, std::nextafter(1.0, 0.0)};
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  for (int i = 0; i < 20000; ++i) us.push_back(uniform(rng));
  for (std::size_t c = 0; c + 1 < cdf.size(); ++c) {
    for (double v : {cdf[c], std::nextafter(cdf[c], 0.0), std::nextafter(cdf[c], 1.0)}) {
      if (v >= 0.0 && v < 1.0) us.push_back(v);
    }
  }
  for (int j = 0; j < entries; ++j) {
    us.push_back(double(j) / entries);
    us.push_back(std::nextafter(double(j + 1) / entries, 0.0));
  }
  for (double u : us) {
    const int c = guided_cell(std::span<const double>(cdf), std::span<const Index>(guide), u);
    ASSERT_EQ(c, scanned_cell(cdf, u)) << cells << " cells, u = " << u;
    ASSERT_GT(cdf[std::size_t(c) + 1], cdf[std::size_t(c)]) << "an empty cell, u = " << u;
  }
}

// The guided search finds exactly the cell a scan finds, with 16-bit and int guides, on CDFs
// whose guide intervals span one cell, a few, or many (the halving path).
TEST(CdfGuideTest, GuidedCellsAreTheScannedCells) {
  std::mt19937_64 rng(7);
  for (int cells : {1, 2, 3, 7, 64, 470, 1000}) {
    expect_scanned_cells<std::uint16_t>(cells, rng);
    expect_scanned_cells<int>(cells, rng);
  }
}

}  // namespace
}  // namespace prism::base
