#include "services/spectral/embedded_data.h"

#include <string>

#include "services/base/check.h"

namespace prism::spectral {

std::string_view embedded_file(std::string_view path) {
  for (const EmbeddedFile& file : embedded_files()) {
    if (file.path == path) return file.text;
  }
  PRISM_CHECK_MSG(false, std::string(path).c_str());
  return {};
}

}  // namespace prism::spectral
