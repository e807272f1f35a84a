// pbrt-v4's image environment (an `infinite` light with a `filename`): radiance over the sphere
// of directions stored in an equal-area octahedral square image (Clarberg 2008), as pbrt-v4
// writes and reads them. A direction's radiance is the nearest texel of its light-space
// square coordinates, that texel's RGB uplifted as an RGB illuminant (m·s(λ)·D65(λ), pbrt-v4's
// RGBIlluminantSpectrum); the light's scale is applied by InfiniteLight.
//
// Sampling draws a texel from a piecewise-constant distribution proportional to the texel's
// mean RGB, then a point uniformly inside it. The mapping has a constant Jacobian (4π sr per
// unit square), so the solid-angle density is the square's density / 4π.
//
// Thread-safety: immutable after create.
#pragma once

#include <memory>
#include <vector>

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"
#include "services/spectral/rgb_uplift.h"
#include "services/spectral/sampled.h"
#include "worker/vecmath.h"

namespace prism::worker {

class EnvironmentMap {
 public:
  // `image` is square, linear RGB (or grey); `light_to_world` orients it.
  static absl::StatusOr<std::shared_ptr<const EnvironmentMap>> create(
      const scene::TextureImage& image, const scene::Transform& light_to_world,
      const spectral::RgbUplift& uplift);

  // Radiance towards the scene from world direction w (unit; pointing away from the scene).
  spectral::SampledSpectrum radiance(const Vec3f& w,
                                     const spectral::SampledWavelengths& lambda) const;
  // A world direction and its solid-angle density; nullopt when the map is black.
  struct Sample {
    Vec3f w;
    float pdf = 0;
  };
  std::optional<Sample> sample(Point2f u) const;
  float pdf(const Vec3f& w) const;
  // The mean linear RGB over the sphere (every texel covers the same solid angle).
  const spectral::Rgb& mean_rgb() const { return mean_; }

 private:
  EnvironmentMap() = default;
  int texel_of(const Vec3f& w_world) const;
  Vec3f to_light(const Vec3f& w) const;
  Vec3f to_world(const Vec3f& w) const;

  int size_ = 0;
  struct Texel {
    float scale = 0;  // m of the RGB illuminant uplift; 0 for black
    spectral::SigmoidPolynomial polynomial;
  };
  std::vector<Texel> texels_;
  std::shared_ptr<const spectral::PiecewiseLinearSpectrum> illuminant_;
  std::vector<float> weight_;       // the sampling function per texel (mean RGB)
  std::vector<double> row_cdf_;     // size_ + 1
  std::vector<double> column_cdf_;  // size_ rows of size_ + 1
  double total_ = 0;                // Σ weight_
  float world_from_light_[3][3] = {};
  float light_from_world_[3][3] = {};
  spectral::Rgb mean_;
};

}  // namespace prism::worker
