#include "worker/spectral_differential.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <optional>
#include <vector>

#include "services/spectral/ior.h"
#include "worker/geometry.h"

namespace prism::worker {
namespace {

// The oracle: refraction and ray-sphere intersection in double, written independently of Eq. 1
// (Snell's law as "keep η times the tangential part"), differentiated by central differences.
struct V {
  double x = 0, y = 0, z = 0;
  V operator+(const V& o) const { return {x + o.x, y + o.y, z + o.z}; }
  V operator-(const V& o) const { return {x - o.x, y - o.y, z - o.z}; }
  V operator*(double s) const { return {x * s, y * s, z * s}; }
};
double dot(const V& a, const V& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
V normalized(const V& v) {
  return v * (1.0 / std::sqrt(dot(v, v)));
}
V of(const Vec3f& v) {
  return {v.x, v.y, v.z};
}
Vec3f to_f(const V& v) {
  return {float(v.x), float(v.y), float(v.z)};
}

// d refracted through n (either side) with relative index eta; nullopt at TIR.
std::optional<V> snell(const V& d, V n, double eta) {
  if (dot(d, n) > 0) n = n * -1.0;
  const V tangential = (d - n * dot(d, n)) * eta;
  const double sin2 = dot(tangential, tangential);
  if (sin2 >= 1) return std::nullopt;
  return tangential - n * std::sqrt(1 - sin2);
}

V mirror(const V& d, const V& n) {
  return d - n * (2 * dot(d, n));
}

void expect_near(const Vec3f& got, const V& want, double tolerance, const char* what) {
  const double scale = std::sqrt(dot(want, want)) + 1e-12;
  const V diff = of(got) - want;
  EXPECT_LE(std::sqrt(dot(diff, diff)) / scale, tolerance)
      << what << ": got (" << got.x << ", " << got.y << ", " << got.z << "), want (" << want.x
      << ", " << want.y << ", " << want.z << ")";
}

// Each glass with the finite-difference step its evaluation supports: the analytic formulas are
// evaluated in double; a table in float, but it is linear between its samples, so a 1 nm step
// inside one segment is exact.
struct Glass {
  const char* name;
  spectral::Ior ior;
  double step_nm;
};

std::vector<Glass> glasses() {
  std::vector<Glass> out;
  const double cauchy[] = {1.5046, 0.00420};  // BK7-like A, B (µm²)
  out.push_back({"cauchy", *spectral::CauchyIor::create(cauchy), 1e-3});
  const double b[] = {1.03961212, 0.231792344, 1.01046945};  // Schott N-BK7
  const double c[] = {0.00600069867, 0.0200179144, 103.560653};
  out.push_back({"sellmeier", *spectral::SellmeierIor::create(0.0, b, c), 1e-3});
  const double lambdas[] = {380, 500, 650, 780}, values[] = {1.80, 1.74, 1.71, 1.70};
  auto table = spectral::PiecewiseLinearSpectrum::create(lambdas, values, "test table");
  out.push_back({"tabulated", *spectral::TabulatedIor::create(*table), 1.0});
  return out;
}

// Eq. 1 at a flat interface, entering and leaving the glass, over incidence angles from normal to
// near grazing (and near the critical angle on the way out), with and without an incoming ∂d.
TEST(SpectralDifferentialTest, RefractionMatchesFiniteDifferencesOfSnellsLaw) {
  const V n{0, 0, 1};
  for (const auto& [name, ior, h] : glasses()) {
    for (bool entering : {true, false}) {
      const double lambda = 550;
      auto relative = [&](double l) {
        const double g = spectral::eta(ior, l);
        return entering ? 1.0 / g : g;
      };
      const double critical =
          entering ? 90.0 : std::asin(1.0 / spectral::eta(ior, lambda)) * 180 / M_PI;
      // Up to 0.05° from the critical angle on the way out, where ∂d' grows as 1/cos θ_t.
      for (double degrees : {0.0, 20.0, 45.0, 70.0, 85.0, 89.0, 90.0}) {
        const double angle = std::min(degrees, critical - (degrees < 90 ? 0.5 : 0.05));
        for (bool incoming : {false, true}) {
          SCOPED_TRACE(testing::Message() << name << (entering ? " entering " : " leaving ")
                                          << angle << "° incoming ∂d " << incoming);
          const double a = angle * M_PI / 180;
          const V d_unit{std::sin(a) * std::cos(0.3), std::sin(a) * std::sin(0.3), -std::cos(a)};
          // An incoming ∂d across d (a previous event's), or none.
          const V dd0 =
              incoming ? normalized(V{0.2, -1, 0.1} - d_unit * dot(V{0.2, -1, 0.1}, d_unit)) * 1e-4
                       : V{};
          auto direction = [&](double l) { return normalized(d_unit + dd0 * (l - lambda)); };
          auto plus = snell(direction(lambda + h), entering ? n : n * -1.0, relative(lambda + h));
          auto minus = snell(direction(lambda - h), entering ? n : n * -1.0, relative(lambda - h));
          ASSERT_TRUE(plus && minus);
          const V fd = (*plus - *minus) * (1 / (2 * h));

          SpectralDifferential diff{{}, to_f(dd0), incoming};
          const double g = spectral::eta(ior, lambda), dg = spectral::deta_dlambda(ior, lambda);
          const RelativeEta eta = entering ? relative_eta(1, 0, g, dg) : relative_eta(g, dg, 1, 0);
          const Vec3f nf = entering ? Vec3f(0, 0, 1) : Vec3f(0, 0, -1);
          ASSERT_TRUE(refract(diff, to_f(d_unit), nf, {}, eta));
          EXPECT_TRUE(diff.tracked);
          // The refracted direction itself agrees too (d' = η·d − μ·n).
          expect_near(diff.dd, fd, 2e-3, "∂d'");
        }
      }
    }
  }
}

// Past the critical angle there is no refracted ray: the differential ends, cleanly.
TEST(SpectralDifferentialTest, TotalInternalReflectionEndsTheDifferential) {
  SpectralDifferential diff{{0.1f, 0, 0}, {0, 0.01f, 0}, true};
  const float a = 60 * kPi / 180;  // beyond 1/1.5's 41.8°
  EXPECT_FALSE(refract(diff, {std::sin(a), 0, std::cos(a)}, {0, 0, 1}, {}, {1.5f, -5e-5f}));
  EXPECT_FALSE(diff.tracked);
  // An untracked differential stays untouched by every later event.
  EXPECT_TRUE(transfer(diff, {0, 0, 1}, 2.0f, {0, 0, 1}));
  reflect(diff, {0, 0, 1}, {0, 0, 1}, {});
  EXPECT_FALSE(diff.tracked);
}

// Zero cost without dispersion: nothing starts tracking at a non-dispersive refraction, and the
// untracked updates are no-ops.
TEST(SpectralDifferentialTest, PathsWithoutDispersionNeverTrack) {
  SpectralDifferential diff;
  EXPECT_TRUE(refract(diff, normalize(Vec3f{0.3f, 0, -1}), {0, 0, 1}, {}, {1 / 1.5f, 0}));
  EXPECT_TRUE(transfer(diff, {0, 0, 1}, 3.0f, {1, 0, 0}));
  reflect(diff, {0, 0, 1}, {0, 0, 1}, {0.1f, 0, 0});
  EXPECT_FALSE(diff.tracked);
  EXPECT_EQ(diff.dp, Vec3f{});
  EXPECT_EQ(diff.dd, Vec3f{});
}

// A whole path through a glass sphere onto a floor: refract in, k internal reflections, refract
// out, land on the plane z = 0. k = 0 is a lens's caustic, k = 1 and 2 the primary and
// secondary rainbows. The floor point's ∂p/∂λ (transfer, reflection with the sphere's curving
// normal, Eq. 1) against central differences of the same path traced in double.
struct SpherePath {
  V centre{0, 0, 3};
  double radius = 1;

  // The hit on the sphere from outside (nearest) or inside (far side), or nullopt.
  std::optional<double> hit(const V& o, const V& d, bool inside) const {
    const V oc = o - centre;
    const double b = dot(oc, d), c = dot(oc, oc) - radius * radius;
    const double disc = b * b - c;
    if (disc < 0) return std::nullopt;
    const double t = inside ? -b + std::sqrt(disc) : -b - std::sqrt(disc);
    return t > 1e-9 ? std::optional(t) : std::nullopt;
  }

  // The floor point reached at wavelength index eta (relative to air), or nullopt.
  std::optional<V> floor_point(const V& o, const V& d0, int reflections, double eta) const {
    auto t = hit(o, d0, false);
    if (!t) return std::nullopt;
    V p = o + d0 * *t;
    auto d = snell(d0, (p - centre) * (1 / radius), 1 / eta);
    if (!d) return std::nullopt;
    for (int k = 0; k <= reflections; ++k) {
      auto s = hit(p, *d, true);
      if (!s) return std::nullopt;
      p = p + *d * *s;
      if (k < reflections) d = mirror(*d, (p - centre) * (1 / radius));
    }
    d = snell(*d, (p - centre) * (1 / radius), eta);
    if (!d || d->z >= 0) return std::nullopt;
    return p + *d * (-p.z / d->z);
  }

  // The same path in float with the spectral differential carried along.
  std::optional<SpectralDifferential> differential(const V& o, const V& d0, int reflections,
                                                   double n, double dn) const {
    SpectralDifferential diff;
    auto normal_at = [&](const V& p) { return to_f((p - centre) * (1 / radius)); };
    // A sphere's normal field (p − c)/r moves by the tangential part of dp over r.
    auto dnormal = [&](const Vec3f& nrm, const Vec3f& dp) {
      return (dp - nrm * prism::worker::dot(nrm, dp)) / float(radius);
    };
    auto t = hit(o, d0, false);
    V p = o + d0 * *t;
    V d = d0;
    // Entering: η = 1/n.
    if (!refract(diff, to_f(d), normal_at(p), dnormal(normal_at(p), diff.dp),
                 relative_eta(1, 0, n, dn))) {
      return std::nullopt;
    }
    d = *snell(d, (p - centre) * (1 / radius), 1 / n);
    for (int k = 0; k <= reflections; ++k) {
      const double s = *hit(p, d, true);
      p = p + d * s;
      if (!transfer(diff, to_f(d), float(s), normal_at(p))) return std::nullopt;
      if (k < reflections) {
        reflect(diff, to_f(d), normal_at(p), dnormal(normal_at(p), diff.dp));
        d = mirror(d, (p - centre) * (1 / radius));
      }
    }
    if (!refract(diff, to_f(d), normal_at(p), dnormal(normal_at(p), diff.dp),
                 relative_eta(n, dn, 1, 0))) {
      return std::nullopt;
    }
    d = *snell(d, (p - centre) * (1 / radius), n);
    if (!transfer(diff, to_f(d), float(-p.z / d.z), {0, 0, 1})) return std::nullopt;
    return diff;
  }
};

TEST(SpectralDifferentialTest, PathsThroughASphereMatchFiniteDifferencesAtEveryDepth) {
  const SpherePath sphere;
  int checked = 0;
  for (const auto& [name, ior, h] : glasses()) {
    for (int reflections : {0, 1, 2}) {
      for (double offset : {0.1, 0.45, 0.8, 0.95}) {
        SCOPED_TRACE(testing::Message()
                     << name << ", " << reflections << " internal reflections, offset " << offset);
        const V o{offset, 0.2 * offset, 8};
        const V d{0, 0, -1};
        const double lambda = 520;
        auto plus = sphere.floor_point(o, d, reflections, spectral::eta(ior, lambda + h));
        auto minus = sphere.floor_point(o, d, reflections, spectral::eta(ior, lambda - h));
        if (!plus || !minus) continue;  // this ray never reaches the floor
        const V fd = (*plus - *minus) * (1 / (2 * h));
        auto diff = sphere.differential(o, d, reflections, spectral::eta(ior, lambda),
                                        spectral::deta_dlambda(ior, lambda));
        ASSERT_TRUE(diff);
        EXPECT_TRUE(diff->tracked);
        // The floor point moves in the floor's plane.
        EXPECT_NEAR(diff->dp.z, 0.0, 1e-6 * (std::abs(fd.x) + std::abs(fd.y) + 1e-9));
        expect_near(diff->dp, fd, 3e-3, "∂p on the floor");
        ++checked;
      }
    }
  }
  EXPECT_GE(checked, 24);  // most of the 36 rays reach the floor
}

// A rough interface's microfacet normal fixed in the shading frame: against the exact rotation
// that takes n to n + h·∂n applied to m.
TEST(SpectralDifferentialTest, MicrofacetNormalTurnsWithTheShadingFrame) {
  const V n = normalized(V{0.1, 0.2, 1});
  const V m = normalized(V{0.5, -0.3, 1});
  const V dn0 = V{0.3, -0.7, 0.2};
  const V dn = dn0 - n * dot(dn0, n);  // a unit normal moves across itself
  auto rotate = [&](double h) {
    // Rodrigues: the rotation about k = n × n' by the angle between n and n'.
    const V n2 = normalized(n + dn * h);
    const V axis{n.y * n2.z - n.z * n2.y, n.z * n2.x - n.x * n2.z, n.x * n2.y - n.y * n2.x};
    const double s = std::sqrt(dot(axis, axis)), c = dot(n, n2);
    const V k = axis * (1 / s);
    const V kxm{k.y * m.z - k.z * m.y, k.z * m.x - k.x * m.z, k.x * m.y - k.y * m.x};
    return m * c + kxm * s + k * (dot(k, m) * (1 - c));
  };
  const double h = 1e-4;
  const V fd = (rotate(h) - rotate(-h)) * (1 / (2 * h));
  expect_near(microfacet_normal_differential(to_f(n), to_f(dn), to_f(m)), fd, 1e-3, "∂m");
}

// Geometry::normal_differential against finite differences of the shading normals Embree's hits
// report, on an ellipsoid (a scaled sphere), a cylinder and a mesh with vertex normals.
TEST(SpectralDifferentialTest, NormalDifferentialsMatchTheSurfacesNormals) {
  EmbreeDevice device;
  scene::SceneDescription desc;
  scene::Shape ellipsoid;
  ellipsoid.geometry = scene::SphereShape{1.0};
  ellipsoid.object_to_world =
      scene::Transform::translate({0, 0, 10}) * *scene::Transform::scale({2, 1, 1.5});
  desc.shapes.push_back(ellipsoid);
  scene::Shape cylinder;
  cylinder.geometry = scene::CylinderShape{1.0, -1.0, 1.0};
  cylinder.object_to_world =
      scene::Transform::translate({10, 0, 10}) * *scene::Transform::rotate(90, {1, 0, 0});
  desc.shapes.push_back(cylinder);
  auto mesh = std::make_shared<scene::TriangleMeshData>();
  mesh->positions = {{-11, -1, 10}, {-9, -1, 10}, {-10, 1, 10}};
  mesh->normals = {{-0.3f, -0.2f, -1}, {0.4f, -0.1f, -1}, {0.0f, 0.5f, -1}};
  mesh->triangles = {{0, 1, 2}};
  scene::Shape smooth;
  smooth.geometry = scene::TriangleMeshShape{mesh, "test"};
  desc.shapes.push_back(smooth);
  auto geometry = Geometry::build(device, desc);
  ASSERT_TRUE(geometry.ok()) << geometry.status();
  for (const Vec3f target :
       {Vec3f{0.6f, 0.3f, 10}, Vec3f{10.3f, 0.2f, 10}, Vec3f{-10, -0.2f, 10}}) {
    SCOPED_TRACE(testing::Message() << "target x " << target.x);
    const Vec3f origin{target.x, target.y, 0};
    auto centre = (*geometry)->intersect({origin, normalize(target - origin)}, 1e30f);
    ASSERT_TRUE(centre);
    for (const Vec3f along : {Vec3f{1, 0, 0}, Vec3f{0, 1, 0}}) {
      const float h = 2e-3f;
      auto at = [&](float s) {
        const Vec3f aim = centre->p + along * s;
        auto hit = (*geometry)->intersect({origin, normalize(aim - origin)}, 1e30f);
        EXPECT_TRUE(hit);
        return *hit;
      };
      const SurfaceHit plus = at(h), minus = at(-h);
      // The finite difference moved the point by plus.p − minus.p (on the surface).
      const Vec3f dp = (plus.p - minus.p) / (2 * h);
      const V fd = of((plus.ns - minus.ns) / (2 * h));
      expect_near((*geometry)->normal_differential(*centre, dp), fd, 2e-2, "∂n");
    }
  }
}

}  // namespace
}  // namespace prism::worker
