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
  std::filesystem::path root;  // canonical scene directory
  std::string scene_relpath;   // the scene file's name inside root
};

// Errors: NOT_FOUND when the scene file does not exist; RESOURCE_EXHAUSTED for limits; every
// parse or validation error as INVALID_ARGUMENT (or the file error's code) with
// `file:line:column: ` first (see parser.h).
absl::StatusOr<LoadedScene> load_scene(const std::filesystem::path& scene_file,
                                       const LoadOptions& options);

// The one rule for named spectra, for every caller that loads a scene to render it: a parameter
// that takes a spectrum (`"spectrum L"`, a conductor's `eta` and `k`, a medium's `sigma_a`)
// must name a spectrum of `library`, one that takes an index of refraction (a dielectric's
// `eta`) an IOR of it, exactly as the worker resolves them. `Library` is
// spectral::SpectrumLibrary (a template so that the parser does not depend on the spectral
// data); it must outlive the returned checks.
template <typename Library>
LoadOptions with_library_names(const Library& library, LoadOptions options = {}) {
  options.is_known_spectrum = [&library](std::string_view name) {
    return library.find_spectrum(name) != nullptr;
  };
  options.is_known_ior = [&library](std::string_view name) {
    return library.find_ior(name) != nullptr;
  };
  return options;
}

}  // namespace prism::scene
