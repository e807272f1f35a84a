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
  // Per triangle its MeshFace, for a mesh with bilinear patches (empty otherwise); `curved`
  // when some patch is not flat and the faces are intersected by Prism (`faces`, owned by the
  // shape that attached them; null on the other instances of a shared mesh).
  std::vector<MeshFace> kinds;
  bool curved = false;
  std::unique_ptr<FaceMeshData> faces;

  Vec3f world_position(std::uint32_t i) const {
    if (!instanced) return to_vec(positions[i]);
    const Float3& p = positions[i];
    return to_vec(object_to_world.apply_point({p.x, p.y, p.z}));
  }
  Vec3f world_normal(std::uint32_t i) const {
    if (!instanced) return to_vec(normals[i]);
    const Float3& n = normals[i];
    return to_vec(object_to_world.apply_normal({n.x, n.y, n.z}));
  }
  bool is_patch(std::uint32_t prim) const { return curved && kinds[prim] == MeshFace::kPatch; }
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

using MeshFace = Geometry::MeshFace;

// A mesh triangle's vertex uvs: the mesh's; without them pbrt-v4's default (0,0), (1,0), (1,1),
// or for a bilinear patch's triangles the patch's own (u, v) at their corners, (p00, p10, p11)
// and (p00, p11, p01), so that a flat patch's texture is pbrt-v4's without a seam.
std::array<Point2f, 3> triangle_uvs(const scene::Float2* uvs, const scene::Triangle& tri,
                                    bool patch_second) {
  if (uvs == nullptr) {
    if (patch_second) return {Point2f{0, 0}, Point2f{1, 1}, Point2f{0, 1}};
    return {Point2f{0, 0}, Point2f{1, 0}, Point2f{1, 1}};
  }
  return {Point2f{uvs[tri[0]].u, uvs[tri[0]].v}, Point2f{uvs[tri[1]].u, uvs[tri[1]].v},
          Point2f{uvs[tri[2]].u, uvs[tri[2]].v}};
}
std::array<Point2f, 3> triangle_uvs(const std::vector<scene::Float2>& uvs,
                                    const std::vector<MeshFace>& kinds, const scene::Triangle& tri,
                                    std::uint32_t prim) {
  return triangle_uvs(uvs.empty() ? nullptr : uvs.data(), tri,
                      !kinds.empty() && kinds[prim] == MeshFace::kPatchRest);
}

// Bilinear interpolation over a patch's corners at (u, v).
template <typename T>
T bilerp(float u, float v, const T& c00, const T& c10, const T& c01, const T& c11) {
  return (c00 * (1 - u) + c10 * u) * (1 - v) + (c01 * (1 - u) + c11 * u) * v;
}

// A patch's texture uv at (u, v): its vertex uvs (of triangles t = (p00, p10, p11) and
// t + 1 = (p00, p11, p01)) interpolated, or (u, v) without uvs.
Point2f patch_texture_uv(const scene::Float2* uvs, const scene::Triangle* triangles,
                         std::uint32_t t, float u, float v) {
  if (uvs == nullptr) return {u, v};
  auto at = [&](std::uint32_t i) { return Point2f{uvs[i].u, uvs[i].v}; };
  const scene::Triangle& a = triangles[t];
  const Point2f c00 = at(a[0]), c10 = at(a[1]), c11 = at(a[2]), c01 = at(triangles[t + 1][2]);
  return {bilerp(u, v, c00.x, c10.x, c01.x, c11.x), bilerp(u, v, c00.y, c10.y, c01.y, c11.y)};
}

// Whether every patch of the mesh is flat: a parallelogram (p00 − p10 − p01 + p11 = 0, to 1e-5
// of its size) whose vertex normals and uvs are affine in the same sense, so that its two
// triangles are the patch with the patch's interpolation.
bool patches_are_flat(const scene::TriangleMeshData& m) {
  auto twisted = [](auto get, std::uint32_t i00, std::uint32_t i10, std::uint32_t i01,
                    std::uint32_t i11) {
    double twist = 0, size = 0;
    for (int c = 0; c < 3; ++c) {
      const double p00 = get(i00, c), p10 = get(i10, c), p01 = get(i01, c), p11 = get(i11, c);
      twist = std::max(twist, std::abs(p00 - p10 - p01 + p11));
      size = std::max({size, std::abs(p10 - p00), std::abs(p01 - p00), std::abs(p11 - p00)});
    }
    return twist > 1e-5 * size;
  };
  auto position = [&](std::uint32_t i, int c) {
    const Float3& p = m.positions[i];
    return c == 0 ? p.x : c == 1 ? p.y : p.z;
  };
  auto normal = [&](std::uint32_t i, int c) {
    const Float3& n = m.normals[i];
    return c == 0 ? n.x : c == 1 ? n.y : n.z;
  };
  auto uv = [&](std::uint32_t i, int c) {
    return c == 0 ? m.uvs[i].u : c == 1 ? m.uvs[i].v : 0.0f;
  };
  for (std::uint32_t t : m.patches) {
    const scene::Triangle& a = m.triangles[t];
    const std::uint32_t i01 = m.triangles[t + 1][2];
    if (twisted(position, a[0], a[1], i01, a[2])) return false;
    if (!m.normals.empty() && twisted(normal, a[0], a[1], i01, a[2])) return false;
    if (!m.uvs.empty() && twisted(uv, a[0], a[1], i01, a[2])) return false;
  }
  return true;
}

// Double-precision vectors for the intersection of curved patches.
struct D3 {
  double x, y, z;
};
D3 operator-(const D3& a, const D3& b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
D3 operator+(const D3& a, const D3& b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
D3 operator*(const D3& a, double s) {
  return {a.x * s, a.y * s, a.z * s};
}
double dot(const D3& a, const D3& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
D3 cross(const D3& a, const D3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
D3 d3(const Float3& f) {
  return {f.x, f.y, f.z};
}

struct FaceCandidate {
  double t, u, v;
};

// The ray o + t·d against the bilinear patch p(u, v) = lerp(v, lerp(u, p00, p10), lerp(u, p01,
// p11)): its hits with t in (t_min, t_max) and (u, v) in [0, 1]², nearest first; returns how many
// (0 to 2). The ray meets the segment of the u-isoline from lerp(u, p00, p10) to lerp(u, p01,
// p11) only where the two are coplanar: det[lerp(u, p00, p10) − o, d, lerp(u, p01 − p00,
// p11 − p10)] = 0, a quadratic in u (Reshetov, "Cool Patches", Ray Tracing Gems 2019); v and t
// then follow from the two lines' closest points.
int intersect_patch(const D3& o, const D3& d, const D3& p00, const D3& p10, const D3& p01,
                    const D3& p11, double t_min, double t_max, FaceCandidate out[2]) {
  const D3 q00 = p00 - o, q10 = p10 - o;
  const D3 e00 = p01 - p00, e11 = p11 - p10;
  const double a = dot(cross(q00, d), e00);
  const double c = dot(cross(p10 - p00, d), e11 - e00);
  const double b = dot(cross(q10, d), e11) - a - c;
  double roots[2];
  int n_roots = 0;
  if (c == 0) {
    if (b != 0) roots[n_roots++] = -a / b;
  } else {
    const double disc = b * b - 4 * a * c;
    if (disc < 0) return 0;
    const double q = -0.5 * (b + std::copysign(std::sqrt(disc), b));
    if (q == 0) {
      roots[n_roots++] = 0;  // b = 0 and a·c = 0: the double root u = 0
    } else {
      roots[n_roots++] = q / c;
      roots[n_roots++] = a / q;
    }
  }
  int found = 0;
  for (int i = 0; i < n_roots; ++i) {
    const double u = roots[i];
    if (!(u >= 0 && u <= 1)) continue;
    const D3 pa = q00 + (q10 - q00) * u;  // the isoline's start, from o
    const D3 pb = e00 + (e11 - e00) * u;  // along the isoline
    const D3 n = cross(d, pb);
    const double det = dot(n, n);
    if (!(det > 0)) continue;
    const double t = dot(cross(pa, pb), n) / det;
    const double v = dot(cross(pa, d), n) / det;
    if (!(v >= 0 && v <= 1 && t > t_min && t < t_max)) continue;
    out[found++] = {t, u, v};
  }
  if (found == 2 && out[1].t < out[0].t) std::swap(out[0], out[1]);
  return found;
}

// The ray against triangle (p0, p1, p2) (Möller–Trumbore in double): t in (t_min, t_max) and
// the barycentrics of p1 and p2, as Embree reports them.
bool intersect_triangle(const D3& o, const D3& d, const D3& p0, const D3& p1, const D3& p2,
                        double t_min, double t_max, FaceCandidate* out) {
  const D3 e1 = p1 - p0, e2 = p2 - p0;
  const D3 pv = cross(d, e2);
  const double det = dot(e1, pv);
  if (det == 0) return false;
  const double inv = 1 / det;
  const D3 tv = o - p0;
  const double b1 = dot(tv, pv) * inv;
  if (!(b1 >= 0 && b1 <= 1)) return false;
  const D3 qv = cross(tv, e1);
  const double b2 = dot(d, qv) * inv;
  if (!(b2 >= 0 && b1 + b2 <= 1)) return false;
  const double t = dot(e2, qv) * inv;
  if (!(t > t_min && t < t_max)) return false;
  *out = {t, b1, b2};
  return true;
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
    const std::uint32_t prim = RTCHitN_primID(hit, 1, 0);
    const auto& tri = f->mesh->source->triangles[prim];
    uv = interpolate_uv(triangle_uvs(f->mesh->uvs, f->mesh->kinds, tri, prim), RTCHitN_u(hit, 1, 0),
                        RTCHitN_v(hit, 1, 0));
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

// A face of a mesh with curved patches against the ray: the nearest hit with t in (tnear,
// tfar) that its alpha keeps. Sets the triangle reported (a patch's first) and the unit normal
// cross(dp/du, dp/dv) before any orientation rule.
bool face_hit(const Geometry::FaceMeshData& m, unsigned prim, const RTCRay& ray, FaceCandidate* hit,
              std::uint32_t* triangle, D3* normal) {
  const std::uint32_t face = m.faces[prim];
  const std::uint32_t t = face & ~Geometry::FaceMeshData::kPatchBit;
  const scene::Triangle& tri = m.triangles[t];
  const D3 o{ray.org_x, ray.org_y, ray.org_z}, d{ray.dir_x, ray.dir_y, ray.dir_z};
  const D3 p0 = d3(m.positions[tri[0]]), p1 = d3(m.positions[tri[1]]), p2 = d3(m.positions[tri[2]]);
  FaceCandidate candidates[2];
  int count = 0;
  const bool patch = (face & Geometry::FaceMeshData::kPatchBit) != 0;
  const D3 p01 = patch ? d3(m.positions[m.triangles[t + 1][2]]) : D3{};
  if (patch) {
    count = intersect_patch(o, d, p0, p1, p01, p2, ray.tnear, ray.tfar, candidates);
  } else {
    count = intersect_triangle(o, d, p0, p1, p2, ray.tnear, ray.tfar, candidates) ? 1 : 0;
  }
  for (int i = 0; i < count; ++i) {
    const FaceCandidate& c = candidates[i];
    D3 n;
    if (patch) {
      const D3 dpdu = (p1 - p0) * (1 - c.v) + (p2 - p01) * c.v;
      const D3 dpdv = (p01 - p0) * (1 - c.u) + (p2 - p1) * c.u;
      n = cross(dpdu, dpdv);
    } else {
      n = cross(p0 - p2, p1 - p2);
    }
    const double len = std::sqrt(dot(n, n));
    n = len > 0 ? n * (1 / len) : D3{0, 0, 1};
    if (m.alpha != nullptr) {
      Point2f uv;
      if (patch) {
        uv = patch_texture_uv(m.uvs, m.triangles, t, float(c.u), float(c.v));
      } else {
        // A curved mesh's plain triangle (a patch's own triangles are not faces here).
        uv = interpolate_uv(triangle_uvs(m.uvs, tri, false), float(c.u), float(c.v));
      }
      if (!alpha_keeps(*m.alpha, uv, {float(n.x), float(n.y), float(n.z)}, ray.org_x, ray.org_y,
                       ray.org_z, ray.dir_x, ray.dir_y, ray.dir_z, float(c.t))) {
        continue;
      }
    }
    *hit = c;
    *triangle = t;
    *normal = n;
    return true;
  }
  return false;
}

void face_bounds(const RTCBoundsFunctionArguments* args) {
  const auto* m = static_cast<const Geometry::FaceMeshData*>(args->geometryUserPtr);
  const std::uint32_t face = m->faces[args->primID];
  const std::uint32_t t = face & ~Geometry::FaceMeshData::kPatchBit;
  const scene::Triangle& tri = m->triangles[t];
  RTCBounds* b = args->bounds_o;
  b->lower_x = b->lower_y = b->lower_z = std::numeric_limits<float>::infinity();
  b->upper_x = b->upper_y = b->upper_z = -std::numeric_limits<float>::infinity();
  auto extend = [&](std::uint32_t i) {
    const Float3& p = m->positions[i];
    b->lower_x = std::min(b->lower_x, p.x);
    b->lower_y = std::min(b->lower_y, p.y);
    b->lower_z = std::min(b->lower_z, p.z);
    b->upper_x = std::max(b->upper_x, p.x);
    b->upper_y = std::max(b->upper_y, p.y);
    b->upper_z = std::max(b->upper_z, p.z);
  };
  for (std::uint32_t i : tri) extend(i);
  // A bilinear patch lies in its corners' convex hull.
  if ((face & Geometry::FaceMeshData::kPatchBit) != 0) extend(m->triangles[t + 1][2]);
}

void face_intersect(const RTCIntersectFunctionNArguments* args) {
  if (args->valid[0] == 0) return;
  const auto* m = static_cast<const Geometry::FaceMeshData*>(args->geometryUserPtr);
  RTCRayHit* rh = reinterpret_cast<RTCRayHit*>(args->rayhit);
  FaceCandidate c;
  std::uint32_t triangle = 0;
  D3 n;
  if (!face_hit(*m, args->primID, rh->ray, &c, &triangle, &n)) return;
  rh->ray.tfar = float(c.t);
  rh->hit.Ng_x = float(n.x);
  rh->hit.Ng_y = float(n.y);
  rh->hit.Ng_z = float(n.z);
  rh->hit.u = float(c.u);
  rh->hit.v = float(c.v);
  rh->hit.primID = triangle;
  rh->hit.geomID = args->geomID;
  rh->hit.instID[0] = args->context->instID[0];
}

void face_occluded(const RTCOccludedFunctionNArguments* args) {
  if (args->valid[0] == 0) return;
  const auto* m = static_cast<const Geometry::FaceMeshData*>(args->geometryUserPtr);
  RTCRay* r = reinterpret_cast<RTCRay*>(args->ray);
  FaceCandidate c;
  std::uint32_t triangle = 0;
  D3 n;
  if (face_hit(*m, args->primID, *r, &c, &triangle, &n))
    r->tfar = -std::numeric_limits<float>::infinity();
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
  // The extent alone, however small: a floor of 1 made the offset an absolute 1e-5 in scenes
  // smaller than a unit, bigger than a 1e-4-scale prism's features (its image came out 4 %
  // darker). The tiny floor only keeps an empty scene's offset positive.
  float extent = std::max({std::abs(g->bounds_.lo.x), std::abs(g->bounds_.lo.y),
                           std::abs(g->bounds_.lo.z), std::abs(g->bounds_.hi.x),
                           std::abs(g->bounds_.hi.y), std::abs(g->bounds_.hi.z), 1e-30f});
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

void Geometry::attach_faces(RTCScene target, MeshShape& mesh, unsigned id, std::size_t shape) {
  auto data = std::make_unique<FaceMeshData>();
  data->positions = mesh.positions.data();
  data->uvs = mesh.uvs.empty() ? nullptr : mesh.uvs.data();
  data->triangles = mesh.source->triangles.data();
  for (std::uint32_t t = 0; t < mesh.kinds.size(); ++t) {
    if (mesh.kinds[t] == MeshFace::kTriangle) data->faces.push_back(t);
    if (mesh.kinds[t] == MeshFace::kPatch) data->faces.push_back(t | FaceMeshData::kPatchBit);
  }
  if (alpha_[shape]) data->alpha = &alpha_[shape];
  RTCGeometry geom = rtcNewGeometry(device_->get(), RTC_GEOMETRY_TYPE_USER);
  rtcSetGeometryUserPrimitiveCount(geom, static_cast<unsigned>(data->faces.size()));
  rtcSetGeometryUserData(geom, data.get());
  rtcSetGeometryBoundsFunction(geom, face_bounds, nullptr);
  rtcSetGeometryIntersectFunction(geom, face_intersect);
  rtcSetGeometryOccludedFunction(geom, face_occluded);
  rtcCommitGeometry(geom);
  rtcAttachGeometryByID(target, geom, id);
  rtcReleaseGeometry(geom);
  mesh.faces = std::move(data);
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
  if (!src.patches.empty()) {
    mesh->kinds.assign(src.triangles.size(), MeshFace::kTriangle);
    for (std::uint32_t t : src.patches) {
      mesh->kinds[t] = MeshFace::kPatch;
      mesh->kinds[t + 1] = MeshFace::kPatchRest;
    }
    mesh->curved = !patches_are_flat(src);
  }
  auto attach = [&](RTCScene target) {
    if (mesh->curved) {
      attach_faces(target, *mesh, target == scene_ ? id : 0, i);
    } else {
      attach_triangles(target, *mesh, target == scene_ ? id : 0, i);
    }
  };
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
      attach(child);
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
    attach(scene_);
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
  w.p0 = m.world_position(tri[0]);
  w.p1 = m.world_position(tri[1]);
  w.p2 = m.world_position(tri[2]);
  if (!m.normals.empty()) {
    w.has_normals = true;
    w.n0 = m.world_normal(tri[0]);
    w.n1 = m.world_normal(tri[1]);
    w.n2 = m.world_normal(tri[2]);
  }
  return w;
}

Geometry::MeshFace Geometry::face(int shape, std::uint32_t primitive) const {
  const MeshShape* m = meshes_[size_t(shape)].get();
  return m != nullptr && m->curved ? m->kinds[primitive] : MeshFace::kTriangle;
}

Geometry::WorldPatch Geometry::patch(int shape, std::uint32_t primitive) const {
  const MeshShape& m = *meshes_[size_t(shape)];
  const scene::Triangle& a = m.source->triangles[primitive];
  const std::uint32_t i01 = m.source->triangles[primitive + 1][2];
  WorldPatch w;
  w.flip = m.flip;
  w.p00 = m.world_position(a[0]);
  w.p10 = m.world_position(a[1]);
  w.p11 = m.world_position(a[2]);
  w.p01 = m.world_position(i01);
  if (!m.normals.empty()) {
    w.has_normals = true;
    w.n00 = m.world_normal(a[0]);
    w.n10 = m.world_normal(a[1]);
    w.n11 = m.world_normal(a[2]);
    w.n01 = m.world_normal(i01);
  }
  return w;
}

Point2f Geometry::patch_uv(int shape, std::uint32_t primitive, float u, float v) const {
  const MeshShape& m = *meshes_[size_t(shape)];
  return patch_texture_uv(m.uvs.empty() ? nullptr : m.uvs.data(), m.source->triangles.data(),
                          primitive, u, v);
}

Vec3f Geometry::WorldPatch::point(float u, float v) const {
  return bilerp(u, v, p00, p10, p01, p11);
}

Vec3f Geometry::WorldPatch::shading_normal(float u, float v) const {
  return has_normals ? bilerp(u, v, n00, n10, n01, n11) : Vec3f{};
}

Vec3f Geometry::WorldPatch::unit_normal(float u, float v) const {
  Vec3f n = cross(dpdu(v), dpdv(u));
  float len = length(n);
  if (!(len > 0)) {
    // A corner where an edge collapses: the normal at the centre.
    n = cross(dpdu(0.5f), dpdv(0.5f));
    len = length(n);
  }
  n = len > 0 ? n / len : Vec3f(0, 0, 1);
  if (flip) n = -n;
  if (has_normals) {
    const Vec3f ns = shading_normal(u, v);
    if (length(ns) > 0) n = face_forward(n, ns);
  }
  return n;
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
  hit.param = {u, v};
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
  const std::array<Point2f, 3> uvs = triangle_uvs(m.uvs, m.kinds, m.source->triangles[prim], prim);
  const Point2f &uv0 = uvs[0], &uv1 = uvs[1], &uv2 = uvs[2];
  hit.uv = interpolate_uv(uvs, u, v);
  // dp/du from the uv parameterisation (pbrt-v4 Triangle), falling back to an edge.
  float du02 = uv0.x - uv2.x, du12 = uv1.x - uv2.x, dv02 = uv0.y - uv2.y, dv12 = uv1.y - uv2.y;
  float det = du02 * dv12 - dv02 * du12;
  Vec3f dp02 = w.p0 - w.p2, dp12 = w.p1 - w.p2;
  hit.dpdu = std::abs(det) > 1e-9f ? (dp02 * dv12 - dp12 * dv02) / det : normalize(dp02);
  return hit;
}

SurfaceHit Geometry::finish_patch_hit(int shape, std::uint32_t prim, float u, float v,
                                      float t) const {
  const MeshShape& m = *meshes_[shape];
  const WorldPatch w = patch(shape, prim);
  SurfaceHit hit;
  hit.t = t;
  hit.shape = shape;
  hit.primitive = prim;
  hit.param = {u, v};
  hit.p = w.point(u, v);
  hit.ng = hit.ns = w.unit_normal(u, v);
  if (w.has_normals) {
    const Vec3f ns = w.shading_normal(u, v);
    const float ls = length(ns);
    if (ls > 0) hit.ns = ns / ls;
  }
  hit.uv = patch_uv(shape, prim, u, v);
  // dp/ds along the texture's s: [dp/du dp/dv] times the inverse of the uv map's Jacobian.
  const Vec3f dpdu = w.dpdu(v), dpdv = w.dpdv(u);
  hit.dpdu = dpdu;
  if (!m.uvs.empty()) {
    const std::array<Point2f, 3> a = triangle_uvs(m.uvs, m.kinds, m.source->triangles[prim], prim);
    const scene::Float2& c01 = m.uvs[m.source->triangles[prim + 1][2]];
    const Point2f uv00 = a[0], uv10 = a[1], uv11 = a[2], uv01{c01.u, c01.v};
    const float dsdu = (uv10.x - uv00.x) * (1 - v) + (uv11.x - uv01.x) * v;
    const float dtdu = (uv10.y - uv00.y) * (1 - v) + (uv11.y - uv01.y) * v;
    const float dsdv = (uv01.x - uv00.x) * (1 - u) + (uv11.x - uv10.x) * u;
    const float dtdv = (uv01.y - uv00.y) * (1 - u) + (uv11.y - uv10.y) * u;
    const float det = dsdu * dtdv - dsdv * dtdu;
    if (std::abs(det) > 1e-9f) hit.dpdu = (dpdu * dtdv - dpdv * dtdu) / det;
  }
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
  if (m.is_patch(primitive)) return alpha_[size_t(shape)](patch_uv(shape, primitive, u, v), n);
  return alpha_[size_t(shape)](
      interpolate_uv(triangle_uvs(m.uvs, m.kinds, m.source->triangles[primitive], primitive), u, v),
      n);
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
  if (meshes_[shape]->is_patch(hit.primitive)) {
    const WorldPatch w = patch(hit.shape, hit.primitive);
    const float u = hit.param.x, v = hit.param.y;
    // (du, dv) from dp in the tangent plane by the dual basis of dp/du, dp/dv.
    const Vec3f dpdu = w.dpdu(v), dpdv = w.dpdv(u);
    const float a = dot(dpdu, dpdu), b = dot(dpdu, dpdv), c = dot(dpdv, dpdv);
    const float det = a * c - b * b;
    if (!(std::abs(det) > 0)) return {};
    const float r1 = dot(dpdu, dp), r2 = dot(dpdv, dp);
    const float du = (c * r1 - b * r2) / det, dv = (a * r2 - b * r1) / det;
    if (w.has_normals) {
      const Vec3f N = w.shading_normal(u, v);
      const Vec3f dN = ((w.n10 - w.n00) * (1 - v) + (w.n11 - w.n01) * v) * du +
                       ((w.n01 - w.n00) * (1 - u) + (w.n11 - w.n10) * u) * dv;
      const float len = length(N);
      if (!(len > 0)) return {};
      return normalized_differential(N / len, len, dN);
    }
    // N = dp/du × dp/dv; ∂N/∂u = dp/du × twist, ∂N/∂v = twist × dp/dv.
    const Vec3f twist = w.p11 - w.p10 - w.p01 + w.p00;
    const Vec3f N = cross(dpdu, dpdv);
    const Vec3f dN = cross(dpdu, twist) * du + cross(twist, dpdv) * dv;
    const float len = length(N);
    if (!(len > 0)) return {};
    const Vec3f d = normalized_differential(N / len, len, dN);
    return dot(N, hit.ns) < 0 ? -d : d;  // ns is ±N/|N|
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
  if (meshes_[shape]->is_patch(rh.hit.primID))
    return finish_patch_hit(shape, rh.hit.primID, rh.hit.u, rh.hit.v, rh.ray.tfar);
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
