#include "services/scene/loop_subdivision.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace prism::scene {
namespace {

using V3 = std::array<double, 3>;

V3 v3(const Float3& p) {
  return {p.x, p.y, p.z};
}
V3 sub(V3 a, V3 b) {
  return {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
}
V3 add(V3 a, V3 b) {
  return {a[0] + b[0], a[1] + b[1], a[2] + b[2]};
}
V3 scale(double s, V3 a) {
  return {s * a[0], s * a[1], s * a[2]};
}
double dot(V3 a, V3 b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
V3 cross(V3 a, V3 b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double norm(V3 a) {
  return std::sqrt(dot(a, a));
}
V3 unit(V3 a) {
  return scale(1.0 / norm(a), a);
}
double angle_deg(V3 a, V3 b) {
  return std::acos(std::clamp(dot(unit(a), unit(b)), -1.0, 1.0)) * 180.0 / std::numbers::pi;
}

struct Control {
  std::vector<Float3> p;
  std::vector<Triangle> t;
};

// Prism's geometric normal of triangle t (not normalised).
V3 face_normal(const std::vector<Float3>& p, const Triangle& t) {
  return cross(sub(v3(p[t[0]]), v3(p[t[2]])), sub(v3(p[t[1]]), v3(p[t[2]])));
}

// Winds every triangle of a mesh that is star-shaped around the origin outward.
Control outward(Control c) {
  for (Triangle& t : c.t) {
    V3 centre = scale(1.0 / 3, add(add(v3(c.p[t[0]]), v3(c.p[t[1]])), v3(c.p[t[2]])));
    if (dot(face_normal(c.p, t), centre) < 0) std::swap(t[1], t[2]);
  }
  return c;
}

Control tetrahedron() {
  return outward({{{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}},
                  {{0, 1, 2}, {0, 1, 3}, {0, 2, 3}, {1, 2, 3}}});
}

Control octahedron() {
  return outward(
      {{{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}},
       {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4}, {0, 2, 5}, {2, 1, 5}, {1, 3, 5}, {3, 0, 5}}});
}

// A bipyramid over a 7-gon: poles of valence 7, equator vertices of valence 4.
Control bipyramid7() {
  Control c;
  c.p.push_back({0, 0, 1.3f});
  c.p.push_back({0, 0, -0.9f});
  for (int i = 0; i < 7; ++i) {
    double a = 2 * std::numbers::pi * i / 7;
    c.p.push_back({static_cast<float>(std::cos(a)), static_cast<float>(std::sin(a)), 0});
  }
  for (std::uint32_t i = 0; i < 7; ++i) {
    std::uint32_t a = 2 + i, b = 2 + (i + 1) % 7;
    c.t.push_back({0, a, b});
    c.t.push_back({1, a, b});
  }
  return outward(c);
}

// A cube split into 12 triangles with diagonals in varying directions: valences 3 to 6.
Control cube() {
  Control c;
  for (int i = 0; i < 8; ++i) {
    c.p.push_back({i & 1 ? 1.0f : -1.0f, i & 2 ? 1.0f : -1.0f, i & 4 ? 1.0f : -1.0f});
  }
  const std::uint32_t quads[6][4] = {{0, 1, 3, 2}, {4, 5, 7, 6}, {0, 1, 5, 4},
                                     {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 3, 7, 5}};
  for (int q = 0; q < 6; ++q) {
    const std::uint32_t* v = quads[q];
    if (q % 2 == 0) {
      c.t.push_back({v[0], v[1], v[2]});
      c.t.push_back({v[0], v[2], v[3]});
    } else {
      c.t.push_back({v[0], v[1], v[3]});
      c.t.push_back({v[1], v[2], v[3]});
    }
  }
  return outward(c);
}

// (nx + 1) x (ny + 1) vertices on [0, nx] x [0, ny] at height z(x, y); each cell is split along
// the same diagonal, so inner vertices have valence 6. Wound counter-clockwise seen from +z.
template <typename Height>
Control grid(int nx, int ny, Height z) {
  Control c;
  for (int j = 0; j <= ny; ++j) {
    for (int i = 0; i <= nx; ++i) {
      c.p.push_back({static_cast<float>(i), static_cast<float>(j), static_cast<float>(z(i, j))});
    }
  }
  auto id = [&](int i, int j) { return static_cast<std::uint32_t>(j * (nx + 1) + i); };
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      c.t.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      c.t.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  }
  return c;
}

Control flat_grid(int nx, int ny) {
  return grid(nx, ny, [](int, int) { return 0.0; });
}

Control reversed(Control c) {
  for (Triangle& t : c.t) std::swap(t[1], t[2]);
  return c;
}

// A fan of `n` triangles around vertex 0 on the boundary of a half disc, ring size n + 1, with
// a little height so it is not planar.
Control half_disc(int n) {
  Control c;
  c.p.push_back({0, 0, 0});
  for (int i = 0; i <= n; ++i) {
    double a = std::numbers::pi * i / n;
    c.p.push_back({static_cast<float>(std::cos(a)), static_cast<float>(std::sin(a)),
                   static_cast<float>(0.3 * std::sin(3.0 * a))});
  }
  for (std::uint32_t i = 1; i <= static_cast<std::uint32_t>(n); ++i) c.t.push_back({0, i, i + 1});
  return c;
}

Control jittered(Control c, unsigned seed, double amount) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> d(static_cast<float>(-amount), static_cast<float>(amount));
  for (Float3& p : c.p) p = {p.x + d(rng), p.y + d(rng), p.z + d(rng)};
  return c;
}

TriangleMeshData subdivide(const Control& c, int levels) {
  auto mesh = loop_subdivide(c.p, c.t, levels, 100'000'000);
  EXPECT_TRUE(mesh.ok()) << mesh.status();
  return mesh.ok() ? *std::move(mesh) : TriangleMeshData{};
}

// Undirected edge -> the half-edges (tail, head) using it.
std::map<std::pair<std::uint32_t, std::uint32_t>,
         std::vector<std::pair<std::uint32_t, std::uint32_t>>>
edges_of(const std::vector<Triangle>& triangles) {
  std::map<std::pair<std::uint32_t, std::uint32_t>,
           std::vector<std::pair<std::uint32_t, std::uint32_t>>>
      edges;
  for (const Triangle& t : triangles) {
    for (int k = 0; k < 3; ++k) {
      std::uint32_t a = t[k], b = t[(k + 1) % 3];
      edges[{std::min(a, b), std::max(a, b)}].push_back({a, b});
    }
  }
  return edges;
}

// Every vertex normal is unit length and on the side of the geometric normal of every triangle
// around it.
void expect_normals_face_winding(const TriangleMeshData& m) {
  ASSERT_EQ(m.normals.size(), m.positions.size());
  for (const Float3& n : m.normals) EXPECT_NEAR(norm(v3(n)), 1.0, 1e-6);
  for (const Triangle& t : m.triangles) {
    V3 g = face_normal(m.positions, t);
    for (std::uint32_t v : t) EXPECT_GT(dot(v3(m.normals[v]), g), 0) << "vertex " << v;
  }
}

// The output boundary: vertices with an edge used by a single triangle.
std::vector<std::uint32_t> boundary_vertices(const std::vector<Triangle>& triangles,
                                             std::size_t* boundary_edges) {
  std::set<std::uint32_t> out;
  *boundary_edges = 0;
  for (const auto& [edge, halves] : edges_of(triangles)) {
    if (halves.size() != 1) continue;
    ++*boundary_edges;
    out.insert(edge.first);
    out.insert(edge.second);
  }
  return {out.begin(), out.end()};
}

// The control boundary as a closed loop of positions, following the winding.
std::vector<V3> boundary_loop(const Control& c) {
  std::map<std::uint32_t, std::uint32_t> next;
  for (const auto& [edge, halves] : edges_of(c.t)) {
    if (halves.size() == 1) next[halves[0].first] = halves[0].second;
  }
  std::vector<V3> loop;
  std::uint32_t v = next.begin()->first;
  do {
    loop.push_back(v3(c.p[v]));
    v = next.at(v);
  } while (v != next.begin()->first);
  EXPECT_EQ(loop.size(), next.size());
  return loop;
}

// Distance from q to the closed uniform cubic B-spline of `loop`, sampled finely.
double distance_to_bspline(const std::vector<V3>& loop, V3 q) {
  const std::size_t n = loop.size();
  constexpr int kSamples = 4096;
  double best = 1e300;
  for (std::size_t i = 0; i < n; ++i) {
    const V3 &a = loop[(i + n - 1) % n], &b = loop[i], &c = loop[(i + 1) % n],
             &d = loop[(i + 2) % n];
    V3 previous{};
    for (int s = 0; s <= kSamples; ++s) {
      double u = static_cast<double>(s) / kSamples;
      double w0 = (1 - u) * (1 - u) * (1 - u) / 6, w1 = (3 * u * u * u - 6 * u * u + 4) / 6,
             w2 = (-3 * u * u * u + 3 * u * u + 3 * u + 1) / 6, w3 = u * u * u / 6;
      V3 p = add(add(scale(w0, a), scale(w1, b)), add(scale(w2, c), scale(w3, d)));
      if (s > 0) {
        // Distance to the chord from the previous sample.
        V3 seg = sub(p, previous);
        double t =
            std::clamp(dot(sub(q, previous), seg) / std::max(dot(seg, seg), 1e-300), 0.0, 1.0);
        best = std::min(best, norm(sub(q, add(previous, scale(t, seg)))));
      }
      previous = p;
    }
  }
  return best;
}

// 1. Counts and topology: ×4 triangles per level, V − E + F = 2, closed 2-manifold.
TEST(LoopSubdivisionTest, ClosedMeshCountsAndTopology) {
  for (const Control& c : {tetrahedron(), octahedron()}) {
    for (int level = 0; level <= 4; ++level) {
      SCOPED_TRACE(::testing::Message() << c.p.size() << " control vertices, level " << level);
      TriangleMeshData m = subdivide(c, level);
      ASSERT_TRUE(m.validate().ok());
      EXPECT_EQ(m.triangles.size(), c.t.size() << (2 * level));
      EXPECT_TRUE(m.uvs.empty());
      auto edges = edges_of(m.triangles);
      const long long v = static_cast<long long>(m.positions.size());
      const long long e = static_cast<long long>(edges.size());
      const long long f = static_cast<long long>(m.triangles.size());
      EXPECT_EQ(v - e + f, 2);
      for (const auto& [edge, halves] : edges) {
        ASSERT_EQ(halves.size(), 2u) << edge.first << "-" << edge.second;
        EXPECT_NE(halves[0].first, halves[1].first) << "inconsistent winding";
      }
      std::vector<bool> used(m.positions.size(), false);
      for (const Triangle& t : m.triangles) {
        for (std::uint32_t i : t) used[i] = true;
      }
      EXPECT_EQ(std::count(used.begin(), used.end(), false), 0);
      expect_normals_face_winding(m);
    }
  }
}

// Children keep the winding of their control triangle, so a closed outward-wound mesh gets
// outward normals, and the reversed mesh inward ones.
TEST(LoopSubdivisionTest, NormalsFollowWinding) {
  for (bool flip : {false, true}) {
    Control c = flip ? reversed(octahedron()) : octahedron();
    TriangleMeshData m = subdivide(c, 3);
    expect_normals_face_winding(m);
    for (std::size_t i = 0; i < m.positions.size(); ++i) {
      double side = dot(v3(m.normals[i]), v3(m.positions[i]));
      EXPECT_TRUE(flip ? side < 0 : side > 0) << "vertex " << i;
    }
  }
}

// 2. A flat regular patch: the limit surface is the plane itself, normals are ±z.
TEST(LoopSubdivisionTest, FlatRegularGridStaysPlanar) {
  for (bool flip : {false, true}) {
    Control c = flip ? reversed(flat_grid(6, 6)) : flat_grid(6, 6);
    for (int level = 0; level <= 3; ++level) {
      TriangleMeshData m = subdivide(c, level);
      for (const Float3& p : m.positions) EXPECT_EQ(p.z, 0.0f);
      for (const Float3& n : m.normals) {
        EXPECT_NEAR(n.x, 0.0, 1e-12);
        EXPECT_NEAR(n.y, 0.0, 1e-12);
        EXPECT_EQ(n.z, flip ? -1.0f : 1.0f);
      }
      expect_normals_face_winding(m);
    }
  }
}

// Affine invariance: a jittered grid in a tilted plane stays in that plane.
TEST(LoopSubdivisionTest, TiltedPlaneStaysPlanar) {
  Control c = jittered(flat_grid(5, 4), 7, 0.3);
  const V3 plane_normal = unit({0.3, -0.2, 1.0});
  for (Float3& p : c.p) p.z = static_cast<float>(-(0.3 * p.x - 0.2 * p.y) + 1.0);
  TriangleMeshData m = subdivide(c, 3);
  double worst_height = 0, worst_angle = 0;
  for (std::size_t i = 0; i < m.positions.size(); ++i) {
    const V3 p = v3(m.positions[i]);
    worst_height = std::max(worst_height, std::abs(dot(p, plane_normal) - plane_normal[2]));
    worst_angle = std::max(worst_angle, angle_deg(v3(m.normals[i]), plane_normal));
  }
  EXPECT_LT(worst_height, 1e-5);
  EXPECT_LT(worst_angle, 1e-3);
  expect_normals_face_winding(m);
}

double max_dihedral_deg(const TriangleMeshData& m) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::vector<std::size_t>> faces;
  for (std::size_t f = 0; f < m.triangles.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      std::uint32_t a = m.triangles[f][k], b = m.triangles[f][(k + 1) % 3];
      faces[{std::min(a, b), std::max(a, b)}].push_back(f);
    }
  }
  double worst = 0;
  for (const auto& [edge, fs] : faces) {
    if (fs.size() != 2) continue;
    worst = std::max(worst, angle_deg(face_normal(m.positions, m.triangles[fs[0]]),
                                      face_normal(m.positions, m.triangles[fs[1]])));
  }
  return worst;
}

// 3. The octahedron converges to a smooth closed surface (not a sphere: its limit radius runs
// from 1/2 at the six control vertices down to about 0.416 at the face centres). Every level's
// vertices lie on the same limit surface, as the old vertices keep their limit positions, so the
// band of radii widens with the levels only as more of the surface is sampled, and converges.
// The surface gets smoother: from level 2 on, the largest angle between neighbouring triangles
// shrinks by at least a quarter per level; and at level 4 the limit normals agree with the
// normals of the triangles around each vertex.
TEST(LoopSubdivisionTest, OctahedronConvergesToSmoothSurface) {
  const Control c = octahedron();
  double previous_lo = 0, previous_hi = 0, previous_dihedral = 0;
  for (int level = 1; level <= 5; ++level) {
    SCOPED_TRACE(::testing::Message() << "level " << level);
    TriangleMeshData m = subdivide(c, level);
    double lo = 1e9, hi = 0;
    for (const Float3& p : m.positions) {
      lo = std::min(lo, norm(v3(p)));
      hi = std::max(hi, norm(v3(p)));
    }
    EXPECT_NEAR(hi, 0.5, 1e-7);  // valence 4: γ = 1/8, so the limit of (1, 0, 0) is 1/2 p
    EXPECT_GT(lo, 0.415);
    const double dihedral = max_dihedral_deg(m);
    if (level > 1) {
      EXPECT_LE(lo, previous_lo + 1e-7);
      EXPECT_GE(hi, previous_hi - 1e-7);
    }
    if (level > 2) {
      EXPECT_LT(dihedral, 0.75 * previous_dihedral);
    }
    if (level == 5) {
      EXPECT_LT(previous_lo - lo, 1e-3);
    }
    previous_lo = lo;
    previous_hi = hi;
    previous_dihedral = dihedral;

    if (level == 4) {
      std::vector<V3> around(m.positions.size(), V3{0, 0, 0});
      for (const Triangle& t : m.triangles) {
        V3 n = unit(face_normal(m.positions, t));
        for (std::uint32_t v : t) around[v] = add(around[v], n);
      }
      double worst = 0;
      for (std::size_t i = 0; i < m.positions.size(); ++i) {
        worst = std::max(worst, angle_deg(v3(m.normals[i]), around[i]));
      }
      EXPECT_LT(worst, 2.0);
    }
  }
}

// 4. Control vertex i keeps index i, and its output position is its limit position, so it does
// not move when the mesh is subdivided two more times; nor does its limit normal turn, boundary
// vertices included (the tangent masks are exact left eigenvectors of the refinement). The
// boundary limit rule 1/5, 3/5, 1/5 that pbrt-v4 uses is not the limit of its own boundary curve
// (a cubic B-spline, whose limit rule is 1/6, 2/3, 1/6): boundary vertices move by a small
// amount that shrinks fourfold per level.
TEST(LoopSubdivisionTest, ControlVerticesSitAtTheirLimit) {
  const std::vector<std::pair<const char*, Control>> meshes = {
      {"tetrahedron", jittered(tetrahedron(), 1, 0.2)},
      {"octahedron", jittered(octahedron(), 2, 0.2)},
      {"bipyramid", jittered(bipyramid7(), 3, 0.1)},
      {"cube", jittered(cube(), 4, 0.2)},
      {"bumpy grid", grid(4, 3, [](int i, int j) { return 0.4 * std::sin(i + 2.0 * j); })},
      {"half disc", half_disc(6)},
  };
  for (const auto& [name, c] : meshes) {
    double previous_boundary_moved = 0;
    for (int level = 0; level <= 1; ++level) {
      SCOPED_TRACE(::testing::Message() << name << ", level " << level);
      TriangleMeshData coarse = subdivide(c, level);
      TriangleMeshData fine = subdivide(c, level + 2);
      std::size_t boundary_edges = 0;
      std::vector<std::uint32_t> boundary = boundary_vertices(coarse.triangles, &boundary_edges);
      const std::set<std::uint32_t> on_boundary(boundary.begin(), boundary.end());
      double size = 0;
      for (const Float3& p : c.p) size = std::max(size, norm(v3(p)));
      double interior_moved = 0, boundary_moved = 0, turned = 0;
      // Every vertex of the coarse mesh is an (even) vertex of the fine one, at the same index.
      for (std::uint32_t i = 0; i < coarse.positions.size(); ++i) {
        const double moved = norm(sub(v3(coarse.positions[i]), v3(fine.positions[i]))) / size;
        double& worst_moved = on_boundary.count(i) ? boundary_moved : interior_moved;
        worst_moved = std::max(worst_moved, moved);
        turned = std::max(turned, angle_deg(v3(coarse.normals[i]), v3(fine.normals[i])));
      }
      EXPECT_LT(interior_moved, 1e-6);
      EXPECT_LT(turned, 1e-4);
      if (boundary.empty()) continue;
      EXPECT_LT(boundary_moved, 0.05);
      if (level == 1) {
        EXPECT_GT(boundary_moved, 0.2 * previous_boundary_moved);
        EXPECT_LT(boundary_moved, 0.3 * previous_boundary_moved);
      }
      previous_boundary_moved = boundary_moved;
    }
  }
}

// 5. Open meshes: the boundary stays a boundary (2^L output edges per control boundary edge);
// its vertices lie on the cubic B-spline of the control boundary polygon up to pbrt-v4's boundary
// limit rule (a distance that shrinks fourfold per level), and straight runs of it stay exactly
// straight; a flat open mesh stays flat with +z normals at every vertex, boundary included.
TEST(LoopSubdivisionTest, OpenFlatMeshesKeepBoundaryCurves) {
  const std::vector<std::pair<const char*, Control>> meshes = {
      {"triangle", {{{0, 0, 0}, {1, 0, 0}, {0.3f, 0.8f, 0}}, {{0, 1, 2}}}},
      {"square", {{{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, {{0, 1, 2}, {0, 2, 3}}}},
      {"3x3 grid", flat_grid(3, 3)},
  };
  for (const auto& [name, c] : meshes) {
    std::size_t control_boundary_edges = 0;
    boundary_vertices(c.t, &control_boundary_edges);
    const std::vector<V3> loop = boundary_loop(c);
    double previous_worst = 0;
    for (int level = 1; level <= 4; ++level) {
      SCOPED_TRACE(::testing::Message() << name << ", level " << level);
      TriangleMeshData m = subdivide(c, level);
      for (const Float3& p : m.positions) EXPECT_EQ(p.z, 0.0f);
      for (const Float3& n : m.normals) {
        EXPECT_NEAR(n.x, 0.0, 1e-6);
        EXPECT_NEAR(n.y, 0.0, 1e-6);
        EXPECT_NEAR(n.z, 1.0, 1e-6);
      }
      expect_normals_face_winding(m);
      std::size_t edges = 0;
      std::vector<std::uint32_t> boundary = boundary_vertices(m.triangles, &edges);
      EXPECT_EQ(edges, control_boundary_edges << level);
      EXPECT_EQ(boundary.size(), edges);
      double worst = 0;
      for (std::uint32_t v : boundary) {
        worst = std::max(worst, distance_to_bspline(loop, v3(m.positions[v])));
      }
      // Off the B-spline only by pbrt-v4's boundary limit rule (see the test above).
      EXPECT_LT(worst, 0.05 / (1 << 2 * (level - 1)));
      if (level > 1) {
        EXPECT_LT(worst, 0.3 * previous_worst);
      }
      previous_worst = worst;
      if (std::string(name) == "3x3 grid") {
        // The middle third of each side depends only on collinear control points: it stays on
        // the side.
        for (std::uint32_t v : boundary) {
          const Float3& p = m.positions[v];
          if (p.y < 0.5f && p.x >= 1 && p.x <= 2) {
            EXPECT_EQ(p.y, 0.0f);
          }
          if (p.y > 2.5f && p.x >= 1 && p.x <= 2) {
            EXPECT_EQ(p.y, 3.0f);
          }
          if (p.x < 0.5f && p.y >= 1 && p.y <= 2) {
            EXPECT_EQ(p.x, 0.0f);
          }
          if (p.x > 2.5f && p.y >= 1 && p.y <= 2) {
            EXPECT_EQ(p.x, 3.0f);
          }
        }
      }
    }
  }
}

TEST(LoopSubdivisionTest, LevelZeroProjectsControlVertices) {
  // A single triangle at level 0: corners go to 3/5 p + 1/5 (other two corners).
  Control c{{{0, 0, 0}, {5, 0, 0}, {0, 5, 0}}, {{0, 1, 2}}};
  TriangleMeshData m = subdivide(c, 0);
  ASSERT_EQ(m.positions.size(), 3u);
  EXPECT_EQ(m.positions[0], (Float3{1, 1, 0}));
  EXPECT_EQ(m.positions[1], (Float3{3, 1, 0}));
  EXPECT_EQ(m.positions[2], (Float3{1, 3, 0}));
  EXPECT_EQ(m.triangles, c.t);
}

TEST(LoopSubdivisionTest, UnreferencedVerticesKeepTheirIndex) {
  Control c = octahedron();
  c.p.insert(c.p.begin() + 3, Float3{7, 8, 9});
  for (Triangle& t : c.t) {
    for (std::uint32_t& i : t) i += i >= 3 ? 1 : 0;
  }
  TriangleMeshData m = subdivide(c, 2);
  EXPECT_EQ(m.positions[3], (Float3{7, 8, 9}));
  EXPECT_EQ(m.normals[3], (Float3{0, 0, 0}));
  for (const Triangle& t : m.triangles) {
    for (std::uint32_t i : t) EXPECT_NE(i, 3u);
  }
  EXPECT_EQ(m.triangles.size(), 8u * 16);
}

// Coincident control points leave the tangent masks (and the triangles) without a plane: the
// result still passes validation, with finite normals.
TEST(LoopSubdivisionTest, CoincidentPointsGiveFiniteNormals) {
  Control c = tetrahedron();
  c.p[1] = c.p[2] = c.p[3] = Float3{0, 0, 0};
  for (int level = 0; level <= 2; ++level) {
    auto m = loop_subdivide(c.p, c.t, level, 1'000'000);
    ASSERT_TRUE(m.ok()) << m.status();
    EXPECT_TRUE(m->validate().ok());
  }
}

void expect_error(const Control& c, int levels, absl::StatusCode code, const std::string& text,
                  std::uint64_t max_triangles = 1'000'000) {
  auto result = loop_subdivide(c.p, c.t, levels, max_triangles);
  ASSERT_FALSE(result.ok()) << text;
  EXPECT_EQ(result.status().code(), code) << result.status();
  EXPECT_NE(result.status().message().find(text), std::string::npos) << result.status();
}

// 6. Bad input.
TEST(LoopSubdivisionTest, RefusesBadInput) {
  using absl::StatusCode;
  const Control octa = octahedron();
  expect_error(octa, -1, StatusCode::kInvalidArgument, "levels is -1, outside [0, 8]");
  expect_error(octa, 9, StatusCode::kInvalidArgument, "levels is 9, outside [0, 8]");
  expect_error({{}, {}}, 1, StatusCode::kInvalidArgument, "control mesh has no vertices");
  expect_error({octa.p, {}}, 1, StatusCode::kInvalidArgument, "control mesh has no triangles");

  Control bad = octa;
  bad.t[5][1] = 6;
  expect_error(bad, 1, StatusCode::kInvalidArgument,
               "triangle 5 refers to vertex 6 but the control mesh has 6 vertices");
  bad = octa;
  bad.t[2] = {4, 1, 4};
  expect_error(bad, 1, StatusCode::kInvalidArgument,
               "triangle 2 (4, 1, 4) is degenerate: it repeats a vertex");
  bad = octa;
  bad.p[4].y = std::numeric_limits<float>::quiet_NaN();
  expect_error(bad, 1, StatusCode::kInvalidArgument, "vertex 4 has a non-finite position");

  // Three sheets along edge (0, 1).
  Control fin{{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}},
              {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}}};
  expect_error(fin, 1, StatusCode::kInvalidArgument,
               "non-manifold edge (0, 1) shared by 3 triangles (0, 1, 2)");
  // Second triangle of the square wound the other way round.
  Control inconsistent{{{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, {{0, 1, 2}, {0, 3, 2}}};
  expect_error(inconsistent, 1, StatusCode::kInvalidArgument,
               "triangles 0 and 1 both run along edge (0, 2) from vertex 2 to vertex 0");
  // Two triangles touching only at vertex 2.
  Control bowtie{{{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {2, 1, 0}, {2, 2, 0}}, {{0, 1, 2}, {2, 3, 4}}};
  expect_error(bowtie, 1, StatusCode::kInvalidArgument,
               "vertex 2 is non-manifold: its 2 triangles do not form a single fan");
  // A triangle glued to its own back.
  Control pillow{{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {{0, 1, 2}, {0, 2, 1}}};
  expect_error(pillow, 1, StatusCode::kInvalidArgument, "vertex 0 is closed off by only 2");

  // 8 triangles x 4^4 = 2048; refused before any allocation (4^8 x 8 would be 524288).
  expect_error(octa, 4, StatusCode::kResourceExhausted,
               "8 control triangles subdivided 4 times make 8 x 4^4 triangles, more than the "
               "limit of 2047",
               2047);
  EXPECT_TRUE(loop_subdivide(octa.p, octa.t, 4, 2048).ok());
  expect_error(octa, 8, StatusCode::kResourceExhausted, "8 x 4^8 triangles, more than the limit",
               500'000);
}

}  // namespace
}  // namespace prism::scene
