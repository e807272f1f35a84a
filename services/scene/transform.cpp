#include "services/scene/transform.h"

#include <cmath>
#include <numbers>

namespace prism::scene {
namespace {

Matrix4 identity_matrix() {
  Matrix4 m{};
  for (int i = 0; i < 4; ++i) m[i][i] = 1.0;
  return m;
}

bool all_finite(const Matrix4& m) {
  for (const auto& row : m)
    for (double v : row)
      if (!std::isfinite(v)) return false;
  return true;
}

Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

double length(const Vec3& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

Vec3 normalized(const Vec3& v) {
  double l = length(v);
  return {v[0] / l, v[1] / l, v[2] / l};
}

}  // namespace

Matrix4 multiply(const Matrix4& a, const Matrix4& b) {
  Matrix4 r{};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      double s = 0.0;
      for (int k = 0; k < 4; ++k) s += a[i][k] * b[k][j];
      r[i][j] = s;
    }
  return r;
}

Matrix4 transpose(const Matrix4& m) {
  Matrix4 r{};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) r[i][j] = m[j][i];
  return r;
}

std::optional<Matrix4> invert(const Matrix4& m) {
  if (!all_finite(m)) return std::nullopt;
  // Gauss-Jordan elimination with partial pivoting.
  Matrix4 a = m;
  Matrix4 inv = identity_matrix();
  for (int col = 0; col < 4; ++col) {
    int pivot = col;
    for (int r = col + 1; r < 4; ++r)
      if (std::abs(a[r][col]) > std::abs(a[pivot][col])) pivot = r;
    if (std::abs(a[pivot][col]) < 1e-300) return std::nullopt;
    std::swap(a[pivot], a[col]);
    std::swap(inv[pivot], inv[col]);
    double d = a[col][col];
    for (int j = 0; j < 4; ++j) {
      a[col][j] /= d;
      inv[col][j] /= d;
    }
    for (int r = 0; r < 4; ++r) {
      if (r == col) continue;
      double f = a[r][col];
      if (f == 0.0) continue;
      for (int j = 0; j < 4; ++j) {
        a[r][j] -= f * a[col][j];
        inv[r][j] -= f * inv[col][j];
      }
    }
  }
  if (!all_finite(inv)) return std::nullopt;
  return inv;
}

Transform::Transform() : m_(identity_matrix()), m_inv_(identity_matrix()) {}

std::optional<Transform> Transform::from_matrix(const Matrix4& m) {
  std::optional<Matrix4> inv = invert(m);
  if (!inv) return std::nullopt;
  return Transform(m, *inv);
}

Transform Transform::translate(const Vec3& d) {
  Matrix4 m = identity_matrix();
  Matrix4 inv = identity_matrix();
  for (int i = 0; i < 3; ++i) {
    m[i][3] = d[i];
    inv[i][3] = -d[i];
  }
  return Transform(m, inv);
}

std::optional<Transform> Transform::scale(const Vec3& s) {
  if (s[0] == 0.0 || s[1] == 0.0 || s[2] == 0.0) return std::nullopt;
  Matrix4 m = identity_matrix();
  Matrix4 inv = identity_matrix();
  for (int i = 0; i < 3; ++i) {
    m[i][i] = s[i];
    inv[i][i] = 1.0 / s[i];
  }
  return Transform(m, inv);
}

std::optional<Transform> Transform::rotate(double angle_deg, const Vec3& axis) {
  if (length(axis) == 0.0) return std::nullopt;
  Vec3 a = normalized(axis);
  double theta = angle_deg * std::numbers::pi / 180.0;
  double s = std::sin(theta);
  double c = std::cos(theta);
  Matrix4 m = identity_matrix();
  m[0][0] = a[0] * a[0] + (1 - a[0] * a[0]) * c;
  m[0][1] = a[0] * a[1] * (1 - c) - a[2] * s;
  m[0][2] = a[0] * a[2] * (1 - c) + a[1] * s;
  m[1][0] = a[0] * a[1] * (1 - c) + a[2] * s;
  m[1][1] = a[1] * a[1] + (1 - a[1] * a[1]) * c;
  m[1][2] = a[1] * a[2] * (1 - c) - a[0] * s;
  m[2][0] = a[0] * a[2] * (1 - c) - a[1] * s;
  m[2][1] = a[1] * a[2] * (1 - c) + a[0] * s;
  m[2][2] = a[2] * a[2] + (1 - a[2] * a[2]) * c;
  // A rotation's inverse is its transpose.
  return Transform(m, transpose(m));
}

std::optional<Transform> Transform::look_at(const Vec3& eye, const Vec3& look, const Vec3& up) {
  Vec3 d = {look[0] - eye[0], look[1] - eye[1], look[2] - eye[2]};
  if (length(d) == 0.0 || length(up) == 0.0) return std::nullopt;
  Vec3 dir = normalized(d);
  Vec3 right_raw = cross(normalized(up), dir);
  if (length(right_raw) < 1e-12) return std::nullopt;
  Vec3 right = normalized(right_raw);
  Vec3 new_up = cross(dir, right);
  Matrix4 world_from_camera = identity_matrix();
  for (int i = 0; i < 3; ++i) {
    world_from_camera[i][0] = right[i];
    world_from_camera[i][1] = new_up[i];
    world_from_camera[i][2] = dir[i];
    world_from_camera[i][3] = eye[i];
  }
  std::optional<Matrix4> camera_from_world = invert(world_from_camera);
  if (!camera_from_world) return std::nullopt;
  return Transform(*camera_from_world, world_from_camera);
}

Transform Transform::inverse() const { return Transform(m_inv_, m_); }

Vec3 Transform::apply_point(const Vec3& p) const {
  Vec3 r{};
  for (int i = 0; i < 3; ++i) r[i] = m_[i][0] * p[0] + m_[i][1] * p[1] + m_[i][2] * p[2] + m_[i][3];
  double w = m_[3][0] * p[0] + m_[3][1] * p[1] + m_[3][2] * p[2] + m_[3][3];
  if (w != 1.0 && w != 0.0)
    for (double& v : r) v /= w;
  return r;
}

Vec3 Transform::apply_vector(const Vec3& v) const {
  Vec3 r{};
  for (int i = 0; i < 3; ++i) r[i] = m_[i][0] * v[0] + m_[i][1] * v[1] + m_[i][2] * v[2];
  return r;
}

Vec3 Transform::apply_normal(const Vec3& n) const {
  Vec3 r{};
  for (int i = 0; i < 3; ++i) r[i] = m_inv_[0][i] * n[0] + m_inv_[1][i] * n[1] + m_inv_[2][i] * n[2];
  return r;
}

bool Transform::swaps_handedness() const {
  const Matrix4& m = m_;
  double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
               m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
               m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  return det < 0.0;
}

bool Transform::is_identity() const { return m_ == identity_matrix(); }

Transform operator*(const Transform& a, const Transform& b) {
  return Transform(multiply(a.m_, b.m_), multiply(b.m_inv_, a.m_inv_));
}

}  // namespace prism::scene
