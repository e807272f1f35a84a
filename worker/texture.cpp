#include "worker/texture.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "worker/material.h"

namespace prism::worker {
namespace {

using spectral::SampledSpectrum;
using spectral::SampledWavelengths;
using texture_nodes::Checkerboard;
using texture_nodes::Constant;
using texture_nodes::DirectionMix;
using texture_nodes::Mix;
using texture_nodes::Scale;

Point2f map_uv(const scene::UvMapping& m, Point2f uv) {
  return {float(m.su * uv.x + m.du), float(m.sv * uv.y + m.dv)};
}

// The four texels around (s, t) and their bilinear weights, pbrt-v4's convention: texel centres
// at half-integers, t = 0 at the bottom row of the image (row height − 1 of the file).
struct Taps {
  int index[4];
  float weight[4];
};

Taps bilinear_taps(const Texture::Image& image, Point2f st) {
  const float x = st.x * float(image.width) - 0.5f;
  const float y = (1.0f - st.y) * float(image.height) - 0.5f;
  const float fx = std::floor(x), fy = std::floor(y);
  const float dx = x - fx, dy = y - fy;
  const int xi = int(fx), yi = int(fy);
  Taps taps;
  const int xs[4] = {xi, xi + 1, xi, xi + 1};
  const int ys[4] = {yi, yi, yi + 1, yi + 1};
  const float ws[4] = {(1 - dx) * (1 - dy), dx * (1 - dy), (1 - dx) * dy, dx * dy};
  for (int k = 0; k < 4; ++k) {
    int px = xs[k], py = ys[k];
    taps.weight[k] = ws[k];
    switch (image.wrap) {
      case scene::TextureWrap::kRepeat:
        px = ((px % image.width) + image.width) % image.width;
        py = ((py % image.height) + image.height) % image.height;
        break;
      case scene::TextureWrap::kClamp:
        px = std::clamp(px, 0, image.width - 1);
        py = std::clamp(py, 0, image.height - 1);
        break;
      case scene::TextureWrap::kBlack:
        if (px < 0 || py < 0 || px >= image.width || py >= image.height) {
          taps.weight[k] = 0;
          px = py = 0;
        }
        break;
    }
    taps.index[k] = py * image.width + px;
  }
  return taps;
}

bool checker_first(const scene::UvMapping& m, Point2f uv) {
  const Point2f st = map_uv(m, uv);
  return ((long(std::floor(st.x)) + long(std::floor(st.y))) & 1) == 0;
}

SampledSpectrum eval_spectrum(const Texture::Input& in, const TextureContext& ctx,
                              const SampledWavelengths& lambda) {
  if (in.texture) return in.texture->spectrum(ctx, lambda);
  return spectral::sample(in.spectrum, lambda);
}

float eval_float(const Texture::Input& in, const TextureContext& ctx) {
  return in.texture ? in.texture->value(ctx) : in.value;
}

class Resolver {
 public:
  Resolver(const scene::SceneDescription& scene, const spectral::SpectrumLibrary& library,
           const spectral::RgbUplift& uplift)
      : scene_(scene), library_(library), uplift_(uplift) {}

  absl::StatusOr<std::vector<TexturePtr>> run() {
    done_.assign(scene_.textures.size(), nullptr);
    busy_.assign(scene_.textures.size(), false);
    for (size_t i = 0; i < scene_.textures.size(); ++i) PRISM_RETURN_IF_ERROR(get(i).status());
    return std::move(done_);
  }

 private:
  // A constant spectrum inside a texture: an RGB within [0, 1] is an albedo (pbrt-v4's context
  // for textures in reflectance slots), anything else is taken as written.
  // Texture `i`, after the textures it names. A material may name a texture defined further on,
  // whose slot then comes before the textures it names (scene::EntityContext::find_texture), so
  // they resolve on demand; a texture names only earlier ones, so they cannot form a cycle.
  absl::StatusOr<TexturePtr> get(size_t i) {
    if (done_[i] != nullptr) return done_[i];
    const scene::Texture& t = scene_.textures[i];
    if (busy_[i])
      return scene::location_error(t.where, absl::StrCat("texture \"", t.name, "\" names itself"));
    busy_[i] = true;
    absl::StatusOr<TexturePtr> r = resolve(t);
    busy_[i] = false;
    if (!r.ok()) {
      if (failed_inside_) return r.status();  // a named texture's error, located already
      failed_inside_ = true;
      return scene::location_error(
          t.where, absl::StrCat("texture \"", t.name, "\": ", r.status().message()));
    }
    done_[i] = *std::move(r);
    return done_[i];
  }

  absl::StatusOr<Texture::Input> input(const scene::TextureInput& in, bool spectrum, bool* varies) {
    Texture::Input out;
    if (in.texture >= 0) {
      PRISM_ASSIGN_OR_RETURN(out.texture, get(size_t(in.texture)));
      *varies = *varies || out.texture->varies_with_wavelength();
      return out;
    }
    out.value = float(in.value);
    if (spectrum) {
      job::SpectrumRole role = job::SpectrumRole::kUnbounded;
      if (const auto* rgb = std::get_if<scene::SpectrumRgb>(&in.spectrum);
          rgb != nullptr && rgb->r <= 1 && rgb->g <= 1 && rgb->b <= 1) {
        role = job::SpectrumRole::kReflectance;
      }
      PRISM_ASSIGN_OR_RETURN(out.spectrum,
                             job::resolve_spectrum(in.spectrum, role, library_, uplift_));
      *varies = *varies || !spectral::is_constant(out.spectrum);
    }
    return out;
  }

  absl::StatusOr<TexturePtr> resolve(const scene::Texture& t) {
    const bool sp = t.spectrum;
    bool varies = false;
    Texture::Node node;
    if (const auto* c = std::get_if<scene::ConstantTexture>(&t.kind)) {
      PRISM_ASSIGN_OR_RETURN(Texture::Input v, input(c->value, sp, &varies));
      node = Constant{std::move(v)};
    } else if (const auto* c = std::get_if<scene::CheckerboardTexture>(&t.kind)) {
      Checkerboard out{c->mapping, {}, {}};
      PRISM_ASSIGN_OR_RETURN(out.tex1, input(c->tex1, sp, &varies));
      PRISM_ASSIGN_OR_RETURN(out.tex2, input(c->tex2, sp, &varies));
      node = std::move(out);
    } else if (const auto* s = std::get_if<scene::ScaleTexture>(&t.kind)) {
      Scale out;
      PRISM_ASSIGN_OR_RETURN(out.tex, input(s->tex, sp, &varies));
      PRISM_ASSIGN_OR_RETURN(out.scale, input(s->scale, false, &varies));
      node = std::move(out);
    } else if (const auto* m = std::get_if<scene::MixTexture>(&t.kind)) {
      Mix out;
      PRISM_ASSIGN_OR_RETURN(out.tex1, input(m->tex1, sp, &varies));
      PRISM_ASSIGN_OR_RETURN(out.tex2, input(m->tex2, sp, &varies));
      PRISM_ASSIGN_OR_RETURN(out.amount, input(m->amount, false, &varies));
      node = std::move(out);
    } else if (const auto* d = std::get_if<scene::DirectionMixTexture>(&t.kind)) {
      DirectionMix out;
      PRISM_ASSIGN_OR_RETURN(out.tex1, input(d->tex1, sp, &varies));
      PRISM_ASSIGN_OR_RETURN(out.tex2, input(d->tex2, sp, &varies));
      out.direction = {float(d->direction_world[0]), float(d->direction_world[1]),
                       float(d->direction_world[2])};
      node = std::move(out);
    } else {
      const auto& im = std::get<scene::ImageTexture>(t.kind);
      PRISM_ASSIGN_OR_RETURN(Texture::Image out, image(im, sp, &varies));
      node = std::move(out);
    }
    return std::make_shared<const Texture>(std::move(node), varies);
  }

  // pbrt-v4's order: scale, then invert (1 − v), then clamp (to >= 0; an albedo to [0, 1]).
  absl::StatusOr<Texture::Image> image(const scene::ImageTexture& im, bool spectrum,
                                       bool* varies) const {
    const scene::TextureImage& src = *im.image;
    Texture::Image out;
    out.width = src.width;
    out.height = src.height;
    out.wrap = im.wrap;
    out.mapping = im.mapping;
    const size_t texels = size_t(src.width) * size_t(src.height);
    const float scale = float(im.scale);
    auto adjust = [&](float v) {
      v *= scale;
      if (im.invert) v = 1.0f - v;
      return std::max(0.0f, v);
    };
    if (!spectrum) {
      // A float texture reads an image's first channel, as pbrt-v4's MIPMap::Texel<Float> does
      // (a packed map's red, not the average of its channels).
      out.grey.resize(texels);
      for (size_t i = 0; i < texels; ++i) {
        out.grey[i] = adjust(src.values[i * size_t(src.channels)]);
      }
      return out;
    }
    out.albedo.resize(texels);
    for (size_t i = 0; i < texels; ++i) {
      float rgb[3];
      for (int c = 0; c < 3; ++c) {
        const int channel = src.channels == 1 ? 0 : c;
        rgb[c] = std::min(1.0f, adjust(src.values[i * size_t(src.channels) + size_t(channel)]));
      }
      PRISM_ASSIGN_OR_RETURN(out.albedo[i], uplift_.fit({rgb[0], rgb[1], rgb[2]}));
      if (out.albedo[i].c0 != 0 || out.albedo[i].c1 != 0) *varies = true;
    }
    return out;
  }

  const scene::SceneDescription& scene_;
  const spectral::SpectrumLibrary& library_;
  const spectral::RgbUplift& uplift_;
  std::vector<TexturePtr> done_;  // by index; null until resolved
  std::vector<bool> busy_;        // being resolved (a guard against a cycle)
  bool failed_inside_ = false;    // the error being returned carries its texture's location
};

}  // namespace

absl::StatusOr<std::vector<TexturePtr>> Texture::resolve_all(
    const scene::SceneDescription& scene, const spectral::SpectrumLibrary& library,
    const spectral::RgbUplift& uplift) {
  return Resolver(scene, library, uplift).run();
}

SampledSpectrum Texture::spectrum(const TextureContext& ctx,
                                  const SampledWavelengths& lambda) const {
  struct Visitor {
    const TextureContext& ctx;
    const SampledWavelengths& lambda;
    SampledSpectrum operator()(const Constant& c) const {
      return eval_spectrum(c.value, ctx, lambda);
    }
    SampledSpectrum operator()(const Checkerboard& c) const {
      return eval_spectrum(checker_first(c.mapping, ctx.uv) ? c.tex1 : c.tex2, ctx, lambda);
    }
    SampledSpectrum operator()(const Scale& s) const {
      const float k = eval_float(s.scale, ctx);
      if (k == 0) return {};
      return eval_spectrum(s.tex, ctx, lambda) * k;
    }
    SampledSpectrum operator()(const Mix& m) const {
      const float a = eval_float(m.amount, ctx);
      SampledSpectrum out;
      if (a != 1) out += eval_spectrum(m.tex1, ctx, lambda) * (1 - a);
      if (a != 0) out += eval_spectrum(m.tex2, ctx, lambda) * a;
      return out;
    }
    SampledSpectrum operator()(const DirectionMix& d) const {
      const float a = std::abs(dot(ctx.n, d.direction));
      SampledSpectrum out;
      if (a != 0) out += eval_spectrum(d.tex1, ctx, lambda) * a;
      if (a != 1) out += eval_spectrum(d.tex2, ctx, lambda) * (1 - a);
      return out;
    }
    SampledSpectrum operator()(const Image& im) const {
      const Taps taps = bilinear_taps(im, map_uv(im.mapping, ctx.uv));
      SampledSpectrum out;
      for (int k = 0; k < 4; ++k) {
        if (taps.weight[k] == 0) continue;
        const spectral::SigmoidPolynomial& p = im.albedo[size_t(taps.index[k])];
        for (int s = 0; s < lambda.count(); ++s) out[s] += taps.weight[k] * p(lambda.lambda(s));
      }
      return out;
    }
  };
  return std::visit(Visitor{ctx, lambda}, node_);
}

float Texture::value(const TextureContext& ctx) const {
  struct Visitor {
    const TextureContext& ctx;
    float operator()(const Constant& c) const { return eval_float(c.value, ctx); }
    float operator()(const Checkerboard& c) const {
      return eval_float(checker_first(c.mapping, ctx.uv) ? c.tex1 : c.tex2, ctx);
    }
    float operator()(const Scale& s) const {
      const float k = eval_float(s.scale, ctx);
      return k == 0 ? 0.0f : eval_float(s.tex, ctx) * k;
    }
    float operator()(const Mix& m) const {
      const float a = eval_float(m.amount, ctx);
      float out = 0;
      if (a != 1) out += (1 - a) * eval_float(m.tex1, ctx);
      if (a != 0) out += a * eval_float(m.tex2, ctx);
      return out;
    }
    float operator()(const DirectionMix& d) const {
      const float a = std::abs(dot(ctx.n, d.direction));
      float out = 0;
      if (a != 0) out += a * eval_float(d.tex1, ctx);
      if (a != 1) out += (1 - a) * eval_float(d.tex2, ctx);
      return out;
    }
    float operator()(const Image& im) const {
      const Taps taps = bilinear_taps(im, map_uv(im.mapping, ctx.uv));
      float out = 0;
      for (int k = 0; k < 4; ++k) out += taps.weight[k] * im.grey[size_t(taps.index[k])];
      return out;
    }
  };
  return std::visit(Visitor{ctx}, node_);
}

}  // namespace prism::worker
