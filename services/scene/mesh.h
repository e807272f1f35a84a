// Triangle mesh data as read from mesh files (PLY, OBJ) and pbrt "trianglemesh" shapes, before
// the parser applies the object-to-world transform and the path tracer uploads it to Embree.
//
// Invariants after validate() returns OK: positions is non-empty; normals and uvs are either
// empty (absent) or have exactly one entry per position; every triangle index is smaller than
// positions.size(); every float is finite; the vertex count fits in a uint32. Float3, Float2 and
// Triangle are tightly packed (12, 8 and 12 bytes), so the vectors can be handed to Embree as
// shared RTC_FORMAT_FLOAT3 / RTC_FORMAT_UINT3 buffers. Embree reads the last vertex with a 16-byte
// load, so whoever shares `positions` must guarantee 4 readable bytes past its end (copying into
// a padded buffer, or reserving one extra element on a vector it owns).
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"

namespace prism::scene {

struct Float3 {
  float x = 0.0f;
  float y = 0.0f;
  float z = 0.0f;
  friend bool operator==(const Float3&, const Float3&) = default;
};

struct Float2 {
  float u = 0.0f;
  float v = 0.0f;
  friend bool operator==(const Float2&, const Float2&) = default;
};

// Three vertex indices, counter-clockwise as written in the source file.
using Triangle = std::array<std::uint32_t, 3>;

static_assert(sizeof(Float3) == 12 && sizeof(Float2) == 8 && sizeof(Triangle) == 12);

struct TriangleMeshData {
  std::vector<Float3> positions;
  std::vector<Float3> normals;  // empty, or one per position (not necessarily unit length)
  std::vector<Float2> uvs;      // empty, or one per position
  std::vector<Triangle> triangles;
  // Bilinear patches (pbrt-v4 "bilinearmesh" and a PLY file's quads), ascending: each entry t is
  // the first of the two triangles t = (p00, p10, p11) and t + 1 = (p00, p11, p01) that the patch
  // is split into. Empty for a mesh of triangles only. The pair is the patch itself where the
  // patch is flat (worker/geometry.h); elsewhere the renderer intersects the curved patch.
  std::vector<std::uint32_t> patches;

  friend bool operator==(const TriangleMeshData&, const TriangleMeshData&) = default;

  // Checks the invariants above. Returns INVALID_ARGUMENT naming the first offending element;
  // callers that know the source file prefix its name.
  absl::Status validate() const {
    if (positions.empty()) return absl::InvalidArgumentError("mesh has no vertices");
    if (triangles.empty()) return absl::InvalidArgumentError("mesh has no triangles");
    if (positions.size() > std::numeric_limits<std::uint32_t>::max()) {
      return absl::InvalidArgumentError(
          absl::StrCat("mesh has ", positions.size(), " vertices, more than uint32 indices reach"));
    }
    if (!normals.empty() && normals.size() != positions.size()) {
      return absl::InvalidArgumentError(absl::StrCat("mesh has ", normals.size(), " normals for ",
                                                     positions.size(), " vertices"));
    }
    if (!uvs.empty() && uvs.size() != positions.size()) {
      return absl::InvalidArgumentError(
          absl::StrCat("mesh has ", uvs.size(), " uvs for ", positions.size(), " vertices"));
    }
    auto finite3 = [](const Float3& p) {
      return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
    };
    for (std::size_t i = 0; i < positions.size(); ++i) {
      if (!finite3(positions[i])) {
        return absl::InvalidArgumentError(absl::StrCat("vertex ", i, " has a non-finite position"));
      }
    }
    for (std::size_t i = 0; i < normals.size(); ++i) {
      if (!finite3(normals[i])) {
        return absl::InvalidArgumentError(absl::StrCat("vertex ", i, " has a non-finite normal"));
      }
    }
    for (std::size_t i = 0; i < uvs.size(); ++i) {
      if (!std::isfinite(uvs[i].u) || !std::isfinite(uvs[i].v)) {
        return absl::InvalidArgumentError(absl::StrCat("vertex ", i, " has a non-finite uv"));
      }
    }
    for (std::size_t t = 0; t < triangles.size(); ++t) {
      for (std::uint32_t index : triangles[t]) {
        if (index >= positions.size()) {
          return absl::InvalidArgumentError(absl::StrCat("triangle ", t, " refers to vertex ",
                                                         index, " but the mesh has ",
                                                         positions.size(), " vertices"));
        }
      }
    }
    for (std::size_t i = 0; i < patches.size(); ++i) {
      const std::uint64_t t = patches[i];
      if (t + 1 >= triangles.size() || (i > 0 && t < std::uint64_t{patches[i - 1]} + 2)) {
        return absl::InvalidArgumentError(absl::StrCat("patch ", i, " starts at triangle ", t,
                                                       ", which is not the first of ",
                                                       "two triangles of its own"));
      }
      const Triangle& a = triangles[t];
      const Triangle& b = triangles[t + 1];
      if (a[0] != b[0] || a[2] != b[1]) {
        return absl::InvalidArgumentError(absl::StrCat(
            "patch ", i, ": triangles ", t, " and ", t + 1, " do not share the diagonal p00-p11"));
      }
    }
    return absl::OkStatus();
  }
};

// Resource limits for reading untrusted mesh files. Exceeding one is RESOURCE_EXHAUSTED (the
// file may be fine, just larger than this deployment accepts); malformed files are
// INVALID_ARGUMENT.
struct MeshLimits {
  std::uint64_t max_file_bytes = std::uint64_t{1} << 30;  // 1 GiB
  std::uint64_t max_triangles = 50'000'000;               // after splitting quads
  std::uint64_t max_vertices = 50'000'000;
};

}  // namespace prism::scene
