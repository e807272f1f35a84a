// pbrt-v4's pixel filters (scene::PixelFilterSpec: box, gaussian, triangle, mitchell, lanczos,
// all separable, f(x, y) = f_x(x)·f_y(y)) by filter importance sampling. A camera sample's offset
// o from its pixel's centre is drawn with a density p(o) ≈ |f(o)| / ∫|f| and the sample carries
// the weight w = f(o) / (p(o)·∫f), so the mean over a pixel's samples estimates
//     ∫ f(o)·L(centre + o) do / ∫ f(o) do
// without bias, for any p that is positive wherever f is not zero. (pbrt-v4 divides by the sum of
// the weights instead; both converge to the same image.) Every sample still belongs to its own
// pixel, so tiles stay independent and merges deterministic; the gradient integrator's base and
// offset paths share the sample's offset and weight.
//
// p per axis is piecewise constant over 64 cells per pixel of radius, each cell's mass the
// integral of |f| over it (Simpson, 16 panels); inside a cell the offset is uniform. The weight
// is then ∫|f|/∫f · sign(f)·|f(x)|/⟨|f|⟩_cell per axis: 1 up to the variation of f inside a
// cell for filters without negative lobes; mitchell and lanczos carry signed weights. A box of
// radius 0.5 is the plain jittered pixel (offset u − 0.5, weight 1), sampled exactly as before
// pixel filters existed.
#pragma once

#include <vector>

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"

namespace prism::worker {

struct FilterSample {
  float x = 0, y = 0;  // film position offset from the pixel's corner, in pixels: pixel + (x, y)
  float weight = 1;
};

class PixelFilter {
 public:
  // INVALID_ARGUMENT for radii or parameters out of range (the parser's ranges).
  static absl::StatusOr<PixelFilter> create(const scene::PixelFilterSpec& spec);

  // u0, u1 in [0, 1). The position is relative to the pixel's corner (centre 0.5, 0.5).
  FilterSample sample(float u0, float u1) const;
  // f at an offset from the pixel's centre (unnormalised, pbrt-v4's definitions).
  double evaluate(double dx, double dy) const;
  // ∫∫ f over its support.
  double integral() const { return axes_[0].integral * axes_[1].integral; }
  bool unit_box() const { return unit_box_; }
  // The support's half-width along an axis (0: x, 1: y), in pixels.
  double radius(int axis) const { return axes_[axis].radius; }
  // One axis (0: x, 1: y) of sample(): the offset from the centre and its weight factor.
  void sample_axis(int axis, double u, double* offset, double* weight) const {
    axes_[axis].sample(u, offset, weight);
  }
  // f along one axis.
  double evaluate_axis(int axis, double offset) const { return axes_[axis].evaluate(offset); }

 private:
  struct Axis {
    scene::PixelFilterType type = scene::PixelFilterType::kBox;
    double radius = 0.5;
    double sigma = 0.5, b = 1.0 / 3.0, c = 1.0 / 3.0, tau = 3.0;
    double integral = 1;      // ∫ f
    double abs_integral = 1;  // ∫ |f|
    std::vector<double> cdf;  // cells + 1 entries from 0 to 1, then a sentinel 1 (cdf_guide.h)
    // base::build_cdf_guide's guide of cdf (services/base/cdf_guide.h).
    std::vector<int> guide;
    double gaussian_floor = 0;      // exp(−r²/2σ²), subtracted by the gaussian
    double inverse_two_sigma2 = 0;  // 1/(2σ²)
    double evaluate(double x) const;
    // Offset from the centre and its weight factor for u in [0, 1).
    void sample(double u, double* x, double* weight) const;
  };
  static Axis make_axis(const scene::PixelFilterSpec& spec, double radius);

  Axis axes_[2];
  bool unit_box_ = false;
};

}  // namespace prism::worker
