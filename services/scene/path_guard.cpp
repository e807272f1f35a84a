#include "services/scene/path_guard.h"

#include <algorithm>
#include <cerrno>
#include <iterator>
#include <string_view>
#include <system_error>
#include <vector>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "services/base/status.h"

namespace prism::scene {
namespace {

namespace fs = std::filesystem;

// Shared by both checks: bytes no path component may contain.
absl::Status check_bytes(absl::string_view path) {
  if (path.empty()) return absl::InvalidArgumentError("empty file name");
  for (char c : path) {
    auto byte = static_cast<unsigned char>(c);
    if (byte == 0) {
      return absl::InvalidArgumentError(
          absl::StrCat("file name '", absl::CEscape(path), "' contains a NUL byte"));
    }
    if (byte < 0x20 || byte == 0x7f) {
      return absl::InvalidArgumentError(
          absl::StrCat("file name '", absl::CEscape(path), "' contains a control character"));
    }
    if (c == '\\') {
      return absl::InvalidArgumentError(absl::StrCat(
          "file name '", path, "' contains a backslash; use '/' to separate directories"));
    }
  }
  if (path.front() == '/') {
    return absl::InvalidArgumentError(absl::StrCat("file name '", path,
                                                   "' is absolute; scene files may only name files "
                                                   "relative to the scene directory"));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::string> normalize_reference(std::string_view reference_in) {
  absl::string_view reference(reference_in.data(), reference_in.size());
  PRISM_RETURN_IF_ERROR(check_bytes(reference));
  std::vector<absl::string_view> parts;
  for (absl::string_view part : absl::StrSplit(reference, '/')) {
    if (part.empty() || part == ".") continue;
    if (part == "..") {
      if (parts.empty()) {
        return absl::InvalidArgumentError(
            absl::StrCat("file name '", reference, "' escapes the scene directory with '..'"));
      }
      parts.pop_back();
      continue;
    }
    parts.push_back(part);
  }
  if (parts.empty()) {
    return absl::InvalidArgumentError(
        absl::StrCat("file name '", reference, "' does not name a file"));
  }
  return absl::StrJoin(parts, "/");
}

absl::Status check_plain_relative_path(std::string_view path_in) {
  absl::string_view path(path_in.data(), path_in.size());
  PRISM_RETURN_IF_ERROR(check_bytes(path));
  for (absl::string_view part : absl::StrSplit(path, '/')) {
    if (part.empty()) {
      return absl::InvalidArgumentError(absl::StrCat("path '", path, "' has an empty component"));
    }
    if (part == "." || part == "..") {
      return absl::InvalidArgumentError(
          absl::StrCat("path '", path, "' has a '", part, "' component"));
    }
  }
  return absl::OkStatus();
}

bool is_within(const fs::path& path, const fs::path& root) {
  auto [root_end, path_it] = std::mismatch(root.begin(), root.end(), path.begin(), path.end());
  if (root_end == root.end()) return true;
  // "/a/b/" iterates with a trailing empty component; it still contains "/a/b/c".
  return std::next(root_end) == root.end() && root_end->empty();
}

absl::StatusOr<PathGuard> PathGuard::create(const fs::path& root) {
  std::error_code ec;
  fs::path canonical = fs::canonical(root, ec);
  if (ec) {
    return absl::NotFoundError(
        absl::StrCat("scene directory ", root.string(), " not found: ", ec.message()));
  }
  if (!fs::is_directory(canonical, ec)) {
    return absl::InvalidArgumentError(
        absl::StrCat("scene directory ", root.string(), " is not a directory"));
  }
  return PathGuard(std::move(canonical));
}

absl::StatusOr<fs::path> PathGuard::resolve(std::string_view reference) const {
  PRISM_ASSIGN_OR_RETURN(ResolvedReference resolved, resolve_reference(reference));
  return std::move(resolved.real_path);
}

absl::StatusOr<ResolvedReference> PathGuard::resolve_reference(
    std::string_view reference_in) const {
  absl::string_view reference(reference_in.data(), reference_in.size());
  PRISM_ASSIGN_OR_RETURN(std::string relative, normalize_reference(reference_in));
  std::error_code ec;
  fs::path real = fs::canonical(root_ / relative, ec);
  if (ec) {
    if (ec == std::errc::no_such_file_or_directory || ec == std::errc::not_a_directory) {
      return absl::NotFoundError(
          absl::StrCat("file '", reference, "' not found in ", root_.string()));
    }
    return absl::InvalidArgumentError(
        absl::StrCat("cannot resolve file '", reference, "': ", ec.message()));
  }
  if (!is_within(real, root_)) {
    return absl::InvalidArgumentError(absl::StrCat("file '", reference, "' resolves to ",
                                                   real.string(), ", outside the scene directory ",
                                                   root_.string(), " (through a symbolic link)"));
  }
  if (!fs::is_regular_file(real, ec)) {
    return absl::InvalidArgumentError(absl::StrCat("file '", reference, "' is not a regular file"));
  }
  return ResolvedReference{std::move(real), std::move(relative)};
}

}  // namespace prism::scene
