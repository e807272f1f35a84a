// Affine transforms of the scene description: a 4x4 matrix and its inverse, kept together so
// points, vectors and normals can be moved either way without re-inverting. Matrices are
// row-major and act on column vectors (p' = M p), like pbrt-v4; composition `a * b` applies b
// first. Invariant: m * m_inv == identity (up to rounding); a Transform is never singular,
// because the only way to build one from arbitrary numbers (from_matrix) refuses singular
// matrices. Angles are in degrees, as in the pbrt file format.
#pragma once

#include <array>
#include <optional>

namespace prism::scene {

using Matrix4 = std::array<std::array<double, 4>, 4>;
using Vec3 = std::array<double, 3>;

class Transform {
 public:
  Transform();  // identity

  // A general matrix; nullopt when it is singular or not finite.
  static std::optional<Transform> from_matrix(const Matrix4& m);

  static Transform translate(const Vec3& d);
  // nullopt when a factor is zero (singular).
  static std::optional<Transform> scale(const Vec3& s);
  // Rotation by angle_deg about axis (right-hand rule in matrix terms, as pbrt-v4's Rotate);
  // nullopt for a zero axis.
  static std::optional<Transform> rotate(double angle_deg, const Vec3& axis);
  // pbrt-v4 LookAt: the camera-from-world transform of a camera at `eye` looking at `look`
  // with `up`: camera +z = normalize(look - eye), camera +x = normalize(cross(up, dir)),
  // camera +y = cross(dir, x). This is a left-handed frame in a left-handed world: with the
  // camera looking down world +z and up = +y, camera +x is world +x. nullopt when eye == look
  // or up is parallel to the view direction.
  static std::optional<Transform> look_at(const Vec3& eye, const Vec3& look, const Vec3& up);

  const Matrix4& matrix() const { return m_; }
  const Matrix4& inverse_matrix() const { return m_inv_; }
  Transform inverse() const;

  Vec3 apply_point(const Vec3& p) const;
  Vec3 apply_vector(const Vec3& v) const;
  // Normals transform by the inverse transpose.
  Vec3 apply_normal(const Vec3& n) const;

  // True when the 3x3 linear part has a negative determinant (a mirror): pbrt-v4 then flips
  // geometric normals of shapes (see scene_description.h).
  bool swaps_handedness() const;
  bool is_identity() const;

  friend Transform operator*(const Transform& a, const Transform& b);
  friend bool operator==(const Transform& a, const Transform& b) { return a.m_ == b.m_; }

 private:
  Transform(const Matrix4& m, const Matrix4& m_inv) : m_(m), m_inv_(m_inv) {}
  Matrix4 m_;
  Matrix4 m_inv_;
};

Matrix4 multiply(const Matrix4& a, const Matrix4& b);
Matrix4 transpose(const Matrix4& m);
// nullopt when singular or not finite.
std::optional<Matrix4> invert(const Matrix4& m);

}  // namespace prism::scene
