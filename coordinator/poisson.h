// Per-pixel 1D screened Poisson reconstruction of spectral gradient sampling
// (docs/estimators.md §5).
//
// For one pixel with B bins, primal estimate I and gradient estimate G (G[b] estimates
// I[b+k] − I[b], bins cyclic), the L2 reconstruction is
//     Î = argmin ‖DÎ − G‖² + α‖Î − I‖²,   (DÎ)[b] = Î[b+k] − Î[b]  (indices mod B),
// whose normal equations (αI + DᵀD)Î = αI + DᵀG read, bin by bin,
//     (α + 2)Î[b] − Î[b−k] − Î[b+k] = α·I[b] + G[b−k] − G[b].
// Bin b only meets b ± k, so the system splits into g = gcd(B, k) independent cyclic chains
// b, b+k, b+2k, ... (mod B) of length L = B/g ≥ 2, each a constant-coefficient cyclic
// tridiagonal system solved exactly in O(L) (poisson.cpp derives the factorisation). The solve
// preserves Σ_b Î = Σ_b I (summing the normal equations) and, G being unbiased, is unbiased.
//
// Pixels are independent: any set of pixels (a tile, a row, one pixel) is reconstructed on its
// own with the same result bit for bit, so tiles are reconstructed as soon as they complete.
//
// The L1 option minimises σ‖DÎ − G‖₁ + α‖Î − I‖² by iteratively reweighted least squares
// (IRLS), σ being the mean |DÎ₂ − G| of the pixel's L2 solution Î₂, so that a gradient whose
// residual has the typical size σ weighs as in L2 and the result scales with the input. It is
// robust to outlier gradients but, unlike L2, slightly biased; it runs a fixed number of
// iterations (kIrlsIterations), so it is deterministic but not converged to machine precision.
//
// Non-finite input is refused, per call: a NaN or infinite I[b] or G[b] makes the call return
// INVALID_ARGUMENT naming the pixel and bin (a pixel's reconstruction mixes all bins of its
// chain, so one bad value would silently poison its neighbours). A result that overflows float
// is OUT_OF_RANGE. On error the contents of `out` are unspecified. Arithmetic is in double;
// results are rounded once to float.
#pragma once

#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/image/tile.h"
#include "services/job/job_parameters.h"

namespace prism::coordinator {

// Fixed IRLS iteration count of the L1 solve (after the L2 start).
inline constexpr int kIrlsIterations = 12;

// Which SIMD code the batched L2 path runs. Every kernel performs the same IEEE operations in the
// same order (poisson.cpp is compiled without FMA contraction), so they give identical bits;
// the choice only changes speed. kAuto takes the widest the CPU supports; asking for one the
// CPU lacks gives kSse2 (generic two-lane vector code, which runs on any target).
enum class PoissonKernel { kAuto, kSse2, kAvx2, kAvx512 };
std::string_view to_string(PoissonKernel kernel);

// The solver for one (B, k, α): immutable once built, shared freely between threads.
class PoissonSolver {
 public:
  // INVALID_ARGUMENT naming the value unless 4 <= bins <= image::kMaxChannels,
  // 1 <= offset_bins < bins and α is finite and in [job::kMinPoissonAlpha, job::kMaxPoissonAlpha].
  static absl::StatusOr<PoissonSolver> create(int bins, int offset_bins, double alpha,
                                              PoissonKernel kernel = PoissonKernel::kAuto);

  int bins() const { return bins_; }
  int offset_bins() const { return k_; }
  double alpha() const { return alpha_; }
  int chains() const { return chains_; }
  int chain_length() const { return length_; }
  // The kernel in use (never kAuto).
  PoissonKernel kernel() const { return kernel_; }

  // One pixel: `primal`, `gradient` and `out` each hold bins() values; `out` must not overlap
  // the inputs. INVALID_ARGUMENT on a size mismatch or non-finite input. No allocation.
  absl::Status solve_l2(std::span<const float> primal, std::span<const float> gradient,
                        std::span<float> out) const;
  // Same for the L1 objective; allocates its scratch (about 8·bins doubles) per call, which
  // solve_pixels amortises over many pixels.
  absl::Status solve_l1(std::span<const float> primal, std::span<const float> gradient,
                        std::span<float> out) const;

  // The variance-weighted L2 reconstruction of one pixel (issue 12): instead of one α for all,
  //   Î = argmin Σ_b ((DÎ)[b] − G[b])² / v_G[b] + Σ_b (Î[b] − I[b])² / v_I[b],
  // v_I and v_G estimates of the variances of the pixel's means I[b] and G[b] (only their ratios
  // matter; tile_finaliser.h says where they come from), each raised to at
  // least kVarianceFloor times its mean over the pixel's bins (a bin no sample landed in has
  // v = 0, but its value is not known exactly). Noisy bins lean on their neighbours through the
  // gradients, noisy gradients on the primal. The same O(L) cyclic solve per chain, with
  // per-bin weights; α is not used. Consistent gradients (G = DI) return I whatever the
  // weights, so with weights independent of I and G the result is unbiased, and with weights
  // estimated from the same samples it is consistent. A pixel whose mean v_I or v_G is 0
  // (nothing varies, or no gradient was measured) returns I. Errors as solve_l2, and
  // INVALID_ARGUMENT for a negative or non-finite variance. Allocates nothing (at most
  // 8·image::kMaxChannels doubles of stack).
  absl::Status solve_weighted(std::span<const float> primal, std::span<const float> gradient,
                              std::span<const float> primal_variance,
                              std::span<const float> gradient_variance, std::span<float> out) const;
  static constexpr double kVarianceFloor = 0.05;

  // Many pixels, pixel-interleaved: pixel p's bins are [p·bins(), (p+1)·bins()) of each span.
  // All three spans have the same size, a multiple of bins(). Errors name the pixel's index in
  // the spans, or (index, image_row) when image_row >= 0 (the spans are that row of an image).
  // Allocates one scratch buffer per call, none per pixel.
  absl::Status solve_pixels(job::PoissonNorm norm, std::span<const float> primal,
                            std::span<const float> gradient, std::span<float> out,
                            int image_row = -1) const;

 private:
  PoissonSolver() = default;

  bool solve_l2_one(const float* primal, const float* gradient, float* out, double* scratch) const;
  // `next_primal`, `next_gradient`, `next_out`: the next batch's, prefetched (nullptr: none).
  bool solve_l2_batch(const float* primal, const float* gradient, float* out, double* z, float* t,
                      const float* next_primal, const float* next_gradient, float* next_out) const;
  void solve_l1_pixel(const float* primal, const float* gradient, float* out,
                      double* scratch) const;

  int bins_ = 0;
  int k_ = 0;
  double alpha_ = 0;
  int chains_ = 0;
  int length_ = 0;
  // Chain order: chain c's j-th bin is order_[c·L + j] = (c + j·k) mod B.
  std::vector<int> order_;
  // The factorisation's constants (poisson.cpp): ρ, ρ^(j+1) for j < L, 1/(1 − ρ^L) and
  // Q = Σ_{m<L} ρ^(2m+1).
  double rho_ = 0;
  std::vector<double> rho_pow_;
  double inv_one_minus_rho_l_ = 0;
  double q_ = 0;
  PoissonKernel kernel_ = PoissonKernel::kSse2;
};

// Reconstructs a whole image: `primal` and `gradient` must have the same width, height and
// bins (INVALID_ARGUMENT naming both sizes otherwise; bins must equal solver.bins()). Rows
// are solved in parallel in the calling TBB arena; the result does not depend on the number
// of threads. Errors name the pixel (x, y) and bin.
absl::StatusOr<image::SpectralImage> reconstruct_image(const PoissonSolver& solver,
                                                       job::PoissonNorm norm,
                                                       const image::SpectralImage& primal,
                                                       const image::SpectralImage& gradient);

}  // namespace prism::coordinator
