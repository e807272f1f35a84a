#include "coordinator/poisson.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>

#include "absl/strings/str_cat.h"
#include "coordinator/poisson_batch.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::coordinator {
namespace {

using poisson_batch::kBatch;
using poisson_batch::kPad;

// IRLS weight floor: a residual below kIrlsFloor·σ weighs as one of size kIrlsFloor·σ, so the
// weights stay within [0, 1/kIrlsFloor] and every reweighted system stays well conditioned.
constexpr double kIrlsFloor = 1e-3;

bool finite(float v) {
  return std::isfinite(v);
}

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
    if ((kernel == PoissonKernel::kAuto || kernel == k) && poisson_batch::cpu_supports(k)) {
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

bool PoissonSolver::solve_l2_batch(const float* primal, const float* gradient, float* out,
                                   double* z, float* t, const float* next_primal,
                                   const float* next_gradient, float* next_out) const {
  auto* run = kernel_ == PoissonKernel::kAvx512 ? poisson_batch::batch_avx512
              : kernel_ == PoissonKernel::kAvx2 ? poisson_batch::batch_avx2
                                                : poisson_batch::batch_sse2;
  return run(order_.data(), rho_pow_.data(), chains_, bins_, length_, alpha_, rho_,
             inv_one_minus_rho_l_, q_, primal, gradient, out, z, t, next_primal, next_gradient,
             next_out);
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
      const bool next = p + 2 * kBatch <= pixels;
      const std::size_t n = o + std::size_t(kBatch) * B;
      if (!solve_l2_batch(primal.data() + o, gradient.data() + o, out.data() + o, scratch.data(),
                          t_buffer.data(), next ? primal.data() + n : nullptr,
                          next ? gradient.data() + n : nullptr, next ? out.data() + n : nullptr)) {
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
