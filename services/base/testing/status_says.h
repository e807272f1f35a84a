// Test helper: whether a status's message contains `text`, for tests that check what an error
// says (file, field, limit) as well as its code.
#pragma once

#include <string>
#include <string_view>

#include "absl/status/status.h"

namespace prism {

inline bool status_says(const absl::Status& status, std::string_view text) {
  return std::string(status.message()).find(text) != std::string::npos;
}

}  // namespace prism
