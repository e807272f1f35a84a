#include "services/scene/scene_parser_fuzz.h"

#include <map>
#include <string>
#include <string_view>

#include "services/base/check.h"
#include "services/scene/parser.h"
#include "services/scene/scene_summary.h"

namespace prism::scene {
namespace {

std::map<std::string, std::string> make_fuzz_root() {
  return {
      {"inc.pbrt", "Material \"diffuse\" \"rgb reflectance\" [0.5 0.5 0.5]\nInclude \"inc.pbrt\"\n"},
      {"sub/leaf.pbrt", "Shape \"sphere\" \"float radius\" 2\n"},
      {"tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"},
      {"tri.ply",
       "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
       "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"},
      {"light.csv", "wavelength_nm,value\n400,0\n500,8\n600,15.6\n700,18.4\n"},
  };
}

// "file:line:column: " at the start; the file name has no ':' or newline.
bool has_location_prefix(std::string_view message) {
  size_t i = 0;
  while (i < message.size() && message[i] != ':' && message[i] != '\n') ++i;
  if (i == 0) return false;
  for (int field = 0; field < 2; ++field) {
    if (i >= message.size() || message[i] != ':') return false;
    size_t digits_start = ++i;
    while (i < message.size() && message[i] >= '0' && message[i] <= '9') ++i;
    if (i == digits_start) return false;
  }
  return message.substr(i).starts_with(": ");
}

}  // namespace

int fuzz_parse(const std::uint8_t* data, std::size_t size) {
  std::string_view text(reinterpret_cast<const char*>(data), size);
  LoadOptions options;
  options.mesh_limits.max_file_bytes = 1 << 20;
  options.mesh_limits.max_triangles = 100'000;
  options.mesh_limits.max_vertices = 100'000;
  options.max_total_triangles = 1'000'000;
  options.is_known_spectrum = [](std::string_view name) { return name.starts_with("stdillum-"); };
  options.is_known_ior = [](std::string_view name) {
    return name.starts_with("glass-") || name.starts_with("metal-");
  };
  absl::StatusOr<SceneDescription> scene = parse_scene_string(text, "fuzz.pbrt", options, make_fuzz_root());
  if (scene.ok()) {
    std::string summary = format_scene_summary(*scene);
    PRISM_CHECK(!summary.empty());
  } else {
    std::string message(scene.status().message());
    PRISM_CHECK_MSG(has_location_prefix(message),
                    message.c_str());
  }
  return 0;
}

}  // namespace prism::scene
