#include "worker/geometry.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace prism::worker {
namespace {

scene::Shape quad_shape(double z, bool reverse = false) {
  auto mesh = std::make_shared<scene::TriangleMeshData>();
  mesh->positions = {{-1, -1, float(z)}, {1, -1, float(z)}, {1, 1, float(z)}, {-1, 1, float(z)}};
  mesh->triangles = {{0, 1, 2}, {0, 2, 3}};
  scene::Shape shape;
  shape.geometry = scene::TriangleMeshShape{mesh, "test"};
  shape.reverse_orientation = reverse;
  return shape;
}

scene::Shape sphere_shape(double radius, const scene::Transform& t) {
  scene::Shape shape;
  shape.geometry = scene::SphereShape{radius};
  shape.object_to_world = t;
  shape.transform_swaps_handedness = t.swaps_handedness();
  return shape;
}

TEST(GeometryTest, TriangleHitFollowsPbrtNormalConvention) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  desc.shapes.push_back(quad_shape(5));
  desc.shapes.push_back(quad_shape(7, /*reverse=*/true));
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  auto hit = (*geometry)->intersect({{0.2f, 0.3f, 0}, {0, 0, 1}}, 1e30f);
  ASSERT_TRUE(hit);
  EXPECT_EQ(hit->shape, 0);
  EXPECT_NEAR(hit->t, 5.0f, 1e-5f);
  EXPECT_NEAR(hit->p.x, 0.2f, 1e-5f);
  // cross(p0 − p2, p1 − p2) for vertices counter-clockwise seen from +z points to +z.
  EXPECT_NEAR(hit->ng.z, 1.0f, 1e-6f);
  // Behind it, the reversed quad's normal points to −z.
  auto far = (*geometry)->intersect({{0.2f, 0.3f, 6}, {0, 0, 1}}, 1e30f);
  ASSERT_TRUE(far);
  EXPECT_EQ(far->shape, 1);
  EXPECT_NEAR(far->ng.z, -1.0f, 1e-6f);
  EXPECT_TRUE((*geometry)->occluded({{0, 0, 0}, {0, 0, 1}}, 6.0f));
  EXPECT_FALSE((*geometry)->occluded({{0, 0, 0}, {0, 0, 1}}, 4.0f));
  EXPECT_FALSE((*geometry)->intersect({{3, 3, 0}, {0, 0, 1}}, 1e30f));
}

// pbrt-v4 negates a mesh's vertex normals under ReverseOrientation and turns the geometric normal
// to them, so a reversed mesh with normals faces the other way, flattened or instanced, as one
// without normals does.
TEST(GeometryTest, ReverseOrientationTurnsAMeshWithNormals) {
  EmbreeDevice device;
  for (bool instanced : {false, true}) {
    scene::SceneDescription desc;
    scene::Shape plain = quad_shape(0);
    auto mesh = std::make_shared<scene::TriangleMeshData>(
        *std::get<scene::TriangleMeshShape>(plain.geometry).mesh);
    mesh->normals.assign(4, {0, 0, 1});
    plain.geometry = scene::TriangleMeshShape{mesh, "test"};
    scene::Shape reversed = plain;
    reversed.reverse_orientation = true;
    // One mesh object used twice is instanced; its own copy is flattened.
    if (!instanced)
      reversed.geometry =
          scene::TriangleMeshShape{std::make_shared<scene::TriangleMeshData>(*mesh), "test"};
    plain.object_to_world = scene::Transform::translate({0, 0, 3});
    reversed.object_to_world = scene::Transform::translate({5, 0, 3});
    desc.shapes = {plain, reversed};
    auto geometry = Geometry::build(device, desc);
    ASSERT_TRUE(geometry.ok()) << geometry.status();
    auto a = (*geometry)->intersect({{0.1f, 0.2f, 0}, {0, 0, 1}}, 1e30f);
    auto b = (*geometry)->intersect({{5.1f, 0.2f, 0}, {0, 0, 1}}, 1e30f);
    ASSERT_TRUE(a && b);
    ASSERT_EQ(a->shape, 0);
    ASSERT_EQ(b->shape, 1);
    EXPECT_NEAR(a->ng.z, 1.0f, 1e-6f) << instanced;
    EXPECT_NEAR(a->ns.z, 1.0f, 1e-6f) << instanced;
    EXPECT_NEAR(b->ng.z, -1.0f, 1e-6f) << instanced;
    EXPECT_NEAR(b->ns.z, -1.0f, 1e-6f) << instanced;
    const Geometry::WorldTriangle w = (*geometry)->triangle(1, 0);
    EXPECT_NEAR(w.n0.z, -1.0f, 1e-6f) << instanced;
  }
}

// A bilinear patch p00 = (0,0,z), p10 = (1,0,z), p01 = (0,1,z), p11 = (1,1,z + twist): the
// saddle z + twist·u·v over the unit square, split as scene::TriangleMeshData's patches are.
std::shared_ptr<scene::TriangleMeshData> saddle(float z, float twist) {
  auto mesh = std::make_shared<scene::TriangleMeshData>();
  mesh->positions = {{0, 0, z}, {1, 0, z}, {0, 1, z}, {1, 1, z + twist}};
  mesh->triangles = {{0, 1, 3}, {0, 3, 2}};
  mesh->patches = {0};
  return mesh;
}

scene::Shape mesh_shape(std::shared_ptr<scene::TriangleMeshData> mesh) {
  scene::Shape shape;
  shape.geometry = scene::TriangleMeshShape{std::move(mesh), "bilinearmesh"};
  return shape;
}

// A curved patch is pbrt-v4's bilinear surface, not its two triangles: a ray straight down at
// (x, y) meets z = x·y (the triangles would give z = min(x, y)), with the patch's (u, v), uv and
// normal cross(∂p/∂u, ∂p/∂v) = (−v, −u, 1); rays past its edges miss; shadow rays agree.
TEST(GeometryTest, CurvedBilinearPatchIsTheSurfaceItself) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  desc.shapes = {mesh_shape(saddle(0, 1))};
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  const Geometry& g = **geometry;
  EXPECT_EQ(g.face(0, 0), Geometry::MeshFace::kPatch);
  EXPECT_EQ(g.face(0, 1), Geometry::MeshFace::kPatchRest);
  double worst = 0;
  for (int i = 0; i < 20; ++i) {
    for (int j = 0; j < 20; ++j) {
      const float x = (i + 0.5f) / 20, y = (j + 0.37f) / 20;
      auto hit = g.intersect({{x, y, 5}, {0, 0, -1}}, 1e30f);
      ASSERT_TRUE(hit) << x << " " << y;
      worst = std::max(worst, double(std::abs(hit->p.z - x * y)));
      EXPECT_NEAR(hit->t, 5 - x * y, 1e-5f);
      EXPECT_EQ(hit->primitive, 0u);
      EXPECT_NEAR(hit->param.x, x, 1e-5f);
      EXPECT_NEAR(hit->param.y, y, 1e-5f);
      EXPECT_NEAR(hit->uv.x, x, 1e-5f);
      EXPECT_NEAR(hit->uv.y, y, 1e-5f);
      const Vec3f n = normalize(Vec3f(-y, -x, 1));
      EXPECT_NEAR(dot(hit->ng, n), 1.0f, 1e-5f);
      EXPECT_NEAR(dot(hit->ns, n), 1.0f, 1e-5f);
      // From below too, and a shadow ray to just short of the surface does not reach it.
      auto under = g.intersect({{x, y, -5}, {0, 0, 1}}, 1e30f);
      ASSERT_TRUE(under);
      EXPECT_NEAR(under->p.z, x * y, 1e-5f);
      EXPECT_TRUE(g.occluded({{x, y, -5}, {0, 0, 1}}, 5 + x * y + 1e-3f));
      EXPECT_FALSE(g.occluded({{x, y, -5}, {0, 0, 1}}, 5 + x * y - 1e-3f));
    }
  }
  EXPECT_LT(worst, 1e-5);
  // An oblique ray's hit lies on the ray and on the saddle.
  const Ray oblique{{0.2f, 0.1f, -1}, normalize(Vec3f(0.2f, 0.3f, 1))};
  auto hit = g.intersect(oblique, 1e30f);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->p.z, hit->p.x * hit->p.y, 1e-5f);
  EXPECT_NEAR(length(oblique.origin + oblique.direction * hit->t - hit->p), 0.0f, 1e-5f);
  EXPECT_FALSE(g.intersect({{1.2f, 0.5f, 5}, {0, 0, -1}}, 1e30f));
  EXPECT_FALSE(g.intersect({{0.5f, -0.1f, 5}, {0, 0, -1}}, 1e30f));

  // Its normal changes as the saddle's does: Igehy's differential against two hits.
  auto a = g.intersect({{0.3f, 0.6f, 5}, {0, 0, -1}}, 1e30f);
  auto b = g.intersect({{0.301f, 0.6005f, 5}, {0, 0, -1}}, 1e30f);
  ASSERT_TRUE(a && b);
  const Vec3f dn = g.normal_differential(*a, b->p - a->p);
  EXPECT_NEAR(length(a->ns + dn - b->ns), 0.0f, 2e-5f);
  EXPECT_GT(length(dn), 1e-4f);
}

// A mesh whose patches are all flat (parallelograms) stays on Embree's triangles with the same
// hits; a patch's second triangle takes the patch's own uv, (0,0) (1,1) (0,1), so a flat quad
// without uvs has pbrt-v4's texture coordinates without a seam.
TEST(GeometryTest, FlatPatchesStayTrianglesWithThePatchsUv) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  auto flat = saddle(2, 0);
  desc.shapes = {mesh_shape(flat)};
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  EXPECT_EQ((*geometry)->face(0, 0), Geometry::MeshFace::kTriangle);
  for (const Point2f& at : {Point2f{0.7f, 0.2f}, Point2f{0.2f, 0.7f}, Point2f{0.5f, 0.9f}}) {
    auto hit = (*geometry)->intersect({{at.x, at.y, 5}, {0, 0, -1}}, 1e30f);
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->uv.x, at.x, 1e-5f);
    EXPECT_NEAR(hit->uv.y, at.y, 1e-5f);
    EXPECT_NEAR(hit->ng.z, 1.0f, 1e-6f);
  }
}

// A mesh with a curved patch is intersected face by face in Prism's code, its plain triangles
// too; shared by two shapes it is instanced like any mesh, and a transform moves the surface.
TEST(GeometryTest, CurvedPatchMeshesMixTrianglesAndAreInstanced) {
  EmbreeDevice device;
  auto mesh = saddle(0, 1);
  mesh->positions.push_back({2, 0, 0});
  mesh->positions.push_back({3, 0, 0});
  mesh->positions.push_back({2, 1, 0});
  mesh->triangles.push_back({4, 5, 6});
  scene::SceneDescription desc;
  scene::Shape a = mesh_shape(mesh), b = mesh_shape(mesh);
  b.object_to_world = scene::Transform::translate({0, 0, 10});
  desc.shapes = {a, b};
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  const Geometry& g = **geometry;
  EXPECT_EQ(g.face(0, 2), Geometry::MeshFace::kTriangle);
  auto tri = g.intersect({{2.25f, 0.5f, 5}, {0, 0, -1}}, 1e30f);
  ASSERT_TRUE(tri);
  EXPECT_EQ(tri->primitive, 2u);
  EXPECT_NEAR(tri->param.x, 0.25f, 1e-5f);  // barycentrics of p1 and p2, as Embree's
  EXPECT_NEAR(tri->param.y, 0.5f, 1e-5f);
  EXPECT_NEAR(tri->ng.z, 1.0f, 1e-6f);
  auto top = g.intersect({{0.5f, 0.8f, 20}, {0, 0, -1}}, 1e30f);
  ASSERT_TRUE(top);
  EXPECT_EQ(top->shape, 1);
  EXPECT_NEAR(top->p.z, 10 + 0.5f * 0.8f, 1e-5f);
  const Geometry::WorldPatch w = g.patch(1, 0);
  EXPECT_NEAR(w.p11.z, 11.0f, 1e-6f);
}

// A mirroring transform keeps a sphere's, disk's or cylinder's outside outside, as it does a
// mesh's: the object-space normal is carried by the normal matrix. Only ReverseOrientation turns
// it (docs/conformance.md, "Mirrored spheres, disks and cylinders").
TEST(GeometryTest, MirroredQuadricsKeepTheirOutside) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  const auto mirror_x = *scene::Transform::scale({-1, 1, 1});
  const auto mirror_z = *scene::Transform::scale({1, 1, -1});
  desc.shapes.push_back(sphere_shape(1, scene::Transform::translate({0, 0, 10}) * mirror_x));
  scene::Shape reversed = sphere_shape(1, scene::Transform::translate({-5, 0, 10}) * mirror_x);
  reversed.reverse_orientation = true;
  desc.shapes.push_back(reversed);
  scene::Shape disk;
  disk.geometry = scene::DiskShape{0.0, 1.0, 0.0};
  disk.object_to_world = scene::Transform::translate({5, 0, 10}) * mirror_z;
  disk.transform_swaps_handedness = true;
  desc.shapes.push_back(disk);
  scene::Shape cylinder;
  cylinder.geometry = scene::CylinderShape{1.0, -1.0, 1.0};
  cylinder.object_to_world = scene::Transform::translate({10, 0, 10}) * mirror_x;
  cylinder.transform_swaps_handedness = true;
  desc.shapes.push_back(cylinder);
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();

  auto sphere = (*geometry)->intersect({{0, 0, 0}, {0, 0, 1}}, 1e30f);
  ASSERT_TRUE(sphere);
  EXPECT_EQ(sphere->shape, 0);
  EXPECT_NEAR(sphere->ng.z, -1.0f, 1e-5f);  // outwards, towards the ray's origin
  auto inward = (*geometry)->intersect({{-5, 0, 0}, {0, 0, 1}}, 1e30f);
  ASSERT_TRUE(inward);
  EXPECT_EQ(inward->shape, 1);
  EXPECT_NEAR(inward->ng.z, 1.0f, 1e-5f);
  // The disk's object +z is world −z under the mirror in z.
  auto face = (*geometry)->intersect({{5, 0.2f, 0}, {0, 0, 1}}, 1e30f);
  ASSERT_TRUE(face);
  EXPECT_EQ(face->shape, 2);
  EXPECT_NEAR(face->ng.z, -1.0f, 1e-6f);
  auto wall = (*geometry)->intersect({{10, -5, 10}, {0, 1, 0}}, 1e30f);
  ASSERT_TRUE(wall);
  EXPECT_EQ(wall->shape, 3);
  EXPECT_NEAR(wall->t, 4.0f, 1e-4f);
  EXPECT_NEAR(wall->ng.y, -1.0f, 1e-5f);
}

// Embree aborts the process on a ray with a NaN or a component beyond its FLT_LARGE (its
// ray.valid() assertion; the far sphere of the helper's scene brought down four farm workers in a
// row). Such a ray hits nothing and its shadow query is blocked, next to shapes that Embree
// enters through an instance transform (the sphere) and directly (the quad).
TEST(GeometryTest, RaysEmbreeCannotTakeHitNothingInsteadOfAborting) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  desc.shapes.push_back(quad_shape(5));
  desc.shapes.push_back(sphere_shape(1.0, scene::Transform::translate({0, 0, 10})));
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  const float nan = std::nanf("");
  const float huge = 1e30f;
  const Ray bad[] = {
      {{0, 0, 0}, {nan, 0, 1}},
      {{nan, 0, 0}, {0, 0, 1}},
      {{0, 0, -huge}, {0, 0, 1}},
      {{0, 0, 0}, {0, 0, huge}},
      {{0, 0, 0}, {0, std::numeric_limits<float>::infinity(), 1}},
      {{0, 0, 12}, {0, 0, -huge}},
  };
  for (const Ray& ray : bad) {
    EXPECT_FALSE((*geometry)->intersect(ray, 1e30f));
    EXPECT_TRUE((*geometry)->occluded(ray, 1e30f));
  }
  // A NaN t_max too, on an otherwise good ray.
  EXPECT_FALSE((*geometry)->intersect({{0, 0, 0}, {0, 0, 1}}, nan));
  EXPECT_TRUE((*geometry)->occluded({{0, 0, 0}, {0, 0, 1}}, nan));
  // The limit itself is still traced.
  const float limit = Geometry::kMaxRayCoordinate;
  auto hit = (*geometry)->intersect({{0.5f, 0.5f, -limit}, {0, 0, 1}}, 1e30f);
  EXPECT_TRUE(hit);
  EXPECT_TRUE((*geometry)->intersect({{0, 0, 0}, {0, 0, 1}}, 1e30f));
}

TEST(GeometryTest, EllipsoidIsIntersectedExactly) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  auto scale = *scene::Transform::scale({2, 1, 1});
  desc.shapes.push_back(sphere_shape(1.5, scene::Transform::translate({0, 0, 10}) * scale));
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  // Along x the semi-axis is 3: a ray from the left hits at x = −3.
  auto hit = (*geometry)->intersect({{-10, 0, 10}, {1, 0, 0}}, 1e30f);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->t, 7.0f, 1e-4f);
  EXPECT_NEAR(hit->ng.x, -1.0f, 1e-5f);
  // Along z the semi-axis is 1.5; from inside, the far side is hit with the outward normal.
  auto inside = (*geometry)->intersect({{0, 0, 10}, {0, 0, 1}}, 1e30f);
  ASSERT_TRUE(inside);
  EXPECT_NEAR(inside->t, 1.5f, 1e-4f);
  EXPECT_NEAR(inside->ng.z, 1.0f, 1e-5f);
  // An oblique hit: the normal of x²/9 + y²/2.25 + z²/2.25 = 1 is ∝ (x/9, y/2.25, z/2.25).
  auto oblique = (*geometry)->intersect({{1, 5, 10.5f}, {0, -1, 0}}, 1e30f);
  ASSERT_TRUE(oblique);
  Vec3f p = oblique->p - Vec3f(0, 0, 10);
  EXPECT_NEAR(p.x * p.x / 9 + p.y * p.y / 2.25f + p.z * p.z / 2.25f, 1.0f, 1e-5f);
  Vec3f expected = normalize(Vec3f(p.x / 9, p.y / 2.25f, p.z / 2.25f));
  EXPECT_NEAR(dot(oblique->ng, expected), 1.0f, 1e-5f);
}

// pbrt-v4's disk (a hole of inner radius, uv = (φ/2π, (R − r)/(R − r_i)), normal +z) and its open
// cylinder (seen from inside too, uv = (φ/2π, (z − z_min)/(z_max − z_min)), normal outwards),
// both under a transform, against the closed-form hits.
TEST(GeometryTest, DisksAndCylindersAreIntersectedExactly) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  scene::Shape disk;
  disk.geometry = scene::DiskShape{0.5, 2.0, 1.0};  // plane z = 0.5, 1 <= r <= 2
  disk.object_to_world = scene::Transform::translate({0, 0, 10});
  desc.shapes.push_back(disk);
  scene::Shape cylinder;
  cylinder.geometry = scene::CylinderShape{1.0, -1.0, 2.0};
  cylinder.object_to_world =
      scene::Transform::translate({10, 0, 0}) * *scene::Transform::scale({2, 2, 1});
  cylinder.transform_swaps_handedness = false;
  desc.shapes.push_back(cylinder);
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();

  // Disk: a ray down −z through r = 1.5 hits the plane z = 10.5; through the hole it misses.
  auto hit = (*geometry)->intersect({{0, 1.5f, 20}, {0, 0, -1}}, 1e30f);
  ASSERT_TRUE(hit);
  EXPECT_EQ(hit->shape, 0);
  EXPECT_NEAR(hit->t, 9.5f, 1e-5f);
  EXPECT_NEAR(hit->ng.z, 1.0f, 1e-6f);
  EXPECT_NEAR(hit->uv.x, 0.25f, 1e-5f);  // φ = 90°
  EXPECT_NEAR(hit->uv.y, 0.5f, 1e-5f);   // (2 − 1.5) / (2 − 1)
  EXPECT_FALSE((*geometry)->intersect({{0, 0.5f, 20}, {0, 0, -1}}, 1e30f));
  EXPECT_FALSE((*geometry)->intersect({{0, 2.5f, 20}, {0, 0, -1}}, 1e30f));
  EXPECT_TRUE((*geometry)->occluded({{1.5f, 0, 20}, {0, 0, -1}}, 10.0f));
  EXPECT_FALSE((*geometry)->occluded({{1.5f, 0, 20}, {0, 0, -1}}, 9.0f));

  // Cylinder of radius 2 (after the scale) about x = 10, z in [−1, 2]: from x = 0 along +x the
  // outside is hit at x = 8 with the outward normal −x.
  auto side = (*geometry)->intersect({{0, 0, 0.5f}, {1, 0, 0}}, 1e30f);
  ASSERT_TRUE(side);
  EXPECT_EQ(side->shape, 1);
  EXPECT_NEAR(side->t, 8.0f, 1e-4f);
  EXPECT_NEAR(side->ng.x, -1.0f, 1e-5f);
  EXPECT_NEAR(side->uv.x, 0.5f, 1e-5f);         // φ = 180°
  EXPECT_NEAR(side->uv.y, 1.5f / 3.0f, 1e-5f);  // (0.5 + 1) / 3
  // From the axis, the inside of the wall at x = 12; the normal still points outwards (+x).
  auto inside = (*geometry)->intersect({{10, 0, 0}, {1, 0, 0}}, 1e30f);
  ASSERT_TRUE(inside);
  EXPECT_NEAR(inside->t, 2.0f, 1e-4f);
  EXPECT_NEAR(inside->ng.x, 1.0f, 1e-5f);
  // Open ends: a ray along the axis passes; above z_max the ray misses the wall.
  EXPECT_FALSE((*geometry)->intersect({{10, 0, -5}, {0, 0, 1}}, 1e30f));
  EXPECT_FALSE((*geometry)->intersect({{0, 0, 2.5f}, {1, 0, 0}}, 1e30f));
  // Oblique: the hit lies on the surface.
  auto oblique = (*geometry)->intersect({{0, 0.7f, 0}, Vec3f(1, 0.1f, 0.05f)}, 1e30f);
  ASSERT_TRUE(oblique);
  const float dx = (oblique->p.x - 10) / 2, dy = oblique->p.y / 2;
  EXPECT_NEAR(dx * dx + dy * dy, 1.0f, 1e-5f);
}

// pbrt-v4's stochastic alpha: a quad of alpha 0.3 stops 30 % of rays (binomial, 5σ), alpha 0
// none; two stacked quads of alpha 0.5 let 25 % through, since layers decide independently;
// shadow rays see the same; a textured alpha is read at the hit's uv.
TEST(GeometryTest, AlphaCutOutsAreStochasticAndIndependentPerLayer) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  desc.shapes.push_back(quad_shape(5));
  desc.shapes.push_back(quad_shape(6));
  desc.shapes.push_back(quad_shape(20));
  {
    // Per-vertex uvs, so that u = (x + 1) / 2 over the whole quad.
    auto mesh = std::make_shared<scene::TriangleMeshData>(
        *std::get<scene::TriangleMeshShape>(desc.shapes[2].geometry).mesh);
    mesh->uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    desc.shapes[2].geometry = scene::TriangleMeshShape{mesh, "test"};
  }
  std::vector<AlphaFunction> alpha(3);
  alpha[0] = [](const Point2f&, const Vec3f&) { return 0.5f; };
  alpha[1] = [](const Point2f&, const Vec3f&) { return 0.5f; };
  // The third: 0 where u < 0.5 (x < 0), else 0.3.
  alpha[2] = [](const Point2f& uv, const Vec3f&) { return uv.x < 0.5f ? 0.0f : 0.3f; };
  auto geometry = Geometry::build(device, desc, alpha);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  constexpr int kN = 40000;
  int first = 0, second = 0, through = 0, occluded = 0;
  for (int i = 0; i < kN; ++i) {
    // Distinct rays: a jittered grid of origins inside the quads' footprint.
    const float x = -0.9f + 1.8f * float(i % 200) / 200, y = -0.9f + 1.8f * float(i / 200) / 200;
    auto hit = (*geometry)->intersect({{x, y, 0}, {0, 0, 1}}, 10.0f);
    if (!hit) {
      ++through;
    } else if (hit->shape == 0) {
      ++first;
    } else {
      ++second;
    }
    if ((*geometry)->occluded({{x, y, 0}, {0, 0, 1}}, 10.0f)) ++occluded;
  }
  auto expect_fraction = [&](int count, double p, const char* what) {
    EXPECT_NEAR(double(count) / kN, p, 5 * std::sqrt(p * (1 - p) / kN)) << what;
  };
  expect_fraction(first, 0.5, "first layer");
  expect_fraction(second, 0.25, "second layer");
  expect_fraction(through, 0.25, "through both");
  EXPECT_EQ(occluded, first + second);  // the same hash decides shadow rays

  // Behind, the textured quad: rays through its u < 0.5 half always pass; the rest stop at 0.3.
  int stopped_left = 0, stopped_right = 0, left = 0, right = 0;
  for (int i = 0; i < kN; ++i) {
    const float x = -0.9f + 1.8f * float(i % 200) / 200, y = -0.9f + 1.8f * float(i / 200) / 200;
    auto hit = (*geometry)->intersect({{x, y, 10}, {0, 0, 1}}, 1e30f);
    const bool stopped = hit && hit->shape == 2;
    const bool on_left = (x + 1) / 2 < 0.5f;
    (on_left ? left : right)++;
    if (stopped) (on_left ? stopped_left : stopped_right)++;
  }
  EXPECT_EQ(stopped_left, 0);
  EXPECT_NEAR(double(stopped_right) / right, 0.3, 5 * std::sqrt(0.21 / right));
  EXPECT_GT(left, 0);
}

TEST(GeometryTest, SharedMeshIsInstanced) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  scene::Shape a = quad_shape(0);
  scene::Shape b = a;  // same mesh object, another transform: an instance
  a.object_to_world = scene::Transform::translate({0, 0, 3});
  b.object_to_world = scene::Transform::translate({5, 0, 3});
  desc.shapes = {a, b};
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  auto ha = (*geometry)->intersect({{0, 0, 0}, {0, 0, 1}}, 1e30f);
  auto hb = (*geometry)->intersect({{5.5f, 0.5f, 0}, {0, 0, 1}}, 1e30f);
  ASSERT_TRUE(ha && hb);
  EXPECT_EQ(ha->shape, 0);
  EXPECT_EQ(hb->shape, 1);
  EXPECT_NEAR(hb->p.x, 5.5f, 1e-5f);
  EXPECT_NEAR(hb->t, 3.0f, 1e-5f);
  EXPECT_NEAR(hb->ng.z, 1.0f, 1e-6f);
  EXPECT_NEAR((*geometry)->triangle(1, 0).p1.x, 6.0f, 1e-6f);
}

TEST(GeometryTest, DeviceErrorsAreRecordedNotThrown) {
  EmbreeDevice device;
  ASSERT_TRUE(device.valid());
  EXPECT_TRUE(device.take_error().ok());
  // An invalid geometry type: Embree reports through the callback, nothing unwinds.
  RTCGeometry g = rtcNewGeometry(device.get(), static_cast<RTCGeometryType>(9999));
  EXPECT_EQ(g, nullptr);
  auto status = device.take_error();
  EXPECT_EQ(status.code(), absl::StatusCode::kInternal);
  EXPECT_NE(status.message().find("invalid geometry type"), std::string::npos) << status;
  // Taking the error clears it.
  EXPECT_TRUE(device.take_error().ok());
}

}  // namespace
}  // namespace prism::worker
