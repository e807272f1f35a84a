#include "worker/fresnel.h"

#include <complex>

namespace prism::worker {

float fresnel_dielectric(float cos_theta_i, float eta) {
  cos_theta_i = std::clamp(cos_theta_i, -1.0f, 1.0f);
  if (cos_theta_i < 0.0f) {
    eta = 1.0f / eta;
    cos_theta_i = -cos_theta_i;
  }
  float sin2_i = 1.0f - cos_theta_i * cos_theta_i;
  float sin2_t = sin2_i / (eta * eta);
  if (sin2_t >= 1.0f) return 1.0f;
  float cos_t = safe_sqrt(1.0f - sin2_t);
  float r_parl = (eta * cos_theta_i - cos_t) / (eta * cos_theta_i + cos_t);
  float r_perp = (cos_theta_i - eta * cos_t) / (cos_theta_i + eta * cos_t);
  return (r_parl * r_parl + r_perp * r_perp) / 2.0f;
}

float fresnel_complex(float cos_theta_i, float eta, float k) {
  using Complex = std::complex<float>;
  cos_theta_i = std::clamp(cos_theta_i, 0.0f, 1.0f);
  Complex n(eta, k);
  // η = k = 0 (a user's conductor; 15 % of samples were NaN): the limit of a vanishing index is
  // total reflection at every angle.
  if (std::norm(n) < 1e-12f) return 1.0f;
  float sin2_i = 1.0f - cos_theta_i * cos_theta_i;
  Complex sin2_t = sin2_i / (n * n);
  Complex cos_t = std::sqrt(Complex(1.0f) - sin2_t);
  Complex r_parl = (n * cos_theta_i - cos_t) / (n * cos_theta_i + cos_t);
  Complex r_perp = (cos_theta_i - n * cos_t) / (cos_theta_i + n * cos_t);
  return (std::norm(r_parl) + std::norm(r_perp)) / 2.0f;
}

std::optional<Refraction> refract(const Vec3f& wi, Vec3f n, float eta) {
  float cos_i = dot(n, wi);
  if (cos_i < 0.0f) {
    eta = 1.0f / eta;
    cos_i = -cos_i;
    n = -n;
  }
  float sin2_i = std::max(0.0f, 1.0f - cos_i * cos_i);
  float sin2_t = sin2_i / (eta * eta);
  if (sin2_t >= 1.0f) return std::nullopt;
  float cos_t = safe_sqrt(1.0f - sin2_t);
  return Refraction{-wi / eta + (cos_i / eta - cos_t) * n, eta};
}

}  // namespace prism::worker
