// Wavefront OBJ triangle meshes, read with tinyobjloader from untrusted files.
//
// All groups and objects are merged into one mesh. OBJ indexes positions, normals and texture
// coordinates separately per face corner; the result has one vertex per distinct
// (position, normal, uv) index triple used by a face, so shared corners stay shared. Normals
// (uvs) are kept only if every face corner has one; otherwise the mesh has none. Triangles are
// kept, a quad (a, b, c, d) becomes (a, b, c) and (a, c, d) as in PLY, and larger polygons are
// split as a fan around their first corner, which is right for the convex polygons exporters
// write. `mtllib`/`usemtl` are ignored (materials come from the pbrt scene) and no .mtl file is
// ever opened, so an OBJ cannot make the reader touch files outside the scene directory. Lines
// and points are ignored. Relative (negative) indices are resolved as OBJ specifies.
//
// Errors: INVALID_ARGUMENT naming the file for malformed input, an index out of range, a face
// with fewer than 3 corners, or no faces at all; RESOURCE_EXHAUSTED when a MeshLimits bound is
// exceeded. A returned mesh has passed TriangleMeshData::validate().
#pragma once

#include <filesystem>
#include <string_view>

#include "absl/status/statusor.h"
#include "services/scene/mesh.h"

namespace prism::scene {

// Reads and parses an OBJ file; NOT_FOUND if it does not exist, RESOURCE_EXHAUSTED if it is
// larger than limits.max_file_bytes.
absl::StatusOr<TriangleMeshData> load_obj(const std::filesystem::path& path,
                                          const MeshLimits& limits = {});

// Parses OBJ text already in memory. `name_for_errors` prefixes every error message.
absl::StatusOr<TriangleMeshData> parse_obj(std::string_view text, std::string_view name_for_errors,
                                           const MeshLimits& limits = {});

}  // namespace prism::scene
