#include "services/base/check.h"

#include <cstdio>
#include <cstdlib>

namespace prism::base {

void check_failed(const char* condition, const char* file, int line, const char* message) {
  std::fprintf(stderr, "prism: invariant violated at %s:%d: %s%s%s\n", file, line, condition,
               message ? ": " : "", message ? message : "");
  std::fflush(stderr);
  std::abort();
}

}  // namespace prism::base
