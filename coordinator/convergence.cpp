#include "coordinator/convergence.h"

#include <cmath>

namespace prism::coordinator {

ConvergenceTracker::ConvergenceTracker(int width, int height)
    : width_(width), pixels_(std::size_t(width) * std::size_t(height)) {}

double ConvergenceTracker::variance_of_mean(const Pixel& p) {
  if (p.n < 2) return 0.0;
  const double n = double(p.n);
  const double variance = std::max(0.0, (p.squares - p.sum * p.sum / n) / (n - 1.0));
  return variance / n;
}

ConvergencePoint ConvergenceTracker::add(const image::TileResult& result, double seconds) {
  if (!result.has_rgb()) return {seconds, samples_, relative_error()};
  const image::TileRect& r = result.rect();
  const auto counts = result.counts();
  const auto sums = result.rgb_sums();
  const auto squares = result.rgb_squares();
  for (int y = r.y0; y < r.y1; ++y) {
    for (int x = r.x0; x < r.x1; ++x) {
      const std::size_t local =
          std::size_t(y - r.y0) * std::size_t(r.width()) + std::size_t(x - r.x0);
      if (counts[local] == 0) continue;
      Pixel& p = pixels_[std::size_t(y) * std::size_t(width_) + std::size_t(x)];
      variance_total_ -= variance_of_mean(p);
      mean_total_ -= mean(p);
      p.n += counts[local];
      p.sum += sums[local * 3 + 1];
      p.squares += squares[local * 3 + 1];
      variance_total_ += variance_of_mean(p);
      mean_total_ += mean(p);
      samples_ += counts[local];
    }
  }
  return {seconds, samples_, relative_error()};
}

void append_point(std::vector<ConvergencePoint>& points, const ConvergencePoint& point) {
  points.push_back(point);
  if (points.size() <= kMaxConvergencePoints) return;
  std::vector<ConvergencePoint> thinned;
  for (std::size_t i = 0; i < points.size(); ++i)
    if (i % 2 == 0 || i + 1 == points.size()) thinned.push_back(points[i]);
  points = std::move(thinned);
}

double ConvergenceTracker::relative_error() const {
  if (mean_total_ == 0.0) return 0.0;
  return std::sqrt(std::max(0.0, variance_total_)) / std::abs(mean_total_);
}

}  // namespace prism::coordinator
