// `prism check scene.pbrt`: loads a scene exactly as a render would (named spectra checked
// against the built-in library, every file confined to the scene's directory), builds its
// bundle, and reports what the scene contains, what in it depends on wavelength, and every
// pbrt-v4 feature it uses with what Prism does with it: supported, approximated, ignored (cannot
// change the image) or refused, with the substitution `--allow-unsupported` would render. All
// refusals are listed, not only the first.
#pragma once

#include <filesystem>
#include <string>

#include "absl/status/statusor.h"

namespace prism::client {

struct CheckOptions {
  std::filesystem::path scene;
  bool json = false;
  bool allow_unsupported = false;  // refusals do not make the check fail
};

struct CheckReport {
  std::string text;  // the summary (or JSON)
  // False when the scene uses refused features and allow_unsupported is off: `prism render`
  // would refuse it (the CLI exits 1).
  bool renders = true;
};

// The report, or the scene's error ("file:line:column: message") when it does not load at all.
absl::StatusOr<CheckReport> run_check(const CheckOptions& options);

}  // namespace prism::client
