// Prism's APIs take std::string_view; the installed Abseil is built with its own
// absl::string_view (ABSL_OPTION_USE_STD_STRING_VIEW = 0), which has no conversion from
// std::string_view. This bridge is the one place the two meet. Internal to services/spectral.
#pragma once

#include <string_view>

#include "absl/strings/string_view.h"

namespace prism::spectral {

inline absl::string_view to_absl(std::string_view s) {
  return absl::string_view(s.data(), s.size());
}
inline std::string_view to_std(absl::string_view s) {
  return std::string_view(s.data(), s.size());
}

}  // namespace prism::spectral
