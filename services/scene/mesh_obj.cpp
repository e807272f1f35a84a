#include "services/scene/mesh_obj.h"

#include <tiny_obj_loader.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/strip.h"
#include "services/base/atomic_file.h"
#include "services/base/decimal.h"
#include "services/base/status.h"

namespace prism::scene {
namespace {

// Answers every `mtllib` without reading anything: materials come from the pbrt scene, and
// opening files named by an untrusted OBJ could read outside the scene directory.
class NoMaterialReader final : public tinyobj::MaterialReader {
 public:
  bool operator()(const std::string& /*mat_id*/, std::vector<tinyobj::material_t>* /*materials*/,
                  std::map<std::string, int>* /*mat_map*/, std::string* /*warn*/,
                  std::string* /*err*/) override {
    return true;
  }
};

absl::Status obj_error(absl::string_view name, absl::string_view message) {
  return absl::InvalidArgumentError(absl::StrCat(name, ": ", message));
}

// tinyobjloader reads a number it cannot parse ("nan", "1,5", "x") as 0 without a word, so the
// vertex data lines (v, vn, vt) are checked first: every value after the keyword must be a finite
// number. The error names the line.
absl::Status check_vertex_numbers(std::string_view text, absl::string_view name) {
  std::size_t line = 0;
  for (std::size_t start = 0; start < text.size();) {
    std::size_t end = text.find('\n', start);
    if (end == std::string_view::npos) end = text.size();
    std::string_view row = text.substr(start, end - start);
    start = end + 1;
    ++line;
    auto is_space = [](char c) { return c == ' ' || c == '\t' || c == '\r'; };
    std::size_t i = 0;
    while (i < row.size() && is_space(row[i])) ++i;
    std::size_t k = i;
    while (k < row.size() && !is_space(row[k])) ++k;
    const std::string_view keyword = row.substr(i, k - i);
    if (keyword != "v" && keyword != "vn" && keyword != "vt") continue;
    for (i = k; i < row.size();) {
      while (i < row.size() && is_space(row[i])) ++i;
      if (i == row.size()) break;
      k = i;
      while (k < row.size() && !is_space(row[k])) ++k;
      const std::string_view token = row.substr(i, k - i);
      i = k;
      if (base::parse_decimal(token).error != base::DecimalError::kNone) {
        return obj_error(
            name, absl::StrCat("line ", line, ": '", absl::string_view(token.data(), token.size()),
                               "' in a '", absl::string_view(keyword.data(), keyword.size()),
                               "' line is not a finite number"));
      }
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<TriangleMeshData> parse_obj(std::string_view text, std::string_view name_in,
                                           const MeshLimits& limits) {
  absl::string_view name(name_in.data(), name_in.size());
  if (text.size() > limits.max_file_bytes) {
    return absl::ResourceExhaustedError(
        absl::StrCat(name, ": ", text.size(), " bytes, over the limit of ", limits.max_file_bytes));
  }
  PRISM_RETURN_IF_ERROR(check_vertex_numbers(text, name));
  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> materials;
  std::string warn;
  std::string err;
  std::istringstream stream{std::string(text)};
  NoMaterialReader no_materials;
  // Triangulation is done below, after every index has been checked; tinyobjloader's own
  // triangulation silently drops faces with bad indices.
  bool ok = tinyobj::LoadObj(&attrib, &shapes, &materials, &warn, &err, &stream, &no_materials,
                             /*triangulate=*/false, /*default_vcols_fallback=*/false);
  if (!ok || !err.empty()) {
    return obj_error(
        name, absl::StripTrailingAsciiWhitespace(err.empty() ? std::string("cannot parse") : err));
  }
  if (warn.find("Degenerated face") != std::string::npos) {
    return obj_error(name, "a face has fewer than 3 corners");
  }

  const std::size_t num_positions = attrib.vertices.size() / 3;
  const std::size_t num_normals = attrib.normals.size() / 3;
  const std::size_t num_uvs = attrib.texcoords.size() / 2;
  std::uint64_t num_triangles = 0;
  bool all_normals = true;
  bool all_uvs = true;
  for (const tinyobj::shape_t& shape : shapes) {
    const tinyobj::mesh_t& m = shape.mesh;
    std::size_t corner = 0;
    for (std::size_t f = 0; f < m.num_face_vertices.size(); ++f) {
      std::size_t n = m.num_face_vertices[f];
      if (n < 3)
        return obj_error(
            name, absl::StrCat("face ", f, " of '", shape.name, "' has fewer than 3 corners"));
      if (corner + n > m.indices.size()) {
        return obj_error(name, "face corner count does not match its indices");
      }
      for (std::size_t c = corner; c < corner + n; ++c) {
        const tinyobj::index_t& idx = m.indices[c];
        if (idx.vertex_index < 0 || static_cast<std::size_t>(idx.vertex_index) >= num_positions) {
          return obj_error(
              name,
              absl::StrCat("face ", f, " of '", shape.name, "' refers to a missing position (",
                           num_positions, " positions; its corner ", c - corner + 1,
                           idx.vertex_index < 0
                               ? std::string(" counts back past the first")
                               : absl::StrCat(" names position ", idx.vertex_index + 1),
                           ")"));
        }
        if (idx.normal_index >= 0 && static_cast<std::size_t>(idx.normal_index) >= num_normals) {
          return obj_error(
              name, absl::StrCat("face ", f, " of '", shape.name, "' refers to a missing normal (",
                                 num_normals, " normals)"));
        }
        if (idx.texcoord_index >= 0 && static_cast<std::size_t>(idx.texcoord_index) >= num_uvs) {
          return obj_error(name, absl::StrCat("face ", f, " of '", shape.name,
                                              "' refers to a missing texture coordinate (", num_uvs,
                                              " texture coordinates)"));
        }
        // tinyobjloader turns a malformed index into a negative one; only -1 means "absent".
        if (idx.normal_index < -1 || idx.texcoord_index < -1) {
          return obj_error(name,
                           absl::StrCat("face ", f, " of '", shape.name, "' has an invalid index"));
        }
        all_normals &= idx.normal_index >= 0;
        all_uvs &= idx.texcoord_index >= 0;
      }
      corner += n;
      num_triangles += n - 2;
    }
    // tinyobjloader stores corner counts in a byte, so a face with more than 255 corners leaves
    // counts and indices out of step.
    if (corner != m.indices.size()) {
      return obj_error(name,
                       absl::StrCat("'", shape.name, "' has a face with more than 255 corners"));
    }
  }
  if (num_triangles == 0) return obj_error(name, "the file has no faces");
  if (num_triangles > limits.max_triangles) {
    return absl::ResourceExhaustedError(absl::StrCat(
        name, ": ", num_triangles, " triangles, over the limit of ", limits.max_triangles));
  }

  TriangleMeshData mesh;
  mesh.triangles.reserve(num_triangles);
  std::uint64_t max_vertices =
      std::min<std::uint64_t>(limits.max_vertices, std::numeric_limits<std::uint32_t>::max());
  absl::flat_hash_map<std::tuple<int, int, int>, std::uint32_t> vertex_of;
  auto vertex_for = [&](const tinyobj::index_t& idx, std::uint32_t* out) -> absl::Status {
    std::tuple<int, int, int> key{idx.vertex_index, all_normals ? idx.normal_index : -1,
                                  all_uvs ? idx.texcoord_index : -1};
    auto [it, inserted] =
        vertex_of.try_emplace(key, static_cast<std::uint32_t>(mesh.positions.size()));
    if (inserted) {
      if (mesh.positions.size() >= max_vertices) {
        return absl::ResourceExhaustedError(
            absl::StrCat(name, ": more than ", max_vertices, " distinct vertices, over the limit"));
      }
      const float* p = &attrib.vertices[3 * static_cast<std::size_t>(idx.vertex_index)];
      mesh.positions.push_back({p[0], p[1], p[2]});
      if (all_normals) {
        const float* n = &attrib.normals[3 * static_cast<std::size_t>(idx.normal_index)];
        mesh.normals.push_back({n[0], n[1], n[2]});
      }
      if (all_uvs) {
        const float* t = &attrib.texcoords[2 * static_cast<std::size_t>(idx.texcoord_index)];
        mesh.uvs.push_back({t[0], t[1]});
      }
    }
    *out = it->second;
    return absl::OkStatus();
  };
  for (const tinyobj::shape_t& shape : shapes) {
    const tinyobj::mesh_t& m = shape.mesh;
    std::size_t corner = 0;
    for (unsigned char n : m.num_face_vertices) {
      std::uint32_t first = 0;
      std::uint32_t previous = 0;
      PRISM_RETURN_IF_ERROR(vertex_for(m.indices[corner], &first));
      PRISM_RETURN_IF_ERROR(vertex_for(m.indices[corner + 1], &previous));
      for (std::size_t c = 2; c < n; ++c) {
        std::uint32_t current = 0;
        PRISM_RETURN_IF_ERROR(vertex_for(m.indices[corner + c], &current));
        mesh.triangles.push_back({first, previous, current});
        previous = current;
      }
      corner += n;
    }
  }
  absl::Status valid = mesh.validate();
  if (!valid.ok()) return obj_error(name, valid.message());
  return mesh;
}

absl::StatusOr<TriangleMeshData> load_obj(const std::filesystem::path& path,
                                          const MeshLimits& limits) {
  PRISM_ASSIGN_OR_RETURN(std::string text, base::read_file(path, limits.max_file_bytes));
  return parse_obj(text, path.string(), limits);
}

}  // namespace prism::scene
