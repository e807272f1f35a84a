#include "worker/light.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"
#include "worker/equal_area.h"
#include "worker/float_hash.h"

namespace prism::worker {
namespace {

Vec3f to_vec(const scene::Vec3& v) {
  return {float(v[0]), float(v[1]), float(v[2])};
}

// 1 − cos θ_max of the cone a sphere of squared radius r2 subtends from squared distance d2 > r2,
// as sin²θ_max / (1 + cos θ_max): the direct difference cancels catastrophically for small or
// distant spheres. sample_sphere and pdf both use it, so they agree bit for bit.
float cone_one_minus_cos(float r2, float d2) {
  float sin2_max = std::min(1.0f, r2 / d2);
  return sin2_max / (1.0f + safe_sqrt(1.0f - sin2_max));
}

// pbrt-v4's SmoothStep: 0 below a, 1 above b, Hermite in between.
float smooth_step(float x, float a, float b) {
  if (a == b) return x < a ? 0.0f : 1.0f;
  float t = std::clamp((x - a) / (b - a), 0.0f, 1.0f);
  return t * t * (3.0f - 2.0f * t);
}

SampledSpectrum scaled(const spectral::Spectrum& s, double scale,
                       const SampledWavelengths& lambda) {
  return spectral::sample(s, lambda) * float(scale);
}

absl::Status check_scale(double scale, const scene::SourceLocation& where) {
  if (!std::isfinite(scale) || scale < 0) {
    return scene::location_error(
        where, absl::StrCat("light scale ", scale, " must be finite and non-negative"));
  }
  return absl::OkStatus();
}

}  // namespace

namespace {

// Seeds the emitter-alpha hash apart from the intersection alpha test's.
constexpr std::uint64_t kEmitterAlphaSeed = 0x616c706861ull;

// s² when the transform's linear part is a similarity (orthogonal columns of one common
// length s), else nullopt.
std::optional<double> similarity_scale_squared(const scene::Transform& t) {
  const scene::Matrix4& m = t.matrix();
  double gram[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      gram[i][j] = m[0][i] * m[0][j] + m[1][i] * m[1][j] + m[2][i] * m[2][j];
  const double s2 = (gram[0][0] + gram[1][1] + gram[2][2]) / 3.0;
  if (!(s2 > 0)) return std::nullopt;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      if (std::abs(gram[i][j] - (i == j ? s2 : 0.0)) > 1e-5 * s2) return std::nullopt;
  return s2;
}

// Curved patches' sampling: attempts before a sample is given up (each accepted with
// probability area / (corners' mean area element), near 1 for any patch short of degenerate),
// and the hash seed of attempts after the first.
constexpr int kPatchAttempts = 32;
constexpr std::uint64_t kPatchSeed = 0x7061746368ull;

// A sample of the density on [0, 1] proportional to a·(1 − x) + b·x (a, b >= 0) from ξ: the
// root of its quadratic CDF, in the form that does not cancel.
float sample_linear(float xi, float a, float b) {
  if (!(a + b > 0)) return xi;
  const float x = xi * (a + b) / (a + std::sqrt(a * a * (1 - xi) + b * b * xi));
  return std::min(x, 0x1.fffffep-1f);
}

// A patch's area ∫∫ |∂p/∂u × ∂p/∂v| du dv by Gauss–Legendre on n×n cells (8 points each way),
// n doubled until two agree to 1e-9 (the area element is smooth unless it vanishes inside).
double patch_area(const Geometry::WorldPatch& w) {
  static constexpr double kNodes[8] = {
      -0.9602898564975363, -0.7966664774136267, -0.5255324099163290, -0.1834346424956498,
      0.1834346424956498,  0.5255324099163290,  0.7966664774136267,  0.9602898564975363};
  static constexpr double kWeights[8] = {0.1012285362903763, 0.2223810344533745, 0.3137066458778873,
                                         0.3626837833783620, 0.3626837833783620, 0.3137066458778873,
                                         0.2223810344533745, 0.1012285362903763};
  auto d = [](const Vec3f& v) { return std::array<double, 3>{v.x, v.y, v.z}; };
  const auto p00 = d(w.p00), p10 = d(w.p10), p01 = d(w.p01), p11 = d(w.p11);
  auto element = [&](double u, double v) {
    double du[3], dv[3];
    for (int k = 0; k < 3; ++k) {
      du[k] = (p10[k] - p00[k]) * (1 - v) + (p11[k] - p01[k]) * v;
      dv[k] = (p01[k] - p00[k]) * (1 - u) + (p11[k] - p10[k]) * u;
    }
    const double x = du[1] * dv[2] - du[2] * dv[1], y = du[2] * dv[0] - du[0] * dv[2],
                 z = du[0] * dv[1] - du[1] * dv[0];
    return std::sqrt(x * x + y * y + z * z);
  };
  auto integrate = [&](int n) {
    double sum = 0;
    const double h = 1.0 / n;
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        for (int a = 0; a < 8; ++a) {
          for (int b = 0; b < 8; ++b) {
            const double u = h * (i + 0.5 * (kNodes[a] + 1)), v = h * (j + 0.5 * (kNodes[b] + 1));
            sum += kWeights[a] * kWeights[b] * element(u, v);
          }
        }
      }
    }
    return sum * h * h / 4;
  };
  double area = integrate(2);
  for (int n = 4; n <= 64; n *= 2) {
    const double finer = integrate(n);
    const bool agree = std::abs(finer - area) <= 1e-9 * finer;
    area = finer;
    if (agree) break;
  }
  return area;
}

}  // namespace

absl::StatusOr<AreaLight> AreaLight::create(const scene::Shape& shape, int shape_index,
                                            const Geometry& geometry, spectral::Spectrum spectrum,
                                            double scale) {
  AreaLight light;
  light.shape_ = shape_index;
  light.geometry_ = &geometry;
  light.spectrum_ = std::move(spectrum);
  light.scale_ = scale;
  light.where_ = shape.area_light ? shape.area_light->where : shape.where;
  light.two_sided_ = shape.area_light && shape.area_light->two_sided;
  if (auto status = check_scale(scale, light.where_); !status.ok()) return status;

  light.has_alpha_ = geometry.has_alpha(shape_index);
  if (const auto* cylinder = std::get_if<scene::CylinderShape>(&shape.geometry)) {
    // Uniform in (z, φ) is uniform by area on the object-space cylinder, and stays so under a
    // similarity (pbrt-v4 samples the same way and ignores the transform's scale).
    const std::optional<double> s2 = similarity_scale_squared(shape.object_to_world);
    if (!s2) {
      return scene::location_error(
          shape.where,
          "a cylinder used as an area light must have a similarity transform (uniform scale, "
          "rotation, translation); model an elliptic emitter as a triangle mesh");
    }
    light.area_ = 2 * M_PI * cylinder->radius * (cylinder->z_max - cylinder->z_min) * *s2;
    if (!(light.area_ > 0) || !std::isfinite(light.area_)) {
      return scene::location_error(shape.where, "cylinder area light has zero area");
    }
    light.is_cylinder_ = true;
    light.cylinder_ = *cylinder;
    light.cylinder_to_world_ = shape.object_to_world;
    light.cylinder_flip_ = quadric_flip(shape);
    return light;
  }
  if (const auto* disk = std::get_if<scene::DiskShape>(&shape.geometry)) {
    // Uniform in the object-space annulus is uniform on the world disk (an affine map scales
    // every area by the same factor: the length of the mapped x and y axes' cross product).
    const scene::Transform& t = shape.object_to_world;
    const Vec3f ex = to_vec(t.apply_vector({1, 0, 0})), ey = to_vec(t.apply_vector({0, 1, 0}));
    const double scale = double(length(cross(ex, ey)));
    light.area_ =
        M_PI * (disk->radius * disk->radius - disk->inner_radius * disk->inner_radius) * scale;
    if (!(light.area_ > 0) || !std::isfinite(light.area_)) {
      return scene::location_error(shape.where, "disk area light has zero area");
    }
    light.is_disk_ = true;
    light.disk_ = *disk;
    light.disk_to_world_ = t;
    Vec3f n = normalize(to_vec(t.apply_normal({0, 0, 1})));
    light.disk_normal_ = quadric_flip(shape) ? -n : n;
    return light;
  }
  if (const auto* sphere = std::get_if<scene::SphereShape>(&shape.geometry)) {
    // A sphere light is sampled by the cone it subtends, which is only a sphere's cone under a
    // similarity.
    const std::optional<double> s2 = similarity_scale_squared(shape.object_to_world);
    if (!s2) {
      return scene::location_error(
          shape.where,
          "a sphere used as an area light must have a similarity transform (uniform scale, "
          "rotation, translation); model an ellipsoidal emitter as a triangle mesh");
    }
    double radius = sphere->radius * std::sqrt(*s2);
    if (!(radius > 0) || !std::isfinite(radius)) {
      return scene::location_error(shape.where, "sphere area light has zero radius");
    }
    // The cone it subtends is sampled in floats: below 1e-18 of the scene's size its sin² θ
    // underflows and the light rendered black without a word (a radius of 1e-19 in a 10 m scene).
    const double size = std::max(double(geometry.bounds().radius()), radius);
    if (radius / size < 1e-18) {
      return scene::location_error(
          shape.where, absl::StrCat("sphere area light of radius ", radius,
                                    " is too small to sample in a scene of radius ", size,
                                    " (its cone underflows a float below 1e-18 of it); use a "
                                    "point light"));
    }
    light.is_sphere_ = true;
    light.sphere_centre_ = to_vec(shape.object_to_world.apply_point({0, 0, 0}));
    light.sphere_radius_ = float(radius);
    light.sphere_flip_ = quadric_flip(shape);
    light.area_ = 4.0 * M_PI * radius * radius;
    return light;
  }

  std::uint32_t count = geometry.triangle_count(shape_index);
  if (count == 0) {
    return scene::location_error(shape.where, "area light shape has no triangles");
  }
  std::vector<double> areas(count);
  double total = 0;
  light.triangles_.resize(count);
  for (std::uint32_t i = 0; i < count; ++i) {
    const Geometry::MeshFace face = geometry.face(shape_index, i);
    if (face == Geometry::MeshFace::kPatchRest) continue;  // the patch's area is its first's
    if (face == Geometry::MeshFace::kPatch) {
      EmitterPatch patch{geometry.patch(shape_index, i), i, {}};
      const Geometry::WorldPatch& w = patch.w;
      patch.corner[0] = w.area_element(0, 0);
      patch.corner[1] = w.area_element(1, 0);
      patch.corner[2] = w.area_element(0, 1);
      patch.corner[3] = w.area_element(1, 1);
      areas[i] = patch_area(w);
      total += areas[i];
      light.triangles_[i].patch = static_cast<int>(light.patches_.size());
      light.patches_.push_back(patch);
      continue;
    }
    Geometry::WorldTriangle t = geometry.triangle(shape_index, i);
    light.triangles_[i] = EmitterTriangle{t, t.unit_normal()};
    Vec3f e1 = t.p1 - t.p0, e2 = t.p2 - t.p0;
    double cx = double(e1.y) * e2.z - double(e1.z) * e2.y;
    double cy = double(e1.z) * e2.x - double(e1.x) * e2.z;
    double cz = double(e1.x) * e2.y - double(e1.y) * e2.x;
    areas[i] = 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
    total += areas[i];
  }
  if (!(total > 0) || !std::isfinite(total)) {
    return scene::location_error(shape.where, "area light shape has zero (or non-finite) area");
  }
  light.area_ = total;
  light.triangle_cdf_.resize(count);
  double running = 0;
  for (std::uint32_t i = 0; i < count; ++i) {
    running += areas[i];
    light.triangle_cdf_[i] = float(running / total);
  }
  light.triangle_cdf_.back() = 1.0f;
  return light;
}

std::optional<LightSample> AreaLight::sample(const LightContext& ctx, Point2f u, float u_tri,
                                             const SampledWavelengths& lambda) const {
  if (is_disk_) return sample_disk(ctx, u, lambda);
  if (is_cylinder_) return sample_cylinder(ctx, u, lambda);
  return is_sphere_ ? sample_sphere(ctx, u, lambda) : sample_triangles(ctx, u, u_tri, lambda);
}

std::optional<LightSample> AreaLight::sample_disk(const LightContext& ctx, Point2f u,
                                                  const SampledWavelengths& lambda) const {
  auto point = point_on_disk(u);
  if (!point) return std::nullopt;
  return uniform_area_sample(ctx, point->p, point->n, lambda);
}

std::optional<AreaPoint> AreaLight::point_on_disk(Point2f u) const {
  const double ri2 = disk_.inner_radius * disk_.inner_radius;
  const double r = std::sqrt(ri2 + double(u.x) * (disk_.radius * disk_.radius - ri2));
  const double phi = 2 * M_PI * double(u.y);
  const Vec3f p =
      to_vec(disk_to_world_.apply_point({r * std::cos(phi), r * std::sin(phi), disk_.height}));
  if (has_alpha_ && masked(geometry_->alpha_at_point(shape_, p, disk_normal_), p))
    return std::nullopt;
  return AreaPoint{p, disk_normal_};
}

std::optional<LightSample> AreaLight::sample_cylinder(const LightContext& ctx, Point2f u,
                                                      const SampledWavelengths& lambda) const {
  auto point = point_on_cylinder(u);
  if (!point) return std::nullopt;
  return uniform_area_sample(ctx, point->p, point->n, lambda);
}

std::optional<AreaPoint> AreaLight::point_on_cylinder(Point2f u) const {
  const double z = cylinder_.z_min + double(u.x) * (cylinder_.z_max - cylinder_.z_min);
  const double phi = 2 * M_PI * double(u.y);
  const scene::Vec3 po{cylinder_.radius * std::cos(phi), cylinder_.radius * std::sin(phi), z};
  const Vec3f p = to_vec(cylinder_to_world_.apply_point(po));
  // The normal exactly as Geometry::finish_quadric_hit builds it.
  Vec3f n = normalize(to_vec(cylinder_to_world_.apply_normal({po[0], po[1], 0})));
  if (cylinder_flip_) n = -n;
  if (has_alpha_ && masked(geometry_->alpha_at_point(shape_, p, n), p)) return std::nullopt;
  return AreaPoint{p, n};
}

std::optional<AreaPoint> AreaLight::point_on_sphere(Point2f u) const {
  const Vec3f n = sample_uniform_sphere(u);
  const Vec3f p = sphere_centre_ + n * sphere_radius_;
  const Vec3f ng = sphere_flip_ ? -n : n;
  if (has_alpha_ && masked(geometry_->alpha_at_point(shape_, p, ng), p)) return std::nullopt;
  return AreaPoint{p, ng};
}

std::optional<AreaPoint> AreaLight::sample_point(Point2f u, float u_tri) const {
  if (is_disk_) return point_on_disk(u);
  if (is_cylinder_) return point_on_cylinder(u);
  return is_sphere_ ? point_on_sphere(u) : point_on_triangles(u, u_tri);
}

bool AreaLight::masked(float alpha, const Vec3f& p) {
  if (alpha >= 1.0f) return false;
  if (!(alpha > 0.0f)) return true;
  return unit_float(hash_floats(kEmitterAlphaSeed, {p.x, p.y, p.z})) > alpha;
}

std::optional<LightSample> AreaLight::uniform_area_sample(const LightContext& ctx, const Vec3f& p,
                                                          const Vec3f& n,
                                                          const SampledWavelengths& lambda) const {
  Vec3f d = p - ctx.p;
  float dist2 = length_squared(d);
  if (!(dist2 > 0)) return std::nullopt;
  float dist = std::sqrt(dist2);
  Vec3f wi = d / dist;
  float cos_light = dot(n, -wi);
  if (!two_sided_ && cos_light <= 0) return std::nullopt;
  float pdf = dist2 / (std::abs(cos_light) * float(area_));
  if (!std::isfinite(pdf) || !(pdf > 0)) return std::nullopt;
  return area_sample(wi, dist, p, n, pdf, lambda);
}

LightSample AreaLight::area_sample(const Vec3f& wi, float dist, const Vec3f& p, const Vec3f& n,
                                   float pdf, const SampledWavelengths& lambda) const {
  LightSample s;
  s.radiance = scaled(spectrum_, scale_, lambda);
  s.wi = wi;
  s.distance = dist;
  s.p_light = p;
  s.n_light = n;
  s.pdf = pdf;
  return s;
}

std::optional<LightSample> AreaLight::sample_triangles(const LightContext& ctx, Point2f u,
                                                       float u_tri,
                                                       const SampledWavelengths& lambda) const {
  auto point = point_on_triangles(u, u_tri);
  if (!point) return std::nullopt;
  return uniform_area_sample(ctx, point->p, point->n, lambda);
}

std::optional<AreaPoint> AreaLight::point_on_triangles(Point2f u, float u_tri) const {
  // The first triangle whose cumulative area exceeds u_tri: zero-area triangles are never chosen.
  auto it = std::upper_bound(triangle_cdf_.begin(), triangle_cdf_.end(), u_tri);
  auto index = std::uint32_t(std::min<std::ptrdiff_t>(it - triangle_cdf_.begin(),
                                                      std::ptrdiff_t(triangle_cdf_.size()) - 1));
  if (const int patch = triangles_[index].patch; patch >= 0) {
    // What of u_tri is left inside the chosen patch's share decides the patch's acceptance.
    const float lo = index > 0 ? triangle_cdf_[index - 1] : 0.0f, hi = triangle_cdf_[index];
    const float u_accept = std::clamp((u_tri - lo) / (hi - lo), 0.0f, 0x1.fffffep-1f);
    return point_on_patch(patches_[size_t(patch)], u, u_accept);
  }
  const Geometry::WorldTriangle& t = triangles_[index].t;
  // Uniform barycentrics by Heitz's area-preserving square-to-triangle map (as pbrt-v4).
  float b0, b1;
  if (u.x < u.y) {
    b0 = u.x / 2;
    b1 = u.y - b0;
  } else {
    b1 = u.y / 2;
    b0 = u.x - b1;
  }
  float b2 = 1.0f - b0 - b1;
  Vec3f p = t.p0 * b0 + t.p1 * b1 + t.p2 * b2;
  // (b1, b2 are finish_triangle_hit's u, v.)
  Vec3f n = triangles_[index].n;
  if (t.has_normals) {
    Vec3f ns = t.n0 * b0 + t.n1 * b1 + t.n2 * b2;
    float ls = length(ns);
    if (ls > 0) n = face_forward(n, ns / ls);
  }
  if (has_alpha_ && masked(geometry_->alpha_on_triangle(shape_, index, b1, b2, n), p))
    return std::nullopt;
  return AreaPoint{p, n};
}

std::optional<AreaPoint> AreaLight::point_on_patch(const EmitterPatch& patch, Point2f u,
                                                   float u_accept) const {
  const Geometry::WorldPatch& w = patch.w;
  const float* c = patch.corner;
  for (int attempt = 0; attempt < kPatchAttempts; ++attempt) {
    if (attempt > 0) {
      // Later attempts draw from a hash of the sample: deterministic, independent enough.
      const std::uint64_t h =
          hash_floats(kPatchSeed + std::uint64_t(attempt), {u.x, u.y, u_accept});
      u = {unit_float(h), unit_float(mix64(h))};
      u_accept = unit_float(mix64(h + kGoldenGamma));
    }
    // v from the edges' sums, then u along the row at v: each a linear density.
    const float v = sample_linear(u.y, c[0] + c[1], c[2] + c[3]);
    const float pu = sample_linear(u.x, c[0] * (1 - v) + c[2] * v, c[1] * (1 - v) + c[3] * v);
    const float bilinear =
        (c[0] * (1 - pu) + c[1] * pu) * (1 - v) + (c[2] * (1 - pu) + c[3] * pu) * v;
    if (!(u_accept * bilinear <= w.area_element(pu, v))) continue;
    const Vec3f p = w.point(pu, v);
    const Vec3f n = w.unit_normal(pu, v);
    if (has_alpha_ && masked(geometry_->alpha_on_triangle(shape_, patch.triangle, pu, v, n), p))
      return std::nullopt;
    return AreaPoint{p, n};
  }
  return std::nullopt;
}

std::optional<LightSample> AreaLight::sample_sphere(const LightContext& ctx, Point2f u,
                                                    const SampledWavelengths& lambda) const {
  const float r2 = sphere_radius_ * sphere_radius_;
  Vec3f to_centre = sphere_centre_ - ctx.p;
  float d2 = length_squared(to_centre);
  Vec3f p, n;  // n: outward unit normal at p
  float pdf;
  if (d2 <= r2) {
    // Inside: uniform by area, converted to solid angle.
    n = sample_uniform_sphere(u);
    p = sphere_centre_ + n * sphere_radius_;
    Vec3f d = p - ctx.p;
    float dist2 = length_squared(d);
    if (!(dist2 > 0)) return std::nullopt;
    float cos_light = std::abs(dot(n, d)) / std::sqrt(dist2);
    pdf = dist2 / (cos_light * float(area_));
  } else {
    // Outside: uniform in the cone of directions that hit the sphere (pbrt-v4 Sphere::Sample),
    // then the nearer intersection found through the angle α at the centre.
    float omc = cone_one_minus_cos(r2, d2);
    float sin2_max = std::min(1.0f, r2 / d2);
    float one_minus_cos = u.x * omc;
    float cos_theta = 1.0f - one_minus_cos;
    float sin2_theta = one_minus_cos * (2.0f - one_minus_cos);
    float sin_max = std::sqrt(sin2_max);
    float cos_alpha = sin2_theta / sin_max + cos_theta * safe_sqrt(1.0f - sin2_theta / sin2_max);
    cos_alpha = std::clamp(cos_alpha, -1.0f, 1.0f);
    float sin_alpha = safe_sqrt(1.0f - cos_alpha * cos_alpha);
    float phi = 2.0f * kPi * u.y;
    Frame frame = Frame::from_z(to_centre / std::sqrt(d2));
    n = frame.from_local({-sin_alpha * std::cos(phi), -sin_alpha * std::sin(phi), -cos_alpha});
    p = sphere_centre_ + n * sphere_radius_;
    pdf = 1.0f / (2.0f * kPi * omc);
  }
  Vec3f ng = sphere_flip_ ? -n : n;
  if (has_alpha_ && masked(geometry_->alpha_at_point(shape_, p, ng), p)) return std::nullopt;
  Vec3f d = p - ctx.p;
  float dist = length(d);
  if (!(dist > 0)) return std::nullopt;
  Vec3f wi = d / dist;
  if (!two_sided_ && dot(ng, -wi) <= 0) return std::nullopt;
  if (!std::isfinite(pdf) || !(pdf > 0)) return std::nullopt;
  return area_sample(wi, dist, p, ng, pdf, lambda);
}

float AreaLight::pdf(const LightContext& ctx, const Vec3f& wi, const SurfaceHit& hit) const {
  // sample() never returns a point that does not emit towards ctx; its density there is 0.
  if (!two_sided_ && dot(hit.ng, -wi) <= 0) return 0;
  if (is_sphere_) {
    const float r2 = sphere_radius_ * sphere_radius_;
    float d2 = length_squared(sphere_centre_ - ctx.p);
    if (d2 > r2) return 1.0f / (2.0f * kPi * cone_one_minus_cos(r2, d2));
  }
  float dist2 = length_squared(hit.p - ctx.p);
  float cos_light = abs_dot(hit.ng, wi);
  if (!(cos_light > 0)) return 0;
  float pdf = dist2 / (cos_light * float(area_));
  return std::isfinite(pdf) ? pdf : 0.0f;
}

SampledSpectrum AreaLight::radiance(const Vec3f& n, const Vec3f& w,
                                    const SampledWavelengths& lambda) const {
  if (!two_sided_ && !(dot(n, w) > 0)) return SampledSpectrum(0.0f);
  return scaled(spectrum_, scale_, lambda);
}

absl::StatusOr<std::shared_ptr<const ProjectionImage>> ProjectionImage::create(
    const scene::TextureImage& image, double fov_deg, const spectral::RgbUplift& uplift) {
  auto out = std::make_shared<ProjectionImage>();
  out->width = image.width;
  out->height = image.height;
  PRISM_ASSIGN_OR_RETURN(out->texels, IlluminantTexels::create(image, uplift));
  const double aspect = double(image.width) / double(image.height);
  out->x_max = float(aspect > 1 ? aspect : 1.0);
  out->y_max = float(aspect > 1 ? 1.0 : 1.0 / aspect);
  out->tan_half = float(std::tan(fov_deg * M_PI / 360.0));
  // A rectangular pyramid of half-angles α, β covers 4·asin(sin α · sin β) sr.
  const double alpha = std::atan(double(out->x_max) * out->tan_half);
  const double beta = std::atan(double(out->y_max) * out->tan_half);
  out->solid_angle_fraction = 4 * std::asin(std::sin(alpha) * std::sin(beta)) / (4 * M_PI);
  constexpr double kLuminance[3] = {0.2126729, 0.7151522, 0.0721750};  // sRGB's Y row
  const double t = out->tan_half;
  const double texel_area =
      4 * t * t * out->x_max * out->y_max / (double(image.width) * image.height);
  double flux = 0;
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const double sx = out->x_max * (2 * (x + 0.5) / image.width - 1);
      const double sy = out->y_max * (2 * (y + 0.5) / image.height - 1);
      const double cos_theta = 1 / std::sqrt(1 + t * t * (sx * sx + sy * sy));
      const size_t texel = (size_t(y) * size_t(image.width) + size_t(x)) * size_t(image.channels);
      double luminance = 0;
      for (int c = 0; c < 3; ++c)
        luminance +=
            kLuminance[c] *
            double(std::max(0.0f, image.values[texel + size_t(image.channels == 1 ? 0 : c)]));
      flux += luminance * cos_theta * cos_theta * cos_theta * texel_area;
    }
  }
  out->flux_per_unit_scale = flux;
  return std::shared_ptr<const ProjectionImage>(std::move(out));
}

absl::StatusOr<PointLight> PointLight::create(const scene::Light& light,
                                              spectral::Spectrum spectrum, double scale,
                                              std::shared_ptr<const ProjectionImage> projection) {
  const auto* point = std::get_if<scene::PointLight>(&light.kind);
  PRISM_CHECK(point != nullptr);
  if (auto status = check_scale(scale, light.where); !status.ok()) return status;
  PointLight l;
  l.position_ = to_vec(point->position_world);
  l.spectrum_ = std::move(spectrum);
  l.scale_ = scale;
  l.where_ = light.where;
  const scene::Matrix4& inverse = light.light_to_world.inverse_matrix();
  if (projection) {
    l.projection_ = std::move(projection);
    l.mean_modulation_ = l.projection_->solid_angle_fraction;
    // pbrt-v4 flips light-space y before projecting.
    for (int c = 0; c < 3; ++c) {
      l.light_from_world_[0][c] = float(inverse[0][c]);
      l.light_from_world_[1][c] = -float(inverse[1][c]);
      l.light_from_world_[2][c] = float(inverse[2][c]);
    }
  }
  if (point->goniometric) {
    l.image_ = point->goniometric;
    double sum = 0;
    for (float v : l.image_->values) sum += std::max(0.0f, v);
    l.mean_modulation_ = sum / double(l.image_->values.size());
    // Light space from world (the rotation part of the light's frame), then pbrt-v4's y <-> z.
    for (int c = 0; c < 3; ++c) {
      l.light_from_world_[0][c] = float(inverse[0][c]);
      l.light_from_world_[1][c] = float(inverse[2][c]);
      l.light_from_world_[2][c] = float(inverse[1][c]);
    }
  }
  return l;
}

SampledSpectrum PointLight::projected(const Vec3f& w, const SampledWavelengths& lambda) const {
  SampledSpectrum out;
  const auto& m = light_from_world_;
  const Vec3f local(m[0][0] * w.x + m[0][1] * w.y + m[0][2] * w.z,
                    m[1][0] * w.x + m[1][1] * w.y + m[1][2] * w.z,
                    m[2][0] * w.x + m[2][1] * w.y + m[2][2] * w.z);
  const ProjectionImage& p = *projection_;
  if (!(local.z > 0)) return out;
  const float sx = local.x / (local.z * p.tan_half), sy = local.y / (local.z * p.tan_half);
  if (std::abs(sx) > p.x_max || std::abs(sy) > p.y_max) return out;
  const float u = (sx + p.x_max) / (2 * p.x_max), v = (sy + p.y_max) / (2 * p.y_max);
  const int x = std::clamp(int(u * float(p.width)), 0, p.width - 1);
  const int y = std::clamp(int(v * float(p.height)), 0, p.height - 1);
  return p.texels.at(size_t(y) * size_t(p.width) + size_t(x), lambda) * float(scale_);
}

float PointLight::modulation(const Vec3f& w) const {
  if (!image_) return 1.0f;
  const auto& m = light_from_world_;
  const Vec3f local = normalize(Vec3f(m[0][0] * w.x + m[0][1] * w.y + m[0][2] * w.z,
                                      m[1][0] * w.x + m[1][1] * w.y + m[1][2] * w.z,
                                      m[2][0] * w.x + m[2][1] * w.y + m[2][2] * w.z));
  const Point2f uv = equal_area_sphere_to_square(local);
  const int n = image_->width;
  const int x = std::clamp(int(uv.x * float(n)), 0, n - 1);
  const int y = std::clamp(int(uv.y * float(n)), 0, n - 1);
  return std::max(0.0f, image_->values[size_t(y) * size_t(n) + size_t(x)]);
}

std::optional<LightSample> PointLight::sample(const LightContext& ctx,
                                              const SampledWavelengths& lambda) const {
  Vec3f d = position_ - ctx.p;
  float dist2 = length_squared(d);
  if (!(dist2 > 0)) return std::nullopt;
  float dist = std::sqrt(dist2);
  LightSample s;
  s.wi = d / dist;
  if (projection_) {
    s.radiance = projected(-s.wi, lambda) / dist2;
  } else {
    s.radiance = scaled(spectrum_, scale_, lambda) * (modulation(-s.wi) / dist2);
  }
  s.distance = dist;
  s.p_light = position_;
  s.pdf = 1;
  s.delta = true;
  return s;
}

absl::StatusOr<SpotLight> SpotLight::create(const scene::Light& light, spectral::Spectrum spectrum,
                                            double scale) {
  const auto* spot = std::get_if<scene::SpotLight>(&light.kind);
  PRISM_CHECK(spot != nullptr);
  if (auto status = check_scale(scale, light.where); !status.ok()) return status;
  double cone = spot->cone_angle_deg, delta = spot->cone_delta_angle_deg;
  if (!(cone >= 0 && cone <= 180) || !(delta >= 0 && delta <= cone)) {
    return scene::location_error(
        light.where, absl::StrCat("spot light needs 0 <= 'float conedeltaangle' (", delta,
                                  delta == 5 ? "; 5 is the default where the scene gives none" : "",
                                  ") <= 'float coneangle' (", cone, ") <= 180 degrees"));
  }
  Vec3f dir = to_vec(spot->direction_world);
  if (!(length(dir) > 0)) return scene::location_error(light.where, "spot light has no direction");
  SpotLight l;
  l.position_ = to_vec(spot->position_world);
  l.direction_ = normalize(dir);
  l.cos_falloff_end_ = float(std::cos(cone * M_PI / 180));
  l.cos_falloff_start_ = float(std::cos((cone - delta) * M_PI / 180));
  l.spectrum_ = std::move(spectrum);
  l.scale_ = scale;
  l.where_ = light.where;
  return l;
}

float SpotLight::falloff(const Vec3f& w) const {
  return smooth_step(dot(direction_, w), cos_falloff_end_, cos_falloff_start_);
}

double SpotLight::power_factor() const {
  // ∫ falloff dω = 2π[(1 − cos_start) + (cos_start − cos_end)/2]: the Hermite step integrates to
  // exactly half its interval in cos θ (pbrt-v4 SpotLight::Phi uses the same closed form).
  double start = cos_falloff_start_, end = cos_falloff_end_;
  return 2 * M_PI * ((1 - start) + (start - end) / 2) / (4 * M_PI);
}

std::optional<LightSample> SpotLight::sample(const LightContext& ctx,
                                             const SampledWavelengths& lambda) const {
  Vec3f d = position_ - ctx.p;
  float dist2 = length_squared(d);
  if (!(dist2 > 0)) return std::nullopt;
  float dist = std::sqrt(dist2);
  Vec3f wi = d / dist;
  float f = falloff(-wi);
  if (!(f > 0)) return std::nullopt;
  LightSample s;
  s.radiance = scaled(spectrum_, scale_, lambda) * (f / dist2);
  s.wi = wi;
  s.distance = dist;
  s.p_light = position_;
  s.pdf = 1;
  s.delta = true;
  return s;
}

absl::StatusOr<InfiniteLight> InfiniteLight::create(const scene::Light& light,
                                                    spectral::Spectrum spectrum, double scale,
                                                    const Bounds3f& scene_bounds,
                                                    std::shared_ptr<const EnvironmentMap> map) {
  if (auto status = check_scale(scale, light.where); !status.ok()) return status;
  InfiniteLight l;
  l.map_ = std::move(map);
  l.spectrum_ = std::move(spectrum);
  l.scale_ = scale;
  l.where_ = light.where;
  if (const auto* inf = std::get_if<scene::InfiniteLight>(&light.kind); inf && inf->portal) {
    if (!l.map_) return scene::location_error(light.where, "a portal needs an environment image");
    l.portal_ = Portal::create(*inf->portal);
  }
  bool empty = scene_bounds.lo.x > scene_bounds.hi.x;
  l.scene_centre_ = empty ? Vec3f() : scene_bounds.centre();
  l.scene_radius_ = empty ? 0.0 : double(scene_bounds.radius());
  // A point-sized scene still needs a finite positive radius for the power estimate.
  if (!(l.scene_radius_ > 0)) l.scene_radius_ = 1;
  return l;
}

// The largest float below 1, for sample numbers stretched back over [0, 1).
constexpr float kBelowOne = 0x1.fffffep-1f;

std::optional<LightSample> InfiniteLight::sample(const LightContext& ctx, Point2f u,
                                                 const SampledWavelengths& lambda) const {
  LightSample s;
  if (portal_) {
    // u.x picks the technique and is then stretched back over [0, 1).
    std::optional<Vec3f> w;
    if (u.x < 0.5f) {
      if (auto m = map_->sample(Point2f{std::min(2 * u.x, kBelowOne), u.y})) w = m->w;
    } else if (auto m = portal_->sample(ctx.p, Point2f{std::min(2 * u.x - 1, kBelowOne), u.y})) {
      w = m->w;
    }
    if (!w) return std::nullopt;
    s.wi = *w;
    s.pdf = pdf(ctx.p, s.wi);
    if (!(s.pdf > 0)) return std::nullopt;
  } else if (map_) {
    auto m = map_->sample(u);
    if (!m) return std::nullopt;
    s.wi = m->w;
    s.pdf = m->pdf;
  } else {
    s.wi = sample_uniform_sphere(u);
    s.pdf = 1.0f / (4.0f * kPi);
  }
  s.radiance = radiance(ctx.p, s.wi, lambda);
  s.distance = std::numeric_limits<float>::infinity();
  // Beyond the scene's bounding sphere in direction wi, for shadow rays that need an endpoint.
  float reach = length(ctx.p - scene_centre_) + 2.0f * float(scene_radius_);
  s.p_light = ctx.p + s.wi * reach;
  return s;
}

float InfiniteLight::pdf(const Vec3f& p, const Vec3f& wi) const {
  if (portal_) {
    const float window = portal_->pdf(p, wi);
    // Directions outside the window carry no radiance: no technique need reach them.
    return window > 0 ? 0.5f * (map_->pdf(wi) + window) : 0.0f;
  }
  return map_ ? map_->pdf(wi) : 1.0f / (4.0f * kPi);
}

SampledSpectrum InfiniteLight::radiance(const Vec3f& p, const Vec3f& w,
                                        const SampledWavelengths& lambda) const {
  if (portal_ && !portal_->passes(p, w)) return SampledSpectrum(0.0f);
  if (map_) return map_->radiance(w, lambda) * float(scale_);
  return scaled(spectrum_, scale_, lambda);
}

std::optional<LightSample> sample_light(const Light& light, const LightContext& ctx, Point2f u,
                                        float u_extra, const SampledWavelengths& lambda) {
  return std::visit(
      [&](const auto& l) -> std::optional<LightSample> {
        using T = std::decay_t<decltype(l)>;
        if constexpr (std::is_same_v<T, AreaLight>) {
          return l.sample(ctx, u, u_extra, lambda);
        } else if constexpr (std::is_same_v<T, InfiniteLight>) {
          return l.sample(ctx, u, lambda);
        } else {
          return l.sample(ctx, lambda);
        }
      },
      light);
}

bool is_delta(const Light& light) {
  return std::holds_alternative<PointLight>(light) || std::holds_alternative<SpotLight>(light) ||
         std::holds_alternative<DistantLight>(light);
}

absl::StatusOr<DistantLight> DistantLight::create(const scene::Light& light,
                                                  spectral::Spectrum spectrum, double scale,
                                                  const Bounds3f& scene_bounds) {
  const auto* distant = std::get_if<scene::DistantLight>(&light.kind);
  PRISM_CHECK(distant != nullptr);
  if (auto status = check_scale(scale, light.where); !status.ok()) return status;
  const Vec3f w = to_vec(distant->direction_world);
  if (!(length(w) > 0)) return scene::location_error(light.where, "distant light has no direction");
  DistantLight l;
  l.direction_ = normalize(w);
  l.spectrum_ = std::move(spectrum);
  l.scale_ = scale;
  const bool empty = scene_bounds.lo.x > scene_bounds.hi.x;
  l.scene_radius_ = empty ? 1.0 : std::max(1e-3, double(scene_bounds.radius()));
  l.where_ = light.where;
  return l;
}

std::optional<LightSample> DistantLight::sample(const LightContext& ctx,
                                                const SampledWavelengths& lambda) const {
  LightSample s;
  s.radiance = scaled(spectrum_, scale_, lambda);
  s.wi = direction_;
  s.distance = std::numeric_limits<float>::infinity();
  s.p_light = ctx.p + direction_ * float(2 * scene_radius_);
  s.pdf = 1;
  s.delta = true;
  return s;
}

const spectral::Spectrum& light_spectrum(const Light& light) {
  return std::visit([](const auto& l) -> const spectral::Spectrum& { return l.spectrum(); }, light);
}

double light_scale(const Light& light) {
  return std::visit([](const auto& l) { return l.scale(); }, light);
}

const scene::SourceLocation& light_location(const Light& light) {
  return std::visit([](const auto& l) -> const scene::SourceLocation& { return l.where(); }, light);
}

double light_power(const Light& light) {
  double emitted =
      light_scale(light) *
      spectral::integrate(light_spectrum(light), spectral::kLambdaMin, spectral::kLambdaMax);
  return std::visit(
      [&](const auto& l) {
        using T = std::decay_t<decltype(l)>;
        if constexpr (std::is_same_v<T, AreaLight>) {
          return emitted * M_PI * l.area() * (l.two_sided() ? 2.0 : 1.0);
        } else if constexpr (std::is_same_v<T, PointLight>) {
          return emitted * 4 * M_PI * l.mean_modulation();
        } else if constexpr (std::is_same_v<T, SpotLight>) {
          return emitted * 4 * M_PI * l.power_factor();
        } else if constexpr (std::is_same_v<T, DistantLight>) {
          // pbrt-v4: the power through the scene's bounding disc.
          const double r = l.scene_radius();
          return emitted * M_PI * r * r;
        } else {
          // Through a portal, the flux a hemisphere of radiance sends through its window.
          if (l.portal()) return emitted * M_PI * l.portal()->area();
          double r = l.scene_radius();
          return emitted * M_PI * r * r * 4 * M_PI;
        }
      },
      light);
}

}  // namespace prism::worker
