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

// An RGB image's texels as RGB illuminants (pbrt-v4's RGBIlluminantSpectrum: m·s(λ)·D65(λ),
// uplifted once per texel), for images that emit: environment maps and projection lights.
struct IlluminantTexels {
  std::vector<float> scale;  // m; 0 for black texels
  std::vector<spectral::SigmoidPolynomial> polynomial;
  std::vector<float> brightness;  // the mean of each texel's RGB (a sampling weight)
  std::shared_ptr<const spectral::PiecewiseLinearSpectrum> illuminant;
  spectral::Rgb mean;  // over the texels

  // Linear RGB (or grey) texels, negative values clamped to 0.
  static absl::StatusOr<IlluminantTexels> create(const scene::TextureImage& image,
                                                 const spectral::RgbUplift& uplift);
  // Texel `texel` at each of lambda's lanes.
  spectral::SampledSpectrum at(size_t texel, const spectral::SampledWavelengths& lambda) const;
};

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
  const spectral::Rgb& mean_rgb() const { return texels_.mean; }
  // The illuminance the map (at scale 1) gives a patch facing light-space +z, from the texels'
  // sRGB luminance: Σ_{z > 0} Y·cos θ · 4π / N, each of the N texels covering 4π / N sr. This
  // is what `illuminance` normalises; pbrt-v4 weighs each texel 2π / N instead, which gives a
  // map twice the illuminance asked for (docs/conformance.md).
  double upper_hemisphere_illuminance() const { return upper_illuminance_; }

 private:
  EnvironmentMap() = default;
  int texel_of(const Vec3f& w_world) const;
  Vec3f to_light(const Vec3f& w) const;
  Vec3f to_world(const Vec3f& w) const;

  int size_ = 0;
  IlluminantTexels texels_;
  std::vector<double> row_cdf_;     // size_ + 1
  std::vector<double> column_cdf_;  // size_ rows of size_ + 1
  double total_ = 0;                // Σ weight_
  double upper_illuminance_ = 0;
  float world_from_light_[3][3] = {};
  float light_from_world_[3][3] = {};
};

}  // namespace prism::worker
