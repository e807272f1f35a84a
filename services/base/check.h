// Invariant checks. A broken invariant is a bug in Prism, never bad input: PRISM_CHECK prints
// the condition and its location and aborts, in every build type. Untrusted input and the
// environment are reported with absl::Status values instead (see status.h).
#pragma once

namespace prism::base {

[[noreturn]] void check_failed(const char* condition, const char* file, int line, const char* message);

}  // namespace prism::base

#define PRISM_CHECK(cond)                                                      \
  do {                                                                         \
    if (!(cond)) [[unlikely]]                                                  \
      ::prism::base::check_failed(#cond, __FILE__, __LINE__, nullptr);         \
  } while (false)

#define PRISM_CHECK_MSG(cond, msg)                                             \
  do {                                                                         \
    if (!(cond)) [[unlikely]]                                                  \
      ::prism::base::check_failed(#cond, __FILE__, __LINE__, (msg));           \
  } while (false)
