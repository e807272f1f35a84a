// Loading a scene from disk: the scene file's directory is the scene root, and every file
// the scene mentions (Include/Import, meshes, spectrum tables) is resolved through PathGuard,
// so nothing outside the root (by absolute path, `..`, or a symbolic link) is ever opened.
// The result lists every opened file relative to the root, which is what make_bundle needs.
#pragma once

#include <filesystem>
#include <string>

#include "absl/status/statusor.h"
#include "services/scene/parser.h"
#include "services/scene/scene_description.h"

namespace prism::scene {

struct LoadedScene {
  SceneDescription description;
  std::filesystem::path root;       // canonical scene directory
  std::string scene_relpath;        // the scene file's name inside root
};

// Errors: NOT_FOUND when the scene file does not exist; RESOURCE_EXHAUSTED for limits; every
// parse or validation error as INVALID_ARGUMENT (or the file error's code) with
// `file:line:column: ` first (see parser.h).
absl::StatusOr<LoadedScene> load_scene(const std::filesystem::path& scene_file, const LoadOptions& options);

}  // namespace prism::scene
