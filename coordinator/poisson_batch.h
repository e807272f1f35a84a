// The batched L2 Poisson solve's SIMD kernels (PoissonSolver::solve_l2_batch, poisson.h): kBatch
// pixels side by side in SIMD lanes, the same IEEE operations in the same order in every
// version (SSE2, AVX2, AVX-512F; compiled with -ffp-contract=off like poisson.cpp, so no fused
// multiply-add), so the bits do not depend on which one runs. Internal to the Poisson solver.
#pragma once

#include "coordinator/poisson.h"

namespace prism::coordinator::poisson_batch {

// Pixels solved together by the L2 fast path (solve_l2_batch): their recurrences are
// independent, so they run in SIMD lanes, and enough of them (4 AVX2 registers) are in flight
// that the lanes do not wait on one recurrence's add-multiply latency.
constexpr int kBatch = 16;

// Floats between the batch's three bin-major buffers. Without it, for B = 64 they sit exactly
// 4 KiB apart, and the loads of one row alias the stores of another in the CPU's 4K-address
// disambiguation, stalling on false dependencies; 24 floats shift them by 96 bytes.
constexpr int kPad = 24;

// The kernels: `order` the chains' bin orders (chains × L), `pw` the per-bin weights, a, rho,
// inv, q the factorisation's constants, kBatch pixels of primal, gradient and out (kBatch·B
// values each); `z` holds kBatch·L doubles, `t` 3·(kBatch·B + kPad) floats; next_primal,
// next_gradient and next_out the next batch's, prefetched while this one computes (nullptr:
// none).
// False when a value is not finite.
bool batch_sse2(const int* order, const double* pw, int chains, int B, int L, double a, double rho,
                double inv, double q, const float* primal, const float* gradient, float* out,
                double* z, float* t, const float* next_primal, const float* next_gradient,
                float* next_out);
bool batch_avx2(const int* order, const double* pw, int chains, int B, int L, double a, double rho,
                double inv, double q, const float* primal, const float* gradient, float* out,
                double* z, float* t, const float* next_primal, const float* next_gradient,
                float* next_out);
bool batch_avx512(const int* order, const double* pw, int chains, int B, int L, double a,
                  double rho, double inv, double q, const float* primal, const float* gradient,
                  float* out, double* z, float* t, const float* next_primal,
                  const float* next_gradient, float* next_out);
// Whether this CPU runs the kernel (SSE2 always on x86-64).
bool cpu_supports(PoissonKernel kernel);

}  // namespace prism::coordinator::poisson_batch
