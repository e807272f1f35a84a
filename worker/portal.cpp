#include "worker/portal.h"

#include <cmath>

namespace prism::worker {
namespace {

using D3 = std::array<double, 3>;

D3 sub(const scene::Vec3& a, const scene::Vec3& b) {
  return {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
}
double dot3(const D3& a, const D3& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
D3 unit(const D3& v) {
  const double l = std::sqrt(dot3(v, v));
  return {v[0] / l, v[1] / l, v[2] / l};
}
D3 d3(const Vec3f& v) {
  return {v.x, v.y, v.z};
}

// The solid angle per unit α·β at the local unit direction w.
double jacobian(const D3& w) {
  return (1 - w[0] * w[0]) * (1 - w[1] * w[1]) / w[2];
}

}  // namespace

Portal Portal::create(const std::array<scene::Vec3, 4>& corners) {
  Portal p;
  p.origin_ = {corners[0][0], corners[0][1], corners[0][2]};
  const D3 e03 = sub(corners[3], corners[0]);
  const D3 e01 = sub(corners[1], corners[0]);
  p.width_ = std::sqrt(dot3(e03, e03));
  p.height_ = std::sqrt(dot3(e01, e01));
  p.x_ = unit(e03);
  // y is e01 made exactly orthogonal to x (the parser allows a 1e-3 slack).
  const double c = dot3(e01, p.x_);
  p.y_ = unit(D3{e01[0] - c * p.x_[0], e01[1] - c * p.x_[1], e01[2] - c * p.x_[2]});
  p.z_ = {p.x_[1] * p.y_[2] - p.x_[2] * p.y_[1], p.x_[2] * p.y_[0] - p.x_[0] * p.y_[2],
          p.x_[0] * p.y_[1] - p.x_[1] * p.y_[0]};
  return p;
}

bool Portal::box_from(const Vec3f& p, Box* box) const {
  const D3 d{double(p.x) - origin_[0], double(p.y) - origin_[1], double(p.z) - origin_[2]};
  const double qx = dot3(d, x_), qy = dot3(d, y_), qz = dot3(d, z_);
  if (!(qz < 0)) return false;  // on or in front of the portal's plane
  const double depth = -qz;
  box->alpha0 = std::atan2(-qx, depth);
  box->alpha1 = std::atan2(width_ - qx, depth);
  box->beta0 = std::atan2(-qy, depth);
  box->beta1 = std::atan2(height_ - qy, depth);
  return box->alpha1 > box->alpha0 && box->beta1 > box->beta0;
}

bool Portal::passes(const Vec3f& p, const Vec3f& w) const {
  return pdf(p, w) > 0;
}

std::optional<Portal::Sample> Portal::sample(const Vec3f& p, Point2f u) const {
  Box b;
  if (!box_from(p, &b)) return std::nullopt;
  const double alpha = b.alpha0 + (b.alpha1 - b.alpha0) * u.x;
  const double beta = b.beta0 + (b.beta1 - b.beta0) * u.y;
  const D3 local = unit(D3{std::tan(alpha), std::tan(beta), 1.0});
  const double j = jacobian(local);
  if (!(j > 0) || !std::isfinite(j)) return std::nullopt;
  Sample s;
  s.w = Vec3f(float(local[0] * x_[0] + local[1] * y_[0] + local[2] * z_[0]),
              float(local[0] * x_[1] + local[1] * y_[1] + local[2] * z_[1]),
              float(local[0] * x_[2] + local[1] * y_[2] + local[2] * z_[2]));
  s.pdf = float(1 / ((b.alpha1 - b.alpha0) * (b.beta1 - b.beta0) * j));
  if (!(s.pdf > 0) || !std::isfinite(s.pdf)) return std::nullopt;
  return s;
}

float Portal::pdf(const Vec3f& p, const Vec3f& w) const {
  const D3 wd = unit(d3(w));
  const D3 local{dot3(wd, x_), dot3(wd, y_), dot3(wd, z_)};
  if (!(local[2] > 0)) return 0;
  Box b;
  if (!box_from(p, &b)) return 0;
  const double alpha = std::atan2(local[0], local[2]);
  const double beta = std::atan2(local[1], local[2]);
  if (alpha < b.alpha0 || alpha > b.alpha1 || beta < b.beta0 || beta > b.beta1) return 0;
  const double j = jacobian(local);
  if (!(j > 0)) return 0;
  return float(1 / ((b.alpha1 - b.alpha0) * (b.beta1 - b.beta0) * j));
}

}  // namespace prism::worker
