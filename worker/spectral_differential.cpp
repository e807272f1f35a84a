#include "worker/spectral_differential.h"

#include <cmath>

namespace prism::worker {
namespace {

// Below this ω = cos θ_t the refracted direction's derivative (∝ 1/ω) is not meaningful in
// float: the ray leaves almost along the surface.
constexpr float kMinCosTransmitted = 1e-5f;

}  // namespace

RelativeEta relative_eta(double n_incident, double dn_incident, double n_transmitted,
                         double dn_transmitted) {
  return {float(n_incident / n_transmitted),
          float((dn_incident * n_transmitted - n_incident * dn_transmitted) /
                (n_transmitted * n_transmitted))};
}

bool transfer(SpectralDifferential& diff, const Vec3f& d, float t, const Vec3f& n) {
  if (!diff.tracked) return true;
  const float dn = dot(d, n);
  if (!(std::abs(dn) > 1e-7f)) {
    diff.tracked = false;
    return false;
  }
  const Vec3f moved = diff.dp + diff.dd * t;
  const float dt = -dot(moved, n) / dn;
  diff.dp = moved + d * dt;
  return true;
}

void reflect(SpectralDifferential& diff, const Vec3f& d, const Vec3f& n, const Vec3f& dn) {
  if (!diff.tracked) return;
  const float cos = dot(d, n);
  const float dcos = dot(diff.dd, n) + dot(d, dn);
  diff.dd = diff.dd - (n * dcos + dn * cos) * 2.0f;
}

bool refract(SpectralDifferential& diff, const Vec3f& d, const Vec3f& n_any, const Vec3f& dn_any,
             RelativeEta eta) {
  if (!diff.tracked) {
    if (eta.deta == 0.0f) return true;
    diff = SpectralDifferential{{}, {}, true};
  }
  // Eq. 1 wants n facing the incoming ray.
  const bool flip = dot(d, n_any) > 0;
  const Vec3f n = flip ? -n_any : n_any;
  const Vec3f dn = flip ? -dn_any : dn_any;
  const float e = eta.eta, de = eta.deta;
  const float theta = dot(d, n);
  const float omega2 = 1.0f - e * e + e * e * theta * theta;
  if (!(omega2 > kMinCosTransmitted * kMinCosTransmitted)) {
    diff.tracked = false;
    return false;
  }
  const float omega = std::sqrt(omega2);
  const float mu = e * theta + omega;
  const float dtheta = dot(diff.dd, n) + dot(d, dn);
  const float domega = (-e * de + e * de * theta * theta + e * e * theta * dtheta) / omega;
  const float dmu = de * theta + e * dtheta + domega;
  diff.dd = d * de + diff.dd * e - n * dmu - dn * mu;
  return true;
}

Vec3f microfacet_normal_differential(const Vec3f& n, const Vec3f& dn, const Vec3f& m) {
  return cross(cross(n, dn), m);
}

}  // namespace prism::worker
