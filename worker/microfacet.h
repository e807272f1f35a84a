// The anisotropic Trowbridge–Reitz (GGX) microfacet distribution (Walter et al. 2007) with
// Heitz's (2018) sampling of visible normals. Directions are in the local shading frame
// (z = macro-surface normal). alpha_x, alpha_y > 0; below kSmoothAlpha a surface is treated as
// perfectly smooth by the BSDFs, because the distribution's peak no longer fits in a float.
#pragma once

#include "worker/vecmath.h"

namespace prism::worker {

class TrowbridgeReitz {
 public:
  static constexpr float kSmoothAlpha = 1e-3f;

  TrowbridgeReitz(float alpha_x, float alpha_y) : alpha_x_(alpha_x), alpha_y_(alpha_y) {}

  // pbrt-v4's `remaproughness`: a perceptual roughness r in [0,1] to alpha = sqrt(r).
  static float roughness_to_alpha(float roughness);

  bool effectively_smooth() const { return std::max(alpha_x_, alpha_y_) < kSmoothAlpha; }
  float alpha_x() const { return alpha_x_; }
  float alpha_y() const { return alpha_y_; }

  // Microfacet normal density D(wm) (per steradian of wm, projected: ∫ D(wm) cos θm dωm = 1).
  float d(const Vec3f& wm) const;
  // Smith's Λ, the masking G1 and the height-correlated masking-shadowing G.
  float lambda(const Vec3f& w) const;
  float g1(const Vec3f& w) const { return 1.0f / (1.0f + lambda(w)); }
  float g(const Vec3f& wo, const Vec3f& wi) const { return 1.0f / (1.0f + lambda(wo) + lambda(wi)); }
  // Density of visible normals seen from w: G1(w) / |cos θ(w)| · D(wm) · |w·wm|.
  float d_visible(const Vec3f& w, const Vec3f& wm) const;
  // Samples a visible normal from w (either hemisphere); wm is in the upper hemisphere.
  Vec3f sample_wm(const Vec3f& w, Point2f u) const;

 private:
  float alpha_x_;
  float alpha_y_;
};

}  // namespace prism::worker
