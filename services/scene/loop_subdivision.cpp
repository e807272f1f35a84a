#include "services/scene/loop_subdivision.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "services/base/check.h"

namespace prism::scene {
namespace {

struct D3 {
  double x = 0, y = 0, z = 0;
};

D3 operator+(D3 a, D3 b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
D3 operator-(D3 a, D3 b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
D3 operator*(double s, D3 a) {
  return {s * a.x, s * a.y, s * a.z};
}
D3& operator+=(D3& a, D3 b) {
  return a = a + b;
}
D3 cross(D3 a, D3 b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
double length(D3 a) {
  return std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z);
}

// Half-edge h = 3 f + k runs from corner k of triangle f to corner k + 1.
constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

std::uint32_t next_half(std::uint32_t h) {
  return h % 3 == 2 ? h - 2 : h + 1;
}
std::uint32_t prev_half(std::uint32_t h) {
  return h % 3 == 0 ? h + 2 : h - 1;
}

// One subdivision level: positions, triangles, the opposite half-edge of every half-edge (kNone
// on the boundary) and, per vertex, one outgoing half-edge to start its one-ring from: the one on
// the boundary for a boundary vertex (so walking counter-clockwise from it covers the whole fan),
// kNone for a vertex no triangle refers to.
struct Level {
  std::vector<D3> p;
  std::vector<Triangle> tri;
  std::vector<std::uint32_t> twin;
  std::vector<std::uint32_t> start;

  std::uint32_t tail(std::uint32_t h) const { return tri[h / 3][h % 3]; }
  std::uint32_t head(std::uint32_t h) const { return tri[h / 3][(h % 3 + 1) % 3]; }
  bool boundary(std::uint32_t v) const { return twin[start[v]] == kNone; }

  // The neighbours of v in counter-clockwise order (seen from the side the triangles' winding
  // faces). A boundary vertex's ring starts and ends with its two boundary neighbours.
  void ring(std::uint32_t v, std::vector<D3>& out) const {
    out.clear();
    std::uint32_t h = start[v];
    while (true) {
      out.push_back(p[head(h)]);
      std::uint32_t incoming = prev_half(h);
      std::uint32_t t = twin[incoming];
      if (t == kNone) {
        out.push_back(p[tail(incoming)]);
        return;
      }
      h = t;
      if (h == start[v]) return;
    }
  }
};

double beta(std::size_t n) {
  return n == 3 ? 3.0 / 16.0 : 3.0 / (8.0 * static_cast<double>(n));
}

double gamma(std::size_t n) {
  return 1.0 / (static_cast<double>(n) + 3.0 / (8.0 * beta(n)));
}

std::string edge_name(std::uint32_t a, std::uint32_t b) {
  return absl::StrCat("(", std::min(a, b), ", ", std::max(a, b), ")");
}

// Fills level.twin and level.start for the control mesh, refusing what the scheme cannot
// handle: edges in more than two triangles, inconsistent winding, several fans at a vertex.
absl::Status build_topology(Level& level) {
  const std::size_t halves = level.tri.size() * 3;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(halves);
  for (std::uint32_t h = 0; h < halves; ++h) {
    std::uint64_t a = level.tail(h), b = level.head(h);
    keyed[h] = {std::min(a, b) << 32 | std::max(a, b), h};
  }
  std::sort(keyed.begin(), keyed.end());
  level.twin.assign(halves, kNone);
  for (std::size_t i = 0; i < halves;) {
    std::size_t j = i + 1;
    while (j < halves && keyed[j].first == keyed[i].first) ++j;
    std::uint32_t h0 = keyed[i].second;
    std::uint32_t a = level.tail(h0), b = level.head(h0);
    if (j - i > 2) {
      std::vector<std::uint32_t> faces;
      for (std::size_t k = i; k < j; ++k) faces.push_back(keyed[k].second / 3);
      return absl::InvalidArgumentError(absl::StrCat(
          "non-manifold edge ", edge_name(a, b), " shared by ", j - i, " triangles (",
          absl::StrJoin(faces, ", "), "); Loop subdivision needs every edge in at most two"));
    }
    if (j - i == 2) {
      std::uint32_t h1 = keyed[i + 1].second;
      if (level.tail(h1) == a) {
        return absl::InvalidArgumentError(absl::StrCat(
            "triangles ", h0 / 3, " and ", h1 / 3, " both run along edge ", edge_name(a, b),
            " from vertex ", a, " to vertex ", b,
            ": neighbouring triangles must be wound consistently (inconsistent orientation)"));
      }
      level.twin[h0] = h1;
      level.twin[h1] = h0;
    }
    i = j;
  }

  const std::size_t n = level.p.size();
  std::vector<std::uint32_t> incident(n, 0);
  level.start.assign(n, kNone);
  for (std::uint32_t h = 0; h < halves; ++h) {
    std::uint32_t v = level.tail(h);
    ++incident[v];
    if (level.start[v] == kNone) level.start[v] = h;
  }
  for (std::uint32_t v = 0; v < n; ++v) {
    if (level.start[v] == kNone) continue;
    // Turn clockwise (to the next outgoing half-edge of v) until the boundary or back where we
    // began. The turn is a bijection on v's outgoing half-edges, so this ends within incident[v].
    const std::uint32_t first = level.start[v];
    std::uint32_t h = first;
    while (level.twin[h] != kNone) {
      h = next_half(level.twin[h]);
      if (h == first) break;
    }
    level.start[v] = h;
    std::uint32_t fan = 0;
    std::uint32_t g = h;
    while (true) {
      ++fan;
      std::uint32_t t = level.twin[prev_half(g)];
      if (t == kNone || t == h || fan > incident[v]) break;
      g = t;
    }
    if (fan != incident[v]) {
      return absl::InvalidArgumentError(absl::StrCat(
          "vertex ", v, " is non-manifold: its ", incident[v],
          " triangles do not form a single fan around it (only ", fan,
          " are connected through shared edges), e.g. two surfaces touching at a point"));
    }
    if (!level.boundary(v) && fan < 3) {
      return absl::InvalidArgumentError(
          absl::StrCat("vertex ", v, " is closed off by only ", fan,
                       " triangles lying on each other (a two-sided, degenerate fan)"));
    }
  }
  return absl::OkStatus();
}

// Refines `in` once. Vertex v keeps index v; the vertex on edge e gets index V + e, with edges
// numbered in order of their first half-edge. Triangle f = (v0, v1, v2) with edge vertices m_k on
// (v_k, v_k+1) becomes the corner triangles 4f + k = (v_k, m_k, m_k−1) and the centre triangle
// 4f + 3 = (m0, m1, m2), all wound like f.
Level subdivide(const Level& in) {
  const std::uint32_t num_vertices = static_cast<std::uint32_t>(in.p.size());
  const std::size_t halves = in.tri.size() * 3;
  std::vector<std::uint32_t> edge_of(halves);
  std::vector<std::uint32_t> first_half;
  for (std::uint32_t h = 0; h < halves; ++h) {
    std::uint32_t t = in.twin[h];
    if (t == kNone || t > h) {
      edge_of[h] = static_cast<std::uint32_t>(first_half.size());
      first_half.push_back(h);
    } else {
      edge_of[h] = edge_of[t];
    }
  }

  Level out;
  out.p.resize(in.p.size() + first_half.size());
  out.start.assign(out.p.size(), kNone);
  std::vector<D3> ring;
  for (std::uint32_t v = 0; v < num_vertices; ++v) {
    const D3 p = in.p[v];
    if (in.start[v] == kNone) {
      out.p[v] = p;
      continue;
    }
    in.ring(v, ring);
    if (in.boundary(v)) {
      out.p[v] = 0.75 * p + 0.125 * (ring.front() + ring.back());
    } else {
      const double b = beta(ring.size());
      D3 sum;
      for (const D3& r : ring) sum += r;
      out.p[v] = (1.0 - static_cast<double>(ring.size()) * b) * p + b * sum;
    }
    const std::uint32_t h = in.start[v];
    out.start[v] = 3 * (4 * (h / 3) + h % 3);  // first half of h, in corner triangle h % 3
  }
  for (std::uint32_t e = 0; e < first_half.size(); ++e) {
    const std::uint32_t h = first_half[e];
    const std::uint32_t t = in.twin[h];
    const D3 a = in.p[in.tail(h)], b = in.p[in.head(h)];
    if (t == kNone) {
      out.p[num_vertices + e] = 0.5 * (a + b);
    } else {
      const D3 c = in.p[in.tail(prev_half(h))], d = in.p[in.tail(prev_half(t))];
      out.p[num_vertices + e] = 0.375 * (a + b) + 0.125 * (c + d);
    }
    // Second half of h (from the edge vertex on), which is on the boundary if h is.
    out.start[num_vertices + e] = 3 * (4 * (h / 3) + (h % 3 + 1) % 3) + 2;
  }

  out.tri.resize(in.tri.size() * 4);
  out.twin.resize(halves * 4);
  for (std::uint32_t f = 0; f < in.tri.size(); ++f) {
    std::uint32_t m[3];
    for (int k = 0; k < 3; ++k) m[k] = num_vertices + edge_of[3 * f + k];
    for (std::uint32_t k = 0; k < 3; ++k) {
      const std::uint32_t km1 = (k + 2) % 3;
      const std::uint32_t corner = 4 * f + k;
      out.tri[corner] = {in.tri[f][k], m[k], m[km1]};
      // (v_k, m_k): first half of parent edge k; its twin is the second half of the twin edge.
      const std::uint32_t t0 = in.twin[3 * f + k];
      out.twin[3 * corner] = t0 == kNone ? kNone : 3 * (4 * (t0 / 3) + (t0 % 3 + 1) % 3) + 2;
      // (m_k, m_k−1) borders the centre triangle's edge (m_k−1, m_k).
      out.twin[3 * corner + 1] = 3 * (4 * f + 3) + km1;
      // (m_k−1, v_k): second half of parent edge k − 1; its twin is the first half of the twin.
      const std::uint32_t t2 = in.twin[3 * f + km1];
      out.twin[3 * corner + 2] = t2 == kNone ? kNone : 3 * (4 * (t2 / 3) + t2 % 3);
      // Centre edge (m_k, m_k+1) borders corner triangle k + 1.
      out.twin[3 * (4 * f + 3) + k] = 3 * (4 * f + (k + 1) % 3) + 1;
    }
    out.tri[4 * f + 3] = {m[0], m[1], m[2]};
  }
  return out;
}

// pbrt-v4's cross-boundary tangent mask for a boundary vertex p with ring r (r.front() and
// r.back() on the boundary, the others inside). Every mask sums to zero.
D3 boundary_cross_tangent(D3 p, const std::vector<D3>& r) {
  const std::size_t n = r.size();
  if (n == 2) return r[0] + r[1] - 2.0 * p;
  if (n == 3) return r[1] - p;
  if (n == 4) return -1.0 * r[0] + 2.0 * r[1] + 2.0 * r[2] - 1.0 * r[3] - 2.0 * p;
  const double theta = std::numbers::pi / static_cast<double>(n - 1);
  D3 t = std::sin(theta) * (r[0] + r[n - 1]);
  for (std::size_t k = 1; k + 1 < n; ++k) {
    t += (2.0 * std::cos(theta) - 2.0) * std::sin(static_cast<double>(k) * theta) * r[k];
  }
  return -1.0 * t;
}

Float3 to_float(D3 a) {
  return {static_cast<float>(a.x), static_cast<float>(a.y), static_cast<float>(a.z)};
}

}  // namespace

absl::StatusOr<TriangleMeshData> loop_subdivide(const std::vector<Float3>& positions,
                                                const std::vector<Triangle>& triangles, int levels,
                                                std::uint64_t max_triangles) {
  if (levels < 0 || levels > kMaxLoopLevels) {
    return absl::InvalidArgumentError(
        absl::StrCat("levels is ", levels, ", outside [0, ", kMaxLoopLevels, "]"));
  }
  if (positions.empty()) return absl::InvalidArgumentError("control mesh has no vertices");
  if (triangles.empty()) return absl::InvalidArgumentError("control mesh has no triangles");
  // Each level multiplies the triangles by 4; checked before anything is allocated.
  const std::uint64_t growth = std::uint64_t{1} << (2 * levels);
  const std::uint64_t input_triangles = triangles.size();
  if (input_triangles > max_triangles / growth) {
    return absl::ResourceExhaustedError(absl::StrCat(
        input_triangles, " control triangles subdivided ", levels, " times make ", input_triangles,
        " x 4^", levels, " triangles, more than the limit of ", max_triangles));
  }
  const std::uint64_t final_triangles = input_triangles * growth;
  if (final_triangles > (kNone - 1) / 3) {
    return absl::ResourceExhaustedError(absl::StrCat(
        final_triangles, " subdivided triangles are more than 32-bit half-edge indices reach"));
  }
  if (positions.size() > kNone - 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("control mesh has ", positions.size(), " vertices, more than 32-bit indices"));
  }
  for (std::size_t i = 0; i < positions.size(); ++i) {
    const Float3& p = positions[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      return absl::InvalidArgumentError(absl::StrCat("vertex ", i, " has a non-finite position"));
    }
  }
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    const Triangle& tri = triangles[t];
    for (std::uint32_t index : tri) {
      if (index >= positions.size()) {
        return absl::InvalidArgumentError(absl::StrCat("triangle ", t, " refers to vertex ", index,
                                                       " but the control mesh has ",
                                                       positions.size(), " vertices"));
      }
    }
    if (tri[0] == tri[1] || tri[1] == tri[2] || tri[2] == tri[0]) {
      return absl::InvalidArgumentError(absl::StrCat("triangle ", t, " (", tri[0], ", ", tri[1],
                                                     ", ", tri[2],
                                                     ") is degenerate: it repeats a vertex"));
    }
  }

  Level level;
  level.p.reserve(positions.size());
  for (const Float3& p : positions) level.p.push_back({p.x, p.y, p.z});
  level.tri = triangles;
  if (absl::Status s = build_topology(level); !s.ok()) return s;

  // Vertex count of the result: each level adds one vertex per edge; an edge becomes two and
  // each triangle adds three inside it.
  std::uint64_t vertices = positions.size();
  std::uint64_t edges = 0;
  for (std::uint32_t h = 0; h < level.twin.size(); ++h) {
    if (level.twin[h] == kNone || level.twin[h] > h) ++edges;
  }
  std::uint64_t faces = input_triangles;
  for (int i = 0; i < levels; ++i) {
    vertices += edges;
    edges = 2 * edges + 3 * faces;
    faces *= 4;
  }
  if (vertices > kNone - 1) {
    return absl::ResourceExhaustedError(absl::StrCat("the subdivided mesh would have ", vertices,
                                                     " vertices, more than 32-bit indices reach"));
  }

  for (int i = 0; i < levels; ++i) level = subdivide(level);
  PRISM_CHECK(level.p.size() == vertices && level.tri.size() == final_triangles);

  // Limit positions and normals, both from the finest level's control points.
  const std::size_t n = level.p.size();
  std::vector<D3> limit(n);
  std::vector<D3> normal(n);
  std::vector<bool> fallback(n, false);
  std::vector<D3> ring;
  for (std::uint32_t v = 0; v < n; ++v) {
    const D3 p = level.p[v];
    if (level.start[v] == kNone) {
      limit[v] = p;
      continue;
    }
    level.ring(v, ring);
    D3 s, t;
    if (level.boundary(v)) {
      limit[v] = 0.6 * p + 0.2 * (ring.front() + ring.back());
      s = ring.front() - ring.back();
      t = boundary_cross_tangent(p, ring);
    } else {
      const std::size_t valence = ring.size();
      const double g = gamma(valence);
      D3 sum;
      for (std::size_t i = 0; i < valence; ++i) {
        sum += ring[i];
        const double angle =
            2.0 * std::numbers::pi * static_cast<double>(i) / static_cast<double>(valence);
        s += std::cos(angle) * ring[i];
        t += std::sin(angle) * ring[i];
      }
      limit[v] = (1.0 - static_cast<double>(valence) * g) * p + g * sum;
    }
    // With the ring counter-clockwise, cross(S, T) points to the side the winding faces.
    normal[v] = cross(s, t);
    const double len = length(normal[v]);
    if (len > 1e-9 * length(s) * length(t) && std::isfinite(len)) {
      normal[v] = (1.0 / len) * normal[v];
    } else {
      fallback[v] = true;  // coincident control points: no tangent plane from the masks
    }
  }
  // Where the masks give no plane, use the area-weighted normals of the limit triangles.
  for (std::uint32_t f = 0; f < level.tri.size(); ++f) {
    const Triangle& tri = level.tri[f];
    if (!fallback[tri[0]] && !fallback[tri[1]] && !fallback[tri[2]]) continue;
    const D3 face = cross(limit[tri[0]] - limit[tri[2]], limit[tri[1]] - limit[tri[2]]);
    for (std::uint32_t v : tri) {
      if (fallback[v]) normal[v] += face;
    }
  }

  TriangleMeshData mesh;
  mesh.positions.reserve(n + 1);  // room for Embree's 16-byte read past the last vertex
  mesh.normals.reserve(n);
  for (std::size_t v = 0; v < n; ++v) {
    mesh.positions.push_back(to_float(limit[v]));
    D3 nv = normal[v];
    if (fallback[v]) {
      const double len = length(nv);
      nv = len > 0 && std::isfinite(len) ? (1.0 / len) * nv : D3{};
    }
    mesh.normals.push_back(to_float(nv));
  }
  mesh.triangles = std::move(level.tri);
  if (absl::Status s = mesh.validate(); !s.ok()) return s;
  return mesh;
}

}  // namespace prism::scene
