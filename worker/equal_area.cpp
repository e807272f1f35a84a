#include "worker/equal_area.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <utility>

namespace prism::worker {

Vec3f equal_area_square_to_sphere(Point2f p) {
  // pbrt-v4's EqualAreaSquareToSphere (Clarberg's octahedral equal-area map).
  const double u = 2.0 * p.x - 1.0, v = 2.0 * p.y - 1.0;
  const double up = std::abs(u), vp = std::abs(v);
  const double signed_distance = 1.0 - (up + vp);
  const double d = std::abs(signed_distance);
  const double r = 1.0 - d;
  const double phi = (r == 0.0 ? 1.0 : (vp - up) / r + 1.0) * std::numbers::pi / 4.0;
  const double z = std::copysign(1.0 - r * r, signed_distance);
  const double cos_phi = std::copysign(std::cos(phi), u);
  const double sin_phi = std::copysign(std::sin(phi), v);
  const double s = r * std::sqrt(std::max(0.0, 2.0 - r * r));
  return {float(cos_phi * s), float(sin_phi * s), float(z)};
}

Point2f equal_area_sphere_to_square(const Vec3f& d) {
  const float x = std::abs(d.x), y = std::abs(d.y), z = std::abs(d.z);
  const float r = std::sqrt(std::max(0.0f, 1 - z));
  const float a = std::max(x, y);
  const float b = a == 0 ? 0 : std::min(x, y) / a;
  float phi = std::atan(b) * (2 / kPi);
  if (x < y) phi = 1 - phi;
  float v = phi * r;
  float u = r - v;
  if (d.z < 0) {
    std::swap(u, v);
    u = 1 - u;
    v = 1 - v;
  }
  u = std::copysign(u, d.x);
  v = std::copysign(v, d.y);
  return {(u + 1) * 0.5f, (v + 1) * 0.5f};
}

}  // namespace prism::worker
