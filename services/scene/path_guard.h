// Confinement of file references from untrusted scene files to one scene directory.
//
// A scene names meshes, textures and included files by path. PathGuard resolves such a
// reference against the scene root and guarantees that the result is a regular file whose real
// path (all symbolic links resolved) lies inside the root's real path. References are first
// normalised lexically: they must be relative, non-empty, without NUL or other control bytes or
// backslashes, and a ".." may only cancel a component before it ("a/../b" means "b" even if "a"
// is a symbolic link, and "../b" is refused). Symbolic links inside the root are followed, and
// allowed as long as their target is inside the root too.
//
// The normalised form ("meshes/bunny.ply": '/'-separated, no ".", "..", or empty components) is
// how a reference is named in scene bundles, so a scene resolves the same way from its original
// directory and from an unpacked bundle.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace prism::scene {

struct ResolvedReference {
  std::filesystem::path real_path;  // canonical, inside the root
  std::string relative_path;        // normalised, relative to the root
};

class PathGuard {
 public:
  // `root` must be an existing directory: NOT_FOUND otherwise, INVALID_ARGUMENT if it is not a
  // directory.
  static absl::StatusOr<PathGuard> create(const std::filesystem::path& root);

  // The canonical scene root.
  const std::filesystem::path& root() const { return root_; }

  // Resolves a reference written in a scene file to the canonical path of a regular file inside
  // the root. INVALID_ARGUMENT for a reference that is malformed, escapes the root (lexically or
  // through a symbolic link) or is not a regular file; NOT_FOUND if nothing exists there.
  absl::StatusOr<std::filesystem::path> resolve(std::string_view reference) const;

  // As resolve, and also returns the normalised path relative to the root (for bundles).
  absl::StatusOr<ResolvedReference> resolve_reference(std::string_view reference) const;

 private:
  explicit PathGuard(std::filesystem::path root) : root_(std::move(root)) {}

  std::filesystem::path root_;
};

// Lexical normalisation of a reference (see above) without touching the file system:
// "./a//b/../c.ply" -> "a/c.ply". INVALID_ARGUMENT says what is wrong with it.
absl::StatusOr<std::string> normalize_reference(std::string_view reference);

// OK if `path` is already in normalised form: relative, non-empty, '/'-separated components that
// are neither empty nor "." nor "..", no NUL or other control bytes, no backslashes. Used to
// check paths from bundles before anything is written. INVALID_ARGUMENT otherwise.
absl::Status check_plain_relative_path(std::string_view path);

// True if `path` equals `root` or lies below it, comparing whole components; both canonical.
bool is_within(const std::filesystem::path& path, const std::filesystem::path& root);

}  // namespace prism::scene
