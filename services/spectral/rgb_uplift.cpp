#include "services/spectral/rgb_uplift.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"

namespace prism::spectral {
namespace {

constexpr int kSamples = 471;  // 1 nm over Λ

using Vec3 = std::array<double, 3>;
using Mat3 = std::array<std::array<double, 3>, 3>;

// Solves m·x = v by Cramer's rule; false when m is (numerically) singular.
bool solve3(const Mat3& m, const Vec3& v, Vec3& x) {
  auto det = [](const Mat3& a) {
    return a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) -
           a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) +
           a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
  };
  const double d = det(m);
  if (!(std::abs(d) > 1e-300) || !std::isfinite(d)) return false;
  for (int c = 0; c < 3; ++c) {
    Mat3 mc = m;
    for (int r = 0; r < 3; ++r) mc[r][c] = v[r];
    x[c] = det(mc) / d;
  }
  return true;
}

// f of CIELAB and its derivative.
constexpr double kDelta = 6.0 / 29.0;
double lab_f(double t) {
  return t > kDelta * kDelta * kDelta ? std::cbrt(t) : t / (3.0 * kDelta * kDelta) + 4.0 / 29.0;
}
double lab_df(double t) {
  if (t > kDelta * kDelta * kDelta) {
    const double c = std::cbrt(t);
    return 1.0 / (3.0 * c * c);
  }
  return 1.0 / (3.0 * kDelta * kDelta);
}

// S⁻¹ for the constant spectrum v ∈ [0, 1]: x = 2y / √(1 − 4y²), y = v − 1/2.
float inverse_sigmoid(float v) {
  if (v <= 0.0f) return -std::numeric_limits<float>::infinity();
  if (v >= 1.0f) return std::numeric_limits<float>::infinity();
  const double y = static_cast<double>(v) - 0.5;
  return static_cast<float>(2.0 * y / std::sqrt(1.0 - 4.0 * y * y));
}

}  // namespace

RgbUplift::RgbUplift(const ColorMatching& cmf)
    : d65_(std::make_shared<const PiecewiseLinearSpectrum>(cie_d65())),
      cache_(std::make_unique<Cache>()) {
  const PiecewiseLinearSpectrum& d65 = *d65_;
  weights_.resize(kSamples);
  double y_sum = 0.0;
  for (int i = 0; i < kSamples; ++i) {
    const float l = kLambdaMin + static_cast<float>(i);
    const Xyz c = cmf.cmf(l);
    const double e = d65(l);
    weights_[i] = {c.x * e, c.y * e, c.z * e};
    y_sum += c.y * e;
  }
  for (auto& w : weights_) {
    for (double& v : w) v /= y_sum;
    white_.x += w[0];
    white_.y += w[1];
    white_.z += w[2];
  }
}

Rgb RgbUplift::to_rgb(const SigmoidPolynomial& p) const {
  Xyz xyz;
  for (int i = 0; i < kSamples; ++i) {
    const double s = p(kLambdaMin + static_cast<float>(i));
    xyz.x += weights_[i][0] * s;
    xyz.y += weights_[i][1] * s;
    xyz.z += weights_[i][2] * s;
  }
  return xyz_to_linear_srgb(xyz);
}

size_t RgbUplift::cache_size() const {
  std::lock_guard<std::mutex> lock(cache_->mu);
  return cache_->fits.size();
}

absl::StatusOr<SigmoidPolynomial> RgbUplift::fit(const Rgb& rgb) const {
  for (double v : {rgb.r, rgb.g, rgb.b}) {
    if (!std::isfinite(v) || v < 0.0 || v > 1.0) {
      return absl::InvalidArgumentError(absl::StrCat(
          "RGB reflectance (", rgb.r, ", ", rgb.g, ", ", rgb.b,
          ") must have every channel within [0, 1]: a reflectance above 1 would create energy; "
          "scale it down, or describe an emitter with an illuminant spectrum instead"));
    }
  }
  const std::array<float, 3> key = {static_cast<float>(rgb.r), static_cast<float>(rgb.g),
                                    static_cast<float>(rgb.b)};
  {
    std::lock_guard<std::mutex> lock(cache_->mu);
    if (auto it = cache_->fits.find(key); it != cache_->fits.end()) return it->second;
  }
  // Solved outside the lock so concurrent fits of different colours proceed in parallel; two
  // threads fitting the same colour compute the same deterministic answer, and the first stays.
  const SigmoidPolynomial p = solve(key);
  std::lock_guard<std::mutex> lock(cache_->mu);
  return cache_->fits.try_emplace(key, p).first->second;
}

absl::StatusOr<RgbAlbedoSpectrum> RgbUplift::albedo(const Rgb& rgb) const {
  auto p = fit(rgb);
  if (!p.ok()) return p.status();
  return RgbAlbedoSpectrum{*p};
}

absl::StatusOr<RgbUnboundedSpectrum> RgbUplift::scaled_fit(const Rgb& rgb) const {
  for (double v : {rgb.r, rgb.g, rgb.b}) {
    if (!std::isfinite(v) || v < 0.0) {
      return absl::InvalidArgumentError(absl::StrCat("RGB value (", rgb.r, ", ", rgb.g, ", ", rgb.b,
                                                     ") must have finite channels >= 0"));
    }
  }
  const double m = 2.0 * std::max({rgb.r, rgb.g, rgb.b});
  if (m == 0.0) return RgbUnboundedSpectrum{0.0f, SigmoidPolynomial{0.0f, 0.0f, 0.0f}};
  auto p = fit({rgb.r / m, rgb.g / m, rgb.b / m});
  if (!p.ok()) return p.status();
  return RgbUnboundedSpectrum{static_cast<float>(m), *p};
}

absl::StatusOr<RgbUnboundedSpectrum> RgbUplift::unbounded(const Rgb& rgb) const {
  return scaled_fit(rgb);
}

absl::StatusOr<RgbIlluminantSpectrum> RgbUplift::illuminant(const Rgb& rgb) const {
  auto s = scaled_fit(rgb);
  if (!s.ok()) return s.status();
  return RgbIlluminantSpectrum{s->scale, s->polynomial, d65_};
}

SigmoidPolynomial RgbUplift::solve(const std::array<float, 3>& rgb) const {
  if (rgb[0] == rgb[1] && rgb[1] == rgb[2]) return {0.0f, 0.0f, inverse_sigmoid(rgb[0])};

  // Lab of a coefficient vector and its Jacobian with respect to the coefficients.
  auto evaluate = [this](const Vec3& c, Vec3& lab, Mat3* jac) {
    Vec3 xyz{};
    Mat3 dxyz{};
    for (int i = 0; i < kSamples; ++i) {
      const double t = static_cast<double>(i) / (kSamples - 1);
      const double x = (c[0] * t + c[1]) * t + c[2];
      const double q = 1.0 + x * x;
      const double s = 0.5 + x / (2.0 * std::sqrt(q));
      const double ds = 1.0 / (2.0 * q * std::sqrt(q));
      const Vec3 dx = {t * t, t, 1.0};
      for (int k = 0; k < 3; ++k) {
        xyz[k] += weights_[i][k] * s;
        if (jac) {
          for (int j = 0; j < 3; ++j) dxyz[k][j] += weights_[i][k] * ds * dx[j];
        }
      }
    }
    const Vec3 white = {white_.x, white_.y, white_.z};
    Vec3 f, df;
    for (int k = 0; k < 3; ++k) {
      f[k] = lab_f(xyz[k] / white[k]);
      df[k] = lab_df(xyz[k] / white[k]) / white[k];
    }
    lab = {116.0 * f[1] - 16.0, 500.0 * (f[0] - f[1]), 200.0 * (f[1] - f[2])};
    if (jac) {
      for (int j = 0; j < 3; ++j) {
        const double fx = df[0] * dxyz[0][j], fy = df[1] * dxyz[1][j], fz = df[2] * dxyz[2][j];
        (*jac)[0][j] = 116.0 * fy;
        (*jac)[1][j] = 500.0 * (fx - fy);
        (*jac)[2][j] = 200.0 * (fy - fz);
      }
    }
  };
  auto target_lab = [this](const Vec3& target_rgb) {
    const Xyz t = linear_srgb_to_xyz({target_rgb[0], target_rgb[1], target_rgb[2]});
    return xyz_to_lab(t, white_);
  };

  const Vec3 goal = {rgb[0], rgb[1], rgb[2]};
  const double grey = (goal[0] + goal[1] + goal[2]) / 3.0;
  Vec3 c = {0.0, 0.0, static_cast<double>(inverse_sigmoid(static_cast<float>(grey)))};
  constexpr int kSteps = 12;
  for (int step = 1; step <= kSteps; ++step) {
    const double a = static_cast<double>(step) / kSteps;
    const Vec3 target_rgb = {grey + a * (goal[0] - grey), grey + a * (goal[1] - grey),
                             grey + a * (goal[2] - grey)};
    const Lab tl = target_lab(target_rgb);
    const Vec3 target = {tl.l, tl.a, tl.b};
    auto residual_of = [&](const Vec3& lab) {
      return Vec3{lab[0] - target[0], lab[1] - target[1], lab[2] - target[2]};
    };
    auto norm2 = [](const Vec3& r) { return r[0] * r[0] + r[1] * r[1] + r[2] * r[2]; };
    double mu = 1e-6;
    Vec3 lab;
    Mat3 j;
    evaluate(c, lab, &j);
    Vec3 r = residual_of(lab);
    const int iterations = step == kSteps ? 100 : 20;
    for (int it = 0; it < iterations && norm2(r) > 1e-20; ++it) {
      // Levenberg–Marquardt: (JᵀJ + μ·diag(JᵀJ)) δ = −Jᵀr; μ shrinks on success, grows on failure.
      Mat3 jtj{};
      Vec3 jtr{};
      for (int a2 = 0; a2 < 3; ++a2) {
        for (int b2 = 0; b2 < 3; ++b2) {
          for (int k = 0; k < 3; ++k) jtj[a2][b2] += j[k][a2] * j[k][b2];
        }
        for (int k = 0; k < 3; ++k) jtr[a2] -= j[k][a2] * r[k];
      }
      bool improved = false;
      for (int attempt = 0; attempt < 20 && !improved; ++attempt) {
        Mat3 m = jtj;
        for (int d = 0; d < 3; ++d) m[d][d] += mu * (jtj[d][d] + 1e-12);
        Vec3 delta;
        if (!solve3(m, jtr, delta)) {
          mu *= 10.0;
          continue;
        }
        const Vec3 trial = {c[0] + delta[0], c[1] + delta[1], c[2] + delta[2]};
        Vec3 trial_lab;
        evaluate(trial, trial_lab, nullptr);
        const Vec3 trial_r = residual_of(trial_lab);
        if (norm2(trial_r) < norm2(r)) {
          c = trial;
          mu = std::max(mu * 0.1, 1e-12);
          improved = true;
        } else {
          mu *= 10.0;
        }
      }
      if (!improved) break;
      evaluate(c, lab, &j);
      r = residual_of(lab);
    }
  }
  return {static_cast<float>(c[0]), static_cast<float>(c[1]), static_cast<float>(c[2])};
}

}  // namespace prism::spectral
