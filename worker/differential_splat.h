// Differential splatting (spectral ray differentials paper §6.1, docs/estimators.md §6.1): a
// light-path splat whose receiver moved with the wavelength (LightSplat::has_differential) is
// drawn as a line instead of a point. With Δλ the spectral neighbourhood, the line runs from
// ρ(p − Δλ·∂p/∂λ) to ρ(p + Δλ·∂p/∂λ) on the film, and its fragment at t ∈ [−1, 1] carries the
// splat's energy at wavelength λ + t·Δλ: the bin of that wavelength, and the R, G, B of that
// wavelength's colour matching functions (the paper's extrapolation across the spectrum).
//
// The fragments are spaced at most half a pixel apart, at the midpoints of equal parts of the
// line, and each lands through the pixel filter as a point splat would. They share the splat's
// energy in proportion to their weights, so each splat keeps its energy (the filtered image holds
// what the unbiased one does, moved along the caustics). A fragment's weight is the product of
//  - the emitting light's spectrum at the fragment's wavelength (when the splat names its light):
//    the caustic keeps its lamp's spectral shape, a line lamp's lines stay lines, and only the
//    rest of the path's throughput is assumed constant over ±Δλ;
//  - a bilateral term in the receiver's geometry: with (q, n) the receiver's point moved along
//    the line and its normal, and (g, n_g) what the camera sees through the pixel centre the
//    fragment lands in (ReceiverImage), exp(−½ (((g − q)·n) / σ)²) · |n·n_g|^32, σ one pixel's
//    footprint at g. A line that runs off its surface (over an edge, behind an occluder) gives
//    nothing there. Off the film the term is 1 and the fragment lands nowhere (what the caustic
//    sends out of the frame).
// With a thin lens the line starts where the splat's own lens point put it and runs along the
// lens centre's d(raster)/dλ (the receiver image is the lens centre's too).
// A line whose fragments all weigh 0 lands as the point. Wavelengths outside the grid cut the
// line short (t is limited so that λ + t·Δλ stays in the grid).
//
// As Δλ → 0 every fragment lands where the point does: the estimate is consistent when Δλ
// shrinks with the samples (job::splat_width_at), biased by O(Δλ²) for a caustic smooth along
// its dispersion curve (the kernel is symmetric in t) with variance O(1/(n·Δλ)).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "worker/light_tracer.h"
#include "worker/pixel_filter.h"
#include "worker/render_scene.h"

namespace prism::worker {

// What the pinhole camera sees through each pixel centre: the first surface's point and unit
// geometric normal (interfaces without a material are passed), and one pixel's footprint there.
// Pixels that see nothing are invalid.
class ReceiverImage {
 public:
  struct Pixel {
    Vec3f position;
    Vec3f normal;
    float footprint = 0;
    bool valid = false;
  };
  // Traces one ray per pixel, in parallel; the result does not depend on the threads.
  explicit ReceiverImage(const RenderScene& scene);

  int width() const { return width_; }
  int height() const { return height_; }
  const Pixel& at(int x, int y) const { return pixels_[std::size_t(y) * width_ + x]; }

 private:
  int width_ = 0, height_ = 0;
  std::vector<Pixel> pixels_;
};

// The filtered image's running sums: bins per pixel and R, G, B per pixel, row-major.
struct FilteredSums {
  int width = 0, height = 0, bins = 0;
  std::span<double> values;  // width·height·bins
  std::span<double> rgb;     // width·height·3
};

// Calls add(x, y, w) for every pixel whose filter reaches film position `raster`, w = f/∫f times
// `scale` (a box filter: the one pixel holding it, weight `scale`), in row order.
template <typename Add>
void for_each_filter_pixel(const PixelFilter& filter, Point2f raster, double scale, int width,
                           int height, Add&& add) {
  if (filter.unit_box()) {
    const int x = int(std::floor(raster.x)), y = int(std::floor(raster.y));
    if (x >= 0 && x < width && y >= 0 && y < height) add(x, y, scale);
    return;
  }
  const double rx = filter.radius(0), ry = filter.radius(1);
  const double inverse_integral = scale / filter.integral();
  const int x0 = std::max(0, int(std::ceil(raster.x - rx - 0.5)));
  const int x1 = std::min(width - 1, int(std::floor(raster.x + rx - 0.5)));
  const int y0 = std::max(0, int(std::ceil(raster.y - ry - 0.5)));
  const int y1 = std::min(height - 1, int(std::floor(raster.y + ry - 0.5)));
  for (int y = y0; y <= y1; ++y) {
    for (int x = x0; x <= x1; ++x) {
      const double f = filter.evaluate(raster.x - (x + 0.5), raster.y - (y + 0.5));
      if (f != 0.0) add(x, y, f * inverse_integral);
    }
  }
}

// Most fragments one line is cut into (a line longer than half this many pixels has them
// further apart than half a pixel).
inline constexpr int kMaxSplatFragments = 1024;

class DifferentialSplatter {
 public:
  // `receivers` must be the scene's (same film) and outlive the splatter.
  DifferentialSplatter(const RenderScene& scene, const ReceiverImage& receivers);

  // Adds splat `s` times `scale` into `out`: a line over ±width_nm when it has a differential,
  // else the point. Returns whether it was drawn as a line.
  bool splat(const LightSplat& s, double width_nm, double scale, FilteredSums& out);

 private:
  void point(const LightSplat& s, double scale, FilteredSums& out) const;

  const RenderScene& scene_;
  const ReceiverImage& receivers_;
  std::vector<double> weights_;  // per fragment (scratch)
};

}  // namespace prism::worker
