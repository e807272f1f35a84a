// Textures resolved for tracing: the scene's Texture directives (texture_description.h) turned
// into immutable trees, evaluated at a hit's (u, v) and normal. A spectrum texture gives every
// lane its own value; a float texture one number.
//
// RGB is uplifted the way pbrt-v4 does it for reflectances (clamped to [0, 1], Jakob–Hanika
// albedo spectra). An image's texels are uplifted once, when the scene is resolved; a lookup
// blends the four texels' spectra bilinearly. Blending spectra rather than RGB gives exactly the
// colour pbrt-v4's bilinear RGB lookup gives (colour is linear in the spectrum); only the
// metamer between texel centres differs, by less than the uplift's own choice of metamer does.
//
// Thread-safety: immutable after resolve; evaluation is const and never allocates.
#pragma once

#include <memory>
#include <variant>
#include <vector>

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/rgb_uplift.h"
#include "services/spectral/sampled.h"
#include "services/spectral/spectrum.h"
#include "worker/geometry.h"
#include "worker/vecmath.h"

namespace prism::worker {

struct TextureContext {
  Point2f uv;
  Vec3f n;  // unit geometric normal (directionmix)
};

inline TextureContext texture_context(const SurfaceHit& hit) {
  return {hit.uv, hit.ng};
}

class Texture;
using TexturePtr = std::shared_ptr<const Texture>;

// The nodes of a resolved texture tree.
namespace texture_nodes {

// A texture input: another texture, or a constant (float or spectrum).
struct Input {
  TexturePtr texture;
  float value = 0;
  spectral::Spectrum spectrum = spectral::ConstantSpectrum{0};
};
struct Image {
  int width = 0, height = 0;
  std::vector<float> grey;                          // float textures: one value per texel
  std::vector<spectral::SigmoidPolynomial> albedo;  // spectrum textures: one per texel
  scene::TextureWrap wrap = scene::TextureWrap::kRepeat;
  scene::UvMapping mapping;
};
struct Checkerboard {
  scene::UvMapping mapping;
  Input tex1, tex2;
};
struct Scale {
  Input tex, scale;
};
struct Mix {
  Input tex1, tex2, amount;
};
struct DirectionMix {
  Input tex1, tex2;
  Vec3f direction;
};
struct Constant {
  Input value;
};

}  // namespace texture_nodes

class Texture {
 public:
  // Resolves every texture of the scene, in order (a texture only refers to earlier ones).
  // Errors name the texture's file:line:column.
  static absl::StatusOr<std::vector<TexturePtr>> resolve_all(
      const scene::SceneDescription& scene, const spectral::SpectrumLibrary& library,
      const spectral::RgbUplift& uplift);

  // Spectrum textures: the value at each of lambda's lanes (lanes beyond count() are 0).
  spectral::SampledSpectrum spectrum(const TextureContext& ctx,
                                     const spectral::SampledWavelengths& lambda) const;
  // Float textures.
  float value(const TextureContext& ctx) const;
  // False when no part of the tree varies with wavelength.
  bool varies_with_wavelength() const { return varies_; }

  using Input = texture_nodes::Input;
  using Image = texture_nodes::Image;
  using Node =
      std::variant<texture_nodes::Constant, texture_nodes::Checkerboard, texture_nodes::Image,
                   texture_nodes::Scale, texture_nodes::Mix, texture_nodes::DirectionMix>;

  Texture(Node node, bool varies) : node_(std::move(node)), varies_(varies) {}

 private:
  Node node_;
  bool varies_ = false;
};

}  // namespace prism::worker
