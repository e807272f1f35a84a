// The worker's on-disk cache of scene bundles, keyed by content hash: `<dir>/<hash>/` holds the
// bundle's files exactly as make_bundle found them under the scene root.
//
// Invariant: a directory named after a hash exists only once every file of the bundle with that
// hash has been written and checked. install() unpacks (which verifies every file's SHA-256 and
// the manifest hash), refuses a blob whose hash is not the one asked for, extracts into a
// private temporary directory and renames it into place, so a crash or a concurrent worker on the
// same cache never leaves a half-written bundle under a hash name.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "services/scene/bundle.h"

namespace prism::worker {

class BundleCache {
 public:
  // `dir` is created on first install if it does not exist.
  explicit BundleCache(std::filesystem::path dir, scene::BundleLimits limits = {})
      : dir_(std::move(dir)), limits_(limits) {}

  // The directory of a cached bundle, or nullopt. INVALID_ARGUMENT for a malformed hash (it
  // becomes a path component, so it must be 64 lower case hex digits).
  absl::StatusOr<std::optional<std::filesystem::path>> find(std::string_view hash) const;

  // Verifies `blob` (the packed bundle) and installs it under `hash`. INVALID_ARGUMENT for a
  // malformed blob or one whose content hash differs from `hash` (nothing is written then);
  // RESOURCE_EXHAUSTED beyond the limits; the file system's errors as they come. Returns the
  // bundle's directory; installing a hash that is already cached is a no-op.
  absl::StatusOr<std::filesystem::path> install(std::string_view hash, std::string_view blob);

  const std::filesystem::path& dir() const { return dir_; }
  const scene::BundleLimits& limits() const { return limits_; }

 private:
  std::filesystem::path dir_;
  scene::BundleLimits limits_;
};

}  // namespace prism::worker
