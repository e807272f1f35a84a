// A position in a scene file, for messages. Every parse and validation error of the scene
// parser is an INVALID_ARGUMENT (or NOT_FOUND / RESOURCE_EXHAUSTED for files) whose message
// starts with `file:line:column: `; `file` is the path relative to the scene root (or the
// name given to an in-memory parse), line and column are 1-based, columns count bytes.
#pragma once

#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"

namespace prism::scene {

// This absl is built with its own string_view (ABSL_OPTION_USE_STD_STRING_VIEW 0); StrCat and
// friends need std::string_view arguments converted.
inline absl::string_view absl_view(std::string_view s) { return absl::string_view(s.data(), s.size()); }

struct SourceLocation {
  std::string file;
  int line = 0;
  int column = 0;

  std::string to_string() const { return absl::StrCat(file, ":", line, ":", column); }
};

inline absl::Status location_error(const SourceLocation& where, std::string_view message) {
  return absl::InvalidArgumentError(absl::StrCat(where.to_string(), ": ", absl_view(message)));
}

// Re-labels a status that came from elsewhere (a mesh loader, a path check) with a location,
// keeping its code.
inline absl::Status located(const SourceLocation& where, const absl::Status& status) {
  return absl::Status(status.code(), absl::StrCat(where.to_string(), ": ", status.message()));
}

}  // namespace prism::scene
