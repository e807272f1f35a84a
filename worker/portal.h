// pbrt-v4's portal on an image environment: a rectangle (a window in a wall, say) through which
// alone the map lights the scene. A ray escaping from p along w sees the map when it crosses the
// rectangle towards the portal's front, +z of the frame x = (p3 − p0)/|…|, y = (p1 − p0)/|…|
// (pbrt-v4's Frame::FromXY(p03, p01)), and nothing otherwise.
//
// Sampling is uniform in the rectified angles of pbrt-v4's portal parametrisation: a local
// direction w = normalize(tan α, tan β, 1) has α = atan2(w.x, w.z), β = atan2(w.y, w.z), and the
// window seen from p is exactly an (α, β) box, because a rectangle's edges run along the frame's
// axes. The solid angle per unit α·β is (1 − w.x²)(1 − w.y²)/w.z, which is 1 facing the window
// and falls towards grazing. pbrt-v4 also weighs the box by the map's brightness; Prism mixes
// this window density with the map's own (worker/light.cpp), which covers a bright sun too.
//
// Thread-safety: immutable after create.
#pragma once

#include <array>
#include <optional>

#include "services/scene/scene_description.h"
#include "worker/vecmath.h"

namespace prism::worker {

class Portal {
 public:
  // `corners` p0..p3 form a rectangle (the parser checks it) in world space.
  static Portal create(const std::array<scene::Vec3, 4>& corners);

  // Whether the ray from p along w (unit) crosses the rectangle towards its front.
  bool passes(const Vec3f& p, const Vec3f& w) const;
  struct Sample {
    Vec3f w;
    float pdf = 0;  // solid angle
  };
  // A direction from p through the window; nullopt when p is not behind the portal.
  std::optional<Sample> sample(const Vec3f& p, Point2f u) const;
  // The solid-angle density of sample(p, ·) at w; 0 when w does not pass the window.
  float pdf(const Vec3f& p, const Vec3f& w) const;
  double area() const { return width_ * height_; }

 private:
  // The (α, β) box the window covers seen from p; false when p is not behind the portal.
  struct Box {
    double alpha0, alpha1, beta0, beta1;
  };
  bool box_from(const Vec3f& p, Box* box) const;

  std::array<double, 3> origin_{};  // p0
  std::array<double, 3> x_{}, y_{}, z_{};
  double width_ = 0, height_ = 0;  // |p3 − p0| along x, |p1 − p0| along y
};

}  // namespace prism::worker
