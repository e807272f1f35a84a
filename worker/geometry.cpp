#include "worker/geometry.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "worker/float_hash.h"

namespace prism::worker {
namespace {

using scene::Float3;

Vec3f to_vec(const scene::Vec3& v) {
  return {float(v[0]), float(v[1]), float(v[2])};
}
scene::Vec3 to_double(const Vec3f& v) {
  return {v.x, v.y, v.z};
}
Vec3f to_vec(const Float3& f) {
  return {f.x, f.y, f.z};
}

// Embree wants a row-major 3x4 matrix (RTC_FORMAT_FLOAT3X4_ROW_MAJOR).
void instance_matrix(const scene::Transform& t, float out[12]) {
  const auto& m = t.matrix();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) out[r * 4 + c] = float(m[r][c]);
  }
}

}  // namespace

void Bounds3f::extend(const Vec3f& p) {
  lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
  hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
}

struct Geometry::MeshShape {
  // World-space positions for a flattened mesh; object-space for an instanced one. Padded by
  // one element for Embree's 16-byte loads.
  std::vector<Float3> positions;
  std::vector<Float3> normals;
  std::vector<scene::Float2> uvs;
  std::shared_ptr<const scene::TriangleMeshData> source;  // triangles (and instanced data)
  bool instanced = false;
  scene::Transform object_to_world;
  bool flip = false;
  std::uint32_t vertex_count = 0;
};

struct Geometry::SphereShape {
  double radius = 1;
  scene::Transform object_to_world;
  scene::Transform world_to_object;
  bool flip = false;
};

// The object-space data (QuadricShapeData) is what Embree's user callbacks read; the instance
// carries the transform.
struct Geometry::QuadricShape : QuadricShapeData {
  scene::Transform object_to_world;
  scene::Transform world_to_object;
  bool flip = false;
};

struct Geometry::AlphaFilter {
  const AlphaFunction* alpha = nullptr;
  const MeshShape* mesh = nullptr;  // triangles: the uvs; null for spheres
};

namespace {

// A mesh triangle's vertex uvs: the mesh's, or pbrt-v4's default (0,0), (1,0), (1,1).
std::array<Point2f, 3> triangle_uvs(const std::vector<scene::Float2>& uvs,
                                    const scene::Triangle& tri) {
  if (uvs.empty()) return {Point2f{0, 0}, Point2f{1, 0}, Point2f{1, 1}};
  return {Point2f{uvs[tri[0]].u, uvs[tri[0]].v}, Point2f{uvs[tri[1]].u, uvs[tri[1]].v},
          Point2f{uvs[tri[2]].u, uvs[tri[2]].v}};
}

// The uv at barycentrics (u, v) of vertices 1 and 2.
Point2f interpolate_uv(const std::array<Point2f, 3>& t, float u, float v) {
  const float b0 = 1 - u - v;
  return {t[0].x * b0 + t[1].x * u + t[2].x * v, t[0].y * b0 + t[1].y * u + t[2].y * v};
}

// pbrt-v4's parameterisations (object space): u = φ/2π everywhere; v = 1 − θ/π on a sphere about
// the origin, (radius − r)/(radius − inner radius) on a disk, (z − z_min)/(z_max − z_min) on a
// cylinder.
double azimuth_u(double x, double y) {
  double phi = std::atan2(y, x);
  if (phi < 0) phi += 2 * M_PI;
  return phi / (2 * M_PI);
}

Point2f sphere_uv(double x, double y, double z) {
  const double r = std::sqrt(x * x + y * y + z * z);
  const double cos_theta = r > 0 ? std::clamp(z / r, -1.0, 1.0) : 1.0;
  return {float(azimuth_u(x, y)), float(1 - std::acos(cos_theta) / M_PI)};
}

Point2f quadric_uv(const Geometry::QuadricShapeData& q, double x, double y, double z) {
  if (q.cylinder) {
    return {float(azimuth_u(x, y)), float((z - q.z_min) / (double(q.z_max) - double(q.z_min)))};
  }
  const double r = std::sqrt(x * x + y * y);
  return {float(azimuth_u(x, y)),
          float((q.radius - r) / (double(q.radius) - double(q.inner_radius)))};
}

// pbrt-v4's stochastic alpha test for a hit at distance t along the ray (o, d): keep it when a
// hash of (o, d, t), uniform in [0, 1), is at most the alpha there.
bool alpha_keeps(const AlphaFunction& alpha, const Point2f& uv, const Vec3f& n, float ox, float oy,
                 float oz, float dx, float dy, float dz, float t) {
  const float a = alpha(uv, n);
  if (a >= 1.0f) return true;
  if (!(a > 0.0f)) return false;
  // The distance t makes layers along one ray decide independently.
  const float u = unit_float(hash_floats(0, {ox, oy, oz, dx, dy, dz, t}));
  return u <= a;
}

Vec3f unit_or_z(float x, float y, float z) {
  const Vec3f n(x, y, z);
  const float len = length(n);
  return len > 0 ? n / len : Vec3f(0, 0, 1);
}

// Intersection and occlusion filters of cut-out triangles and spheres (N = 1).
void alpha_filter(const RTCFilterFunctionNArguments* args) {
  if (args->valid[0] == 0) return;
  const auto* f = static_cast<const Geometry::AlphaFilter*>(args->geometryUserPtr);
  RTCRayN* ray = args->ray;
  RTCHitN* hit = args->hit;
  const float ox = RTCRayN_org_x(ray, 1, 0), oy = RTCRayN_org_y(ray, 1, 0),
              oz = RTCRayN_org_z(ray, 1, 0);
  const float dx = RTCRayN_dir_x(ray, 1, 0), dy = RTCRayN_dir_y(ray, 1, 0),
              dz = RTCRayN_dir_z(ray, 1, 0);
  const float t = RTCRayN_tfar(ray, 1, 0);
  const Vec3f n =
      unit_or_z(RTCHitN_Ng_x(hit, 1, 0), RTCHitN_Ng_y(hit, 1, 0), RTCHitN_Ng_z(hit, 1, 0));
  Point2f uv;
  if (f->mesh != nullptr) {
    const auto& tri = f->mesh->source->triangles[RTCHitN_primID(hit, 1, 0)];
    uv =
        interpolate_uv(triangle_uvs(f->mesh->uvs, tri), RTCHitN_u(hit, 1, 0), RTCHitN_v(hit, 1, 0));
  } else {
    // The sphere's object space (the instance's): the hit point on the sphere about the origin.
    uv = sphere_uv(ox + double(t) * dx, oy + double(t) * dy, oz + double(t) * dz);
  }
  if (!alpha_keeps(*f->alpha, uv, n, ox, oy, oz, dx, dy, dz, t)) args->valid[0] = 0;
}

// The nearest hit with t in (tnear, tfar) of a quadric in its object space, or −1: a disk is the
// plane z = height where inner_radius <= r <= radius; a cylinder is x² + y² = radius² with
// z_min <= z <= z_max, open at both ends, so a ray may hit its inside. Double precision keeps
// the cylinder's quadratic from cancelling at grazing angles.
float quadric_hit_t(const Geometry::QuadricShapeData& q, const RTCRay& ray) {
  const double ox = ray.org_x, oy = ray.org_y, oz = ray.org_z;
  const double dx = ray.dir_x, dy = ray.dir_y, dz = ray.dir_z;
  if (q.cylinder) {
    const double a = dx * dx + dy * dy;
    if (a == 0) return -1.0f;
    const double b = 2 * (dx * ox + dy * oy);
    const double c = ox * ox + oy * oy - double(q.radius) * q.radius;
    const double discriminant = b * b - 4 * a * c;
    if (discriminant < 0) return -1.0f;
    const double root = std::sqrt(discriminant);
    const double qq = b < 0 ? -0.5 * (b - root) : -0.5 * (b + root);
    double t0 = qq / a, t1 = qq != 0 ? c / qq : t0;
    if (t0 > t1) std::swap(t0, t1);
    for (double t : {t0, t1}) {
      if (!(t > ray.tnear && t < ray.tfar)) continue;
      const double z = oz + t * dz;
      if (!(z >= q.z_min && z <= q.z_max)) continue;
      if (q.alpha != nullptr) {
        const double x = ox + t * dx, y = oy + t * dy;
        if (!alpha_keeps(*q.alpha, quadric_uv(q, x, y, z), unit_or_z(float(x), float(y), 0),
                         ray.org_x, ray.org_y, ray.org_z, ray.dir_x, ray.dir_y, ray.dir_z,
                         float(t))) {
          continue;
        }
      }
      return float(t);
    }
    return -1.0f;
  }
  if (dz == 0) return -1.0f;
  const double t = (q.height - oz) / dz;
  if (!(t > ray.tnear && t < ray.tfar)) return -1.0f;
  const double x = ox + t * dx, y = oy + t * dy;
  const double r2 = x * x + y * y;
  if (r2 > double(q.radius) * q.radius || r2 < double(q.inner_radius) * q.inner_radius) {
    return -1.0f;
  }
  if (q.alpha != nullptr) {
    if (!alpha_keeps(*q.alpha, quadric_uv(q, x, y, q.height), {0, 0, 1}, ray.org_x, ray.org_y,
                     ray.org_z, ray.dir_x, ray.dir_y, ray.dir_z, float(t))) {
      return -1.0f;
    }
  }
  return float(t);
}

void quadric_bounds(const RTCBoundsFunctionArguments* args) {
  const auto* q = static_cast<const Geometry::QuadricShapeData*>(args->geometryUserPtr);
  RTCBounds* b = args->bounds_o;
  b->lower_x = b->lower_y = -q->radius;
  b->upper_x = b->upper_y = q->radius;
  b->lower_z = q->cylinder ? q->z_min : q->height;
  b->upper_z = q->cylinder ? q->z_max : q->height;
}

void quadric_intersect(const RTCIntersectFunctionNArguments* args) {
  if (args->valid[0] == 0) return;
  const auto* q = static_cast<const Geometry::QuadricShapeData*>(args->geometryUserPtr);
  RTCRayHit* rh = reinterpret_cast<RTCRayHit*>(args->rayhit);
  const float t = quadric_hit_t(*q, rh->ray);
  if (t < 0.0f) return;
  rh->ray.tfar = t;
  rh->hit.Ng_x = 0;
  rh->hit.Ng_y = 0;
  rh->hit.Ng_z = 1;
  rh->hit.u = rh->hit.v = 0;
  rh->hit.primID = args->primID;
  rh->hit.geomID = args->geomID;
  rh->hit.instID[0] = args->context->instID[0];
}

void quadric_occluded(const RTCOccludedFunctionNArguments* args) {
  if (args->valid[0] == 0) return;
  const auto* q = static_cast<const Geometry::QuadricShapeData*>(args->geometryUserPtr);
  RTCRay* r = reinterpret_cast<RTCRay*>(args->ray);
  if (quadric_hit_t(*q, *r) >= 0.0f) r->tfar = -std::numeric_limits<float>::infinity();
}

}  // namespace

Geometry::~Geometry() {
  if (scene_ != nullptr) rtcReleaseScene(scene_);
  for (RTCScene s : sub_scenes_) rtcReleaseScene(s);
}

absl::StatusOr<std::unique_ptr<Geometry>> Geometry::build(EmbreeDevice& device,
                                                          const scene::SceneDescription& desc,
                                                          std::vector<AlphaFunction> alpha) {
  if (!device.valid()) return device.take_error();
  std::unique_ptr<Geometry> g(new Geometry());
  g->device_ = &device;
  g->scene_ = rtcNewScene(device.get());
  rtcSetSceneBuildQuality(g->scene_, RTC_BUILD_QUALITY_HIGH);
  g->meshes_.resize(desc.shapes.size());
  g->shape_bounds_.resize(desc.shapes.size());
  g->spheres_.resize(desc.shapes.size());
  g->quadrics_.resize(desc.shapes.size());
  g->alpha_ = std::move(alpha);
  g->alpha_.resize(desc.shapes.size());

  // A mesh object shared by several shapes is instanced; count the sharing first.
  std::map<const scene::TriangleMeshData*, int> uses;
  for (const auto& shape : desc.shapes) {
    if (auto* m = std::get_if<scene::TriangleMeshShape>(&shape.geometry)) ++uses[m->mesh.get()];
  }
  std::map<const scene::TriangleMeshData*, RTCScene> instanced_scenes;
  for (std::size_t i = 0; i < desc.shapes.size(); ++i) {
    const scene::Shape& shape = desc.shapes[i];
    if (auto* m = std::get_if<scene::TriangleMeshShape>(&shape.geometry)) {
      // A cut-out mesh is never shared: its filter is its own.
      const bool shared = uses[m->mesh.get()] > 1 && !g->alpha_[i];
      g->add_mesh(i, shape, *m, shared ? &instanced_scenes[m->mesh.get()] : nullptr);
    } else if (auto* s = std::get_if<scene::SphereShape>(&shape.geometry)) {
      g->add_sphere(i, shape, *s);
    } else if (std::holds_alternative<scene::DiskShape>(shape.geometry) ||
               std::holds_alternative<scene::CylinderShape>(shape.geometry)) {
      g->add_quadric(i, shape);
    }
  }
  rtcCommitScene(g->scene_);
  if (auto status = device.take_error(); !status.ok()) return status;
  if (desc.shapes.empty()) g->bounds_.extend({0, 0, 0});
  float extent = std::max({std::abs(g->bounds_.lo.x), std::abs(g->bounds_.lo.y),
                           std::abs(g->bounds_.lo.z), std::abs(g->bounds_.hi.x),
                           std::abs(g->bounds_.hi.y), std::abs(g->bounds_.hi.z), 1.0f});
  // Float positions carry ~1e-7 relative error; 1e-5 of the extent clears it with margin.
  g->epsilon_ = extent * 1e-5f;
  return g;
}

void Geometry::add_alpha_filter(RTCGeometry geom, std::size_t shape, const MeshShape* mesh) {
  if (!alpha_[shape]) return;
  auto filter = std::make_unique<AlphaFilter>();
  filter->alpha = &alpha_[shape];
  filter->mesh = mesh;
  rtcSetGeometryUserData(geom, filter.get());
  rtcSetGeometryIntersectFilterFunction(geom, alpha_filter);
  rtcSetGeometryOccludedFilterFunction(geom, alpha_filter);
  filters_.push_back(std::move(filter));
}

void Geometry::attach_triangles(RTCScene target, MeshShape& mesh, unsigned id, std::size_t shape) {
  RTCGeometry geom = rtcNewGeometry(device_->get(), RTC_GEOMETRY_TYPE_TRIANGLE);
  add_alpha_filter(geom, shape, &mesh);
  rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                             mesh.positions.data(), 0, sizeof(Float3), mesh.vertex_count);
  rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                             mesh.source->triangles.data(), 0, sizeof(scene::Triangle),
                             mesh.source->triangles.size());
  rtcCommitGeometry(geom);
  rtcAttachGeometryByID(target, geom, id);
  rtcReleaseGeometry(geom);
}

void Geometry::attach_instance(RTCScene child, const scene::Transform& t, unsigned id) {
  RTCGeometry inst = rtcNewGeometry(device_->get(), RTC_GEOMETRY_TYPE_INSTANCE);
  rtcSetGeometryInstancedScene(inst, child);
  float m[12];
  instance_matrix(t, m);
  rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, m);
  rtcCommitGeometry(inst);
  rtcAttachGeometryByID(scene_, inst, id);
  rtcReleaseGeometry(inst);
}

void Geometry::attach_object_space(RTCGeometry geom, const scene::Transform& t, unsigned id,
                                   const scene::Vec3& lo, const scene::Vec3& hi) {
  RTCScene child = rtcNewScene(device_->get());
  rtcCommitGeometry(geom);
  rtcAttachGeometryByID(child, geom, 0);
  rtcReleaseGeometry(geom);
  rtcCommitScene(child);
  sub_scenes_.push_back(child);
  attach_instance(child, t, id);
  for (int corner = 0; corner < 8; ++corner) {
    const scene::Vec3 c{corner & 1 ? hi[0] : lo[0], corner & 2 ? hi[1] : lo[1],
                        corner & 4 ? hi[2] : lo[2]};
    bounds_.extend(to_vec(t.apply_point(c)));
    shape_bounds_[id].extend(to_vec(t.apply_point(c)));
  }
}

void Geometry::add_mesh(std::size_t i, const scene::Shape& shape, const scene::TriangleMeshShape& m,
                        RTCScene* instanced) {
  const unsigned id = static_cast<unsigned>(i);
  auto mesh = std::make_unique<MeshShape>();
  mesh->source = m.mesh;
  mesh->flip = shape.reverse_orientation != shape.transform_swaps_handedness;
  mesh->object_to_world = shape.object_to_world;
  mesh->vertex_count = static_cast<std::uint32_t>(m.mesh->positions.size());
  mesh->instanced = instanced != nullptr;
  const auto& src = *m.mesh;
  for (const Float3& p : src.positions) {
    bounds_.extend(to_vec(shape.object_to_world.apply_point({p.x, p.y, p.z})));
    shape_bounds_[i].extend(to_vec(shape.object_to_world.apply_point({p.x, p.y, p.z})));
  }
  if (instanced != nullptr) {
    RTCScene& child = *instanced;
    if (child == nullptr) {
      mesh->positions.reserve(src.positions.size() + 1);
      mesh->positions = src.positions;
      mesh->positions.push_back({});
      child = rtcNewScene(device_->get());
      attach_triangles(child, *mesh, 0, i);
      rtcCommitScene(child);
      sub_scenes_.push_back(child);
    } else {
      // Another shape owns the padded copy Embree reads; keep a reference copy for shading.
      mesh->positions = src.positions;
    }
    mesh->normals = src.normals;
    if (shape.reverse_orientation) {
      for (Float3& n : mesh->normals) n = {-n.x, -n.y, -n.z};
    }
    mesh->uvs = src.uvs;
    attach_instance(child, shape.object_to_world, id);
  } else {
    mesh->positions.reserve(src.positions.size() + 1);
    for (const Float3& p : src.positions) {
      auto w = shape.object_to_world.apply_point({p.x, p.y, p.z});
      mesh->positions.push_back({float(w[0]), float(w[1]), float(w[2])});
    }
    mesh->positions.push_back({});
    mesh->normals.reserve(src.normals.size());
    // pbrt-v4 negates a mesh's vertex normals under ReverseOrientation (and the geometric
    // normal then follows them), so a reversed mesh with normals turns round as one without.
    const double sign = shape.reverse_orientation ? -1.0 : 1.0;
    for (const Float3& n : src.normals) {
      auto w = shape.object_to_world.apply_normal({n.x, n.y, n.z});
      mesh->normals.push_back({float(sign * w[0]), float(sign * w[1]), float(sign * w[2])});
    }
    mesh->uvs = src.uvs;
    attach_triangles(scene_, *mesh, id, i);
  }
  meshes_[i] = std::move(mesh);
}

void Geometry::add_sphere(std::size_t i, const scene::Shape& shape, const scene::SphereShape& s) {
  auto sphere = std::make_unique<SphereShape>();
  sphere->radius = s.radius;
  sphere->object_to_world = shape.object_to_world;
  sphere->world_to_object = shape.object_to_world.inverse();
  sphere->flip = quadric_flip(shape);
  RTCGeometry geom = rtcNewGeometry(device_->get(), RTC_GEOMETRY_TYPE_SPHERE_POINT);
  auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                        RTC_FORMAT_FLOAT4, 4 * sizeof(float), 1));
  if (v != nullptr) {
    v[0] = v[1] = v[2] = 0.0f;
    v[3] = float(s.radius);
  }
  add_alpha_filter(geom, i, nullptr);
  attach_object_space(geom, shape.object_to_world, static_cast<unsigned>(i),
                      {-s.radius, -s.radius, -s.radius}, {s.radius, s.radius, s.radius});
  spheres_[i] = std::move(sphere);
}

void Geometry::add_quadric(std::size_t i, const scene::Shape& shape) {
  auto quadric = std::make_unique<QuadricShape>();
  if (const auto* d = std::get_if<scene::DiskShape>(&shape.geometry)) {
    quadric->height = float(d->height);
    quadric->radius = float(d->radius);
    quadric->inner_radius = float(d->inner_radius);
  } else {
    const auto& c = std::get<scene::CylinderShape>(shape.geometry);
    quadric->cylinder = true;
    quadric->radius = float(c.radius);
    quadric->z_min = float(c.z_min);
    quadric->z_max = float(c.z_max);
  }
  quadric->object_to_world = shape.object_to_world;
  quadric->world_to_object = shape.object_to_world.inverse();
  quadric->flip = quadric_flip(shape);
  if (alpha_[i]) quadric->alpha = &alpha_[i];
  RTCGeometry geom = rtcNewGeometry(device_->get(), RTC_GEOMETRY_TYPE_USER);
  rtcSetGeometryUserPrimitiveCount(geom, 1);
  rtcSetGeometryUserData(geom, static_cast<QuadricShapeData*>(quadric.get()));
  rtcSetGeometryBoundsFunction(geom, quadric_bounds, nullptr);
  rtcSetGeometryIntersectFunction(geom, quadric_intersect);
  rtcSetGeometryOccludedFunction(geom, quadric_occluded);
  const double r = quadric->radius;
  const double z0 = quadric->cylinder ? quadric->z_min : quadric->height;
  const double z1 = quadric->cylinder ? quadric->z_max : quadric->height;
  attach_object_space(geom, shape.object_to_world, static_cast<unsigned>(i), {-r, -r, z0},
                      {r, r, z1});
  quadrics_[i] = std::move(quadric);
}

Vec3f Geometry::offset_origin(const Vec3f& p, const Vec3f& ng, const Vec3f& direction) const {
  Vec3f offset = ng * epsilon_;
  if (dot(direction, ng) < 0) offset = -offset;
  return p + offset;
}

Geometry::WorldTriangle Geometry::triangle(int shape, std::uint32_t primitive) const {
  const MeshShape& m = *meshes_[shape];
  const auto& tri = m.source->triangles[primitive];
  WorldTriangle w;
  w.flip = m.flip;
  auto pos = [&](std::uint32_t i) {
    if (!m.instanced) return to_vec(m.positions[i]);
    const Float3& p = m.positions[i];
    return to_vec(m.object_to_world.apply_point({p.x, p.y, p.z}));
  };
  auto nor = [&](std::uint32_t i) {
    if (!m.instanced) return to_vec(m.normals[i]);
    const Float3& n = m.normals[i];
    return to_vec(m.object_to_world.apply_normal({n.x, n.y, n.z}));
  };
  w.p0 = pos(tri[0]);
  w.p1 = pos(tri[1]);
  w.p2 = pos(tri[2]);
  if (!m.normals.empty()) {
    w.has_normals = true;
    w.n0 = nor(tri[0]);
    w.n1 = nor(tri[1]);
    w.n2 = nor(tri[2]);
  }
  return w;
}

std::uint32_t Geometry::triangle_count(int shape) const {
  return meshes_[shape] ? static_cast<std::uint32_t>(meshes_[shape]->source->triangles.size()) : 0;
}

SurfaceHit Geometry::finish_triangle_hit(int shape, std::uint32_t prim, float u, float v,
                                         float t) const {
  const MeshShape& m = *meshes_[shape];
  WorldTriangle w = triangle(shape, prim);
  float b0 = 1.0f - u - v;
  SurfaceHit hit;
  hit.t = t;
  hit.shape = shape;
  hit.primitive = prim;
  hit.p = w.p0 * b0 + w.p1 * u + w.p2 * v;
  const Vec3f n = w.unit_normal();
  hit.ng = n;
  hit.ns = n;
  if (w.has_normals) {
    Vec3f ns = w.n0 * b0 + w.n1 * u + w.n2 * v;
    float ls = length(ns);
    if (ls > 0) {
      hit.ns = ns / ls;
      hit.ng = face_forward(n, hit.ns);
    }
  }
  const std::array<Point2f, 3> uvs = triangle_uvs(m.uvs, m.source->triangles[prim]);
  const Point2f &uv0 = uvs[0], &uv1 = uvs[1], &uv2 = uvs[2];
  hit.uv = interpolate_uv(uvs, u, v);
  // dp/du from the uv parameterisation (pbrt-v4 Triangle), falling back to an edge.
  float du02 = uv0.x - uv2.x, du12 = uv1.x - uv2.x, dv02 = uv0.y - uv2.y, dv12 = uv1.y - uv2.y;
  float det = du02 * dv12 - dv02 * du12;
  Vec3f dp02 = w.p0 - w.p2, dp12 = w.p1 - w.p2;
  hit.dpdu = std::abs(det) > 1e-9f ? (dp02 * dv12 - dp12 * dv02) / det : normalize(dp02);
  return hit;
}

SurfaceHit Geometry::finish_sphere_hit(int shape, const Ray& ray, float t) const {
  const SphereShape& s = *spheres_[shape];
  Vec3f pw = ray.origin + ray.direction * t;
  scene::Vec3 po = s.world_to_object.apply_point(to_double(pw));
  double r = std::sqrt(po[0] * po[0] + po[1] * po[1] + po[2] * po[2]);
  // Re-project onto the surface: the float hit point drifts off it.
  if (r > 0) {
    for (double& c : po) c *= s.radius / r;
  }
  SurfaceHit hit;
  hit.t = t;
  hit.shape = shape;
  hit.p = to_vec(s.object_to_world.apply_point(po));
  Vec3f n = normalize(to_vec(s.object_to_world.apply_normal(po)));
  if (s.flip) n = -n;
  hit.ng = hit.ns = n;
  hit.uv = sphere_uv(po[0], po[1], po[2]);
  hit.dpdu = to_vec(s.object_to_world.apply_vector({-2 * M_PI * po[1], 2 * M_PI * po[0], 0}));
  return hit;
}

float Geometry::alpha_on_triangle(int shape, std::uint32_t primitive, float u, float v,
                                  const Vec3f& n) const {
  if (!has_alpha(shape)) return 1.0f;
  const MeshShape& m = *meshes_[size_t(shape)];
  return alpha_[size_t(shape)](
      interpolate_uv(triangle_uvs(m.uvs, m.source->triangles[primitive]), u, v), n);
}

float Geometry::alpha_at_point(int shape, const Vec3f& p, const Vec3f& n) const {
  if (!has_alpha(shape)) return 1.0f;
  if (spheres_[size_t(shape)]) {
    const scene::Vec3 po = spheres_[size_t(shape)]->world_to_object.apply_point(to_double(p));
    return alpha_[size_t(shape)](sphere_uv(po[0], po[1], po[2]), n);
  }
  PRISM_CHECK(quadrics_[size_t(shape)] != nullptr);
  const QuadricShape& q = *quadrics_[size_t(shape)];
  const scene::Vec3 po = q.world_to_object.apply_point(to_double(p));
  return alpha_[size_t(shape)](quadric_uv(q, po[0], po[1], q.cylinder ? po[2] : q.height), n);
}

SurfaceHit Geometry::finish_quadric_hit(int shape, const Ray& ray, float t) const {
  const QuadricShape& q = *quadrics_[shape];
  scene::Vec3 po = q.world_to_object.apply_point(to_double(ray.origin + ray.direction * t));
  const double r = std::sqrt(po[0] * po[0] + po[1] * po[1]);
  if (q.cylinder) {
    // Back onto the surface: the float hit point drifts off it.
    if (r > 0) {
      po[0] *= q.radius / r;
      po[1] *= q.radius / r;
    }
  } else {
    po[2] = q.height;
  }
  SurfaceHit hit;
  hit.t = t;
  hit.shape = shape;
  hit.p = to_vec(q.object_to_world.apply_point(po));
  // Normals: +z on a disk, outwards on a cylinder.
  const scene::Vec3 n_object = q.cylinder ? scene::Vec3{po[0], po[1], 0} : scene::Vec3{0, 0, 1};
  Vec3f n = normalize(to_vec(q.object_to_world.apply_normal(n_object)));
  if (q.flip) n = -n;
  hit.ng = hit.ns = n;
  hit.uv = quadric_uv(q, po[0], po[1], po[2]);
  hit.dpdu = r > 0
                 ? to_vec(q.object_to_world.apply_vector({-2 * M_PI * po[1], 2 * M_PI * po[0], 0}))
                 : to_vec(q.object_to_world.apply_vector({1, 0, 0}));
  return hit;
}

namespace {

// d(N/|N|) for the unnormalised normal N changing by dN: the part of dN/|N| across n = N/|N|.
Vec3f normalized_differential(const Vec3f& n, float length_n, const Vec3f& dN) {
  return (dN - n * dot(n, dN)) / length_n;
}

}  // namespace

Vec3f Geometry::normal_differential(const SurfaceHit& hit, const Vec3f& dp) const {
  const auto shape = size_t(hit.shape);
  // N(p) = A·(B·p + c) for an affine world-to-object B and a linear normal map A: dN = A·B·dp.
  // The sign of `flip` multiplies N and dN alike, so ns = ±N/|N| and dns = ±d(N/|N|) agree.
  auto affine_normal = [&](const scene::Transform& object_to_world,
                           const scene::Transform& world_to_object, bool flip, bool drop_z) {
    scene::Vec3 po = world_to_object.apply_point(to_double(hit.p));
    scene::Vec3 dpo = world_to_object.apply_vector(to_double(dp));
    if (drop_z) po[2] = dpo[2] = 0;  // a cylinder's normal is (x, y, 0)
    const Vec3f N = to_vec(object_to_world.apply_normal(po));
    const Vec3f dN = to_vec(object_to_world.apply_normal(dpo));
    const float len = length(N);
    if (!(len > 0)) return Vec3f{};
    const Vec3f d = normalized_differential(N / len, len, dN);
    return flip ? -d : d;
  };
  if (shape < spheres_.size() && spheres_[shape]) {
    const SphereShape& s = *spheres_[shape];
    return affine_normal(s.object_to_world, s.world_to_object, s.flip, false);
  }
  if (shape < quadrics_.size() && quadrics_[shape]) {
    const QuadricShape& q = *quadrics_[shape];
    if (!q.cylinder) return {};
    return affine_normal(q.object_to_world, q.world_to_object, q.flip, true);
  }
  const WorldTriangle w = triangle(hit.shape, hit.primitive);
  if (!w.has_normals) return {};
  // p = p0 + e1·u + e2·v on the triangle's plane: (du, dv) from dp by the dual basis.
  const Vec3f e1 = w.p1 - w.p0, e2 = w.p2 - w.p0;
  const float a = dot(e1, e1), b = dot(e1, e2), c = dot(e2, e2);
  const float det = a * c - b * b;
  if (!(std::abs(det) > 0)) return {};
  auto barycentrics = [&](const Vec3f& v) {
    const float r1 = dot(e1, v), r2 = dot(e2, v);
    return Point2f{(c * r1 - b * r2) / det, (a * r2 - b * r1) / det};
  };
  const Point2f uv = barycentrics(hit.p - w.p0);
  const Point2f duv = barycentrics(dp);
  const Vec3f N = w.n0 * (1 - uv.x - uv.y) + w.n1 * uv.x + w.n2 * uv.y;
  const Vec3f dN = (w.n1 - w.n0) * duv.x + (w.n2 - w.n0) * duv.y;
  const float len = length(N);
  if (!(len > 0)) return {};
  // ns is N/|N| (finish_triangle_hit), whatever the orientation flags.
  return normalized_differential(N / len, len, dN);
}

std::optional<SurfaceHit> Geometry::intersect(const Ray& ray, float t_max) const {
  if (const RayObserver* o = observer_.load(std::memory_order_relaxed); o != nullptr) [[unlikely]] {
    o->traced(ray, t_max, false);
  }
  if (!embree_can_trace(ray, t_max)) [[unlikely]] {
    return std::nullopt;
  }
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rh;
  rh.ray.org_x = ray.origin.x;
  rh.ray.org_y = ray.origin.y;
  rh.ray.org_z = ray.origin.z;
  rh.ray.dir_x = ray.direction.x;
  rh.ray.dir_y = ray.direction.y;
  rh.ray.dir_z = ray.direction.z;
  rh.ray.tnear = 0.0f;
  rh.ray.tfar = t_max;
  rh.ray.time = 0.0f;
  rh.ray.mask = 0xffffffffu;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(scene_, &context, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return std::nullopt;
  int shape =
      rh.hit.instID[0] != RTC_INVALID_GEOMETRY_ID ? int(rh.hit.instID[0]) : int(rh.hit.geomID);
  if (spheres_[shape]) return finish_sphere_hit(shape, ray, rh.ray.tfar);
  if (quadrics_[shape]) return finish_quadric_hit(shape, ray, rh.ray.tfar);
  return finish_triangle_hit(shape, rh.hit.primID, rh.hit.u, rh.hit.v, rh.ray.tfar);
}

bool Geometry::occluded(const Ray& ray, float t_max) const {
  if (const RayObserver* o = observer_.load(std::memory_order_relaxed); o != nullptr) [[unlikely]] {
    o->traced(ray, t_max, true);
  }
  if (!embree_can_trace(ray, t_max)) [[unlikely]] {
    return true;
  }
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRay r;
  r.org_x = ray.origin.x;
  r.org_y = ray.origin.y;
  r.org_z = ray.origin.z;
  r.dir_x = ray.direction.x;
  r.dir_y = ray.direction.y;
  r.dir_z = ray.direction.z;
  r.tnear = 0.0f;
  r.tfar = t_max;
  r.time = 0.0f;
  r.mask = 0xffffffffu;
  r.id = 0;
  r.flags = 0;
  rtcOccluded1(scene_, &context, &r);
  return r.tfar < 0.0f;
}

}  // namespace prism::worker
