// A running job's error estimate against time, for the dashboard's convergence plot. Each
// accepted final-pass result adds its samples' linear-sRGB green (a luminance proxy whose
// per-sample squares the results carry) to per-pixel sums; the estimate is the relative standard
// error of the image's mean green over the pixels sampled so far:
//   sqrt(Σ_p s²_p / n_p) / |Σ_p m_p|,  s²_p the sample variance and m_p the mean of pixel p.
// Pixels with fewer than two samples add no variance. Updating is O(the result's pixels).
#pragma once

#include <cstdint>
#include <vector>

#include "services/image/tile.h"

namespace prism::coordinator {

struct ConvergencePoint {
  double seconds = 0;         // since the job started (this coordinator's incarnation)
  std::uint64_t samples = 0;  // pixel samples accepted so far
  double relative_error = 0;  // 0 until two samples of one pixel are in
};

class ConvergenceTracker {
 public:
  ConvergenceTracker(int width, int height);
  // Adds a final-pass result (ignored without RGB buffers); the estimate after it, at `seconds`.
  ConvergencePoint add(const image::TileResult& result, double seconds);
  double relative_error() const;

 private:
  struct Pixel {
    std::uint64_t n = 0;
    double sum = 0, squares = 0;
  };
  static double variance_of_mean(const Pixel& p);
  static double mean(const Pixel& p) { return p.n > 0 ? p.sum / double(p.n) : 0.0; }

  int width_;
  std::vector<Pixel> pixels_;
  double variance_total_ = 0;  // Σ_p s²_p / n_p
  double mean_total_ = 0;      // Σ_p m_p
  std::uint64_t samples_ = 0;
};

// Appends `point` to a job's series, keeping at most kMaxConvergencePoints: beyond that every
// other point is dropped (the first and the last stay).
inline constexpr std::size_t kMaxConvergencePoints = 2048;
void append_point(std::vector<ConvergencePoint>& points, const ConvergencePoint& point);

}  // namespace prism::coordinator
