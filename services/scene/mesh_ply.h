// Stanford PLY triangle meshes, read from untrusted files.
//
// Formats: ascii, binary_little_endian and binary_big_endian, version 1.0. The "vertex" element
// supplies x, y, z (required), nx, ny, nz (used only if all three are present) and texture
// coordinates from the first complete pair among (u, v), (s, t), (texture_u, texture_v),
// (texture_s, texture_t). The "face" element supplies a list property "vertex_indices" (or
// "vertex_index") with any integer count and index types. Triangles are kept; a quad (a, b, c, d)
// becomes the triangles (a, b, c) and (a, c, d); faces with fewer than 3 or more than 4 vertices
// are refused rather than triangulated, since a fan is wrong for non-convex polygons. Every other
// property and element, scalar or list, of any PLY type (char/int8 ... double/float64), is
// read past and ignored.
//
// Robustness: the reader never reads outside `bytes`. Before allocating, the element counts from
// the header are checked against the bytes that follow it, so a header claiming billions of
// vertices in a small file is refused at once. Data after the last element is an error.
//
// Errors: INVALID_ARGUMENT for a malformed file, naming the file and either the line (header and
// ascii body) or the byte offset (binary body); RESOURCE_EXHAUSTED when a MeshLimits bound is
// exceeded. A returned mesh has passed TriangleMeshData::validate().
#pragma once

#include <filesystem>
#include <string_view>

#include "absl/status/statusor.h"
#include "services/scene/mesh.h"

namespace prism::scene {

// Reads and parses a PLY file; NOT_FOUND if it does not exist, RESOURCE_EXHAUSTED if it is larger
// than limits.max_file_bytes.
absl::StatusOr<TriangleMeshData> load_ply(const std::filesystem::path& path,
                                          const MeshLimits& limits = {});

// Parses PLY bytes already in memory. `name_for_errors` prefixes every error message.
absl::StatusOr<TriangleMeshData> parse_ply(std::string_view bytes, std::string_view name_for_errors,
                                           const MeshLimits& limits = {});

}  // namespace prism::scene
