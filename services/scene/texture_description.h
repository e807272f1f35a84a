// pbrt-v4 textures as parsed: `Texture "name" "float"|"spectrum" "class" params...`. Nothing is
// evaluated here; the worker resolves a texture tree once per scene (worker/texture.h) and
// evaluates it at each hit. Image files are decoded at parse time into linear values (the
// file's `encoding` applied), so the bundle's bytes, not a path, are what a render depends on.
//
// Supported classes: constant, checkerboard (2D, `uv` mapping), imagemap (PNG and OpenEXR),
// scale, mix and directionmix. pbrt-v4 filters checkerboards and picks image MIP levels from ray
// differentials; Prism evaluates the unfiltered texture at the hit (the pixel filter and the
// samples average it), which is the limit pbrt-v4's own filtering approaches as its footprints
// shrink. docs/conformance.md says where that shows.
#pragma once

#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "services/scene/source_location.h"
#include "services/scene/spectrum_param.h"
#include "services/scene/transform.h"

namespace prism::scene {

// An image decoded for lookups: linear values (the encoding already undone, `scale` and
// `invert` not yet applied), row 0 at the top of the file as pbrt-v4 stores it.
struct TextureImage {
  int width = 0;
  int height = 0;
  int channels = 0;  // 1 or 3
  std::vector<float> values;
};

// pbrt-v4's `uv` mapping: (s, t) = (su·u + du, sv·v + dv).
struct UvMapping {
  double su = 1, sv = 1, du = 0, dv = 0;
};

// A texture's parameter: another texture (an index into SceneDescription::textures, of the
// parameter's type) or a constant: `value` for float inputs, `spectrum` for spectrum inputs.
struct TextureInput {
  int texture = -1;
  double value = 0;
  SpectrumParam spectrum = SpectrumConstant{0};
};

struct ConstantTexture {
  TextureInput value;
};

// 2D checkerboard: tex1 where floor(s) + floor(t) is even, else tex2.
struct CheckerboardTexture {
  UvMapping mapping;
  TextureInput tex1, tex2;
};

enum class TextureWrap { kRepeat, kClamp, kBlack };

struct ImageTexture {
  UvMapping mapping;
  std::shared_ptr<const TextureImage> image;
  std::string filename;  // relative to the scene root
  double scale = 1.0;
  bool invert = false;
  TextureWrap wrap = TextureWrap::kRepeat;
};

// tex · scale (scale is a float input).
struct ScaleTexture {
  TextureInput tex, scale;
};

// (1 − amount)·tex1 + amount·tex2 (amount is a float input).
struct MixTexture {
  TextureInput tex1, tex2, amount;
};

// a·tex1 + (1 − a)·tex2 with a = |n · dir| at the hit (n the geometric normal).
struct DirectionMixTexture {
  TextureInput tex1, tex2;
  Vec3 direction_world{0, 1, 0};  // unit
};

using TextureKind = std::variant<ConstantTexture, CheckerboardTexture, ImageTexture, ScaleTexture,
                                 MixTexture, DirectionMixTexture>;

struct Texture {
  std::string name;
  bool spectrum = true;  // false: a float texture
  TextureKind kind;
  SourceLocation where;
};

}  // namespace prism::scene
