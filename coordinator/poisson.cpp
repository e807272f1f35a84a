#include "coordinator/poisson.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::coordinator {
namespace {

// Pixels solved together by the L2 fast path (solve_l2_batch): their recurrences are
// independent, so they run in SIMD lanes, and enough of them (4 AVX2 registers) are in flight
// that the lanes do not wait on one recurrence's add-multiply latency.
constexpr int kBatch = 16;

// Floats between the batch's three bin-major buffers. Without it, for B = 64 they sit exactly
// 4 KiB apart, and the loads of one row alias the stores of another in the CPU's 4K-address
// disambiguation, stalling on false dependencies; 24 floats shift them by 96 bytes.
constexpr int kPad = 24;

// IRLS weight floor: a residual below kIrlsFloor·σ weighs as one of size kIrlsFloor·σ, so the
// weights stay within [0, 1/kIrlsFloor] and every reweighted system stays well conditioned.
constexpr double kIrlsFloor = 1e-3;

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

// kBatch pixels of B values, pixel-major (in[p·B + b]), to bin-major t[b·kBatch + p], by
// 4x4 blocks.
[[gnu::always_inline]] inline void to_bin_major(const float* in, int B, float* t) {
  const int B4 = B & ~3;
  // One group of four pixels at a time, so the loads walk four contiguous rows (prefetch
  // friendly) rather than all kBatch rows at once.
  for (int g = 0; g < kBatch; g += 4) {
    for (int b = 0; b < B4; b += 4) {
      F4 r0 = load<F4>(in + (g + 0) * B + b);
      F4 r1 = load<F4>(in + (g + 1) * B + b);
      F4 r2 = load<F4>(in + (g + 2) * B + b);
      F4 r3 = load<F4>(in + (g + 3) * B + b);
      transpose4(r0, r1, r2, r3);
      store(t + (b + 0) * kBatch + g, r0);
      store(t + (b + 1) * kBatch + g, r1);
      store(t + (b + 2) * kBatch + g, r2);
      store(t + (b + 3) * kBatch + g, r3);
    }
  }
  for (int b = B4; b < B; ++b) {
    for (int p = 0; p < kBatch; ++p) t[b * kBatch + p] = in[p * B + b];
  }
}

// The inverse of to_bin_major.
[[gnu::always_inline]] inline void to_pixel_major(const float* t, int B, float* out) {
  const int B4 = B & ~3;
  for (int g = 0; g < kBatch; g += 4) {
    for (int b = 0; b < B4; b += 4) {
      F4 r0 = load<F4>(t + (b + 0) * kBatch + g);
      F4 r1 = load<F4>(t + (b + 1) * kBatch + g);
      F4 r2 = load<F4>(t + (b + 2) * kBatch + g);
      F4 r3 = load<F4>(t + (b + 3) * kBatch + g);
      transpose4(r0, r1, r2, r3);
      store(out + (g + 0) * B + b, r0);
      store(out + (g + 1) * B + b, r1);
      store(out + (g + 2) * B + b, r2);
      store(out + (g + 3) * B + b, r3);
    }
  }
  for (int b = B4; b < B; ++b) {
    for (int p = 0; p < kBatch; ++p) out[p * B + b] = t[b * kBatch + p];
  }
}

bool finite(float v) {
  return std::isfinite(v);
}

// Defined with the batch kernels below.
bool cpu_supports(PoissonKernel kernel);

std::string describe(float v) {
  if (std::isnan(v)) return "nan";
  return v > 0 ? "inf" : "-inf";
}

std::string value_text(float v) {
  return std::isfinite(v) ? absl::StrCat(v) : describe(v);
}

// Where a failed run went wrong: a non-finite input value or an overflowing result.
struct Fault {
  std::int64_t pixel = 0;
  int bin = 0;
  std::string what;  // "primal", "gradient" or "result"
  float value = 0;
};

// The first fault among pixels [first, first + count); the inputs are checked before the
// outputs so that a bad input is reported as such and not as the overflow it caused.
Fault locate_fault(std::span<const float> primal, std::span<const float> gradient,
                   std::span<const float> out, int bins, std::int64_t first, std::int64_t count) {
  const std::size_t begin = static_cast<std::size_t>(first) * bins;
  const std::size_t end = static_cast<std::size_t>(first + count) * bins;
  for (std::size_t i = begin; i < end; ++i) {
    if (!finite(primal[i])) return {std::int64_t(i / bins), int(i % bins), "primal", primal[i]};
    if (!finite(gradient[i])) {
      return {std::int64_t(i / bins), int(i % bins), "gradient", gradient[i]};
    }
  }
  for (std::size_t i = begin; i < end; ++i) {
    if (!finite(out[i])) return {std::int64_t(i / bins), int(i % bins), "result", out[i]};
  }
  PRISM_CHECK_MSG(false, "a Poisson run failed without a non-finite value");
}

absl::Status fault_status(const Fault& fault, const std::string& pixel) {
  if (fault.what == "result") {
    return absl::OutOfRangeError(absl::StrCat("Poisson reconstruction of pixel ", pixel,
                                              " overflows float in bin ", fault.bin));
  }
  return absl::InvalidArgumentError(
      absl::StrCat("Poisson reconstruction: pixel ", pixel, " ", fault.what, "[", fault.bin,
                   "] = ", describe(fault.value), "; non-finite input is refused"));
}

// Solves the symmetric cyclic tridiagonal system of one weighted chain in place of `x`:
//   row j: (a[j] + w[j−1] + w[j])·x[j] − w[j−1]·x[j−1] − w[j]·x[j+1] = rhs[j]   (indices mod L),
// the normal equations of Σ_j w[j](x[j+1] − x[j] − G[j])² + Σ_j a[j](x[j] − I[j])²; `a` is a
// callable giving a[j] (α for every j in the global-α solves). The matrix is strictly
// diagonally dominant (a > 0, w >= 0), so elimination without pivoting is stable.
// L = 2: both neighbours are the same element and the row is a 2x2 system, solved directly.
// L >= 3: Sherman–Morrison on the tridiagonal part (Numerical Recipes' `cyclic`): with
// γ = −d[0] the corners move into a rank-one update u·vᵀ, u = (γ, 0, ..., 0, A[L−1][0]),
// v = (1, 0, ..., 0, A[0][L−1]/γ), and the modified diagonal d[0] − γ = 2d[0],
// d[L−1] − A[L−1][0]·A[0][L−1]/γ = d[L−1] + w[L−1]²/d[0] stays dominant.
// `cp`, `dp`, `dz` are scratch of L doubles.
template <typename Data>
void solve_chain(int L, const Data& a, const double* w, const double* rhs, double* x, double* cp,
                 double* dp, double* dz) {
  if (L == 2) {
    const double e = w[0] + w[1];
    const double a0 = a(0), a1 = a(1);
    const double det = a0 * a1 + e * (a0 + a1);  // (a0 + e)(a1 + e) − e², without cancellation
    const double x0 = ((a1 + e) * rhs[0] + e * rhs[1]) / det;
    const double x1 = (e * rhs[0] + (a0 + e) * rhs[1]) / det;
    x[0] = x0;
    x[1] = x1;
    return;
  }
  const double corner = -w[L - 1];  // A[0][L−1] = A[L−1][0]
  const double d0 = a(0) + w[L - 1] + w[0];
  const double gamma = -d0;
  auto diag = [&](int j) {
    if (j == 0) return d0 - gamma;
    const double d = a(j) + w[j - 1] + w[j];
    return j == L - 1 ? d - corner * corner / gamma : d;
  };
  // Thomas elimination for T·x = rhs and T·z = u at once; super[j] = −w[j], sub[j] = −w[j−1].
  double denom = diag(0);
  cp[0] = -w[0] / denom;
  dp[0] = rhs[0] / denom;
  dz[0] = gamma / denom;
  for (int j = 1; j < L; ++j) {
    const double sub = -w[j - 1];
    denom = diag(j) - sub * cp[j - 1];
    cp[j] = j < L - 1 ? -w[j] / denom : 0.0;
    const double uj = j == L - 1 ? corner : 0.0;
    dp[j] = (rhs[j] - sub * dp[j - 1]) / denom;
    dz[j] = (uj - sub * dz[j - 1]) / denom;
  }
  for (int j = L - 2; j >= 0; --j) {
    dp[j] -= cp[j] * dp[j + 1];
    dz[j] -= cp[j] * dz[j + 1];
  }
  const double fact =
      (dp[0] + corner * dp[L - 1] / gamma) / (1.0 + dz[0] + corner * dz[L - 1] / gamma);
  for (int j = 0; j < L; ++j) x[j] = dp[j] - fact * dz[j];
}

void solve_weighted_chain(int L, double alpha, const double* w, const double* rhs, double* x,
                          double* cp, double* dp, double* dz) {
  solve_chain(
      L, [alpha](int) { return alpha; }, w, rhs, x, cp, dp, dz);
}

absl::Status check_one_pixel(int bins, std::span<const float> primal,
                             std::span<const float> gradient, std::span<const float> out) {
  const std::size_t B = static_cast<std::size_t>(bins);
  if (primal.size() == B && gradient.size() == B && out.size() == B) return absl::OkStatus();
  return absl::InvalidArgumentError(absl::StrCat(
      "Poisson reconstruction: primal, gradient and output have ", primal.size(), ", ",
      gradient.size(), " and ", out.size(), " values; want ", bins, " (the bins) each"));
}

}  // namespace

std::string_view to_string(PoissonKernel kernel) {
  switch (kernel) {
    case PoissonKernel::kAuto:
      return "auto";
    case PoissonKernel::kSse2:
      return "sse2";
    case PoissonKernel::kAvx2:
      return "avx2";
    case PoissonKernel::kAvx512:
      return "avx512";
  }
  return "?";
}

// The L2 factorisation. Along a chain (x_j = Î[b_j], b_j = c + j·k mod B) the system is
//   (α + 2)·x_j − x_{j−1} − x_{j+1} = r_j,   r_j = α·I[b_j] + G[b_{j−1}] − G[b_j],
// i.e. A = (α + 2)·Id − S − S⁻¹ with the cyclic shift (Sx)_j = x_{j−1}. With ρ the root in
// (0, 1) of ρ + 1/ρ = α + 2,
//   A = (1/ρ)·(Id − ρS)·(Id − ρS⁻¹),
// which holds for every L >= 1 because S·S⁻¹ = Id (for L = 2, S = S⁻¹ and A's two off-diagonal
// −1s land on the same element, as the normal equations require). So A·x = r is
//   u_j = ρ·r_j + ρ·u_{j−1}   then   x_j = u_j + ρ·x_{j+1},   both cyclic.
// A cyclic first-order recurrence is the open one plus a geometric correction: with z the
// recurrence started from z_{−1} = 0, u_j = z_j + ρ^(j+1)·U where U = u_{L−1} = z_{L−1}/(1 − ρ^L).
// Unrolling the backward recurrence once around the cycle gives
//   x_0 = Σ_{m<L} ρ^m·u_m / (1 − ρ^L) = (Σ_m ρ^m·z_m + U·Q) / (1 − ρ^L),  Q = Σ_{m<L} ρ^(2m+1),
// and then x_j = u_j + ρ·x_{j+1} for j = L−1 down to 1 (x_L = x_0). Two passes per chain. Both
// recurrences multiply by ρ < 1, so rounding errors are damped, never amplified; the
// intermediates are bounded by |r|/(1 − ρ)², the same order as the solution's bound |r|/α.
// ρ = 2/(α + 2 + √(α(α + 4))) and 1 − ρ^L = −expm1(L·log1p(−(1 − ρ))) avoid cancellation for
// both tiny and large α.
absl::StatusOr<PoissonSolver> PoissonSolver::create(int bins, int offset_bins, double alpha,
                                                    PoissonKernel kernel) {
  if (bins < 4 || bins > image::kMaxChannels) {
    return absl::InvalidArgumentError(
        absl::StrCat("Poisson reconstruction: bins = ", bins, "; want 4..", image::kMaxChannels));
  }
  if (offset_bins < 1 || offset_bins >= bins) {
    return absl::InvalidArgumentError(
        absl::StrCat("Poisson reconstruction: gradient offset k = ", offset_bins,
                     " bins; want 1 <= k < ", bins, " (the number of bins)"));
  }
  if (!std::isfinite(alpha) || alpha < job::kMinPoissonAlpha || alpha > job::kMaxPoissonAlpha) {
    return absl::InvalidArgumentError(
        absl::StrCat("Poisson reconstruction: alpha = ", alpha, "; want a finite value in [",
                     job::kMinPoissonAlpha, ", ", job::kMaxPoissonAlpha, "] (alpha must be > 0)"));
  }
  PoissonSolver s;
  s.bins_ = bins;
  s.k_ = offset_bins;
  s.alpha_ = alpha;
  s.chains_ = std::gcd(bins, offset_bins);
  s.length_ = bins / s.chains_;
  const int L = s.length_;
  s.order_.resize(bins);
  for (int c = 0; c < s.chains_; ++c) {
    for (int j = 0; j < L; ++j) {
      const int b = static_cast<int>((c + std::int64_t{j} * offset_bins) % bins);
      s.order_[c * L + j] = b;
    }
  }
  const double root = std::sqrt(alpha * (alpha + 4.0));
  s.rho_ = 2.0 / (alpha + 2.0 + root);
  const double one_minus_rho = (alpha + root) / (alpha + 2.0 + root);
  const double log_rho = std::log1p(-one_minus_rho);
  s.inv_one_minus_rho_l_ = -1.0 / std::expm1(L * log_rho);
  s.rho_pow_.resize(L + 1);
  double q = 0;
  for (int j = 0; j <= L; ++j) {
    s.rho_pow_[j] = std::exp(j * log_rho);
    if (j < L) q += std::exp((2.0 * j + 1.0) * log_rho);
  }
  s.q_ = q;
  s.kernel_ = PoissonKernel::kSse2;
  for (PoissonKernel k : {PoissonKernel::kAvx512, PoissonKernel::kAvx2}) {
    if ((kernel == PoissonKernel::kAuto || kernel == k) && cpu_supports(k)) {
      s.kernel_ = k;
      break;
    }
  }
  return s;
}

// The L2 solve of one pixel, the reference path; solve_l2_batch does the same arithmetic in
// the same order on kBatch pixels at once, so both give the same bits.
//  1. r[b] = α·I[b] + G[b − k] − G[b], the right-hand side, in bin order (b − k wraps only
//     for b < k); `scratch` holds B + L doubles: r, then z.
//  2. Per chain, the two recurrences of the factorisation above, writing rounded results.
// Returns false when a result is not finite, which includes every non-finite input: a NaN or
// infinity in I or G enters some r_j, makes every later z of its chain and hence
// U = z_{L−1}/(1 − ρ^L) non-finite, and every x_j of the chain adds ρ^(j+1)·U (0·inf is NaN
// too). The caller then locates the value. The test is f − f summed: 0 for finite f, NaN
// otherwise, and branch-free.
bool PoissonSolver::solve_l2_one(const float* primal, const float* gradient, float* out,
                                 double* scratch) const {
  const int B = bins_;
  const int L = length_;
  const int k = k_;
  const double a = alpha_;
  const double rho = rho_;
  const double inv = inv_one_minus_rho_l_;
  const double* pw = rho_pow_.data();
  double* r = scratch;
  double* z = scratch + B;
  for (int b = 0; b < k; ++b) r[b] = a * primal[b] + gradient[b - k + B] - gradient[b];
  for (int b = k; b < B; ++b) r[b] = a * primal[b] + gradient[b - k] - gradient[b];
  float check = 0;
  for (int c = 0; c < chains_; ++c) {
    const int* order = order_.data() + c * L;
    double zl = 0;
    double sz = 0;
    for (int j = 0; j < L; ++j) {
      zl = rho * (r[order[j]] + zl);
      z[j] = zl;
      sz += pw[j] * zl;
    }
    const double u_last = zl * inv;
    double x = (sz + u_last * q_) * inv;
    float f = static_cast<float>(x);
    check += f - f;
    out[order[0]] = f;
    for (int j = L - 1; j >= 1; --j) {
      x = z[j] + pw[j + 1] * u_last + rho * x;
      f = static_cast<float>(x);
      check += f - f;
      out[order[j]] = f;
    }
  }
  return check == 0;
}

// kBatch pixels (kBatch·B consecutive values of each array) side by side in SIMD lanes. The
// lanes need the pixels bin-major, so I and G are transposed into t[b·kBatch + p] (4x4 blocks),
// the recurrences run one bin row of kBatch lanes at a time (r is formed on the way: G[b − k]
// is the previous chain element's G), and the bin-major result is transposed back. `z` holds
// kBatch·L doubles, `t` 3·(kBatch·B + kPad) floats.
namespace {

// The body of solve_l2_batch for W doubles per register (see there). Inlined into each
// caller, so the AVX2 caller compiles it with 256-bit registers.
template <int W>
[[gnu::always_inline]] inline bool batch_kernel(const int* order_all, const double* pw, int chains,
                                                int B, int L, double a, double rho, double inv,
                                                double q, const float* primal,
                                                const float* gradient, float* out, double* z,
                                                float* t) {
  using V = Lanes<W>;
  using D = typename V::D;
  using F = typename V::F;
  constexpr int N = V::N;
  float* ti = t;
  float* tg = t + kBatch * B + kPad;
  float* to = tg + kBatch * B + kPad;
  to_bin_major(primal, B, ti);
  to_bin_major(gradient, B, tg);
  F check[N] = {};
  for (int c = 0; c < chains; ++c) {
    const int* order = order_all + c * L;
    D zl[N] = {};
    D sz[N] = {};
    D g_prev[N];
    V::widen(tg + order[L - 1] * kBatch, g_prev);
    for (int j = 0; j < L; ++j) {
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
  to_pixel_major(to, B, out);
  float all = 0;
  for (int k = 0; k < N; ++k) {
    for (int p = 0; p < W; ++p) all += check[k][p];
  }
  return all == 0;
}

bool batch_sse2(const int* order, const double* pw, int chains, int B, int L, double a, double rho,
                double inv, double q, const float* primal, const float* gradient, float* out,
                double* z, float* t) {
  return batch_kernel<2>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t);
}

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
// AVX2 without FMA: the same IEEE operations in the same order, four lanes per register, so
// the bits do not depend on which version runs (no fused multiply-add is available to it).
[[gnu::target("avx2")]] bool batch_avx2(const int* order, const double* pw, int chains, int B,
                                        int L, double a, double rho, double inv, double q,
                                        const float* primal, const float* gradient, float* out,
                                        double* z, float* t) {
  return batch_kernel<4>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t);
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
                                             double* z, float* t) {
  return batch_kernel<8>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t);
}
#else
bool batch_avx2(const int* order, const double* pw, int chains, int B, int L, double a, double rho,
                double inv, double q, const float* primal, const float* gradient, float* out,
                double* z, float* t) {
  return batch_kernel<2>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t);
}
bool batch_avx512(const int* order, const double* pw, int chains, int B, int L, double a,
                  double rho, double inv, double q, const float* primal, const float* gradient,
                  float* out, double* z, float* t) {
  return batch_kernel<2>(order, pw, chains, B, L, a, rho, inv, q, primal, gradient, out, z, t);
}
bool cpu_supports(PoissonKernel kernel) {
  return kernel == PoissonKernel::kSse2;
}
#endif

}  // namespace

bool PoissonSolver::solve_l2_batch(const float* primal, const float* gradient, float* out,
                                   double* z, float* t) const {
  auto* run = kernel_ == PoissonKernel::kAvx512 ? batch_avx512
              : kernel_ == PoissonKernel::kAvx2 ? batch_avx2
                                                : batch_sse2;
  return run(order_.data(), rho_pow_.data(), chains_, bins_, length_, alpha_, rho_,
             inv_one_minus_rho_l_, q_, primal, gradient, out, z, t);
}

// One pixel's L1 reconstruction: scratch holds 8·B doubles.
void PoissonSolver::solve_l1_pixel(const float* primal, const float* gradient, float* out,
                                   double* scratch) const {
  const int B = bins_;
  const int L = length_;
  double* x_all = scratch;   // B: every chain's solution, chain order
  double* iv = scratch + B;  // L each below
  double* gv = iv + L;
  double* w = gv + L;
  double* rhs = w + L;
  double* cp = rhs + L;
  double* dp = cp + L;
  double* dz = dp + L;
  auto gather = [&](int c) {
    for (int j = 0; j < L; ++j) {
      iv[j] = primal[order_[c * L + j]];
      gv[j] = gradient[order_[c * L + j]];
    }
  };
  auto build_rhs = [&]() {
    for (int j = 0; j < L; ++j) {
      const int jp = j == 0 ? L - 1 : j - 1;
      rhs[j] = alpha_ * iv[j] + w[jp] * gv[jp] - w[j] * gv[j];
    }
  };
  auto residual = [&](const double* x, int j) { return x[j == L - 1 ? 0 : j + 1] - x[j] - gv[j]; };
  // The L2 start (all weights 1) and σ, the mean absolute gradient residual of the pixel.
  double sigma = 0;
  for (int c = 0; c < chains_; ++c) {
    gather(c);
    std::fill(w, w + L, 1.0);
    build_rhs();
    double* x = x_all + c * L;
    solve_weighted_chain(L, alpha_, w, rhs, x, cp, dp, dz);
    for (int j = 0; j < L; ++j) sigma += std::abs(residual(x, j));
  }
  sigma /= B;
  // σ = 0: the L2 solution fits every gradient exactly; the L1 objective's gradient term is
  // then zero for it too, and reweighting has nothing to act on.
  if (sigma > 0 && std::isfinite(sigma)) {
    const double floor = kIrlsFloor * sigma;
    for (int c = 0; c < chains_; ++c) {
      gather(c);
      double* x = x_all + c * L;
      for (int it = 0; it < kIrlsIterations; ++it) {
        // Minimising Σ w_j·r_j² with w_j = σ/|r_j| at the current iterate reproduces σ·Σ|r_j|
        // there; iterating is the IRLS fixed point of the L1 objective.
        for (int j = 0; j < L; ++j) w[j] = sigma / std::max(std::abs(residual(x, j)), floor);
        build_rhs();
        solve_weighted_chain(L, alpha_, w, rhs, x, cp, dp, dz);
      }
    }
  }
  for (int c = 0; c < chains_; ++c) {
    for (int j = 0; j < L; ++j) out[order_[c * L + j]] = static_cast<float>(x_all[c * L + j]);
  }
}

absl::Status PoissonSolver::solve_l2(std::span<const float> primal, std::span<const float> gradient,
                                     std::span<float> out) const {
  PRISM_RETURN_IF_ERROR(check_one_pixel(bins_, primal, gradient, out));
  // 2·image::kMaxChannels doubles at most (64 KiB); this path allocates nothing.
  double scratch[2 * image::kMaxChannels];
  if (solve_l2_one(primal.data(), gradient.data(), out.data(), scratch)) {
    return absl::OkStatus();
  }
  return fault_status(locate_fault(primal, gradient, out, bins_, 0, 1), "0");
}

absl::Status PoissonSolver::solve_weighted(std::span<const float> primal,
                                           std::span<const float> gradient,
                                           std::span<const float> primal_variance,
                                           std::span<const float> gradient_variance,
                                           std::span<float> out) const {
  PRISM_RETURN_IF_ERROR(check_one_pixel(bins_, primal, gradient, out));
  const std::size_t B = static_cast<std::size_t>(bins_);
  if (primal_variance.size() != B || gradient_variance.size() != B) {
    return absl::InvalidArgumentError(
        absl::StrCat("Poisson reconstruction: ", primal_variance.size(), " primal and ",
                     gradient_variance.size(), " gradient variances; want ", bins_, " (the bins)"));
  }
  double mean_i = 0, mean_g = 0;
  for (std::size_t b = 0; b < B; ++b) {
    if (!finite(primal[b]) || !finite(gradient[b])) {
      return fault_status(locate_fault(primal, gradient, out, bins_, 0, 1), "0");
    }
    const float vi = primal_variance[b], vg = gradient_variance[b];
    if (!(vi >= 0.0f) || !(vg >= 0.0f) || !finite(vi) || !finite(vg)) {
      return absl::InvalidArgumentError(
          absl::StrCat("Poisson reconstruction: pixel 0 variance[", b, "] = ", value_text(vi),
                       " / ", value_text(vg), " (primal / gradient); want finite values >= 0"));
    }
    mean_i += vi;
    mean_g += vg;
  }
  mean_i /= double(B);
  mean_g /= double(B);
  if (!(mean_i > 0) || !(mean_g > 0)) {
    std::copy(primal.begin(), primal.end(), out.begin());
    return absl::OkStatus();
  }
  // Weights scaled by the mean primal variance (the solution does not change), so they are of
  // order 1 and bounded by 1/kVarianceFloor relative to each other within each term.
  double a[image::kMaxChannels], w_all[image::kMaxChannels];
  for (std::size_t b = 0; b < B; ++b) {
    a[b] = mean_i / std::max(double(primal_variance[b]), kVarianceFloor * mean_i);
    w_all[b] = mean_i / std::max(double(gradient_variance[b]), kVarianceFloor * mean_g);
  }
  const int L = length_;
  double chain_a[image::kMaxChannels], w[image::kMaxChannels], rhs[image::kMaxChannels],
      x[image::kMaxChannels];
  double cp[image::kMaxChannels], dp[image::kMaxChannels], dz[image::kMaxChannels];
  for (int c = 0; c < chains_; ++c) {
    const int* order = order_.data() + c * L;
    for (int j = 0; j < L; ++j) {
      chain_a[j] = a[order[j]];
      w[j] = w_all[order[j]];
    }
    for (int j = 0; j < L; ++j) {
      const int jp = j == 0 ? L - 1 : j - 1;
      rhs[j] =
          chain_a[j] * primal[order[j]] + w[jp] * gradient[order[jp]] - w[j] * gradient[order[j]];
    }
    solve_chain(
        L, [&](int j) { return chain_a[j]; }, w, rhs, x, cp, dp, dz);
    for (int j = 0; j < L; ++j) out[order[j]] = static_cast<float>(x[j]);
  }
  for (std::size_t b = 0; b < B; ++b) {
    if (!finite(out[b])) return fault_status(locate_fault(primal, gradient, out, bins_, 0, 1), "0");
  }
  return absl::OkStatus();
}

absl::Status PoissonSolver::solve_l1(std::span<const float> primal, std::span<const float> gradient,
                                     std::span<float> out) const {
  PRISM_RETURN_IF_ERROR(check_one_pixel(bins_, primal, gradient, out));
  return solve_pixels(job::PoissonNorm::kL1, primal, gradient, out);
}

absl::Status PoissonSolver::solve_pixels(job::PoissonNorm norm, std::span<const float> primal,
                                         std::span<const float> gradient, std::span<float> out,
                                         int image_row) const {
  const std::size_t B = static_cast<std::size_t>(bins_);
  if (primal.size() != gradient.size() || primal.size() != out.size() || primal.size() % B != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("Poisson reconstruction: primal, gradient and output have ", primal.size(),
                     ", ", gradient.size(), " and ", out.size(),
                     " values; want the same multiple of ", bins_, " (the bins)"));
  }
  if (norm == job::PoissonNorm::kWeighted) {
    return absl::InvalidArgumentError(
        "the variance-weighted reconstruction needs each pixel's variances: use solve_weighted");
  }
  const std::int64_t pixels = static_cast<std::int64_t>(primal.size() / B);
  std::vector<double> scratch(norm == job::PoissonNorm::kL2 ? std::size_t(kBatch) * length_ + B
                                                            : 8 * B);
  std::vector<float> t_buffer(norm == job::PoissonNorm::kL2 ? 3 * (std::size_t(kBatch) * B + kPad)
                                                            : 0);
  std::int64_t p = 0;
  auto fail = [&](std::int64_t count) {
    const Fault fault = locate_fault(primal, gradient, out, bins_, p, count);
    return fault_status(fault, image_row < 0
                                   ? absl::StrCat(fault.pixel)
                                   : absl::StrCat("(", fault.pixel, ", ", image_row, ")"));
  };
  if (norm == job::PoissonNorm::kL2) {
    for (; p + kBatch <= pixels; p += kBatch) {
      const std::size_t o = static_cast<std::size_t>(p) * B;
      if (!solve_l2_batch(primal.data() + o, gradient.data() + o, out.data() + o, scratch.data(),
                          t_buffer.data())) {
        return fail(kBatch);
      }
    }
    for (; p < pixels; ++p) {
      const std::size_t o = static_cast<std::size_t>(p) * B;
      if (!solve_l2_one(primal.data() + o, gradient.data() + o, out.data() + o, scratch.data())) {
        return fail(1);
      }
    }
    return absl::OkStatus();
  }
  for (; p < pixels; ++p) {
    const std::size_t o = static_cast<std::size_t>(p) * B;
    // IRLS divides by residuals, so the inputs are checked before rather than after.
    bool ok = true;
    for (std::size_t i = o; i < o + B; ++i) ok = ok && finite(primal[i]) && finite(gradient[i]);
    if (ok) {
      solve_l1_pixel(primal.data() + o, gradient.data() + o, out.data() + o, scratch.data());
      for (std::size_t i = o; i < o + B; ++i) ok = ok && finite(out[i]);
    }
    if (!ok) return fail(1);
  }
  return absl::OkStatus();
}

absl::StatusOr<image::SpectralImage> reconstruct_image(const PoissonSolver& solver,
                                                       job::PoissonNorm norm,
                                                       const image::SpectralImage& primal,
                                                       const image::SpectralImage& gradient) {
  if (primal.width() != gradient.width() || primal.height() != gradient.height() ||
      primal.bins() != gradient.bins()) {
    return absl::InvalidArgumentError(
        absl::StrCat("Poisson reconstruction: primal is ", primal.width(), "x", primal.height(),
                     " with ", primal.bins(), " bins but gradient is ", gradient.width(), "x",
                     gradient.height(), " with ", gradient.bins(), " bins"));
  }
  if (primal.bins() != solver.bins()) {
    return absl::InvalidArgumentError(
        absl::StrCat("Poisson reconstruction: the images have ", primal.bins(),
                     " bins but the solver was built for ", solver.bins()));
  }
  PRISM_ASSIGN_OR_RETURN(
      image::SpectralImage out,
      image::SpectralImage::create(primal.width(), primal.height(), primal.bins()));
  const std::size_t row = static_cast<std::size_t>(primal.width()) * primal.bins();
  std::vector<absl::Status> row_status(primal.height());
  tbb::parallel_for(
      tbb::blocked_range<int>(0, primal.height()), [&](const tbb::blocked_range<int>& rows) {
        for (int y = rows.begin(); y < rows.end(); ++y) {
          const std::size_t o = static_cast<std::size_t>(y) * row;
          row_status[y] =
              solver.solve_pixels(norm, primal.data().subspan(o, row),
                                  gradient.data().subspan(o, row), out.data().subspan(o, row), y);
        }
      });
  // The first failing row in raster order, so the message does not depend on scheduling.
  for (const absl::Status& status : row_status) {
    if (!status.ok()) return status;
  }
  return out;
}

}  // namespace prism::coordinator
