#include "services/scene/transform.h"

#include <gtest/gtest.h>

#include <cmath>

namespace prism::scene {
namespace {

void expect_near(const Vec3& a, const Vec3& b) {
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(a[i], b[i], 1e-12) << i;
}

TEST(Transform, ComposesRightToLeft) {
  Transform t = Transform::translate({1, 0, 0}) * *Transform::scale({2, 2, 2});
  expect_near(t.apply_point({1, 1, 1}), {3, 2, 2});
  expect_near(t.inverse().apply_point({3, 2, 2}), {1, 1, 1});
  expect_near(t.apply_vector({1, 0, 0}), {2, 0, 0});
}

TEST(Transform, RotateFollowsTheMatrixRightHandRule) {
  Transform r = *Transform::rotate(90, {0, 0, 1});
  expect_near(r.apply_vector({1, 0, 0}), {0, 1, 0});
  expect_near(r.apply_vector({0, 1, 0}), {-1, 0, 0});
  EXPECT_FALSE(r.swaps_handedness());
  EXPECT_FALSE(Transform::rotate(10, {0, 0, 0}).has_value());
}

TEST(Transform, LookAtIsPbrtsLeftHandedCameraFrame) {
  // Eye at origin looking down +z, up +y: camera space is world space.
  EXPECT_TRUE(Transform::look_at({0, 0, 0}, {0, 0, 1}, {0, 1, 0})->is_identity());
  // Looking down -z from (0,0,5): camera +x (raster right) is world -x.
  Transform camera_from_world = *Transform::look_at({0, 0, 5}, {0, 0, 0}, {0, 1, 0});
  Transform world_from_camera = camera_from_world.inverse();
  expect_near(world_from_camera.apply_vector({1, 0, 0}), {-1, 0, 0});
  expect_near(world_from_camera.apply_vector({0, 1, 0}), {0, 1, 0});
  expect_near(world_from_camera.apply_vector({0, 0, 1}), {0, 0, -1});
  expect_near(world_from_camera.apply_point({0, 0, 0}), {0, 0, 5});
  EXPECT_FALSE(Transform::look_at({0, 0, 0}, {0, 1, 0}, {0, 1, 0}).has_value());
  EXPECT_FALSE(Transform::look_at({1, 1, 1}, {1, 1, 1}, {0, 1, 0}).has_value());
}

TEST(Transform, MirrorsAndSingularMatrices) {
  EXPECT_TRUE(Transform::scale({-1, 1, 1})->swaps_handedness());
  EXPECT_FALSE(Transform::scale({-1, -1, 1})->swaps_handedness());
  EXPECT_FALSE(Transform::scale({0, 1, 1}).has_value());
  Matrix4 zero{};
  EXPECT_FALSE(Transform::from_matrix(zero).has_value());
  Matrix4 m{};
  m[0] = {0, 1, 0, 2};
  m[1] = {1, 0, 0, 3};
  m[2] = {0, 0, 1, 4};
  m[3] = {0, 0, 0, 1};
  std::optional<Transform> t = Transform::from_matrix(m);
  ASSERT_TRUE(t.has_value());
  EXPECT_TRUE(t->swaps_handedness());
  expect_near(t->inverse().apply_point(t->apply_point({5, 6, 7})), {5, 6, 7});
  // Normals stay perpendicular to transformed tangents.
  Transform s = *Transform::scale({1, 4, 1});
  Vec3 n = s.apply_normal({1, 1, 0});
  Vec3 tangent = s.apply_vector({1, -1, 0});
  EXPECT_NEAR(n[0] * tangent[0] + n[1] * tangent[1] + n[2] * tangent[2], 0.0, 1e-12);
}

}  // namespace
}  // namespace prism::scene
