// Loop subdivision surfaces (Loop 1987) for pbrt-v4's `Shape "loopsubdiv"`: a triangle control
// mesh is refined `levels` times at load time and every vertex of the result is moved to the
// limit surface, so the renderer only ever sees an ordinary TriangleMeshData with smooth
// per-vertex normals. The weights are pbrt-v4's (its LoopSubdivide):
//
//   odd (edge) vertex, interior edge (a, b) with opposite vertices c, d: 3/8 a + 3/8 b + 1/8 c +
//     1/8 d; boundary edge: 1/2 a + 1/2 b.
//   even vertex p with n ring neighbours r_i: interior (1 − nβ) p + β Σ r_i with Warren's
//     β(n) = 3/16 for n = 3, else 3/(8n); boundary 3/4 p + 1/8 (r_first + r_last), where
//     r_first and r_last are its two neighbours along the boundary.
//   limit position: interior (1 − nγ) p + γ Σ r_i with γ(n) = 1/(n + 3/(8 β(n))); boundary
//     3/5 p + 1/5 (r_first + r_last).
//   limit normal cross(S, T) from two tangent masks: interior S = Σ cos(2πi/n) r_i,
//     T = Σ sin(2πi/n) r_i; boundary S along the boundary (r_first − r_last) and T across it
//     with pbrt-v4's masks for 2, 3 and 4 ring neighbours (a corner of one triangle, two
//     triangles, the regular case) and its sine mask for more.
//
// So boundary curves are uniform cubic B-splines of the control boundary polygon (a straight run
// of boundary vertices stays straight) and no boundary vertex is pinned as a corner. pbrt-v4's
// boundary limit rule is kept although the exact limit of that B-spline is 1/6, 2/3, 1/6: it
// leaves boundary vertices slightly off the limit curve, by an amount that shrinks fourfold per
// level (about 1e-3 of a control edge at the default 3 levels). Interior vertices are exactly on
// the limit surface.
//
// Two deliberate differences from pbrt-v4. The tangent masks are applied to the finest level's
// control points, which is what the masks are derived for (they are left eigenvectors of the
// refinement, so a vertex's normal does not turn when the mesh is refined further); pbrt-v4
// applies them to the already projected limit points, which tilts interior normals by up to a
// few degrees at low levels. And the normals point to the side of Prism's geometric normal
// cross(p0 − p2, p1 − p2) of the triangles around them (the side their winding faces), whereas
// pbrt-v4's cross(S, T), with its one-ring order, points to the other side.
//
// Output layout: control vertex i keeps index i at every level (even vertices come first, then
// one new vertex per edge of the level before), so its output position is its limit position.
// Vertices no triangle refers to are kept, unmoved, with a zero normal, and stay unreferenced.
// Each control triangle (a, b, c) is replaced by 4^levels triangles wound the same way. Normals
// are unit length except at unreferenced vertices; no uvs are produced.
//
// Input requirements (INVALID_ARGUMENT naming the offending vertex, triangle or edge): levels in
// [0, kMaxLoopLevels]; indices in range; no triangle repeating a vertex; every edge in one or two
// triangles, and two triangles sharing an edge wound consistently (they run along it in opposite
// directions); the triangles around each vertex form a single fan (no two sheets touching at a
// vertex), which is not a closed fan of only two triangles; finite positions.
// RESOURCE_EXHAUSTED when the result would exceed max_triangles (checked before any allocation)
// or would need more than 32-bit vertex or half-edge indices. A returned mesh has passed
// TriangleMeshData::validate().
#pragma once

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "services/scene/mesh.h"

namespace prism::scene {

inline constexpr int kMaxLoopLevels = 8;

// Subdivides the control mesh (positions + triangles) `levels` times (0..kMaxLoopLevels) and
// moves vertices to the limit surface; returns a mesh with per-vertex limit normals.
absl::StatusOr<TriangleMeshData> loop_subdivide(const std::vector<Float3>& positions,
                                                const std::vector<Triangle>& triangles, int levels,
                                                std::uint64_t max_triangles);

}  // namespace prism::scene
