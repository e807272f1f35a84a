#include "coordinator/poisson_batch.h"

#include <cstring>

namespace prism::coordinator::poisson_batch {
namespace {

template <typename V, typename T>
V load(const T* p) {
  V v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <typename T, typename V>
void store(T* p, const V& v) {
  std::memcpy(p, &v, sizeof v);
}

// A batch's lanes, as compiler vector types (GCC/Clang): the compiler maps them onto
// whatever SIMD the target has, and every lane is plain IEEE arithmetic, so the results
// are the same bits as the scalar path's.
using F4 = float __attribute__((vector_size(16)));

// W doubles per SIMD register: 2 for SSE2 (every x86-64), 4 for AVX2, 8 for AVX-512. The
// kBatch lanes of a batch are N = kBatch/W registers. (GCC ignores vector_size on a dependent type,
// hence the explicit types.)
using F2 = float __attribute__((vector_size(8)));
using D2 = double __attribute__((vector_size(16)));
using D4 = double __attribute__((vector_size(32)));
template <int W>
struct LaneTypes;
template <>
struct LaneTypes<2> {
  using D = D2;
  using F = F2;
};
template <>
struct LaneTypes<4> {
  using D = D4;
  using F = F4;
};

using F8 = float __attribute__((vector_size(32)));
using D8 = double __attribute__((vector_size(64)));
template <>
struct LaneTypes<8> {
  using D = D8;
  using F = F8;
};

template <int W>
struct Lanes {
  using D = typename LaneTypes<W>::D;
  using F = typename LaneTypes<W>::F;
  static constexpr int N = kBatch / W;

  // kBatch floats at p, widened.
  [[gnu::always_inline]] static void widen(const float* p, D (&d)[N]) {
    for (int q = 0; q < N; ++q) {
      F f;
      std::memcpy(&f, p + W * q, sizeof f);
      d[q] = __builtin_convertvector(f, D);
    }
  }
  // kBatch doubles rounded to floats at p; adds f − f to `check` (0 for finite f, NaN else).
  [[gnu::always_inline]] static void narrow(const D (&d)[N], float* p, F (&check)[N]) {
    for (int q = 0; q < N; ++q) {
      const F f = __builtin_convertvector(d[q], F);
      check[q] += f - f;
      std::memcpy(p + W * q, &f, sizeof f);
    }
  }
};

[[gnu::always_inline]] inline void transpose4(F4& r0, F4& r1, F4& r2, F4& r3) {
  const F4 t0 = __builtin_shufflevector(r0, r1, 0, 4, 1, 5);
  const F4 t1 = __builtin_shufflevector(r0, r1, 2, 6, 3, 7);
  const F4 t2 = __builtin_shufflevector(r2, r3, 0, 4, 1, 5);
  const F4 t3 = __builtin_shufflevector(r2, r3, 2, 6, 3, 7);
  r0 = __builtin_shufflevector(t0, t2, 0, 1, 4, 5);
  r1 = __builtin_shufflevector(t0, t2, 2, 3, 6, 7);
  r2 = __builtin_shufflevector(t1, t3, 0, 1, 4, 5);
  r3 = __builtin_shufflevector(t1, t3, 2, 3, 6, 7);
}

// A 4x4 block of floats from rows `in` (stride in_stride) to columns of `out` (stride out_stride).
[[gnu::always_inline]] inline void transpose_block(const float* in, int in_stride, float* out,
                                                   int out_stride) {
  F4 r0 = load<F4>(in);
  F4 r1 = load<F4>(in + in_stride);
  F4 r2 = load<F4>(in + 2 * in_stride);
  F4 r3 = load<F4>(in + 3 * in_stride);
  transpose4(r0, r1, r2, r3);
  store(out, r0);
  store(out + out_stride, r1);
  store(out + 2 * out_stride, r2);
  store(out + 3 * out_stride, r3);
}

// kBatch pixels of B values between pixel-major (p·B + b) and bin-major (b·kBatch + p) layouts,
// by 4x4 blocks: to bin-major when kToBinMajor, back otherwise. One group of four pixels at a
// time, so the pixel-major side walks four contiguous rows (prefetch friendly) rather than all
// kBatch rows at once.
template <bool kToBinMajor>
[[gnu::always_inline]] inline void transpose_batch(const float* from, int B, float* to) {
  const int B4 = B & ~3;
  for (int g = 0; g < kBatch; g += 4) {
    for (int b = 0; b < B4; b += 4) {
      if constexpr (kToBinMajor) {
        transpose_block(from + g * B + b, B, to + b * kBatch + g, kBatch);
      } else {
        transpose_block(from + b * kBatch + g, kBatch, to + g * B + b, B);
      }
    }
  }
  for (int b = B4; b < B; ++b) {
    for (int p = 0; p < kBatch; ++p) {
      if constexpr (kToBinMajor) {
        to[b * kBatch + p] = from[p * B + b];
      } else {
        to[p * B + b] = from[b * kBatch + p];
      }
    }
  }
}

// kBatch pixels (kBatch·B consecutive values of each array) side by side in SIMD lanes. The
// lanes need the pixels bin-major, so I and G are transposed into t[b·kBatch + p] (4x4 blocks),
// the recurrences run one bin row of kBatch lanes at a time (r is formed on the way: G[b − k]
// is the previous chain element's G), and the bin-major result is transposed back. `z` holds
// kBatch·L doubles, `t` 3·(kBatch·B + kPad) floats.

// The body of solve_l2_batch for W doubles per register (see there). Inlined into each
// caller, so the AVX2 caller compiles it with 256-bit registers.
template <int W>
[[gnu::always_inline]] inline bool batch_kernel(const int* order_all, const double* pw, int chains,
                                                int B, int L, double a, double rho, double inv,
                                                double q, const float* primal,
                                                const float* gradient, float* out, double* z,
                                                float* t, const float* next_primal,
                                                const float* next_gradient, float* next_out) {
  using V = Lanes<W>;
  using D = typename V::D;
  using F = typename V::F;
  constexpr int N = V::N;
  float* ti = t;
  float* tg = t + kBatch * B + kPad;
  float* to = tg + kBatch * B + kPad;
  transpose_batch<true>(primal, B, ti);
  transpose_batch<true>(gradient, B, tg);
  F check[N] = {};
  for (int c = 0; c < chains; ++c) {
    const int* order = order_all + c * L;
    D zl[N] = {};
    D sz[N] = {};
    D g_prev[N];
    V::widen(tg + order[L - 1] * kBatch, g_prev);
    for (int j = 0; j < L; ++j) {
      // The next batch's inputs and output, kBatch/16 cache lines of each per step (chains·L = B
      // steps cover its kBatch·B floats, 16 per line): fetching them while this batch computes
      // keeps the stream from memory going (0.35 → 0.6 of memcpy at 64 bins, docs/benchmarks.md).
      if (next_primal != nullptr) {
        for (int l = 0; l < kBatch / 16; ++l) {
          const int line = ((c * L + j) * (kBatch / 16) + l) * 16;
          __builtin_prefetch(next_primal + line);
          __builtin_prefetch(next_gradient + line);
          __builtin_prefetch(next_out + line, 1);  // for writing
        }
      }
      const int b = order[j];
      D iv[N], gv[N];
      V::widen(ti + b * kBatch, iv);
      V::widen(tg + b * kBatch, gv);
      const double wj = pw[j];
      for (int k = 0; k < N; ++k) {
        const D r = a * iv[k] + g_prev[k] - gv[k];
        g_prev[k] = gv[k];
        zl[k] = rho * (r + zl[k]);
        std::memcpy(z + j * kBatch + W * k, &zl[k], sizeof(D));
        sz[k] += wj * zl[k];
      }
    }
    D u_last[N], x[N];
    for (int k = 0; k < N; ++k) {
      u_last[k] = zl[k] * inv;
      x[k] = (sz[k] + u_last[k] * q) * inv;
    }
    V::narrow(x, to + order[0] * kBatch, check);
    for (int j = L - 1; j >= 1; --j) {
      const double corr = pw[j + 1];
      for (int k = 0; k < N; ++k) {
        D zj;
        std::memcpy(&zj, z + j * kBatch + W * k, sizeof(D));
        x[k] = zj + corr * u_last[k] + rho * x[k];
      }
      V::narrow(x, to + order[j] * kBatch, check);
    }
  }
  transpose_batch<false>(to, B, out);
  float all = 0;
  for (int k = 0; k < N; ++k) {
    for (int p = 0; p < W; ++p) all += check[k][p];
  }
  return all == 0;
}

}  // namespace

bool batch_sse2(const int* order, const double* pw, int chains, int B, int L, double a, double rho,
                double inv, double q, const float* primal, const float* gradient, float* out,
                double* z, float* t, const float* next_primal, const float* next_gradient,
                float* next_out) {
  return batch_kernel<2>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t,
                         next_primal, next_gradient, next_out);
}

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
// AVX2 without FMA: the same IEEE operations in the same order, four lanes per register, so
// the bits do not depend on which version runs (no fused multiply-add is available to it).
[[gnu::target("avx2")]] bool batch_avx2(const int* order, const double* pw, int chains, int B,
                                        int L, double a, double rho, double inv, double q,
                                        const float* primal, const float* gradient, float* out,
                                        double* z, float* t, const float* next_primal,
                                        const float* next_gradient, float* next_out) {
  return batch_kernel<4>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t,
                         next_primal, next_gradient, next_out);
}
bool cpu_supports(PoissonKernel kernel) {
  switch (kernel) {
    case PoissonKernel::kAvx512:
      return __builtin_cpu_supports("avx512f");
    case PoissonKernel::kAvx2:
      return __builtin_cpu_supports("avx2");
    default:
      return kernel == PoissonKernel::kSse2;
  }
}
// AVX-512F, eight lanes per register; as for AVX2, poisson.cpp is compiled with
// -ffp-contract=off, so the FMA instructions AVX-512F brings are never used.
[[gnu::target("avx512f")]] bool batch_avx512(const int* order, const double* pw, int chains, int B,
                                             int L, double a, double rho, double inv, double q,
                                             const float* primal, const float* gradient, float* out,
                                             double* z, float* t, const float* next_primal,
                                             const float* next_gradient, float* next_out) {
  return batch_kernel<8>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t,
                         next_primal, next_gradient, next_out);
}
#else
bool batch_avx2(const int* order, const double* pw, int chains, int B, int L, double a, double rho,
                double inv, double q, const float* primal, const float* gradient, float* out,
                double* z, float* t, const float* next_primal, const float* next_gradient,
                float* next_out) {
  return batch_kernel<2>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t,
                         next_primal, next_gradient, next_out);
}
bool batch_avx512(const int* order, const double* pw, int chains, int B, int L, double a,
                  double rho, double inv, double q, const float* primal, const float* gradient,
                  float* out, double* z, float* t, const float* next_primal,
                  const float* next_gradient, float* next_out) {
  return batch_kernel<2>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t,
                         next_primal, next_gradient, next_out);
}
bool cpu_supports(PoissonKernel kernel) {
  return kernel == PoissonKernel::kSse2;
}
#endif

}  // namespace prism::coordinator::poisson_batch
