#include "worker/camera.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <random>

#include "absl/strings/match.h"
#include "worker/sampler.h"

namespace prism::worker {
namespace {

scene::Camera look_at_camera(const scene::Vec3& eye, const scene::Vec3& look, const scene::Vec3& up,
                             double fov) {
  scene::Camera c;
  c.world_from_camera = scene::Transform::look_at(eye, look, up)->inverse();
  c.fov_deg = fov;
  c.where = {"test.pbrt", 3, 1};
  return c;
}

double angle_deg(const Vec3f& a, const Vec3f& b) {
  double d = double(a.x) * b.x + double(a.y) * b.y + double(a.z) * b.z;
  return std::acos(std::clamp(d / (length(a) * length(b)), -1.0, 1.0)) * 180.0 / kPi;
}

TEST(CameraTest, CentrePixelLooksDownTheAxisFromTheEye) {
  auto cam = Camera::create(look_at_camera({1, 2, 3}, {4, 6, 15}, {0, 1, 0}, 50), 320, 240);
  ASSERT_TRUE(cam.ok()) << cam.status();
  Ray r = cam->generate_ray({160, 120}, {0.5f, 0.5f});
  Vec3f axis = normalize(Vec3f(3, 4, 12));
  EXPECT_NEAR(r.direction.x, axis.x, 1e-6f);
  EXPECT_NEAR(r.direction.y, axis.y, 1e-6f);
  EXPECT_NEAR(r.direction.z, axis.z, 1e-6f);
  EXPECT_NEAR(length(r.direction), 1.0f, 1e-6f);
  EXPECT_FLOAT_EQ(r.origin.x, 1);
  EXPECT_FLOAT_EQ(r.origin.y, 2);
  EXPECT_FLOAT_EQ(r.origin.z, 3);
  EXPECT_FLOAT_EQ(cam->position().z, 3);
}

// fov spans the shorter image axis; the longer one is wider by the aspect ratio.
TEST(CameraTest, FieldOfViewSpansTheShorterAxis) {
  const double fov = 60;
  const double tan_half = std::tan(fov / 2 * kPi / 180);
  for (auto [w, h] : {std::pair{200, 100}, std::pair{100, 200}, std::pair{64, 64}}) {
    auto cam = Camera::create(look_at_camera({0, 0, 0}, {1, 1, 1}, {0, 1, 0}, fov), w, h);
    ASSERT_TRUE(cam.ok()) << cam.status();
    float fw = float(w), fh = float(h);
    Vec3f left = cam->generate_ray({0, fh / 2}, {}).direction;
    Vec3f right = cam->generate_ray({fw, fh / 2}, {}).direction;
    Vec3f top = cam->generate_ray({fw / 2, 0}, {}).direction;
    Vec3f bottom = cam->generate_ray({fw / 2, fh}, {}).direction;
    double horizontal = angle_deg(left, right), vertical = angle_deg(top, bottom);
    double shorter = std::min(w, h), longer = std::max(w, h);
    double wide = 2 * std::atan(tan_half * longer / shorter) * 180 / kPi;
    EXPECT_NEAR(w <= h ? horizontal : vertical, fov, 1e-3) << w << "x" << h;
    EXPECT_NEAR(w <= h ? vertical : horizontal, wide, 1e-3) << w << "x" << h;
  }
}

// pbrt-v4's left-handed convention (scene_description.h): with camera space equal to world
// space, world +x is on the right of the image and +y at the top.
TEST(CameraTest, RasterOrientationFollowsPbrt) {
  auto cam = Camera::create(look_at_camera({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, 45), 64, 48);
  ASSERT_TRUE(cam.ok()) << cam.status();
  Ray right = cam->generate_ray({60, 24}, {});
  Ray left = cam->generate_ray({4, 24}, {});
  Ray top = cam->generate_ray({32, 3}, {});
  Ray bottom = cam->generate_ray({32, 45}, {});
  EXPECT_GT(right.direction.x, 0);
  EXPECT_LT(left.direction.x, 0);
  EXPECT_GT(top.direction.y, 0);
  EXPECT_LT(bottom.direction.y, 0);
  EXPECT_NEAR(right.direction.y, 0, 1e-7f);
  EXPECT_NEAR(top.direction.x, 0, 1e-7f);
  EXPECT_GT(right.direction.z, 0);
}

// `Scale -1 1 1` before LookAt (scenes/cornell-two-lights.pbrt) mirrors the image: the left of
// the image then looks towards world +x.
TEST(CameraTest, MirroredCameraTransform) {
  scene::Transform camera_from_world =
      *scene::Transform::scale({-1, 1, 1}) *
      *scene::Transform::look_at({278, 273, -800}, {278, 273, -799}, {0, 1, 0});
  scene::Camera c;
  c.world_from_camera = camera_from_world.inverse();
  c.fov_deg = 39.3077;
  auto cam = Camera::create(c, 256, 256);
  ASSERT_TRUE(cam.ok()) << cam.status();
  Ray left = cam->generate_ray({10, 128}, {});
  EXPECT_GT(left.direction.x, 0);
  EXPECT_NEAR(length(left.direction), 1, 1e-6f);
  EXPECT_FLOAT_EQ(left.origin.x, 278);
  EXPECT_FLOAT_EQ(left.origin.z, -800);
  Ray top = cam->generate_ray({128, 10}, {});
  EXPECT_GT(top.direction.y, 0);
}

// A screen window given in the scene replaces the aspect-derived one.
TEST(CameraTest, ScreenWindowIsHonoured) {
  scene::Camera c = look_at_camera({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, 90);
  c.screen_window = std::array<double, 4>{0, 1, 0, 1};
  auto cam = Camera::create(c, 10, 10);
  ASSERT_TRUE(cam.ok()) << cam.status();
  // Raster (0, 10) is the bottom-left corner (xmin, ymin) = (0, 0): the axis, tan(45°) = 1.
  Ray r = cam->generate_ray({0, 10}, {});
  EXPECT_NEAR(r.direction.x, 0, 1e-7f);
  EXPECT_NEAR(r.direction.y, 0, 1e-7f);
  Ray corner = cam->generate_ray({10, 0}, {});
  EXPECT_NEAR(corner.direction.x, 1 / std::sqrt(3.0f), 1e-6f);
  EXPECT_NEAR(corner.direction.y, 1 / std::sqrt(3.0f), 1e-6f);
}

// Thin lens: the ray from any lens point through a film point meets the focal plane where the
// pinhole ray through the same film point does (exact: that is the construction's definition).
TEST(CameraTest, ThinLensRaysConvergeOnTheFocalPlane) {
  scene::Camera c = look_at_camera({10, -3, 2}, {12, -2, 9}, {0, 1, 0}, 40);
  c.lens_radius = 0.25;
  c.focal_distance = 7.5;
  auto lens = Camera::create(c, 96, 64);
  c.lens_radius = 0;
  auto pinhole = Camera::create(c, 96, 64);
  ASSERT_TRUE(lens.ok()) << lens.status();
  ASSERT_TRUE(pinhole.ok());
  const Vec3f axis = normalize(Vec3f(2, 1, 7));
  const Vec3f eye(10, -3, 2);
  for (Point2f film : {Point2f{48, 32}, Point2f{0.5f, 0.5f}, Point2f{90.25f, 7.75f}}) {
    // The pinhole ray's point at camera depth f: distance along the axis equal to f.
    Ray p = pinhole->generate_ray(film, {});
    float tp = 7.5f / dot(p.direction, axis);
    Vec3f focus = p.origin + p.direction * tp;
    double max_lens_offset = 0;
    for (std::uint32_t i = 0; i < 64; ++i) {
      Sampler s(job::SamplerKind::kSobol, SampleKey{3, 0, 0, 0, i});
      Point2f u;
      s.get2d(u.x, u.y);
      Ray r = lens->generate_ray(film, u);
      EXPECT_NEAR(length(r.direction), 1, 1e-6f);
      // The origin lies on the lens disk: in the plane through the eye normal to the axis.
      Vec3f off = r.origin - eye;
      EXPECT_NEAR(dot(off, axis), 0, 1e-5f);
      EXPECT_LE(length(off), 0.25f + 1e-6f);
      max_lens_offset = std::max(max_lens_offset, double(length(off)));
      float t = dot(focus - r.origin, axis) / dot(r.direction, axis);
      Vec3f hit = r.origin + r.direction * t;
      EXPECT_NEAR(hit.x, focus.x, 2e-5f);
      EXPECT_NEAR(hit.y, focus.y, 2e-5f);
      EXPECT_NEAR(hit.z, focus.z, 2e-5f);
    }
    EXPECT_GT(max_lens_offset, 0.2);  // the lens samples really cover the disk
  }
}

// A ray is a pure function of its inputs: the same arguments give the same bits.
TEST(CameraTest, RaysArePureFunctions) {
  scene::Camera c = look_at_camera({1, 5, -8}, {1.8, 0.8, 0}, {0, 1, 0}, 40);
  c.lens_radius = 0.1;
  c.focal_distance = 9;
  auto a = Camera::create(c, 320, 240);
  auto b = Camera::create(c, 320, 240);
  ASSERT_TRUE(a.ok() && b.ok());
  for (std::uint32_t i = 0; i < 256; ++i) {
    Sampler s(job::SamplerKind::kIndependent, SampleKey{1, 0, i, 0, 0});
    Point2f film{s.get1d() * 320, s.get1d() * 240}, u{s.get1d(), s.get1d()};
    Ray r1 = a->generate_ray(film, u), r2 = a->generate_ray(film, u), r3 = b->generate_ray(film, u);
    EXPECT_EQ(std::memcmp(&r1, &r2, sizeof(Ray)), 0);
    EXPECT_EQ(std::memcmp(&r1, &r3, sizeof(Ray)), 0);
  }
}

// pbrt-v4's orthographic camera: parallel rays along the view direction from the film point,
// the screen window in camera-space units (default [-1, 1] on the shorter axis), raster y down;
// with a thin lens every lens point aims at where the film point's ray meets the focal plane.
TEST(CameraTest, OrthographicRaysAreParallelAndSpanTheScreenWindow) {
  scene::Camera c = look_at_camera({1, 2, 3}, {1, 2, 13}, {0, 1, 0}, 45);
  c.type = "orthographic";
  auto cam = Camera::create(c, 200, 100);
  ASSERT_TRUE(cam.ok()) << cam.status();
  // 200x100: x spans [-2, 2], y [-1, 1] in camera space; camera +x is world +x here (pbrt's
  // look-at: right = up × forward), raster x runs with it and raster y against +y.
  for (auto [fx, fy, wx, wy] :
       {std::array<float, 4>{0, 0, 1 - 2, 2 + 1}, std::array<float, 4>{200, 100, 1 + 2, 2 - 1},
        std::array<float, 4>{100, 50, 1, 2}}) {
    const Ray r = cam->generate_ray({fx, fy}, {0.5f, 0.5f});
    EXPECT_NEAR(r.direction.x, 0, 1e-6);
    EXPECT_NEAR(r.direction.y, 0, 1e-6);
    EXPECT_NEAR(r.direction.z, 1, 1e-6);
    EXPECT_NEAR(r.origin.x, wx, 1e-5) << fx << "," << fy;
    EXPECT_NEAR(r.origin.y, wy, 1e-5) << fx << "," << fy;
    EXPECT_NEAR(r.origin.z, 3, 1e-5);
  }
  c.lens_radius = 0.3;
  c.focal_distance = 4;
  auto lens = Camera::create(c, 200, 100);
  ASSERT_TRUE(lens.ok()) << lens.status();
  for (float u : {0.1f, 0.5f, 0.9f}) {
    const Ray r = lens->generate_ray({50, 20}, {u, 1 - u});
    const Ray pinhole = cam->generate_ray({50, 20}, {0.5f, 0.5f});
    // Both reach the same point on the focal plane z = 3 + 4.
    const float t = (7 - r.origin.z) / r.direction.z;
    EXPECT_NEAR(r.origin.x + t * r.direction.x, pinhole.origin.x, 1e-4);
    EXPECT_NEAR(r.origin.y + t * r.direction.y, pinhole.origin.y, 1e-4);
  }
}

// pbrt-v4's equal-area square-to-sphere map: unit directions, the square's centre on +z and its
// corners on −z, and equal areas (its Jacobian is constant).
TEST(CameraTest, EqualAreaMapIsUnitAndPreservesArea) {
  const Vec3f centre = equal_area_square_to_sphere({0.5f, 0.5f});
  EXPECT_NEAR(centre.z, 1.0f, 1e-6);
  for (Point2f corner : {Point2f{0, 0}, Point2f{1, 0}, Point2f{0, 1}, Point2f{1, 1}}) {
    EXPECT_NEAR(equal_area_square_to_sphere(corner).z, -1.0f, 1e-6);
  }
  // The map's Jacobian is the sphere's area over the square's, 4π, wherever it is smooth (off the
  // axes and the diamond |u − ½| + |v − ½| = ½ where the octants meet).
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> uniform(0.02f, 0.98f);
  int checked = 0;
  for (int i = 0; i < 400; ++i) {
    const Point2f p{uniform(rng), uniform(rng)};
    const float a = std::abs(p.x - 0.5f), b = std::abs(p.y - 0.5f);
    if (a < 0.01f || b < 0.01f || std::abs(a + b - 0.5f) < 0.01f) continue;
    constexpr float kEps = 1e-3f;
    const Vec3f du = (equal_area_square_to_sphere({p.x + kEps, p.y}) -
                      equal_area_square_to_sphere({p.x - kEps, p.y})) /
                     (2 * kEps);
    const Vec3f dv = (equal_area_square_to_sphere({p.x, p.y + kEps}) -
                      equal_area_square_to_sphere({p.x, p.y - kEps})) /
                     (2 * kEps);
    EXPECT_NEAR(length(cross(du, dv)), 4 * kPi, 0.01 * 4 * kPi) << p.x << "," << p.y;
    EXPECT_NEAR(length(equal_area_square_to_sphere(p)), 1.0f, 1e-5);
    ++checked;
  }
  EXPECT_GT(checked, 300);
}

// The spherical camera sees the whole sphere from its origin: equirectangular rows are
// latitudes (the top row looks along camera +y, the bottom along −y), the equal-area film's
// centre looks up; every ray leaves the camera's position.
TEST(CameraTest, SphericalCamerasMapTheFilmOntoTheSphere) {
  scene::Camera c = look_at_camera({1, 2, 3}, {1, 2, 13}, {0, 1, 0}, 45);
  c.type = "spherical";
  c.mapping = "equirectangular";
  auto equirect = Camera::create(c, 64, 32);
  ASSERT_TRUE(equirect.ok()) << equirect.status();
  const Ray top = equirect->generate_ray({17.3f, 0.0f}, {});
  EXPECT_NEAR(top.direction.y, 1.0f, 1e-5);
  const Ray bottom = equirect->generate_ray({40.0f, 32.0f}, {});
  EXPECT_NEAR(bottom.direction.y, -1.0f, 1e-5);
  const Ray horizon = equirect->generate_ray({16.0f, 16.0f}, {});  // θ = π/2, φ = π/2
  EXPECT_NEAR(horizon.direction.y, 0.0f, 1e-5);
  EXPECT_NEAR(horizon.direction.z, 1.0f, 1e-5);  // camera +z (the look direction) is world +z
  EXPECT_NEAR(horizon.origin.x, 1.0f, 1e-5);
  EXPECT_NEAR(horizon.origin.y, 2.0f, 1e-5);
  EXPECT_NEAR(horizon.origin.z, 3.0f, 1e-5);
  c.mapping = "equalarea";
  auto area = Camera::create(c, 32, 32);
  ASSERT_TRUE(area.ok()) << area.status();
  EXPECT_NEAR(area->generate_ray({16.0f, 16.0f}, {}).direction.y, 1.0f, 1e-5);
  c.mapping = "cylindrical";
  EXPECT_FALSE(Camera::create(c, 32, 32).ok());
}

TEST(CameraTest, UnsupportedCamerasAreRefusedWithTheirLocation) {
  scene::Camera c = look_at_camera({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, 45);
  c.type = "realistic";
  auto r = Camera::create(c, 8, 8);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StrContains(r.status().message(), "test.pbrt:3:1:")) << r.status();
  EXPECT_TRUE(absl::StrContains(r.status().message(), "realistic")) << r.status();

  c = look_at_camera({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, 180);
  EXPECT_FALSE(Camera::create(c, 8, 8).ok());
  c.fov_deg = 45;
  c.lens_radius = 0.5;
  c.focal_distance = 0;
  r = Camera::create(c, 8, 8);
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(absl::StrContains(r.status().message(), "focaldistance")) << r.status();
  c.focal_distance = 1;
  EXPECT_TRUE(Camera::create(c, 8, 8).ok());
  EXPECT_FALSE(Camera::create(c, 0, 8).ok());
}

}  // namespace
}  // namespace prism::worker
