// Test helper: a tile's image mean per bin and its standard error, from per-pixel sums and sums
// of squares (pixels are independent estimators, each with n >= 2 samples). The integrator
// tests compare these between integrators with z-bounds.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "services/image/tile.h"

namespace prism::worker::testing {

struct BinStats {
  std::vector<double> mean;
  std::vector<double> standard_error;
};

inline BinStats bin_stats(const image::TileResult& r) {
  const int bins = r.bins();
  const auto& rect = r.rect();
  const double pixels = double(rect.area());
  BinStats stats{std::vector<double>(bins, 0.0), std::vector<double>(bins, 0.0)};
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x) {
      const double n = double(r.count(x, y));
      for (int b = 0; b < bins; ++b) {
        double m = r.sum(x, y, b) / n;
        double variance = std::max(0.0, r.sum_squares(x, y, b) / n - m * m) * n / (n - 1);
        stats.mean[b] += m / pixels;
        stats.standard_error[b] += variance / n / (pixels * pixels);
      }
    }
  }
  for (double& se : stats.standard_error) se = std::sqrt(se);
  return stats;
}

}  // namespace prism::worker::testing
