// The pbrt-v4 perspective camera (pinhole or thin lens) with a box pixel filter. A camera ray
// is a pure function of (pixel, film sample, lens sample): the tracer draws those from the
// pixel's sampler, so rays never depend on tiles or threads.
//
// Conventions (scene_description.h): camera space looks down +z, +y up, +x to the image's
// right; raster y grows downwards. `fov` spans the shorter image axis. With a lens radius
// r > 0 and focal distance f, rays start on the lens disk and pass through the point the
// pinhole ray meets at depth f (pbrt-v4 PerspectiveCamera::GenerateRay).
#pragma once

#include <optional>

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"
#include "worker/equal_area.h"
#include "worker/geometry.h"
#include "worker/vecmath.h"

namespace prism::worker {

// Where a world point lands on a pinhole camera's film, for light paths that connect to the
// camera (light_tracer.h): the raster position, the unit direction from the point to the pinhole,
// their distance, and the importance W per unit raster area, 1 / (|dx|·|dy|·cos³θ) with dx, dy
// one pixel's size on the z = 1 plane and θ the angle to the optical axis. An eye sample measures
// a pixel as ∫ L(x) dx over raster positions; dx = W dω, so a light path's vertex y adds
// L(y → camera)·W·|cos θ_y|/d² per unit area of y.
struct CameraConnection {
  Point2f raster;
  Vec3f to_camera;
  float distance = 0;
  float importance = 0;
  Vec3f lens_point;  // where the connection meets the camera (the pinhole, or a lens point)
};

class Camera {
 public:
  // Film resolution width x height (the job's, which may override the scene's). pbrt-v4's
  // perspective, orthographic (its screen window in camera-space units) and spherical cameras.
  // Errors: other cameras, fov outside (0, 180), non-positive focal distance with a lens.
  static absl::StatusOr<Camera> create(const scene::Camera& camera, int width, int height);

  // `film` is the position in raster space (pixel x + offset in [0,1), y likewise); `lens`
  // in [0,1)² picks the lens point. The direction is unit length, in world space.
  Ray generate_ray(Point2f film, Point2f lens) const;

  int width() const { return width_; }
  int height() const { return height_; }
  Vec3f position() const;  // the pinhole (lens centre) in world space
  // Whether connect() is defined: a perspective camera, a pinhole or a thin lens.
  bool is_perspective() const { return !orthographic_ && spherical_ == 0; }
  bool is_pinhole() const { return is_perspective() && !(lens_radius_ > 0); }
  // The connection to world point p through the lens point `lens` picks (in [0,1)², mapped as
  // generate_ray maps it; ignored by a pinhole), or nullopt when p is behind the camera or its
  // raster position is farther than `margin` pixels outside the film (a pixel filter of radius r
  // reaches r − 0.5 beyond the film's edge). is_perspective() must hold. With a lens, the raster
  // position is where the ray from the lens point through p meets the plane in focus, and the
  // importance is the pinhole's with θ the angle of that ray: the eye estimate averages over the
  // lens, and a lens point's rays cover the film as the pinhole's do (dω = dA₁·cos³θ).
  std::optional<CameraConnection> connect(const Vec3f& p, float margin,
                                          Point2f lens = {0.5f, 0.5f}) const;
  bool has_lens() const { return lens_radius_ > 0; }
  // How p's raster position moves when p moves by dp (first order; p in front of the camera).
  Point2f raster_differential(const Vec3f& p, const Vec3f& dp) const;
  // The width in world units of one pixel's cone at p's depth (is_pinhole(); 0 behind the camera).
  float pixel_footprint(const Vec3f& p) const;

 private:
  int width_ = 0, height_ = 0;
  // camera-from-raster: raster (x, y) -> point on the z = 1 plane in camera space.
  double screen_x0_ = 0, screen_y0_ = 0, screen_dx_ = 0, screen_dy_ = 0;
  double lens_radius_ = 0, focal_distance_ = 1;
  bool orthographic_ = false;
  int spherical_ = 0;  // 0: not spherical; 1: equal-area; 2: equirectangular
  scene::Transform world_from_camera_;
  scene::Transform camera_from_world_;
};

}  // namespace prism::worker
