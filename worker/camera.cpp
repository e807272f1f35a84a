#include "worker/camera.h"

#include <cmath>
#include <numbers>
#include <string>

#include "absl/strings/str_cat.h"
#include "services/scene/source_location.h"

namespace prism::worker {

absl::StatusOr<Camera> Camera::create(const scene::Camera& camera, int width, int height) {
  const bool orthographic = camera.type == "orthographic";
  const bool spherical = camera.type == "spherical";
  if (camera.type != "perspective" && !orthographic && !spherical) {
    return scene::location_error(camera.where,
                                 absl::StrCat("camera \"", camera.type,
                                              "\" is not supported; Prism renders \"perspective\", "
                                              "\"orthographic\" and \"spherical\""));
  }
  if (spherical && camera.mapping != "equalarea" && camera.mapping != "equirectangular") {
    return scene::location_error(camera.where,
                                 absl::StrCat("spherical camera mapping \"", camera.mapping,
                                              "\": want equalarea or equirectangular"));
  }
  if (width < 1 || height < 1 || width > scene::kMaxResolution || height > scene::kMaxResolution) {
    return scene::location_error(
        camera.where, absl::StrCat("film resolution ", width, "x", height, " is outside 1..",
                                   scene::kMaxResolution, " per axis"));
  }
  if (!orthographic && !spherical && !(camera.fov_deg > 0.0 && camera.fov_deg < 180.0)) {
    return scene::location_error(
        camera.where, absl::StrCat("fov ", camera.fov_deg, " must be in (0, 180) degrees"));
  }
  if (!(camera.lens_radius >= 0.0) || !std::isfinite(camera.lens_radius)) {
    return scene::location_error(camera.where,
                                 absl::StrCat("lensradius ", camera.lens_radius, " must be >= 0"));
  }
  if (camera.lens_radius > 0.0 &&
      !(camera.focal_distance > 0.0 && std::isfinite(camera.focal_distance))) {
    return scene::location_error(camera.where,
                                 absl::StrCat("focaldistance ", camera.focal_distance,
                                              " must be > 0 for a thin lens (lensradius > 0)"));
  }

  // pbrt-v4 CameraBase: the screen window spans [-1, 1] on the shorter axis, so `fov` does too.
  double xmin, xmax, ymin, ymax;
  if (camera.screen_window) {
    xmin = (*camera.screen_window)[0];
    xmax = (*camera.screen_window)[1];
    ymin = (*camera.screen_window)[2];
    ymax = (*camera.screen_window)[3];
  } else {
    const double frame = camera.frame_aspect_ratio.value_or(double(width) / double(height));
    if (!(frame > 0.0) || !std::isfinite(frame)) {
      return scene::location_error(camera.where,
                                   absl::StrCat("frameaspectratio ", frame, " must be > 0"));
    }
    if (frame > 1.0) {
      xmin = -frame, xmax = frame, ymin = -1.0, ymax = 1.0;
    } else {
      xmin = -1.0, xmax = 1.0, ymin = -1.0 / frame, ymax = 1.0 / frame;
    }
  }
  if (!(xmax > xmin) || !(ymax > ymin)) {
    return scene::location_error(
        camera.where, absl::StrCat("screenwindow [", xmin, " ", xmax, " ", ymin, " ", ymax,
                                   "] is empty; it needs xmin < xmax and ymin < ymax"));
  }

  // Perspective: screen space maps to the z = 1 plane scaled by tan(fov/2) (pbrt-v4's
  // Perspective()); orthographic: screen space is camera space on z = 0, unscaled.
  // Raster (0, 0) is the window's top-left corner, (xmin, ymax): raster y runs down, screen y up.
  const double tan_half =
      orthographic ? 1.0 : std::tan(camera.fov_deg * 0.5 * std::numbers::pi / 180.0);
  Camera c;
  c.orthographic_ = orthographic;
  c.spherical_ = spherical ? (camera.mapping == "equalarea" ? 1 : 2) : 0;
  c.width_ = width;
  c.height_ = height;
  c.screen_x0_ = xmin * tan_half;
  c.screen_dx_ = (xmax - xmin) * tan_half / width;
  c.screen_y0_ = ymax * tan_half;
  c.screen_dy_ = -(ymax - ymin) * tan_half / height;
  c.lens_radius_ = camera.lens_radius;
  c.focal_distance_ = camera.focal_distance;
  c.world_from_camera_ = camera.world_from_camera;
  c.camera_from_world_ = camera.world_from_camera.inverse();
  return c;
}

std::optional<CameraConnection> Camera::connect(const Vec3f& p, float margin, Point2f lens) const {
  const scene::Vec3 q = camera_from_world_.apply_point({p.x, p.y, p.z});
  if (!(q[2] > 0.0)) return std::nullopt;
  // The lens point (the pinhole: the origin) and the ray from it through q.
  double lx = 0.0, ly = 0.0;
  if (lens_radius_ > 0.0) {
    const Point2f d = sample_uniform_disk_concentric(lens);
    lx = lens_radius_ * d.x;
    ly = lens_radius_ * d.y;
  }
  const double vx = q[0] - lx, vy = q[1] - ly, vz = q[2];
  // Where it meets z = f, over f: the z = 1 point whose pinhole ray every lens point aims at.
  const double f = lens_radius_ > 0.0 ? focal_distance_ : 1.0;
  const double sx = (lx + vx * f / vz) / f, sy = (ly + vy * f / vz) / f;
  const double rx = (sx - screen_x0_) / screen_dx_, ry = (sy - screen_y0_) / screen_dy_;
  if (!(rx >= -margin && rx < width_ + margin && ry >= -margin && ry < height_ + margin)) {
    return std::nullopt;
  }
  // cos θ in camera space (angles survive a similarity world_from_camera).
  const double cos_theta = vz / std::sqrt(vx * vx + vy * vy + vz * vz);
  const scene::Vec3 o = world_from_camera_.apply_point({lx, ly, 0.0});
  const double dx = o[0] - p.x, dy = o[1] - p.y, dz = o[2] - p.z;
  const double distance = std::sqrt(dx * dx + dy * dy + dz * dz);
  if (!(distance > 0.0)) return std::nullopt;
  CameraConnection c;
  c.raster = {float(rx), float(ry)};
  c.to_camera = {float(dx / distance), float(dy / distance), float(dz / distance)};
  c.distance = float(distance);
  c.lens_point = {float(o[0]), float(o[1]), float(o[2])};
  c.importance =
      float(1.0 / (std::abs(screen_dx_ * screen_dy_) * cos_theta * cos_theta * cos_theta));
  return c;
}

Point2f Camera::raster_differential(const Vec3f& p, const Vec3f& dp) const {
  const scene::Vec3 q = camera_from_world_.apply_point({p.x, p.y, p.z});
  const scene::Vec3 dq = camera_from_world_.apply_vector({dp.x, dp.y, dp.z});
  if (!(q[2] > 0.0)) return {};
  // raster = ((q_x/q_z − x0)/dx, (q_y/q_z − y0)/dy): the quotient rule.
  const double inv = 1.0 / (q[2] * q[2]);
  return {float((dq[0] * q[2] - q[0] * dq[2]) * inv / screen_dx_),
          float((dq[1] * q[2] - q[1] * dq[2]) * inv / screen_dy_)};
}

float Camera::pixel_footprint(const Vec3f& p) const {
  const scene::Vec3 q = camera_from_world_.apply_point({p.x, p.y, p.z});
  if (!(q[2] > 0.0)) return 0.0f;
  const double axis = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]) / q[2];
  return float(q[2] * std::max(std::abs(screen_dx_), std::abs(screen_dy_)) * axis);
}

Ray Camera::generate_ray(Point2f film, Point2f lens) const {
  if (spherical_ != 0) {
    // pbrt-v4's SphericalCamera: the film's (u, v) in [0, 1]² picks a direction on the whole
    // sphere, the map's z axis turned to camera +y.
    const Point2f uv{film.x / float(width_), film.y / float(height_)};
    Vec3f d;
    if (spherical_ == 1) {
      d = equal_area_square_to_sphere(uv);
    } else {
      const double theta = std::numbers::pi * uv.y, phi = 2.0 * std::numbers::pi * uv.x;
      d = {float(std::sin(theta) * std::cos(phi)), float(std::sin(theta) * std::sin(phi)),
           float(std::cos(theta))};
    }
    std::swap(d.y, d.z);
    const scene::Vec3 o = world_from_camera_.apply_point({0.0, 0.0, 0.0});
    const scene::Vec3 w = world_from_camera_.apply_vector({d.x, d.y, d.z});
    const double len = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    return Ray{{float(o[0]), float(o[1]), float(o[2])},
               {float(w[0] / len), float(w[1] / len), float(w[2] / len)}};
  }
  // Everything in double: the camera transform may carry large translations (scenes in mm).
  const double px = screen_x0_ + double(film.x) * screen_dx_;
  const double py = screen_y0_ + double(film.y) * screen_dy_;
  scene::Vec3 origin{0.0, 0.0, 0.0};
  scene::Vec3 direction{px, py, 1.0};
  if (orthographic_) {
    // pbrt-v4's OrthographicCamera: parallel rays from the film point; a thin lens aims every
    // lens point at where that ray meets z = f.
    origin = {px, py, 0.0};
    direction = {0.0, 0.0, 1.0};
    if (lens_radius_ > 0.0) {
      const Point2f d = sample_uniform_disk_concentric(lens);
      origin = {px + lens_radius_ * d.x, py + lens_radius_ * d.y, 0.0};
      direction = {px - origin[0], py - origin[1], focal_distance_};
    }
  } else if (lens_radius_ > 0.0) {
    // The pinhole ray through this film point meets z = f at f·(px, py, 1); every lens point
    // aims there, which is what puts that plane in focus.
    const Point2f d = sample_uniform_disk_concentric(lens);
    origin = {lens_radius_ * d.x, lens_radius_ * d.y, 0.0};
    direction = {px * focal_distance_ - origin[0], py * focal_distance_ - origin[1],
                 focal_distance_};
  }
  const scene::Vec3 o = world_from_camera_.apply_point(origin);
  const scene::Vec3 w = world_from_camera_.apply_vector(direction);
  const double len = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
  return Ray{{float(o[0]), float(o[1]), float(o[2])},
             {float(w[0] / len), float(w[1] / len), float(w[2] / len)}};
}

Vec3f Camera::position() const {
  const scene::Vec3 o = world_from_camera_.apply_point({0.0, 0.0, 0.0});
  return {float(o[0]), float(o[1]), float(o[2])};
}

}  // namespace prism::worker
