#include "worker/vecmath.h"

namespace prism::worker {

Point2f sample_uniform_disk_concentric(Point2f u) {
  float ox = 2.0f * u.x - 1.0f, oy = 2.0f * u.y - 1.0f;
  if (ox == 0.0f && oy == 0.0f) return {0.0f, 0.0f};
  float r, theta;
  if (std::abs(ox) > std::abs(oy)) {
    r = ox;
    theta = (kPi / 4.0f) * (oy / ox);
  } else {
    r = oy;
    theta = kPi / 2.0f - (kPi / 4.0f) * (ox / oy);
  }
  return {r * std::cos(theta), r * std::sin(theta)};
}

Vec3f sample_cosine_hemisphere(Point2f u) {
  Point2f d = sample_uniform_disk_concentric(u);
  float z = safe_sqrt(1.0f - d.x * d.x - d.y * d.y);
  return {d.x, d.y, z};
}

Vec3f sample_uniform_sphere(Point2f u) {
  float z = 1.0f - 2.0f * u.x;
  float r = safe_sqrt(1.0f - z * z);
  float phi = 2.0f * kPi * u.y;
  return {r * std::cos(phi), r * std::sin(phi), z};
}

}  // namespace prism::worker
