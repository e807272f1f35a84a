#include "worker/microfacet.h"

namespace prism::worker {

float TrowbridgeReitz::roughness_to_alpha(float roughness) { return std::sqrt(roughness); }

float TrowbridgeReitz::d(const Vec3f& wm) const {
  float cos2 = cos2_theta(wm);
  if (!(cos2 > 0.0f)) return 0.0f;
  float sin2 = std::max(0.0f, 1.0f - cos2);
  // tan²θ (cos²φ/αx² + sin²φ/αy²) written without dividing by sin θ.
  float e = (wm.x * wm.x / (alpha_x_ * alpha_x_) + wm.y * wm.y / (alpha_y_ * alpha_y_)) / cos2;
  if (sin2 == 0.0f) e = 0.0f;
  float cos4 = cos2 * cos2;
  return 1.0f / (kPi * alpha_x_ * alpha_y_ * cos4 * (1.0f + e) * (1.0f + e));
}

float TrowbridgeReitz::lambda(const Vec3f& w) const {
  float cos2 = cos2_theta(w);
  if (!(cos2 > 0.0f)) return 0.0f;
  // α²(φ) tan²θ = (αx² x² + αy² y²) / z².
  float alpha2_tan2 = (alpha_x_ * alpha_x_ * w.x * w.x + alpha_y_ * alpha_y_ * w.y * w.y) / cos2;
  return (std::sqrt(1.0f + alpha2_tan2) - 1.0f) / 2.0f;
}

float TrowbridgeReitz::d_visible(const Vec3f& w, const Vec3f& wm) const {
  float cos_w = abs_cos_theta(w);
  if (cos_w == 0.0f) return 0.0f;
  return g1(w) / cos_w * d(wm) * abs_dot(w, wm);
}

Vec3f TrowbridgeReitz::sample_wm(const Vec3f& w, Point2f u) const {
  // Stretch the view direction to the hemisphere configuration (α = 1).
  Vec3f wh = normalize(Vec3f(alpha_x_ * w.x, alpha_y_ * w.y, w.z));
  if (wh.z < 0) wh = -wh;
  Vec3f t1 = wh.z < 0.99999f ? normalize(cross(Vec3f(0, 0, 1), wh)) : Vec3f(1, 0, 0);
  Vec3f t2 = cross(wh, t1);
  // Uniform point on the disk, warped to the projected visible hemisphere.
  float r = std::sqrt(u.x);
  float phi = 2.0f * kPi * u.y;
  float px = r * std::cos(phi), py = r * std::sin(phi);
  float h = std::sqrt(1.0f - px * px);
  float s = (1.0f + wh.z) / 2.0f;
  py = (1.0f - s) * h + s * py;
  float pz = safe_sqrt(1.0f - px * px - py * py);
  Vec3f nh = t1 * px + t2 * py + wh * pz;
  // Unstretch back to the ellipsoid configuration.
  return normalize(Vec3f(alpha_x_ * nh.x, alpha_y_ * nh.y, std::max(1e-6f, nh.z)));
}

}  // namespace prism::worker
