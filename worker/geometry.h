// World geometry on Embree 3: every shape of a SceneDescription as Embree geometry in one
// committed scene, plus what shading needs at a hit. Triangle meshes are moved to world space at
// build time and shared with Embree without a copy; a mesh object used by several shapes (pbrt
// object instancing) is built once in its own scene and instanced. Spheres are exact: an
// Embree sphere primitive in object space inside an instance carrying the shape's transform, so
// any affine transform (an ellipsoid) is still intersected exactly. Disks and cylinders are
// exact too: Embree user geometry in object space, inside an instance.
//
// Normals follow pbrt-v4 (scene_description.h): a triangle's geometric normal is
// cross(p0 − p2, p1 − p2) from world positions, negated under reverse orientation XOR a
// handedness-swapping transform, or turned to the side of the interpolated vertex normal when
// the mesh has one (vertex normals negated under reverse orientation, as pbrt-v4's meshes do). A
// sphere's, disk's or cylinder's normal is its object-space normal (outwards; +z on a disk) carried
// by the transform's normal matrix, negated under reverse orientation only: a mirroring transform
// then leaves the outside outside, as it does for a mesh. pbrt-v4 negates it under a mirroring
// transform too when it intersects the shape, though not when it samples it as a light
// (docs/conformance.md, "Mirrored spheres, disks and cylinders"). Area lights emit on the geometric
// normal's side.
//
// Bilinear patches (pbrt-v4's "bilinearmesh" and a PLY file's quads; scene::TriangleMeshData's
// `patches`) arrive as two triangles each. A mesh whose patches are all flat (parallelograms
// whose vertex normals and uvs are affine too, e.g. every wall and lamp of a Cornell box) is
// those triangles: the same surface with the same interpolation. A mesh with any other patch is
// intersected face by face in Prism's own code (Embree user geometry): each patch as pbrt-v4's
// curved bilinear surface p(u, v) = lerp(v, lerp(u, p00, p10), lerp(u, p01, p11)), its
// geometric normal cross(dp/du, dp/dv) under the triangles' orientation rule, its vertex
// normals and uvs interpolated bilinearly; a hit on it reports the first of its two triangles.
//
// Thread-safety: after build(), intersect() and occluded() are const and safe from any thread.
#pragma once

#include <embree3/rtcore.h>

#include <atomic>
#include <cmath>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "absl/status/statusor.h"
#include "services/scene/scene_description.h"
#include "worker/embree_device.h"
#include "worker/vecmath.h"

namespace prism::worker {

struct Ray {
  Vec3f origin;
  Vec3f direction;  // not necessarily unit length; t is in units of |direction|
};

struct SurfaceHit {
  float t = 0;
  Vec3f p;     // world position
  Vec3f ng;    // unit geometric normal (pbrt-v4 orientation, see above)
  Vec3f ns;    // unit shading normal, on the same side as ng
  Vec3f dpdu;  // surface tangent for anisotropic frames (may be zero)
  Point2f uv;
  int shape = -1;               // index into SceneDescription::shapes
  std::uint32_t primitive = 0;  // triangle index within the shape's mesh (0 for spheres)
  // The primitive's own parameters at the hit: a triangle's barycentrics of p1 and p2, a
  // bilinear patch's (u, v); zero on spheres, disks and cylinders.
  Point2f param;
};

// Sees every query a Geometry answers (closest hit or occlusion), for prism-bench-tracer, which
// records a render's rays and replays them through bare Embree calls. Called on the tracing
// threads, concurrently; an implementation must be thread-safe.
class RayObserver {
 public:
  virtual void traced(const Ray& ray, float t_max, bool shadow) const = 0;

 protected:
  ~RayObserver() = default;
};

struct Bounds3f {
  Vec3f lo{1e30f, 1e30f, 1e30f};
  Vec3f hi{-1e30f, -1e30f, -1e30f};
  void extend(const Vec3f& p);
  Vec3f centre() const { return (lo + hi) * 0.5f; }
  float radius() const { return length(hi - lo) * 0.5f; }
};

// A shape's alpha (pbrt-v4's `alpha`, a float or a float texture) at a hit's uv and unit
// geometric normal; empty for opaque shapes.
using AlphaFunction = std::function<float(const Point2f& uv, const Vec3f& n)>;

// Whether a sphere, disk or cylinder's normal is negated (see above).
inline bool quadric_flip(const scene::Shape& shape) {
  return shape.reverse_orientation;
}

class Geometry {
 public:
  // Builds and commits the scene. `alpha` (empty, or one per shape) makes shapes cut-outs:
  // pbrt-v4's stochastic test, a hit with alpha a < 1 is ignored when a hash of the ray and the
  // hit distance, uniform in [0, 1), exceeds a (always when a <= 0), for every ray, shadow rays
  // included. The hash includes the distance so that layers along one ray decide independently,
  // as pbrt-v4's re-spawned rays do. Errors: Embree failures (with Embree's message) or shapes
  // Prism cannot intersect.
  static absl::StatusOr<std::unique_ptr<Geometry>> build(EmbreeDevice& device,
                                                         const scene::SceneDescription& scene,
                                                         std::vector<AlphaFunction> alpha = {});
  ~Geometry();
  Geometry(const Geometry&) = delete;
  Geometry& operator=(const Geometry&) = delete;

  // Closest hit with t in (0, t_max). A ray Embree cannot take (a NaN, or a coordinate or
  // direction component beyond kMaxRayCoordinate: Embree's own check would abort the process)
  // hits nothing, and occluded() calls it blocked, so that a numerical accident loses one path
  // instead of the worker. The scene's load refuses coordinates that could reach that far
  // (services/scene/coordinate_range.h), so a valid scene's rays never meet this.
  std::optional<SurfaceHit> intersect(const Ray& ray, float t_max) const;
  // How the hit's unit shading normal ns changes when its point moves by the tangent vector dp
  // (first order, world space): Igehy's normal differential, used by spectral ray differentials
  // (spectral_differential.h). Exact for the shape's own normal field: a sphere's (under any
  // affine transform), a cylinder's, interpolated vertex normals; 0 on flat triangles and disks.
  Vec3f normal_differential(const SurfaceHit& hit, const Vec3f& dp) const;
  // True when anything blocks the segment origin + t·direction, t in (0, t_max), or when
  // Embree cannot take the ray (see intersect).
  bool occluded(const Ray& ray, float t_max) const;
  // Embree's largest ray coordinate (its FLT_LARGE, 1.844e18).
  static constexpr float kMaxRayCoordinate = 1.844e18f;
  static bool embree_can_trace(const Ray& ray, float t_max) {
    auto in_range = [](float x) { return std::abs(x) <= kMaxRayCoordinate; };  // false for NaN
    return in_range(ray.origin.x) & in_range(ray.origin.y) & in_range(ray.origin.z) &
           in_range(ray.direction.x) & in_range(ray.direction.y) & in_range(ray.direction.z) &
           !std::isnan(t_max);
  }
  // Every later query is also passed to `observer` (null: none, the default). Set it while
  // nothing traces; it must outlive the queries. Costs one predictable branch per query.
  void observe(const RayObserver* observer) const {
    observer_.store(observer, std::memory_order_relaxed);
  }
  // The committed Embree scene, for benchmarks that time bare Embree calls on it.
  RTCScene embree_scene() const { return scene_; }

  const Bounds3f& bounds() const { return bounds_; }
  // One shape's world bounds (a box around it for spheres, disks and cylinders).
  const Bounds3f& shape_bounds(int shape) const { return shape_bounds_[std::size_t(shape)]; }
  // World-space triangle of a mesh shape (for area light sampling).
  struct WorldTriangle {
    Vec3f p0, p1, p2;
    Vec3f n0, n1, n2;  // vertex normals, or all zero
    bool has_normals = false;
    bool flip = false;  // reverse orientation XOR handedness swap
    // The unit geometric normal, oriented (flip applied); (0, 0, ±1) for a degenerate triangle.
    Vec3f unit_normal() const {
      Vec3f n = cross(p0 - p2, p1 - p2);
      const float len = length(n);
      n = len > 0 ? n / len : Vec3f(0, 0, 1);
      return flip ? -n : n;
    }
  };
  WorldTriangle triangle(int shape, std::uint32_t primitive) const;
  std::uint32_t triangle_count(int shape) const;

  // What a mesh triangle is to the intersector: a triangle, the first triangle of a curved
  // bilinear patch (hits on the patch report it), or the patch's second (never hit).
  enum class MeshFace : std::uint8_t { kTriangle, kPatch, kPatchRest };
  MeshFace face(int shape, std::uint32_t primitive) const;
  // A curved patch in world space, given its first triangle.
  struct WorldPatch {
    Vec3f p00, p10, p01, p11;
    Vec3f n00, n10, n01, n11;  // vertex normals (negated under reverse orientation), or zero
    bool has_normals = false;
    bool flip = false;  // reverse orientation XOR handedness swap
    Vec3f point(float u, float v) const;
    Vec3f dpdu(float v) const { return (p10 - p00) * (1 - v) + (p11 - p01) * v; }
    Vec3f dpdv(float u) const { return (p01 - p00) * (1 - u) + (p11 - p10) * u; }
    // |dp/du × dp/dv|: the area element of the (u, v) square.
    float area_element(float u, float v) const { return length(cross(dpdu(v), dpdv(u))); }
    // The interpolated vertex normal (not unit), or zero without normals.
    Vec3f shading_normal(float u, float v) const;
    // The unit geometric normal a hit at (u, v) gets: cross(dp/du, dp/dv), negated when `flip`,
    // or turned to the vertex normal's side when there is one.
    Vec3f unit_normal(float u, float v) const;
  };
  WorldPatch patch(int shape, std::uint32_t primitive) const;
  // The texture uv at a curved patch's (u, v): its vertex uvs interpolated bilinearly, or (u, v)
  // itself when the mesh has none.
  Point2f patch_uv(int shape, std::uint32_t primitive, float u, float v) const;

  // Whether the shape has an alpha, and its value at a point of the surface (unit geometric
  // normal n), for sampling emitters: on a mesh triangle by the barycentrics of p1 and p2 (the
  // hit's u, v), on a curved patch by its (u, v), on a sphere, disk or cylinder at the world
  // point p. 1 without an alpha.
  bool has_alpha(int shape) const { return size_t(shape) < alpha_.size() && alpha_[size_t(shape)]; }
  float alpha_on_triangle(int shape, std::uint32_t primitive, float u, float v,
                          const Vec3f& n) const;
  float alpha_at_point(int shape, const Vec3f& p, const Vec3f& n) const;

  // A small offset along the normal for rays leaving a surface at p, scaled with the scene's
  // extent so millimetre and kilometre scenes both avoid self-intersection.
  Vec3f offset_origin(const Vec3f& p, const Vec3f& ng, const Vec3f& direction) const;

  // What Embree's user callbacks for disks and cylinders read (object space); public for the
  // callbacks only.
  struct QuadricShapeData {
    bool cylinder = false;
    float radius = 1;
    float height = 0, inner_radius = 0;  // disk
    float z_min = -1, z_max = 1;         // cylinder
    const AlphaFunction* alpha = nullptr;
  };
  // What the triangle and sphere filter callbacks read; public for the callbacks only.
  struct AlphaFilter;
  // What the user callbacks of a mesh with curved patches read (the mesh's own space: world, or
  // object space when instanced); public for the callbacks only.
  struct FaceMeshData {
    static constexpr std::uint32_t kPatchBit = 0x80000000u;
    const scene::Float3* positions = nullptr;
    const scene::Float2* uvs = nullptr;  // null: none
    const scene::Triangle* triangles = nullptr;
    // Per face its first triangle, with kPatchBit set for a patch (triangles t and t + 1).
    std::vector<std::uint32_t> faces;
    const AlphaFunction* alpha = nullptr;
  };

 private:
  Geometry() = default;
  struct MeshShape;
  struct SphereShape;
  struct QuadricShape;
  SurfaceHit finish_quadric_hit(int shape, const Ray& ray, float t) const;
  SurfaceHit finish_triangle_hit(int shape, std::uint32_t prim, float u, float v, float t) const;
  SurfaceHit finish_sphere_hit(int shape, const Ray& ray, float t) const;
  SurfaceHit finish_patch_hit(int shape, std::uint32_t prim, float u, float v, float t) const;
  // Building (build): each shape kind into the scene, with its bounds and alpha filter.
  void add_mesh(std::size_t shape_index, const scene::Shape& shape,
                const scene::TriangleMeshShape& mesh,
                RTCScene* instanced);  // the shared mesh's scene (null: not shared)
  void add_sphere(std::size_t shape_index, const scene::Shape& shape,
                  const scene::SphereShape& sphere);
  void add_quadric(std::size_t shape_index, const scene::Shape& shape);
  // Cut-outs get Embree filter callbacks reading this per-geometry data.
  void add_alpha_filter(RTCGeometry geom, std::size_t shape, const MeshShape* mesh);
  void attach_triangles(RTCScene target, MeshShape& mesh, unsigned id, std::size_t shape);
  // A mesh with curved patches: one user primitive per face (FaceMeshData).
  void attach_faces(RTCScene target, MeshShape& mesh, unsigned id, std::size_t shape);
  void attach_instance(RTCScene child, const scene::Transform& t, unsigned id);
  // An object-space primitive in its own scene, instanced with the shape's transform; its
  // object-space box [lo, hi] extends the world bounds.
  void attach_object_space(RTCGeometry geom, const scene::Transform& t, unsigned id,
                           const scene::Vec3& lo, const scene::Vec3& hi);

  EmbreeDevice* device_ = nullptr;
  RTCScene scene_ = nullptr;
  std::vector<RTCScene> sub_scenes_;
  // Per shape: either mesh data (world space, or object space for instanced meshes) or sphere
  // data. Indexed by shape; geometry IDs equal shape indices.
  std::vector<std::unique_ptr<MeshShape>> meshes_;
  std::vector<std::unique_ptr<SphereShape>> spheres_;
  std::vector<std::unique_ptr<QuadricShape>> quadrics_;
  std::vector<AlphaFunction> alpha_;  // per shape (empty: none)
  std::vector<std::unique_ptr<AlphaFilter>> filters_;
  Bounds3f bounds_;
  std::vector<Bounds3f> shape_bounds_;
  float epsilon_ = 1e-4f;
  mutable std::atomic<const RayObserver*> observer_{nullptr};
};

}  // namespace prism::worker
