// Inverting a tabulated CDF quickly: a guide of 2^m >= 4 · cells intervals of u, each holding
// the last cell whose lower CDF value is at or below the interval's start, and the search it
// speeds up. With four intervals per cell most intervals span at most three cells, which two
// comparisons settle without a branch (a search loop whose trip count, 0 or 1, is a coin toss
// costs a misprediction every other sample); a longer span (cells of little mass, so rarely
// drawn) is halved. Used by the pixel tables' composite CDFs (services/spectral/binned_shape.h)
// and the pixel filter's sampling (worker/pixel_filter.h); prism-bench-wavelength-sampling
// measures it.
#pragma once

#include <algorithm>
#include <cstddef>
#include <span>
#include <vector>

namespace prism::base {

// The guide's interval count for a CDF of `cells` cells: the first power of two >= 4 · cells, so
// that u · entries and j / entries are exact.
inline int cdf_guide_entries(int cells) {
  int g = 1;
  while (g < 4 * cells) g *= 2;
  return g;
}

// Both functions take `cdf` as cells + 1 non-decreasing values from 0 to 1 followed by a sentinel
// of 1 (cells + 2 values): the search reads up to two values past a cell, and the sentinel saves
// it a clamp on the hot path.
//
// Builds the guide (cdf_guide_entries(cells) + 1 values) of `cdf`: guide[j] is the last cell c <
// cells with cdf[c] <= j / entries, and guide[entries] the last cell. Each cell writes a run of
// eight entries unconditionally and loops only past that (the next cell overwrites the excess), so
// the fill does not mispredict at every cell's end. `Index` must hold cells − 1.
template <typename Index>
void build_cdf_guide(std::span<const double> cdf, std::vector<Index>& guide) {
  constexpr int kRun = 8;
  const int cells = int(cdf.size()) - 2;
  const int g = cdf_guide_entries(cells);
  guide.resize(std::size_t(g) + 1 + kRun);
  const double dg = double(g);
  Index* out = guide.data();
  int j = 0;
  for (int k = 0; k + 1 < cells; ++k) {
    // The first entry of the next cell: the least j with j >= cdf[k + 1] · g (exact: g is a power
    // of two), at most g.
    const double x = std::min(cdf[std::size_t(k) + 1] * dg, dg);
    int end = static_cast<int>(x);
    end += double(end) < x ? 1 : 0;
    const Index cell = Index(k);
    int i = j;
    do {
      for (int r = 0; r < kRun; ++r) out[i + r] = cell;
      i += kRun;
    } while (i < end);
    j = end;
  }
  std::fill(out + j, out + g + 1, Index(cells - 1));
  guide.resize(std::size_t(g) + 1);
}

// The last cell c < cells with cdf[c] <= u, for u in [0, 1), by the guide above: the cell has
// positive mass.
template <typename Index>
int guided_cell(std::span<const double> cdf, std::span<const Index> guide, double u) {
  const double* c = cdf.data();
  const int entries = int(guide.size()) - 1;  // (an int: size_t to double would branch)
  const int j = static_cast<int>(u * double(entries));
  const int first = guide[std::size_t(j)], last = guide[std::size_t(j) + 1];
  if (last > first + 2) [[unlikely]] {
    const double* cell = c + first;
    int span = last - first + 1;
    while (span > 1) {
      const int half = span / 2;
      cell = cell[half] <= u ? cell + half : cell;
      span -= half;
    }
    return int(cell - c);
  }
  // cdf[cells] = 1 > u and the sentinel stand in for boundaries past the last cell.
  return first + (c[first + 1] <= u ? 1 : 0) + (c[first + 2] <= u ? 1 : 0);
}

}  // namespace prism::base
