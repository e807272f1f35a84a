// `prism check scene.pbrt`: loads a scene exactly as a render would (named spectra checked
// against the built-in library, every file confined to the scene's directory), builds its
// bundle, and reports what the scene contains and what in it depends on wavelength.
#pragma once

#include <filesystem>
#include <string>

#include "absl/status/statusor.h"

namespace prism::client {

struct CheckOptions {
  std::filesystem::path scene;
  bool json = false;
};

// The report text (or JSON), or the scene's error ("file:line:column: message").
absl::StatusOr<std::string> run_check(const CheckOptions& options);

}  // namespace prism::client
