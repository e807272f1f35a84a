// Test helper: per-pixel wavelength tables deliberately unlike any default distribution, for the
// tests of tracing with a pixel's table. Every table is positive over all of Λ (so wherever light
// is emitted) but puts most of its mass in a few narrow spikes and a steep ramp that move from
// pixel to pixel; the tests check that the estimates stay unbiased whatever the table.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "services/spectral/pixel_tables.h"
#include "services/spectral/wavelength_distribution.h"

namespace prism::worker::testing {

// The wire bytes of a width × height tile's tables over `cells` cells (pixel_tables.h). Pixels
// for which `uses_default(x, y)` (tile-local) holds get the all-zero row of the job's default.
inline std::string skewed_table_bytes(int width, int height, int cells,
                                      const std::function<bool(int, int)>& uses_default = {}) {
  std::string bytes;
  std::vector<double> weights(static_cast<std::size_t>(cells));
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      if (uses_default && uses_default(x, y)) {
        spectral::append_default_pixel(cells, bytes);
        continue;
      }
      const bool rising = (x + y) % 2 == 0;
      for (int i = 0; i < cells; ++i) {
        const double t = (i + 0.5) / cells;
        const double ramp = rising ? t * t * t : (1 - t) * (1 - t) * (1 - t);
        const bool spike = (i + 3 * x + 5 * y) % 7 == 0;
        weights[std::size_t(i)] = 0.02 + 3.0 * ramp + (spike ? 4.0 : 0.0);
      }
      const std::vector<std::uint16_t> cdf =
          spectral::WavelengthDistribution::from_table(weights)->quantise();
      spectral::append_pixel_table(cdf, bytes);
    }
  }
  return bytes;
}

inline spectral::PixelTables skewed_tables(int width, int height, int cells,
                                           const std::function<bool(int, int)>& uses_default = {}) {
  return *spectral::PixelTables::decode(width, height, cells,
                                        skewed_table_bytes(width, height, cells, uses_default));
}

}  // namespace prism::worker::testing
