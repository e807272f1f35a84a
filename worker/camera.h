// The pbrt-v4 perspective camera (pinhole or thin lens) with a box pixel filter. A camera ray
// is a pure function of (pixel, film sample, lens sample): the tracer draws those from the
// pixel's sampler, so rays never depend on tiles or threads.
//
// Conventions (scene_description.h): camera space looks down +z, +y up, +x to the image's
// right; raster y grows downwards. `fov` spans the shorter image axis. With a lens radius
// r > 0 and focal distance f, rays start on the lens disk and pass through the point the
// pinhole ray meets at depth f (pbrt-v4 PerspectiveCamera::GenerateRay).
#pragma once

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"
#include "worker/equal_area.h"
#include "worker/geometry.h"
#include "worker/vecmath.h"

namespace prism::worker {

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

 private:
  int width_ = 0, height_ = 0;
  // camera-from-raster: raster (x, y) -> point on the z = 1 plane in camera space.
  double screen_x0_ = 0, screen_y0_ = 0, screen_dx_ = 0, screen_dy_ = 0;
  double lens_radius_ = 0, focal_distance_ = 1;
  bool orthographic_ = false;
  int spherical_ = 0;  // 0: not spherical; 1: equal-area; 2: equirectangular
  scene::Transform world_from_camera_;
};

}  // namespace prism::worker
