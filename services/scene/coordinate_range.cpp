#include "services/scene/coordinate_range.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <variant>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/str_cat.h"
#include "services/base/status.h"

namespace prism::scene {
namespace {

struct Box {
  Vec3 lo{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
          std::numeric_limits<double>::infinity()};
  Vec3 hi{-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
          -std::numeric_limits<double>::infinity()};

  bool empty() const { return !(lo[0] <= hi[0]); }
  void add(const Vec3& p) {
    for (int i = 0; i < 3; ++i) {
      lo[i] = std::min(lo[i], p[i]);
      hi[i] = std::max(hi[i], p[i]);
    }
  }
  void add(const Box& b) {
    if (b.empty()) return;
    add(b.lo);
    add(b.hi);
  }
  Vec3 corner(int k) const {
    return {(k & 1) ? hi[0] : lo[0], (k & 2) ? hi[1] : lo[1], (k & 4) ? hi[2] : lo[2]};
  }
};

// The largest |coordinate| of p, or infinity when one is not finite.
double magnitude(const Vec3& p) {
  double m = 0.0;
  for (double c : p) {
    if (!std::isfinite(c)) return std::numeric_limits<double>::infinity();
    m = std::max(m, std::abs(c));
  }
  return m;
}

// The box's eight corners through t: a bound of the transformed box (t is affine).
Box transformed(const Box& b, const Transform& t) {
  Box out;
  if (b.empty()) return out;
  for (int k = 0; k < 8; ++k) out.add(t.apply_point(b.corner(k)));
  return out;
}

double magnitude(const Box& b) {
  return b.empty() ? 0.0 : std::max(magnitude(b.lo), magnitude(b.hi));
}

Box object_bounds(const ShapeGeometry& g,
                  absl::flat_hash_map<const TriangleMeshData*, Box>& mesh_bounds) {
  Box b;
  if (const auto* m = std::get_if<TriangleMeshShape>(&g)) {
    if (m->mesh == nullptr) return b;
    auto [it, inserted] = mesh_bounds.try_emplace(m->mesh.get());
    if (inserted) {
      for (const Float3& p : m->mesh->positions) it->second.add(Vec3{p.x, p.y, p.z});
    }
    return it->second;
  }
  if (const auto* s = std::get_if<SphereShape>(&g)) {
    b.add(Vec3{-s->radius, -s->radius, -s->radius});
    b.add(Vec3{s->radius, s->radius, s->radius});
  } else if (const auto* d = std::get_if<DiskShape>(&g)) {
    b.add(Vec3{-d->radius, -d->radius, d->height});
    b.add(Vec3{d->radius, d->radius, d->height});
  } else if (const auto* c = std::get_if<CylinderShape>(&g)) {
    b.add(Vec3{-c->radius, -c->radius, c->z_min});
    b.add(Vec3{c->radius, c->radius, c->z_max});
  }
  return b;
}

absl::Status too_far(const SourceLocation& where, absl::string_view what, double reach) {
  return location_error(
      where,
      absl::StrCat(what, " reaches coordinates of ", reach, ", beyond the ", kMaxSceneCoordinate,
                   " that Prism's ray tracer (Embree) can carry: move it closer or scale "
                   "the scene down"));
}

}  // namespace

absl::Status check_coordinate_range(const SceneDescription& scene) {
  absl::flat_hash_map<const TriangleMeshData*, Box> mesh_bounds;
  std::vector<Box> objects(scene.shapes.size());
  Box extent;
  for (std::size_t i = 0; i < scene.shapes.size(); ++i) {
    const Shape& shape = scene.shapes[i];
    objects[i] = object_bounds(shape.geometry, mesh_bounds);
    const Box world = transformed(objects[i], shape.object_to_world);
    if (const double m = magnitude(world); !(m <= kMaxSceneCoordinate)) {
      return too_far(shape.where, "the shape", m);
    }
    extent.add(world);
  }
  const Vec3 eye = scene.camera.world_from_camera.apply_point({0.0, 0.0, 0.0});
  if (const double m = magnitude(eye); !(m <= kMaxSceneCoordinate)) {
    return too_far(scene.camera.where, "the camera", m);
  }
  extent.add(eye);
  for (const Light& light : scene.lights) {
    if (!std::holds_alternative<PointLight>(light.kind) &&
        !std::holds_alternative<SpotLight>(light.kind)) {
      continue;
    }
    const Vec3 p = light.light_to_world.apply_point({0.0, 0.0, 0.0});
    if (const double m = magnitude(p); !(m <= kMaxSceneCoordinate)) {
      return too_far(light.where, "the light", m);
    }
    extent.add(p);
  }
  // Rays reach a shape's object space through the inverse of its transform (Embree's instances,
  // Prism's spheres, disks and cylinders): every point of the scene must land within range there.
  for (std::size_t i = 0; i < scene.shapes.size(); ++i) {
    const Shape& shape = scene.shapes[i];
    const Box mapped = transformed(extent, shape.object_to_world.inverse());
    if (const double m = magnitude(mapped); !(m <= kMaxSceneCoordinate)) {
      return location_error(
          shape.where,
          absl::StrCat("the shape's transform maps the scene (within ", magnitude(extent),
                       " of the origin) to coordinates of ", m,
                       " in the shape's own space, "
                       "beyond the ",
                       kMaxSceneCoordinate,
                       " that Prism's ray tracer (Embree) can carry: is the shape scaled down by a "
                       "huge factor?"));
    }
  }
  return absl::OkStatus();
}

}  // namespace prism::scene
