#include "worker/light.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "services/spectral/testing/chi_square.h"
#include "worker/equal_area.h"
#include "worker/light_sampler.h"
#include "worker/testing/sphere_histogram.h"

namespace prism::worker {
namespace {

using spectral::testing::chi_square;

constexpr float kInf = std::numeric_limits<float>::infinity();

scene::SourceLocation at(int line) {
  return {"test.pbrt", line, 3};
}

// An area-light shape of the given geometry under t, declared at test line `line`.
scene::Shape light_shape(scene::ShapeGeometry geometry, const scene::Transform& t, bool reverse,
                         int line) {
  scene::Shape s;
  s.geometry = std::move(geometry);
  s.object_to_world = t;
  s.transform_swaps_handedness = t.swaps_handedness();
  s.reverse_orientation = reverse;
  s.area_light = scene::AreaLight{};
  s.where = at(line);
  return s;
}

spectral::Spectrum band(double lo, double hi) {
  std::vector<double> l = {lo - 10, lo, hi, hi + 10}, v = {0, 1, 1, 0};
  auto s = spectral::PiecewiseLinearSpectrum::create(l, v, "band");
  PRISM_CHECK(s.ok());
  return *s;
}

SampledWavelengths lanes(std::initializer_list<float> nm) {
  SampledWavelengths w(int(nm.size()));
  int i = 0;
  for (float l : nm) w.set(i++, l, 1.0f / 470);
  return w;
}

// A quad with corners c0..c3 (two triangles (0,1,2), (0,2,3)); optionally with vertex normals.
scene::Shape quad(std::array<Vec3f, 4> c, bool two_sided = false, bool reverse = false,
                  std::optional<Vec3f> vertex_normal = std::nullopt, int line = 10) {
  auto mesh = std::make_shared<scene::TriangleMeshData>();
  for (const Vec3f& p : c) mesh->positions.push_back({p.x, p.y, p.z});
  if (vertex_normal) {
    for (int i = 0; i < 4; ++i) {
      mesh->normals.push_back({vertex_normal->x, vertex_normal->y, vertex_normal->z});
    }
  }
  mesh->triangles = {{0, 1, 2}, {0, 2, 3}};
  scene::Shape shape;
  shape.geometry = scene::TriangleMeshShape{mesh, "test"};
  shape.reverse_orientation = reverse;
  shape.area_light = scene::AreaLight{};
  shape.area_light->two_sided = two_sided;
  shape.area_light->where = at(line);
  shape.where = at(line - 1);
  return shape;
}

// A horizontal square [-a, a]² at height z, counter-clockwise seen from +z unless `down`, so its
// winding normal is +z (or −z).
scene::Shape square(float a, float z, bool down, bool two_sided = false) {
  std::array<Vec3f, 4> c = {Vec3f(-a, -a, z), Vec3f(a, -a, z), Vec3f(a, a, z), Vec3f(-a, a, z)};
  if (down) std::swap(c[1], c[3]);
  return quad(c, two_sided);
}

scene::Shape sphere(double radius, const scene::Transform& t, bool reverse = false,
                    bool two_sided = false) {
  scene::Shape shape;
  shape.geometry = scene::SphereShape{radius};
  shape.object_to_world = t;
  shape.transform_swaps_handedness = t.swaps_handedness();
  shape.reverse_orientation = reverse;
  shape.area_light = scene::AreaLight{};
  shape.area_light->two_sided = two_sided;
  shape.area_light->where = at(20);
  shape.where = at(19);
  return shape;
}

scene::Light point_desc(Vec3f p, int line) {
  scene::PointLight point;
  point.position_world = {p.x, p.y, p.z};
  scene::Light l;
  l.kind = point;
  l.where = at(line);
  return l;
}

scene::Light spot_desc(Vec3f p, Vec3f dir, double cone, double delta, int line) {
  scene::SpotLight spot;
  spot.position_world = {p.x, p.y, p.z};
  spot.direction_world = {dir.x, dir.y, dir.z};
  spot.cone_angle_deg = cone;
  spot.cone_delta_angle_deg = delta;
  scene::Light l;
  l.kind = spot;
  l.where = at(line);
  return l;
}

struct World {
  EmbreeDevice device;
  scene::SceneDescription desc;
  std::unique_ptr<Geometry> geometry;
};

std::unique_ptr<World> build(std::vector<scene::Shape> shapes,
                             std::vector<AlphaFunction> alpha = {}) {
  auto w = std::make_unique<World>();
  w->desc.shapes = std::move(shapes);
  auto g = Geometry::build(w->device, w->desc, std::move(alpha));
  PRISM_CHECK(g.ok());
  w->geometry = std::move(*g);
  return w;
}

AreaLight area_light(const World& w, int shape,
                     spectral::Spectrum s = spectral::ConstantSpectrum{1}, double scale = 1) {
  auto l = AreaLight::create(w.desc.shapes[shape], shape, *w.geometry, std::move(s), scale);
  PRISM_CHECK(l.ok());
  return *l;
}

// pdf() of the direction w as the integrator sees it: through the first hit of a ray.
float traced_pdf(const World& w, const AreaLight& light, const LightContext& ctx,
                 const Vec3f& dir) {
  auto hit = w.geometry->intersect({ctx.p, dir}, kInf);
  if (!hit || hit->shape != light.shape()) return 0;
  return light.pdf(ctx, dir, *hit);
}

// Chi-square test of sampled directions against a density, binned in (θ, φ) about an axis with
// θ uniform in [0, theta_max] (the cone that holds every direction with non-zero density, so the
// cells resolve the light rather than the empty sphere). Expected counts integrate the density
// over each cell (dω = sin θ dθ dφ) with a midpoint rule refined per cell until two successive
// refinements agree (after worker/bsdf_test.cpp). Failed samples (nullopt) are not binned; the
// density of those directions is 0 in pdf() as well.
constexpr int kThetaCells = 16;
constexpr int kPhiCells = 32;
constexpr int kChiSamples = 100000;

struct Binning {
  Frame frame;
  double theta_max;

  int cell(const Vec3f& w) const {
    Vec3f l = frame.to_local(w);
    double theta = std::acos(std::clamp(double(l.z), -1.0, 1.0));
    double phi = std::atan2(l.y, l.x);
    if (phi < 0) phi += 2 * M_PI;
    int ti = std::min(kThetaCells - 1, int(theta / theta_max * kThetaCells));
    int pi = std::min(kPhiCells - 1, int(phi / (2 * M_PI) * kPhiCells));
    return ti * kPhiCells + pi;
  }
  double integrate(const std::function<float(const Vec3f&)>& pdf, int ti, int pi, int n) const {
    double sum = 0;
    testing::for_each_midpoint(
        ti * theta_max / kThetaCells, theta_max / kThetaCells, pi * 2 * M_PI / kPhiCells,
        2 * M_PI / kPhiCells, n,
        [&](const Vec3f& local, double weight) { sum += pdf(frame.from_local(local)) * weight; });
    return sum;
  }
};

void expect_directions_follow_pdf(const std::function<std::optional<Vec3f>(Point2f, float)>& sample,
                                  const std::function<float(const Vec3f&)>& pdf,
                                  const Binning& bins, const std::string& name) {
  std::vector<double> observed(kThetaCells * kPhiCells, 0.0), expected(observed.size(), 0.0);
  std::mt19937 rng(12345);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  int failed = 0;
  for (int i = 0; i < kChiSamples; ++i) {
    Point2f u{uni(rng), uni(rng)};
    float u_extra = uni(rng);
    auto w = sample(u, u_extra);
    if (!w) {
      ++failed;
      continue;
    }
    ASSERT_TRUE(is_finite(*w) && std::abs(length(*w) - 1) < 1e-4f) << name;
    observed[bins.cell(*w)] += 1;
  }
  // A light's silhouette can cut a thin sliver out of a cell that a coarse midpoint rule misses
  // entirely, so every cell that is non-zero at the coarse level or holds samples, and their
  // neighbours, is integrated finely (from 32² points, refined until two levels agree). Where
  // the rule is refined does not change what it converges to, so choosing it from the samples
  // does not bias the test.
  std::vector<double> coarse_mass(observed.size());
  for (int ti = 0; ti < kThetaCells; ++ti) {
    for (int pi = 0; pi < kPhiCells; ++pi) {
      coarse_mass[ti * kPhiCells + pi] = bins.integrate(pdf, ti, pi, 8);
    }
  }
  double mass = 0;
  for (int ti = 0; ti < kThetaCells; ++ti) {
    for (int pi = 0; pi < kPhiCells; ++pi) {
      bool near_light = false;
      for (int dt = -1; dt <= 1; ++dt) {
        for (int dp = -1; dp <= 1; ++dp) {
          int t = ti + dt, q = (pi + dp + kPhiCells) % kPhiCells;
          if (t < 0 || t >= kThetaCells) continue;
          near_light |= coarse_mass[t * kPhiCells + q] > 0 || observed[t * kPhiCells + q] > 0;
        }
      }
      // Near the pole every φ cell touches the same point.
      if (ti == 0) {
        for (int q = 0; q < kPhiCells; ++q) near_light |= coarse_mass[q] > 0 || observed[q] > 0;
      }
      double fine = 0;
      if (near_light) {
        int n = 32;
        double coarse = bins.integrate(pdf, ti, pi, n);
        fine = bins.integrate(pdf, ti, pi, 2 * n);
        // Stop once the integration error is far below the cell's Poisson noise √E.
        while (n < 256 && std::abs(fine - coarse) * kChiSamples >
                              0.05 + 0.02 * std::sqrt(fine * kChiSamples)) {
          n *= 2;
          coarse = fine;
          fine = bins.integrate(pdf, ti, pi, 2 * n);
        }
      }
      // Samples in a cell the rule found empty: a sliver finer than its spacing; resolve it.
      for (int n = 512; fine == 0 && observed[ti * kPhiCells + pi] > 0 && n <= 2048; n *= 2) {
        fine = bins.integrate(pdf, ti, pi, n);
      }
      expected[ti * kPhiCells + pi] = fine * kChiSamples;
      mass += fine;
    }
  }
  // The density integrates to the probability that sample() succeeds.
  EXPECT_NEAR(mass, 1.0 - double(failed) / kChiSamples, 5e-3) << name;
  auto result = chi_square(observed, expected);
  EXPECT_GT(result.p_value, 1e-5) << name << ": " << result.describe();
}

// Angular radius of a bounding sphere (centre c, radius r) seen from p, or π from inside it.
double cone_of(const Vec3f& p, const Vec3f& c, float r) {
  float d = length(c - p);
  return d <= r * 1.0001f ? M_PI : std::asin(std::min(1.0f, r / d));
}

struct AreaCase {
  std::string name;
  LightContext ctx;
  Vec3f centre;  // of a sphere bounding the light
  float radius;
};

void check_area_light(const World& w, const AreaLight& light, const AreaCase& c) {
  SampledWavelengths lambda = lanes({550});
  Vec3f axis = c.centre - c.ctx.p;
  axis = length(axis) > 1e-3f ? normalize(axis) : Vec3f(0, 0, 1);
  Binning bins{Frame::from_z(axis), cone_of(c.ctx.p, c.centre, c.radius)};
  expect_directions_follow_pdf(
      [&](Point2f u, float ue) -> std::optional<Vec3f> {
        auto s = light.sample(c.ctx, u, ue, lambda);
        if (!s) return std::nullopt;
        return s->wi;
      },
      [&](const Vec3f& dir) { return traced_pdf(w, light, c.ctx, dir); }, bins, c.name);

  // sample().pdf is pdf() of the point a ray along wi finds, at the sampled distance.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  int checked = 0, misses = 0;
  for (int i = 0; i < 2000; ++i) {
    auto s = light.sample(c.ctx, {uni(rng), uni(rng)}, uni(rng), lambda);
    if (!s) continue;
    ++checked;
    auto hit = w.geometry->intersect({c.ctx.p, s->wi}, kInf);
    // A direction grazing the light's silhouette may slip past it in float arithmetic.
    if (!hit || hit->shape != light.shape()) {
      ++misses;
      continue;
    }
    EXPECT_NEAR(hit->t, s->distance, 1e-3f * s->distance) << c.name;
    // At grazing angles the density ∝ 1/cos θ_light magnifies the float error of the hit point
    // (a cylinder's silhouette is always grazing); there only the distribution test above holds.
    if (abs_dot(hit->ng, s->wi) > 0.05f) {
      EXPECT_NEAR(light.pdf(c.ctx, s->wi, *hit), s->pdf, 2e-3f * s->pdf) << c.name;
    }
    EXPECT_NEAR(length(hit->p - s->p_light), 0.0f, 1e-3f * s->distance) << c.name;
    // n_light is the geometric normal intersections report there (shadow rays offset by it).
    EXPECT_NEAR(dot(hit->ng, s->n_light), 1.0f, 1e-3f) << c.name;
    EXPECT_FALSE(s->delta);
  }
  EXPECT_LE(misses, checked / 500 + 1) << c.name;
}

TEST(AreaLightTest, TriangleMeshDirectionsFollowPdf) {
  // One mesh of three triangles of different areas (a 2x2 square and a large triangle), facing
  // down (−z) at z = 2.
  auto mesh = std::make_shared<scene::TriangleMeshData>();
  mesh->positions = {{-1, -1, 2}, {-1, 1, 2}, {1, 1, 2}, {1, -1, 2},
                     {1, -1, 2},  {4, 2, 2},  {4, -3, 2}};
  mesh->triangles = {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}};
  scene::Shape shape;
  shape.geometry = scene::TriangleMeshShape{mesh, "test"};
  shape.area_light = scene::AreaLight{};
  auto w = build({shape});
  AreaLight light = area_light(*w, 0);
  EXPECT_NEAR(light.area(), 4.0 + 7.5, 1e-5);
  Vec3f centre(1.5f, -0.5f, 2), extent(2.5f, 2.5f, 0);
  float radius = length(extent) + 0.01f;
  for (const AreaCase& c : {AreaCase{"below", {{0.3f, 0.2f, 0}, {0, 0, 1}}, centre, radius},
                            AreaCase{"near", {{0.5f, 0, 1.7f}, {0, 0, 1}}, centre, radius},
                            AreaCase{"grazing", {{-9, 0, 1.9f}, {0, 0, 1}}, centre, radius}}) {
    check_area_light(*w, light, c);
  }
  // Behind a one-sided light nothing is sampled and pdf() agrees.
  LightContext behind{{0.2f, 0.1f, 3}, {0, 0, -1}};
  SampledWavelengths lambda = lanes({550});
  for (int i = 0; i < 100; ++i) {
    EXPECT_FALSE(
        light.sample(behind, {(i + 0.5f) / 100, 0.37f}, (i * 0.618f) - int(i * 0.618f), lambda));
  }
  EXPECT_EQ(traced_pdf(*w, light, behind, {0, 0, -1}), 0.0f);
  EXPECT_GT(traced_pdf(*w, light, {{0.2f, 0.1f, 0}, {}}, {0, 0, 1}), 0.0f);
}

// A curved bilinear patch emits from the surface itself, uniformly by area: its area is the
// integral of |∂p/∂u × ∂p/∂v|, sampled directions follow pdf() of what rays hit (the patch's
// points and normals, not its triangles'), beside a flat triangle of the same mesh.
TEST(AreaLightTest, CurvedBilinearPatchesAreSampledUniformlyByArea) {
  // Two saddles z = 2 + t·u·v (t = 0.8 over the unit square, t = 0.6 over [1.5, 2.5] x
  // [0, 0.5]) and a triangle at z = 2; every normal has +z: they light what is above. The
  // viewpoints look down more steeply than any slope of the surface, so no ray meets it twice
  // (what pdf() of the first hit assumes).
  auto mesh = std::make_shared<scene::TriangleMeshData>();
  mesh->positions = {{0, 0, 2},    {1, 0, 2},    {0, 1, 2},       {1, 1, 2.8f},
                     {1.5f, 0, 2}, {2.5f, 0, 2}, {1.5f, 0.5f, 2}, {2.5f, 0.5f, 2.6f},
                     {0, 1.2f, 2}, {1, 1.2f, 2}, {0, 2, 2}};
  mesh->triangles = {{0, 1, 3}, {0, 3, 2}, {4, 5, 7}, {4, 7, 6}, {8, 9, 10}};
  mesh->patches = {0, 2};
  scene::Shape shape;
  shape.geometry = scene::TriangleMeshShape{mesh, "bilinearmesh"};
  shape.area_light = scene::AreaLight{};
  auto w = build({shape});
  ASSERT_EQ(w->geometry->face(0, 0), Geometry::MeshFace::kPatch);
  AreaLight light = area_light(*w, 0);
  // The area by a fine midpoint rule, independently: |(−t v, −t u, 1)| per unit (u, v), times
  // the patch's side lengths (1 x 1, and 1 x 0.5 with a rise of 2 over it).
  auto saddle_area = [](double sx, double sy, double rise) {
    double sum = 0;
    const int n = 2000;
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        const double u = (i + 0.5) / n, v = (j + 0.5) / n;
        // p = (sx·u, sy·v, rise·u·v): ∂p/∂u = (sx, 0, rise·v), ∂p/∂v = (0, sy, rise·u).
        const double x = -rise * v * sy, y = -sx * rise * u, z = sx * sy;
        sum += std::sqrt(x * x + y * y + z * z);
      }
    }
    return sum / (double(n) * n);
  };
  const double area = saddle_area(1, 1, 0.8) + saddle_area(1, 0.5, 0.6) + 0.5 * 1 * 0.8;
  EXPECT_NEAR(light.area(), area, 1e-6 * area);
  Vec3f centre(1.25f, 1, 2.4f), extent(1.3f, 1.05f, 0.5f);
  const float radius = length(extent);
  for (const AreaCase& c : {AreaCase{"above", {{1.2f, 0.9f, 7}, {0, 0, -1}}, centre, radius},
                            AreaCase{"oblique", {{-1, -1, 9}, {0, 0, 1}}, centre, radius}}) {
    check_area_light(*w, light, c);
  }
  // Points by area, sharper than directions, on a steeper saddle z = 3·u·v where (u, v) =
  // (x, y): an 8x8 histogram of its points must follow the area element's integral over each
  // cell (the bilinear proposal alone, without the acceptance step, fails this by far).
  auto steep = std::make_shared<scene::TriangleMeshData>();
  steep->positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 3}};
  steep->triangles = {{0, 1, 3}, {0, 3, 2}};
  steep->patches = {0};
  shape.geometry = scene::TriangleMeshShape{steep, "bilinearmesh"};
  auto steep_world = build({shape});
  AreaLight steep_light = area_light(*steep_world, 0);
  constexpr int kCells = 8, kPoints = 200000;
  std::vector<double> observed(kCells * kCells), expected(kCells * kCells);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (int i = 0; i < kPoints; ++i) {
    auto point = steep_light.sample_point({uni(rng), uni(rng)}, uni(rng));
    ASSERT_TRUE(point);
    EXPECT_NEAR(point->p.z, 3 * point->p.x * point->p.y, 1e-5f);
    const int cx = std::clamp(int(point->p.x * kCells), 0, kCells - 1);
    const int cy = std::clamp(int(point->p.y * kCells), 0, kCells - 1);
    observed[cy * kCells + cx] += 1;
  }
  double total = 0;
  for (int cy = 0; cy < kCells; ++cy) {
    for (int cx = 0; cx < kCells; ++cx) {
      double sum = 0;
      const int n = 100;
      for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
          const double u = (cx + (i + 0.5) / n) / kCells, v = (cy + (j + 0.5) / n) / kCells;
          sum += std::sqrt(9 * (u * u + v * v) + 1);
        }
      }
      expected[cy * kCells + cx] = sum / (double(n) * n * kCells * kCells);
      total += expected[cy * kCells + cx];
    }
  }
  EXPECT_NEAR(steep_light.area(), total, 1e-5 * total);
  for (double& e : expected) e *= kPoints / total;
  auto result = chi_square(observed, expected);
  EXPECT_GT(result.p_value, 1e-5) << result.describe();
}

TEST(AreaLightTest, TwoSidedAndVertexNormalOrientation) {
  // Wound to face +z but with vertex normals pointing −z: Geometry turns ng to −z, so the light
  // emits downwards only.
  auto w = build({square(1, 2, /*down=*/false), square(1, -2, false, /*two_sided=*/true)});
  auto with_normals =
      build({quad({Vec3f(-1, -1, 2), Vec3f(1, -1, 2), Vec3f(1, 1, 2), Vec3f(-1, 1, 2)}, false,
                  false, Vec3f(0, 0, -1))});
  SampledWavelengths lambda = lanes({550});
  LightContext below{{0.1f, 0.2f, 0}, {}}, above{{0.1f, 0.2f, 4}, {}};
  AreaLight up = area_light(*w, 0), both = area_light(*w, 1), turned = area_light(*with_normals, 0);
  EXPECT_FALSE(up.sample(below, {0.3f, 0.6f}, 0.2f, lambda));
  EXPECT_TRUE(up.sample(above, {0.3f, 0.6f}, 0.2f, lambda));
  EXPECT_TRUE(both.sample(below, {0.3f, 0.6f}, 0.2f, lambda));
  EXPECT_TRUE(both.sample({{0, 0, -4}, {}}, {0.3f, 0.6f}, 0.2f, lambda));
  EXPECT_TRUE(turned.sample(below, {0.3f, 0.6f}, 0.2f, lambda));
  EXPECT_FALSE(turned.sample(above, {0.3f, 0.6f}, 0.2f, lambda));
  check_area_light(*with_normals, turned, {"vertex normals", below, {0, 0, 2}, 1.5f});
  check_area_light(*w, both, {"two-sided, back", {{0.4f, -0.3f, -3}, {}}, {0, 0, -2}, 1.5f});
  // radiance() follows the same side rule.
  EXPECT_EQ(up.radiance({0, 0, 1}, {0, 0, -1}, lambda)[0], 0.0f);
  EXPECT_EQ(up.radiance({0, 0, 1}, {0, 0.6f, 0.8f}, lambda)[0], 1.0f);
  EXPECT_EQ(both.radiance({0, 0, 1}, {0, 0, -1}, lambda)[0], 1.0f);
}

TEST(AreaLightTest, InstancedMirroredMeshLight) {
  // One mesh shared by two shapes (so Geometry instances it); the light is the copy under a
  // mirror. The mirror reverses the world-space winding (normal +z) and, swapping handedness,
  // flips it back: the light still emits towards −z, as in pbrt-v4.
  auto mesh = std::make_shared<scene::TriangleMeshData>();
  mesh->positions = {{-1, -1, 0}, {-1, 1, 0}, {1, 1, 0}, {1, -1, 0}};  // winding normal −z
  mesh->triangles = {{0, 1, 2}, {0, 2, 3}};
  scene::Shape plain;
  plain.geometry = scene::TriangleMeshShape{mesh, "shared"};
  plain.object_to_world = scene::Transform::translate({0, 0, 10});
  scene::Shape mirrored = plain;
  auto mirror = *scene::Transform::scale({-1.5, 1.5, 1.5});
  mirrored.object_to_world = scene::Transform::translate({0.5f, 0, -2}) * mirror;
  mirrored.transform_swaps_handedness = mirrored.object_to_world.swaps_handedness();
  ASSERT_TRUE(mirrored.transform_swaps_handedness);
  mirrored.area_light = scene::AreaLight{};
  auto w = build({plain, mirrored});
  AreaLight light = area_light(*w, 1);
  EXPECT_NEAR(light.area(), 9.0, 1e-5);
  SampledWavelengths lambda = lanes({550});
  EXPECT_FALSE(light.sample({{0.2f, 0.4f, 0}, {}}, {0.3f, 0.6f}, 0.2f, lambda));
  check_area_light(*w, light,
                   {"mirrored instance", {{0.8f, 0.4f, -3.5f}, {}}, {0.5f, 0, -2}, 2.2f});
}

TEST(AreaLightTest, SphereDirectionsFollowPdf) {
  const Vec3f c(0.5f, -0.25f, 3);
  auto t = scene::Transform::translate({c.x, c.y, c.z}) * *scene::Transform::scale({2, 2, 2}) *
           *scene::Transform::rotate(30, {1, 1, 0});
  // Radius 0.4 scaled by 2: world radius 0.8.
  // One world per orientation, so rays find the light under test.
  auto outward = build({sphere(0.4, t)});
  auto inward = build({sphere(0.4, t, true)});
  auto two = build({sphere(0.4, t, false, true)});
  AreaLight out = area_light(*outward, 0), in = area_light(*inward, 0), both = area_light(*two, 0);
  EXPECT_NEAR(out.area(), 4 * M_PI * 0.64, 1e-4);
  for (const AreaCase& k : {AreaCase{"outside near", {{0.5f, -0.25f, 1.9f}, {}}, c, 0.8f},
                            AreaCase{"outside oblique", {{-2, 1, 2.5f}, {}}, c, 0.8f},
                            AreaCase{"outside far", {{30, 20, -10}, {}}, c, 0.8f}}) {
    check_area_light(*outward, out, k);
    check_area_light(*two, both, k);
  }
  for (const AreaCase& k :
       {AreaCase{"inside centre", {c, {}}, c, 0.8f},
        AreaCase{"inside off-centre", {c + Vec3f(0.5f, 0.2f, -0.3f), {}}, c, 0.8f}}) {
    check_area_light(*inward, in, k);
    check_area_light(*two, both, k);
    // An outward-facing sphere does not light its inside.
    EXPECT_FALSE(out.sample(k.ctx, {0.3f, 0.3f}, 0.5f, lanes({550})));
  }
  // An inward-facing sphere does not light its outside.
  EXPECT_FALSE(in.sample({{0, 0, 0}, {}}, {0.3f, 0.3f}, 0.5f, lanes({550})));
}

TEST(AreaLightTest, NonSimilaritySphereIsRefusedWithLocation) {
  auto t = *scene::Transform::scale({1, 2, 1});
  auto w = build({sphere(1, t)});
  auto l = AreaLight::create(w->desc.shapes[0], 0, *w->geometry, spectral::ConstantSpectrum{1}, 1);
  ASSERT_FALSE(l.ok());
  EXPECT_EQ(l.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(std::string(l.status().message()).find("test.pbrt:19:3"), std::string::npos)
      << l.status();
  EXPECT_NE(std::string(l.status().message()).find("similarity"), std::string::npos);
}

// Monte-Carlo irradiance at (p, n) from sample(): mean of L·cos/pdf, with a 5σ bound.
void expect_irradiance(const std::function<std::optional<LightSample>(Point2f, float)>& sample,
                       const Vec3f& n, double exact, const std::string& name, int count = 200000) {
  std::mt19937 rng(99);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  double sum = 0, sum2 = 0;
  for (int i = 0; i < count; ++i) {
    Point2f u{uni(rng), uni(rng)};
    auto s = sample(u, uni(rng));
    if (!s) continue;
    double f = s->radiance[0] * std::max(0.0f, dot(s->wi, n)) / s->pdf;
    sum += f;
    sum2 += f * f;
  }
  double mean = sum / count, var = std::max(0.0, sum2 / count - mean * mean);
  double sigma = std::sqrt(var / count);
  EXPECT_NEAR(mean, exact, 5 * sigma + 1e-6 * exact) << name << " sigma " << sigma;
}

// Irradiance at a point on the normal through a corner of a parallel a×b rectangle of radiance 1
// at distance h: π times the classic form factor.
double corner_irradiance(double a, double b, double h) {
  double x = a / h, y = b / h;
  double sx = std::sqrt(1 + x * x), sy = std::sqrt(1 + y * y);
  return 0.5 * (x / sx * std::atan(y / sx) + y / sy * std::atan(x / sy));
}

TEST(AreaLightTest, IrradianceMatchesAnalyticValues) {
  // A 10x10 square at height 1 facing down, radiance 2 (spectrum 0.5, scale 4).
  auto w = build({square(5, 1, /*down=*/true)});
  AreaLight light = area_light(*w, 0, spectral::ConstantSpectrum{0.5f}, 4.0);
  SampledWavelengths lambda = lanes({600});
  for (Vec3f p : {Vec3f(0, 0, 0), Vec3f(2, -1.5f, 0.2f)}) {
    double h = 1 - p.z;
    double exact =
        2 * (corner_irradiance(5 - p.x, 5 - p.y, h) + corner_irradiance(5 + p.x, 5 - p.y, h) +
             corner_irradiance(5 - p.x, 5 + p.y, h) + corner_irradiance(5 + p.x, 5 + p.y, h));
    expect_irradiance(
        [&](Point2f u, float ue) {
          return light.sample({p, {0, 0, 1}}, u, ue, lambda);
        },
        {0, 0, 1}, exact, "square");
  }
  // A sphere of radius R at distance d: E = π L (R/d)² facing the centre.
  auto ws = build({sphere(1.5, scene::Transform::translate({0, 0, 4}))});
  AreaLight ball = area_light(*ws, 0, spectral::ConstantSpectrum{3}, 1.0);
  expect_irradiance(
      [&](Point2f u, float ue) {
        return ball.sample({{0, 0, 0}, {}}, u, ue, lambda);
      },
      {0, 0, 1}, 3 * M_PI * (1.5 / 4) * (1.5 / 4), "sphere outside");
  // Tilted 60° from the centre direction the sphere is still fully above the horizon
  // (half-angle 22°): E = π L (R/d)² cos 60°.
  Vec3f tilted(std::sin(kPi / 3), 0, std::cos(kPi / 3));
  expect_irradiance(
      [&](Point2f u, float ue) {
        return ball.sample({{0, 0, 0}, {}}, u, ue, lambda);
      },
      tilted, 3 * M_PI * (1.5 / 4) * (1.5 / 4) * 0.5, "sphere outside tilted");
  // Inside a sphere emitting inwards the radiance field is uniform: E = π L for any normal.
  auto wi = build({sphere(1.5, scene::Transform::translate({0, 0, 4}), /*reverse=*/true)});
  AreaLight shell = area_light(*wi, 0, spectral::ConstantSpectrum{3}, 1.0);
  expect_irradiance(
      [&](Point2f u, float ue) {
        return shell.sample({{0.3f, -0.5f, 4.6f}, {}}, u, ue, lambda);
      },
      normalize(Vec3f(1, 2, -1)), 3 * M_PI, "sphere inside");
}

// Under a mirroring transform a sphere, disk or cylinder light emits on the side it did
// without it (its outside stays outside), and its samples agree with what rays find there; a
// mirrored emitter seen from outside lights as the unmirrored one.
TEST(AreaLightTest, MirroredQuadricLightsKeepTheirOutside) {
  const auto mirror = *scene::Transform::scale({-1, 1, 1});
  SampledWavelengths lambda = lanes({600});
  auto ws = build({sphere(1.5, scene::Transform::translate({0, 0, 4}) * mirror)});
  AreaLight ball = area_light(*ws, 0, spectral::ConstantSpectrum{3}, 1.0);
  check_area_light(*ws, ball, AreaCase{"mirrored sphere", {{0, 0, 0}, {}}, {0, 0, 4}, 1.5f});
  expect_irradiance(
      [&](Point2f u, float ue) {
        return ball.sample({{0, 0, 0}, {}}, u, ue, lambda);
      },
      {0, 0, 1}, 3 * M_PI * (1.5 / 4) * (1.5 / 4), "mirrored sphere outside");
  auto wt = build({light_shape(scene::CylinderShape{0.5, -1.0, 1.0},
                               scene::Transform::translate({0.2f, -0.3f, 4}) * mirror, false, 37)});
  AreaLight tube = area_light(*wt, 0);
  check_area_light(*wt, tube,
                   AreaCase{"mirrored cylinder", {{0, 0, 0}, {}}, {0.2f, -0.3f, 4}, 1.2f});
  // A disk facing +z mirrored in z faces −z: it lights the origin below it.
  auto wd = build({light_shape(
      scene::DiskShape{0.0, 1.0, 0.0},
      scene::Transform::translate({0, 0, 2}) * *scene::Transform::scale({1, 1, -1}), false, 31)});
  AreaLight disk = area_light(*wd, 0);
  check_area_light(*wd, disk, AreaCase{"mirrored disk", {{0, 0, 0}, {}}, {0, 0, 2}, 1.0f});
  EXPECT_FALSE(disk.sample({{0, 0, 4}, {}}, {0.3f, 0.3f}, 0.5f, lambda));
}

// A disk light (with a hole, under a rotation and a non-uniform scale: an elliptical annulus):
// sampled directions follow pdf(), and on its axis a circular disk gives the closed-form
// irradiance E = π L (R²/(h² + R²) − r²/(h² + r²)); reversed, it lights the other side only.
TEST(AreaLightTest, DiskDirectionsFollowPdfAndIrradianceIsAnalytic) {
  auto shape = [](const scene::Transform& t, double inner, bool reverse) {
    return light_shape(scene::DiskShape{0.0, 1.0, inner}, t, reverse, 31);
  };
  auto t = scene::Transform::translate({0.3f, 0.1f, 3}) * *scene::Transform::rotate(25, {1, 0, 0}) *
           *scene::Transform::scale({1.5, 0.8, 1});
  auto w = build({shape(t, 0.4, /*reverse=*/true)});
  AreaLight ring = area_light(*w, 0);
  EXPECT_NEAR(ring.area(), M_PI * (1 - 0.16) * 1.2, 1e-4);
  // The disk's +z (rotated) faces away from the origin; reversed, it emits towards it.
  for (const AreaCase& k : {AreaCase{"below", {{0, 0, 0}, {}}, {0.3f, 0.1f, 3}, 1.5f},
                            AreaCase{"oblique", {{2, -1, 1}, {}}, {0.3f, 0.1f, 3}, 1.5f}}) {
    check_area_light(*w, ring, k);
  }
  EXPECT_FALSE(ring.sample({{0, 0, 6}, {}}, {0.3f, 0.3f}, 0.5f, lanes({550})));

  // Circular, facing down at height h = 2, radiance 2.
  auto wc = build({shape(scene::Transform::translate({0, 0, 2}), 0.5, /*reverse=*/true)});
  AreaLight disk = area_light(*wc, 0, spectral::ConstantSpectrum{0.5f}, 4.0);
  const double h = 2, big = 1, hole = 0.5;
  expect_irradiance(
      [&](Point2f u, float ue) {
        return disk.sample({{0, 0, 0}, {0, 0, 1}}, u, ue, lanes({600}));
      },
      {0, 0, 1}, 2 * M_PI * (big * big / (h * h + big * big) - hole * hole / (h * h + hole * hole)),
      "disk on axis");
}

// A cylinder light under a rotation and a uniform scale: sampled directions follow pdf() from
// outside and from inside; on the axis at the middle of an inward-emitting cylinder of radius
// R and half-length h, a patch facing along the axis receives E = π L h²/(h² + R²) (the open
// end takes the cone of half-angle atan(R/h)).
TEST(AreaLightTest, CylinderDirectionsFollowPdfAndIrradianceIsAnalytic) {
  auto shape = [](const scene::Transform& t, bool reverse) {
    return light_shape(scene::CylinderShape{0.5, -1.0, 1.0}, t, reverse, 37);
  };
  auto t = scene::Transform::translate({0.2f, -0.3f, 4}) *
           *scene::Transform::rotate(40, {1, 1, 0}) * *scene::Transform::scale({1.5, 1.5, 1.5});
  auto w = build({shape(t, /*reverse=*/false)});
  AreaLight tube = area_light(*w, 0);
  EXPECT_NEAR(tube.area(), 2 * M_PI * 0.5 * 2 * 1.5 * 1.5, 1e-4);
  for (const AreaCase& k : {AreaCase{"outside", {{0, 0, 0}, {}}, {0.2f, -0.3f, 4}, 2.0f},
                            AreaCase{"oblique", {{3, -1, 4.5f}, {}}, {0.2f, -0.3f, 4}, 2.0f}}) {
    check_area_light(*w, tube, k);
  }
  auto wi = build({shape(t, /*reverse=*/true)});
  AreaLight inward = area_light(*wi, 0);
  check_area_light(*wi, inward, AreaCase{"inside", {{0.2f, -0.3f, 4}, {}}, {0.2f, -0.3f, 4}, 2.0f});

  // Radius 1, half-length 2, centred at the origin along z, emitting inwards with radiance 2.
  scene::Shape long_tube = shape(scene::Transform(), true);
  long_tube.geometry = scene::CylinderShape{1.0, -2.0, 2.0};
  auto wl = build({long_tube});
  AreaLight lamp = area_light(*wl, 0, spectral::ConstantSpectrum{0.5f}, 4.0);
  expect_irradiance(
      [&](Point2f u, float ue) {
        return lamp.sample({{0, 0, 0}, {0, 0, 1}}, u, ue, lanes({600}));
      },
      {0, 0, 1}, 2 * M_PI * 4.0 / (4.0 + 1.0), "cylinder on axis");
}

// Under a non-uniform scale the uniform (z, φ) sample is not uniform by area: refused by name.
TEST(AreaLightTest, NonSimilarityCylinderIsRefusedWithLocation) {
  scene::Shape s;
  s.geometry = scene::CylinderShape{1.0, -1.0, 1.0};
  s.object_to_world = *scene::Transform::scale({1, 2, 1});
  s.area_light = scene::AreaLight{};
  s.where = at(12);
  auto w = build({s});
  auto light = AreaLight::create(s, 0, *w->geometry, spectral::ConstantSpectrum{1}, 1.0);
  ASSERT_FALSE(light.ok());
  EXPECT_NE(light.status().message().find(":12:"), std::string_view::npos) << light.status();
  EXPECT_NE(light.status().message().find("similarity transform"), std::string_view::npos);
}

// pbrt-v4's emitter alpha: a sampled point whose alpha is 0 (or, for a fraction a, whose
// position hashes above a) gives no sample. On the axis of a disk of radiance 2, an alpha that
// keeps the half φ < π gives half the full disk's irradiance, a constant 0.3 keeps 0.3 of it,
// and the sampled density is unchanged (pbrt-v4 does not renormalise).
TEST(AreaLightTest, AlphaMaskedEmittersLoseTheMaskedPart) {
  scene::Shape disk;
  disk.geometry = scene::DiskShape{0.0, 1.0, 0.0};
  disk.object_to_world = scene::Transform::translate({0, 0, 2});
  disk.reverse_orientation = true;  // faces down, towards the origin
  disk.area_light = scene::AreaLight{};
  disk.where = at(41);
  const double full = 2 * M_PI * 1.0 / (4.0 + 1.0);
  struct Case {
    const char* name;
    AlphaFunction alpha;
    double fraction;
  };
  const Case cases[] = {
      {"half disk", [](const Point2f& uv, const Vec3f&) { return uv.x < 0.5f ? 1.0f : 0.0f; }, 0.5},
      {"alpha 0.3", [](const Point2f&, const Vec3f&) { return 0.3f; }, 0.3},
      {"opaque", nullptr, 1.0}};
  for (const Case& c : cases) {
    auto w = build({disk}, {c.alpha});
    AreaLight light = area_light(*w, 0, spectral::ConstantSpectrum{0.5f}, 4.0);
    expect_irradiance(
        [&](Point2f u, float ue) {
          return light.sample({{0, 0, 0}, {0, 0, 1}}, u, ue, lanes({600}));
        },
        {0, 0, 1}, c.fraction * full, c.name);
    if (c.alpha) {
      // The masked half is where φ >= π: y < 0 on the disk.
      int kept_below = 0;
      for (int i = 0; i < 2000; ++i) {
        auto ls =
            light.sample({{0, 0, 0}, {0, 0, 1}},
                         {(i + 0.5f) / 2000, (i * 0.618f) - int(i * 0.618f)}, 0.5f, lanes({600}));
        if (ls && ls->p_light.y < -1e-4f) ++kept_below;
      }
      if (c.fraction == 0.5) {
        EXPECT_EQ(kept_below, 0) << c.name;
      }
    }
  }
}

TEST(PointSpotInfiniteTest, PointLightIsInverseSquare) {
  scene::Light desc = point_desc({1, 2, 3}, 30);
  auto light = PointLight::create(desc, spectral::ConstantSpectrum{2}, 3.0);
  ASSERT_TRUE(light.ok());
  SampledWavelengths lambda = lanes({450, 600});
  auto s = light->sample({{1, 2, 0}, {0, 0, 1}}, lambda);
  ASSERT_TRUE(s);
  EXPECT_TRUE(s->delta);
  EXPECT_EQ(s->pdf, 1.0f);
  EXPECT_NEAR(s->distance, 3.0f, 1e-6f);
  EXPECT_NEAR(s->wi.z, 1.0f, 1e-6f);
  EXPECT_NEAR(s->radiance[0], 6.0f / 9.0f, 1e-6f);
  EXPECT_NEAR(s->radiance[1], 6.0f / 9.0f, 1e-6f);
  // Irradiance on a tilted receiver: I cos θ / d².
  auto t = light->sample({{4, 2, -1}, {}}, lambda);
  ASSERT_TRUE(t);
  EXPECT_NEAR(t->radiance[0] * dot(t->wi, Vec3f(0, 0, 1)), 6.0 * 0.8 / 25.0, 1e-6);
  EXPECT_NEAR(light_power(Light(*light)), 6.0 * 470 * 4 * M_PI, 1e-2);
}

// pbrt-v4's goniometric light: a point light times its equal-area image at the light-space
// direction with y and z swapped, so the image's centre (+z of the square) is light-space +y.
// An image bright (1) on that hemisphere and dim (0.25) on the other, under a 90° rotation
// about z (light +y becomes world −x): intensity 1 towards −x, 0.25 towards +x; its power
// integrates the image over the sphere.
TEST(PointSpotInfiniteTest, GoniometricLightFollowsItsImage) {
  auto image = std::make_shared<scene::TextureImage>();
  constexpr int kN = 16;
  image->width = image->height = kN;
  image->channels = 1;
  for (int y = 0; y < kN; ++y) {
    for (int x = 0; x < kN; ++x) {
      const Vec3f d = equal_area_square_to_sphere({(x + 0.5f) / kN, (y + 0.5f) / kN});
      image->values.push_back(d.z > 0 ? 1.0f : 0.25f);
    }
  }
  scene::PointLight point;
  point.goniometric = image;
  scene::Light desc;
  desc.light_to_world = *scene::Transform::rotate(90, {0, 0, 1});
  point.position_world = {0, 0, 0};
  desc.kind = point;
  desc.where = at(41);
  auto light = PointLight::create(desc, spectral::ConstantSpectrum{2}, 1.5);
  ASSERT_TRUE(light.ok()) << light.status();
  SampledWavelengths lambda = lanes({550});
  auto towards = [&](Vec3f p) {
    auto s = light->sample({p, {}}, lambda);
    EXPECT_TRUE(s.has_value());
    return s ? s->radiance[0] * length_squared(p) : 0.0f;
  };
  EXPECT_NEAR(towards({-4, 0, 0}), 3.0f, 1e-5f);
  EXPECT_NEAR(towards({4, 0, 0}), 0.75f, 1e-5f);
  // Every texel covers 4π/N² sr: the mean is the image's mean (texels on the diamond |u|+|v| = 1
  // have z = 0 and count as dim).
  double mean = 0;
  for (float v : image->values) mean += v;
  mean /= kN * kN;
  EXPECT_NEAR(light->mean_modulation(), mean, 1e-9);
  const double emitted = 2 * 1.5 * 470;
  EXPECT_NEAR(light_power(Light(*light)), emitted * 4 * M_PI * mean, 1e-6 * emitted);
}

// pbrt-v4's projection light: an image through a perspective frustum along light +z, the image's
// top towards light +y (pbrt-v4 flips y), each texel an RGB illuminant, nothing outside the
// frustum or behind the light.
TEST(PointSpotInfiniteTest, ProjectionLightProjectsItsImage) {
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  const spectral::RgbUplift uplift(cmf);
  auto light_for = [&](int w, int h, std::vector<float> rgb) {
    scene::TextureImage image;
    image.width = w;
    image.height = h;
    image.channels = 3;
    image.values = std::move(rgb);
    auto projection = ProjectionImage::create(image, 60, uplift);
    EXPECT_TRUE(projection.ok());
    scene::PointLight point;
    scene::Light desc;
    desc.kind = point;
    desc.where = at(43);
    auto l = PointLight::create(desc, spectral::ConstantSpectrum{1}, 2.0, *projection);
    EXPECT_TRUE(l.ok());
    return *l;
  };
  SampledWavelengths lambda = lanes({450, 550, 650});
  auto expect_texel = [&](const PointLight& l, Vec3f p, std::optional<spectral::Rgb> rgb,
                          const char* what) {
    auto s = l.sample({p, {}}, lambda);
    ASSERT_TRUE(s.has_value()) << what;
    for (int k = 0; k < 3; ++k) {
      float want = 0;
      if (rgb) {
        auto illuminant = uplift.illuminant(*rgb);
        ASSERT_TRUE(illuminant.ok());
        want = 2.0f * (*illuminant)(lambda.lambda(k)) / length_squared(p);
      }
      EXPECT_NEAR(s->radiance[k], want, 1e-5f * (1 + want)) << what << " lane " << k;
    }
  };
  // 2x1, red | blue, fov 60 (the shorter, vertical axis): x spans ±2·tan 30°·z.
  PointLight wide = light_for(2, 1, {1, 0, 0, 0, 0, 1});
  expect_texel(wide, {-0.5f, 0, 1}, spectral::Rgb{1, 0, 0}, "left");
  expect_texel(wide, {0.5f, 0.2f, 1}, spectral::Rgb{0, 0, 1}, "right");
  expect_texel(wide, {1.3f, 0, 1}, std::nullopt, "beyond the side (tan > 2 tan 30°)");
  expect_texel(wide, {0, 0.7f, 1}, std::nullopt, "beyond the top (tan > tan 30°)");
  expect_texel(wide, {0, 0, -1}, std::nullopt, "behind");
  // 1x2, green over white: the file's top row towards +y.
  PointLight tall = light_for(1, 2, {0, 1, 0, 1, 1, 1});
  expect_texel(tall, {0, 0.3f, 1}, spectral::Rgb{0, 1, 0}, "up");
  expect_texel(tall, {0, -0.3f, 1}, spectral::Rgb{1, 1, 1}, "down");
  // Its power for emitter selection counts the frustum's solid angle: 4·asin(sin α·sin β).
  const double alpha = std::atan(std::tan(M_PI / 6)), beta = std::atan(2 * std::tan(M_PI / 6));
  // (tan(fov/2) is kept as a float: agreement to float precision.)
  EXPECT_NEAR(tall.mean_modulation(), std::asin(std::sin(alpha) * std::sin(beta)) / M_PI, 1e-7);
}

// pbrt-v4's `power` on a projection light divides by the flux at unit scale: the image's sRGB
// luminance integrated over the frustum's solid angle. A uniform image's flux is its luminance
// times the pyramid's solid angle, 4·asin(sin α·sin β).
TEST(PointSpotInfiniteTest, ProjectionFluxIsTheLuminanceOverTheFrustum) {
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  const spectral::RgbUplift uplift(cmf);
  const double alpha = std::atan(2 * std::tan(M_PI / 6)), beta = std::atan(std::tan(M_PI / 6));
  const double frustum = 4 * std::asin(std::sin(alpha) * std::sin(beta));
  for (const auto& [rgb, luminance] :
       {std::pair{spectral::Rgb{1, 1, 1}, 1.0}, std::pair{spectral::Rgb{1, 0, 0}, 0.2126729},
        std::pair{spectral::Rgb{0, 0.5, 0}, 0.5 * 0.7151522}}) {
    scene::TextureImage image;
    image.width = 128;
    image.height = 64;
    image.channels = 3;
    for (int i = 0; i < image.width * image.height; ++i)
      image.values.insert(image.values.end(), {float(rgb.r), float(rgb.g), float(rgb.b)});
    auto projection = ProjectionImage::create(image, 60, uplift);
    ASSERT_TRUE(projection.ok());
    EXPECT_NEAR((*projection)->flux_per_unit_scale, luminance * frustum, 1e-4 * frustum);
  }
}

TEST(PointSpotInfiniteTest, SpotFalloffIsPbrtSmoothStep) {
  scene::Light desc = spot_desc({0, 0, 0}, {0, 0, 1}, 30, 10, 31);
  auto light = SpotLight::create(desc, spectral::ConstantSpectrum{1}, 1.0);
  ASSERT_TRUE(light.ok());
  SampledWavelengths lambda = lanes({550});
  auto at_angle = [&](double deg) {
    double r = deg * M_PI / 180;
    return light->sample({{float(2 * std::sin(r)), 0, float(2 * std::cos(r))}, {}}, lambda);
  };
  auto inner = at_angle(15);
  ASSERT_TRUE(inner);
  EXPECT_NEAR(inner->radiance[0], 0.25f, 1e-6f);
  auto mid = at_angle(25);
  ASSERT_TRUE(mid);
  double t = (std::cos(25 * M_PI / 180) - std::cos(30 * M_PI / 180)) /
             (std::cos(20 * M_PI / 180) - std::cos(30 * M_PI / 180));
  EXPECT_NEAR(mid->radiance[0], 0.25 * t * t * (3 - 2 * t), 1e-5);
  EXPECT_FALSE(at_angle(35));
  EXPECT_FALSE(at_angle(150));
  // power_factor() is the mean falloff over the sphere: compare with quadrature in θ.
  double integral = 0;
  const int steps = 200000;
  for (int i = 0; i < steps; ++i) {
    double theta = (i + 0.5) * M_PI / steps;
    Vec3f w(float(std::sin(theta)), 0, float(std::cos(theta)));
    integral += light->falloff(w) * 2 * M_PI * std::sin(theta) * M_PI / steps;
  }
  EXPECT_NEAR(light->power_factor(), integral / (4 * M_PI), 1e-5);
}

TEST(PointSpotInfiniteTest, InfiniteLightIsUniformAndGivesPiL) {
  scene::Light desc;
  desc.kind = scene::InfiniteLight{};
  Bounds3f bounds;
  bounds.extend({-1, -2, -2});
  bounds.extend({1, 2, 2});
  auto light = InfiniteLight::create(desc, spectral::ConstantSpectrum{0.5f}, 2.0, bounds);
  ASSERT_TRUE(light.ok());
  EXPECT_NEAR(light->scene_radius(), 3.0, 1e-6);
  SampledWavelengths lambda = lanes({550});
  LightContext ctx{{0.5f, 0.5f, 0.5f}, {0, 0, 1}};
  Binning bins{Frame::from_z(normalize(Vec3f(1, 1, 0))), M_PI};
  expect_directions_follow_pdf(
      [&](Point2f u, float) -> std::optional<Vec3f> {
        auto s = light->sample(ctx, u, lambda);
        EXPECT_TRUE(s);
        EXPECT_EQ(s->pdf, light->pdf(ctx.p, s->wi));
        EXPECT_EQ(s->distance, kInf);
        EXPECT_GT(length(s->p_light - bounds.centre()), 3.0f);
        return s->wi;
      },
      [&](const Vec3f& w) { return light->pdf(ctx.p, w); }, bins, "infinite");
  expect_irradiance([&](Point2f u, float) { return light->sample(ctx, u, lambda); },
                    normalize(Vec3f(0.3f, -0.2f, 1)), M_PI, "infinite");
  EXPECT_NEAR(light_power(Light(*light)), 1.0 * 470 * M_PI * 9 * 4 * M_PI, 1e-2);
}

// An environment seen through pbrt-v4's portal: an a×b window in the plane z = 2, its front
// (x = p3 − p0, y = p1 − p0, z = x × y) facing +z. Under a uniform map, the irradiance below a
// corner is the map's radiance times the corner form factor; samples follow the mixture density
// the light reports, a bright patch in the map included; nothing reaches a point in front of the
// window or a direction beside it; the power is π·A times the radiance.
TEST(PointSpotInfiniteTest, PortalLetsTheMapInThroughItsWindowOnly) {
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  const spectral::RgbUplift uplift(cmf);
  const double a = 1.5, b = 0.75, h = 2;
  scene::InfiniteLight inf;
  inf.portal = std::array<scene::Vec3, 4>{scene::Vec3{0, 0, h}, scene::Vec3{0, b, h},
                                          scene::Vec3{a, b, h}, scene::Vec3{a, 0, h}};
  scene::Light desc;
  desc.kind = inf;
  desc.where = at(7);
  auto light_for = [&](float sun) {
    scene::TextureImage image;
    image.width = image.height = 32;
    image.channels = 3;
    for (int y = 0; y < 32; ++y) {
      for (int x = 0; x < 32; ++x) {
        const Vec3f d = equal_area_square_to_sphere({(x + 0.5f) / 32, (y + 0.5f) / 32});
        const float v = dot(d, normalize(Vec3f(0.6f, 0.2f, 1))) > 0.97f ? sun : 1.0f;
        image.values.insert(image.values.end(), {v, v, v});
      }
    }
    auto map = EnvironmentMap::create(image, scene::Transform(), uplift);
    EXPECT_TRUE(map.ok());
    Bounds3f bounds;
    bounds.extend({-1, -1, -1});
    bounds.extend({1, 1, 1});
    auto light = InfiniteLight::create(desc, spectral::ConstantSpectrum{1}, 2.0, bounds, *map);
    EXPECT_TRUE(light.ok()) << light.status();
    return *light;
  };
  SampledWavelengths lambda = lanes({550});
  const LightContext below{{0, 0, 0}, {0, 0, 1}};

  const InfiniteLight uniform = light_for(1.0f);
  const float radiance = uniform.radiance(below.p, Vec3f(0, 0, 1) * 1.0f, lambda)[0];
  ASSERT_GT(radiance, 0);
  // Looking straight up from the corner passes the window's edge; just beside it does not.
  EXPECT_EQ(uniform.radiance(below.p, normalize(Vec3f(-0.01f, 0.2f, 1)), lambda)[0], 0);
  EXPECT_EQ(uniform.pdf(below.p, normalize(Vec3f(-0.01f, 0.2f, 1))), 0);
  EXPECT_EQ(uniform.radiance(below.p, normalize(Vec3f(0.5f, 0.2f, -1)), lambda)[0], 0);
  expect_irradiance([&](Point2f u, float) { return uniform.sample(below, u, lambda); },
                    Vec3f(0, 0, 1), radiance * corner_irradiance(a, b, h), "portal corner");
  // In front of the window (z > 2) nothing comes through, whatever the direction.
  const LightContext outside{{0.5f, 0.3f, 3}, {0, 0, 1}};
  EXPECT_FALSE(uniform.sample(outside, {0.3f, 0.4f}, lambda));
  EXPECT_FALSE(uniform.sample(outside, {0.8f, 0.4f}, lambda));
  EXPECT_EQ(uniform.radiance(outside.p, Vec3f(0, 0, 1), lambda)[0], 0);
  EXPECT_NEAR(light_power(Light(uniform)), 2.0 * 470 * M_PI * a * b, 1e-2);

  const InfiniteLight sunny = light_for(200.0f);
  const LightContext off_axis{{1.2f, -0.4f, 0.5f}, {0, 0, 1}};
  Binning bins{Frame::from_z(Vec3f(0, 0, 1)), M_PI / 2};
  expect_directions_follow_pdf(
      [&](Point2f u, float) -> std::optional<Vec3f> {
        auto s = sunny.sample(off_axis, u, lambda);
        if (!s) return std::nullopt;
        EXPECT_NEAR(s->pdf, sunny.pdf(off_axis.p, s->wi), 1e-4f * s->pdf);
        EXPECT_GT(s->radiance[0], 0);
        return s->wi;
      },
      [&](const Vec3f& w) { return sunny.pdf(off_axis.p, w); }, bins, "portal mixture");
}

// ---- LightSampler ------------------------------------------------------------------------------

// Six emitters of different spectra and kinds: a red square light facing down, a blue square
// facing up, a white sphere, a green point light, a white spot and a white environment.
struct SamplerScene {
  std::unique_ptr<World> world;
  std::vector<Light> lights;
};

SamplerScene sampler_scene() {
  SamplerScene s;
  s.world = build({square(1, 4, /*down=*/true), square(0.5f, -4, /*down=*/false),
                   sphere(0.5, scene::Transform::translate({3, 0, 0}))});
  s.lights.push_back(area_light(*s.world, 0, band(600, 700), 2.0));
  s.lights.push_back(area_light(*s.world, 1, band(420, 480), 1.0));
  s.lights.push_back(area_light(*s.world, 2, spectral::ConstantSpectrum{1}, 0.5));
  s.lights.push_back(*PointLight::create(point_desc({-3, 0, 0}, 30), band(510, 560), 5.0));
  s.lights.push_back(*SpotLight::create(spot_desc({0, 3, 0}, {0, -1, 0}, 30, 5, 31),
                                        spectral::ConstantSpectrum{1}, 1.0));
  scene::Light env;
  env.kind = scene::InfiniteLight{};
  env.where = at(32);
  s.lights.push_back(*InfiniteLight::create(env, spectral::ConstantSpectrum{1}, 0.01,
                                            s.world->geometry->bounds()));
  return s;
}

spectral::WavelengthGrid grid16() {
  return *spectral::WavelengthGrid::create(16);
}

LightSampler make_sampler(const SamplerScene& s, job::LightSelectionKind base,
                          bool spectral_factor) {
  auto sampler =
      LightSampler::create(s.lights, *s.world->geometry, grid16(), base, spectral_factor);
  PRISM_CHECK(sampler.ok());
  return *sampler;
}

constexpr job::LightSelectionKind kBases[] = {job::LightSelectionKind::kUniform,
                                              job::LightSelectionKind::kPower,
                                              job::LightSelectionKind::kSpatial};

TEST(LightSamplerTest, UnitEmissionRowsSumToOne) {
  SamplerScene s = sampler_scene();
  LightSampler sampler = make_sampler(s, job::LightSelectionKind::kPower, true);
  const auto& e = sampler.unit_emission();
  ASSERT_EQ(e.size(), s.lights.size());
  auto grid = grid16();
  for (std::size_t i = 0; i < e.size(); ++i) {
    ASSERT_EQ(int(e[i].size()), grid.bins());
    double sum = 0;
    for (float x : e[i]) {
      EXPECT_GE(x, 0.0f);
      sum += x;
    }
    EXPECT_NEAR(sum, 1.0, 1e-5) << i;
  }
  // The red light has nothing below 590 nm; constant spectra are flat.
  EXPECT_EQ(e[0][grid.bin_of(450)], 0.0f);
  EXPECT_GT(e[0][grid.bin_of(650)], 0.0f);
  for (float x : e[2]) EXPECT_NEAR(x, 1.0f / 16, 1e-6f);
}

SampledWavelengths random_lanes(std::mt19937& rng) {
  std::uniform_real_distribution<float> uni(360.0f, 830.0f);
  SampledWavelengths w(4);
  for (int i = 0; i < 4; ++i) w.set(i, uni(rng), 1.0f / 470);
  if (rng() % 3 == 0) w.terminate_secondary();
  return w;
}

TEST(LightSamplerTest, PmfIsNormalisedForEveryBaseAndLaneSet) {
  SamplerScene s = sampler_scene();
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> pos(-6.0f, 6.0f);
  for (job::LightSelectionKind base : kBases) {
    for (bool factor : {true, false}) {
      LightSampler sampler = make_sampler(s, base, factor);
      for (int trial = 0; trial < 300; ++trial) {
        Vec3f p(pos(rng), pos(rng), pos(rng));
        SampledWavelengths lambda = random_lanes(rng);
        double sum = 0;
        for (int e = 0; e < int(s.lights.size()); ++e) {
          float q = sampler.pmf(p, lambda, e);
          EXPECT_GE(q, 0.0f);
          sum += q;
        }
        EXPECT_NEAR(sum, 1.0, 1e-5) << int(base) << " " << factor;
      }
    }
  }
}

TEST(LightSamplerTest, SampleFrequenciesMatchPmf) {
  SamplerScene s = sampler_scene();
  int tests = 0;
  for (job::LightSelectionKind base : kBases) {
    for (bool factor : {true, false}) {
      LightSampler sampler = make_sampler(s, base, factor);
      for (Vec3f p : {Vec3f(0, 0, 3.5f), Vec3f(2.5f, 0.3f, -0.2f)}) {
        for (SampledWavelengths lambda :
             {lanes({450, 520, 650, 700}), lanes({455}), lanes({630, 640, 800, 370})}) {
          const int n = 50000;
          std::vector<double> observed(s.lights.size(), 0.0), expected(s.lights.size(), 0.0);
          for (int e = 0; e < int(s.lights.size()); ++e)
            expected[e] = sampler.pmf(p, lambda, e) * n;
          for (int i = 0; i < n; ++i) {
            auto c = sampler.sample(p, lambda, (i + 0.5f) / n);
            ASSERT_TRUE(c);
            // The returned pmf is pmf() bit for bit, and never zero for a chosen light.
            EXPECT_EQ(c->pmf, sampler.pmf(p, lambda, c->light));
            EXPECT_GT(c->pmf, 0.0f);
            observed[c->light] += 1;
          }
          auto result = chi_square(observed, expected);
          EXPECT_GT(result.p_value, 1e-5) << result.describe();
          ++tests;
        }
      }
    }
  }
  EXPECT_EQ(tests, 36);
}

TEST(LightSamplerTest, SpectralFactorFollowsUnitEmission) {
  SamplerScene s = sampler_scene();
  LightSampler on = make_sampler(s, job::LightSelectionKind::kUniform, true);
  LightSampler off = make_sampler(s, job::LightSelectionKind::kUniform, false);
  const auto& e = on.unit_emission();
  auto grid = grid16();
  Vec3f p(0.1f, 0.2f, 0.3f);
  // All lanes in the red band: the blue light is never chosen with the factor, uniformly without.
  SampledWavelengths red = lanes({610, 640, 670, 690});
  EXPECT_EQ(on.pmf(p, red, 1), 0.0f);
  EXPECT_GT(on.pmf(p, red, 0), 1.0f / 6);
  for (int i = 0; i < 6; ++i) EXPECT_FLOAT_EQ(off.pmf(p, red, i), 1.0f / 6);
  // The exact oracle for a uniform base: q(e) = Σ_s Ê[e][b_s] / Σ_e' Σ_s Ê[e'][b_s].
  SampledWavelengths mixed = lanes({450, 530, 650, 800});
  double total = 0;
  std::vector<double> terms(6, 0.0);
  for (int i = 0; i < 6; ++i) {
    for (int l = 0; l < 4; ++l) terms[i] += e[i][grid.bin_of(mixed.lambda(l))];
    total += terms[i];
  }
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(on.pmf(p, mixed, i), terms[i] / total, 1e-6) << i;
  // Lanes outside Λ carry no weight.
  SampledWavelengths outside = lanes({900, 1000});
  EXPECT_FALSE(on.sample(p, outside, 0.5f));
  EXPECT_EQ(on.pmf(p, outside, 2), 0.0f);
}

TEST(LightSamplerTest, TerminatedLanesDropOut) {
  SamplerScene s = sampler_scene();
  for (job::LightSelectionKind base : kBases) {
    LightSampler sampler = make_sampler(s, base, true);
    Vec3f p(0.5f, -0.5f, 1.0f);
    SampledWavelengths all = lanes({650, 450, 530, 700});
    SampledWavelengths hero_only = all;
    hero_only.terminate_secondary();
    SampledWavelengths single = lanes({650});
    bool differs = false;
    for (int i = 0; i < 6; ++i) {
      EXPECT_EQ(sampler.pmf(p, hero_only, i), sampler.pmf(p, single, i)) << i;
      differs |= sampler.pmf(p, hero_only, i) != sampler.pmf(p, all, i);
    }
    EXPECT_TRUE(differs);
    // The blue light (no emission at 650 nm) has zero probability once only the hero is live.
    EXPECT_EQ(sampler.pmf(p, hero_only, 1), 0.0f);
    EXPECT_GT(sampler.pmf(p, all, 1), 0.0f);
    for (int i = 0; i < 1000; ++i) {
      auto c = sampler.sample(p, hero_only, (i + 0.5f) / 1000);
      ASSERT_TRUE(c);
      EXPECT_NE(c->light, 1);
    }
  }
}

TEST(LightSamplerTest, PowerBaseIsProportionalToPower) {
  SamplerScene s = sampler_scene();
  // Powers by hand: scale · ∫S · geometric factor. band(lo, hi) integrates to hi − lo + 10.
  std::vector<double> expected = {
      2.0 * 110 * M_PI * 4,                // red square, 2x2, one-sided
      1.0 * 70 * M_PI * 1,                 // blue square, 1x1
      0.5 * 470 * M_PI * 4 * M_PI * 0.25,  // sphere r = 0.5
      5.0 * 60 * 4 * M_PI,                 // point
      1.0 * 470 * 4 * M_PI * std::get<SpotLight>(s.lights[4]).power_factor(),
      0.01 * 470 * M_PI * std::pow(std::get<InfiniteLight>(s.lights[5]).scene_radius(), 2) * 4 *
          M_PI};
  double total = 0;
  for (int i = 0; i < 6; ++i) {
    EXPECT_NEAR(light_power(s.lights[i]), expected[i], 1e-4 * expected[i]) << i;
    total += expected[i];
  }
  LightSampler sampler = make_sampler(s, job::LightSelectionKind::kPower, false);
  for (int i = 0; i < 6; ++i) {
    EXPECT_NEAR(sampler.pmf({1, 1, 1}, lanes({500}), i), expected[i] / total, 1e-5) << i;
  }
}

TEST(LightSamplerTest, SpatialNeverStarvesAnEmitterAndPrefersNearOnes) {
  SamplerScene s = sampler_scene();
  LightSampler spatial = make_sampler(s, job::LightSelectionKind::kSpatial, false);
  LightSampler again = make_sampler(s, job::LightSelectionKind::kSpatial, false);
  LightSampler spectral_on = make_sampler(s, job::LightSelectionKind::kSpatial, true);
  SampledWavelengths white = lanes({450, 530, 650, 700});
  for (float x = -7; x <= 7; x += 0.9f) {
    for (float y = -7; y <= 7; y += 0.9f) {
      for (float z = -7; z <= 7; z += 0.9f) {
        for (int i = 0; i < 6; ++i) {
          float q = spatial.pmf({x, y, z}, white, i);
          ASSERT_GT(q, 0.0f) << x << " " << y << " " << z << " light " << i;
          ASSERT_EQ(q, again.pmf({x, y, z}, white, i));  // deterministic
          ASSERT_GT(spectral_on.pmf({x, y, z}, white, i), 0.0f);
        }
      }
    }
  }
  // Just below the red square, it dominates; beside the sphere, the sphere does.
  Vec3f under_red(0, 0, 3.5f), by_sphere(2.3f, 0, 0);
  EXPECT_GT(spatial.pmf(under_red, white, 0), spatial.pmf(by_sphere, white, 0));
  EXPECT_GT(spatial.pmf(by_sphere, white, 2), spatial.pmf(under_red, white, 2));
  EXPECT_GT(spatial.pmf(under_red, white, 0), 0.3f);
}

TEST(LightSamplerTest, EmitterWithoutVisiblePowerIsAnError) {
  SamplerScene s = sampler_scene();
  scene::Light ir = point_desc({0, 0, 0}, 44);
  s.lights.push_back(*PointLight::create(ir, band(900, 1000), 1.0));
  auto sampler = LightSampler::create(s.lights, *s.world->geometry, grid16(),
                                      job::LightSelectionKind::kPower, true);
  ASSERT_FALSE(sampler.ok());
  EXPECT_EQ(sampler.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(std::string(sampler.status().message()).find("test.pbrt:44:3"), std::string::npos)
      << sampler.status();
}

TEST(LightSamplerTest, NoLightsSamplesNothing) {
  auto w = build({square(1, 0, false)});
  std::vector<Light> none;
  for (job::LightSelectionKind base : kBases) {
    auto sampler = LightSampler::create(none, *w->geometry, grid16(), base, true);
    ASSERT_TRUE(sampler.ok());
    EXPECT_FALSE(sampler->sample({0, 0, 0}, lanes({500}), 0.5f));
    EXPECT_EQ(sampler->pmf({0, 0, 0}, lanes({500}), 0), 0.0f);
  }
}

TEST(LightDispatchTest, SampleLightDispatchesEveryKind) {
  SamplerScene s = sampler_scene();
  SampledWavelengths lambda = lanes({650});
  LightContext ctx{{0, 0.5f, 0}, {}};
  for (int i = 0; i < 6; ++i) {
    auto sample = sample_light(s.lights[i], ctx, {0.3f, 0.7f}, 0.4f, lambda);
    EXPECT_EQ(is_delta(s.lights[i]), i == 3 || i == 4) << i;
    ASSERT_TRUE(sample) << i;
    EXPECT_EQ(sample->delta, is_delta(s.lights[i]));
    EXPECT_EQ(light_location(s.lights[i]).file, "test.pbrt");
  }
}

}  // namespace
}  // namespace prism::worker
