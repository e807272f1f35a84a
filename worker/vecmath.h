// Small float vector algebra for the tracer: 3-vectors, 2-points and orthonormal frames. Shading
// happens in a local frame whose z axis is the shading normal, so BSDFs read cos θ as v.z.
// Everything is a trivially copyable value and inline; nothing allocates.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>

namespace prism::worker {

inline constexpr float kPi = 3.14159265358979323846f;
inline constexpr float kInvPi = 0.31830988618379067154f;
// The distance of a ray that has no end (to the environment).
inline constexpr float kInfinity = std::numeric_limits<float>::infinity();

struct Vec3f {
  float x = 0, y = 0, z = 0;

  constexpr Vec3f() = default;
  constexpr Vec3f(float x_, float y_, float z_) : x(x_), y(y_), z(z_) {}

  float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  float& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
  Vec3f& operator+=(const Vec3f& o) { x += o.x, y += o.y, z += o.z; return *this; }
  Vec3f& operator-=(const Vec3f& o) { x -= o.x, y -= o.y, z -= o.z; return *this; }
  Vec3f& operator*=(float s) { x *= s, y *= s, z *= s; return *this; }
  friend Vec3f operator+(Vec3f a, const Vec3f& b) { return a += b; }
  friend Vec3f operator-(Vec3f a, const Vec3f& b) { return a -= b; }
  friend Vec3f operator*(Vec3f a, float s) { return a *= s; }
  friend Vec3f operator*(float s, Vec3f a) { return a *= s; }
  friend Vec3f operator/(Vec3f a, float s) { return a *= 1.0f / s; }
  friend Vec3f operator-(const Vec3f& a) { return {-a.x, -a.y, -a.z}; }
  friend bool operator==(const Vec3f&, const Vec3f&) = default;
};

struct Point2f {
  float x = 0, y = 0;
};

inline float dot(const Vec3f& a, const Vec3f& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline float abs_dot(const Vec3f& a, const Vec3f& b) { return std::abs(dot(a, b)); }
inline Vec3f cross(const Vec3f& a, const Vec3f& b) {
  // Products in double: the difference of nearly equal products loses most float bits.
  double x = double(a.y) * b.z - double(a.z) * b.y;
  double y = double(a.z) * b.x - double(a.x) * b.z;
  double z = double(a.x) * b.y - double(a.y) * b.x;
  return {float(x), float(y), float(z)};
}
inline float length_squared(const Vec3f& v) { return dot(v, v); }
inline float length(const Vec3f& v) { return std::sqrt(dot(v, v)); }
inline Vec3f normalize(const Vec3f& v) { return v / length(v); }
inline Vec3f face_forward(const Vec3f& n, const Vec3f& v) { return dot(n, v) < 0 ? -n : n; }
inline bool is_finite(const Vec3f& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

// Local shading coordinates: the z axis is the (shading) normal.
inline float cos_theta(const Vec3f& w) { return w.z; }
inline float abs_cos_theta(const Vec3f& w) { return std::abs(w.z); }
inline float cos2_theta(const Vec3f& w) { return w.z * w.z; }
inline float sin2_theta(const Vec3f& w) { return std::max(0.0f, 1.0f - cos2_theta(w)); }
inline float tan2_theta(const Vec3f& w) { return sin2_theta(w) / cos2_theta(w); }
inline bool same_hemisphere(const Vec3f& a, const Vec3f& b) { return a.z * b.z > 0; }
inline float safe_sqrt(float x) { return std::sqrt(std::max(0.0f, x)); }

// An orthonormal basis (Duff et al. 2017, "Building an Orthonormal Basis, Revisited").
struct Frame {
  Vec3f s, t, n;

  static Frame from_z(const Vec3f& n) {
    float sign = std::copysign(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    return {{1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x}, {b, sign + n.y * n.y * a, -n.y}, n};
  }
  // Frame with z = n and x as close as possible to the tangent `dpdu` (for anisotropic BSDFs).
  static Frame from_xz(const Vec3f& dpdu, const Vec3f& n) {
    Vec3f s = dpdu - n * dot(n, dpdu);
    float len2 = length_squared(s);
    if (!(len2 > 1e-12f)) return from_z(n);
    s = s / std::sqrt(len2);
    return {s, cross(n, s), n};
  }
  Vec3f to_local(const Vec3f& v) const { return {dot(v, s), dot(v, t), dot(v, n)}; }
  Vec3f from_local(const Vec3f& v) const { return s * v.x + t * v.y + n * v.z; }
};

// Cosine-weighted direction on the upper hemisphere (Malley's method on a concentric disk);
// pdf = cos θ / π.
Vec3f sample_cosine_hemisphere(Point2f u);
Point2f sample_uniform_disk_concentric(Point2f u);
// Uniform direction on the sphere; pdf = 1 / 4π.
Vec3f sample_uniform_sphere(Point2f u);

}  // namespace prism::worker
