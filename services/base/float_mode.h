// The floating-point mode of every thread a Prism binary runs: denormal results flushed to
// zero (FTZ) and denormal inputs read as zero (DAZ), as Embree recommends for its traversal.
//
// Embree turns both on in the threads that run its BVH builds and leaves them on, so without a
// process-wide choice a value could depend on which thread computed it: `prism render` filtered
// a gathered image partly on such threads and the coordinator on fresh ones, and their bytes
// differed in values below 1e-38. A new thread starts with its creator's mode (POSIX), so each
// binary sets it first thing in main(), before it starts any thread.
#pragma once

#if defined(__SSE__) || defined(__x86_64__)
#include <xmmintrin.h>
#endif

namespace prism::base {

inline void flush_denormals_to_zero() {
#if defined(__SSE__) || defined(__x86_64__)
  constexpr unsigned kFlushToZero = 0x8000;       // MXCSR.FTZ
  constexpr unsigned kDenormalsAreZero = 0x0040;  // MXCSR.DAZ
  _mm_setcsr(_mm_getcsr() | kFlushToZero | kDenormalsAreZero);
#endif
}

}  // namespace prism::base
