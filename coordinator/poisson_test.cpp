#include "coordinator/poisson.h"

#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <iostream>
#include <limits>
#include <numbers>
#include <numeric>
#include <random>
#include <vector>

namespace prism::coordinator {
namespace {

using Complex = std::complex<long double>;

// The oracle, derived from D rather than copied. With the DFT X^[j] = Σ_b x[b]·e^{−2πi·jb/B},
// a cyclic advance y[b] = x[b+k] has Y^[j] = e^{+2πi·jk/B}·X^[j], so D (x[b+k] − x[b]) is the
// multiplier d_j = e^{2πi·jk/B} − 1, its transpose (Dᵀy)[b] = y[b−k] − y[b] is conj(d_j), and
// the normal equations (α + DᵀD)Î = αI + DᵀG become
//   Î^[j] = (α·I^[j] + conj(d_j)·G^[j]) / (α + |d_j|²).
// Evaluated by a direct O(B²) DFT in long double with exactly reduced twiddle angles
// (j·b mod B), so its own error (~B·2^-64·κ) is far below the solver's.
std::vector<long double> oracle(const std::vector<float>& primal,
                                const std::vector<float>& gradient, int k, double alpha) {
  const int B = static_cast<int>(primal.size());
  auto twiddle = [B](long long m, int sign) {
    const long double angle = sign * 2.0L * std::numbers::pi_v<long double> * (m % B) / B;
    return Complex(std::cos(angle), std::sin(angle));
  };
  std::vector<Complex> spectrum(B);
  for (int j = 0; j < B; ++j) {
    Complex ih = 0, gh = 0;
    for (int b = 0; b < B; ++b) {
      const Complex t = twiddle(static_cast<long long>(j) * b, -1);
      ih += static_cast<long double>(primal[b]) * t;
      gh += static_cast<long double>(gradient[b]) * t;
    }
    const Complex d = twiddle(static_cast<long long>(j) * k, +1) - 1.0L;
    spectrum[j] = (static_cast<long double>(alpha) * ih + std::conj(d) * gh) /
                  (static_cast<long double>(alpha) + std::norm(d));
  }
  std::vector<long double> result(B);
  for (int b = 0; b < B; ++b) {
    Complex sum = 0;
    for (int j = 0; j < B; ++j) sum += spectrum[j] * twiddle(static_cast<long long>(j) * b, +1);
    result[b] = sum.real() / B;
  }
  return result;
}

std::vector<float> random_values(std::mt19937_64& rng, int n, float lo, float hi) {
  std::uniform_real_distribution<float> dist(lo, hi);
  std::vector<float> v(n);
  for (float& x : v) x = dist(rng);
  return v;
}

// Offsets for B: small ones, one sharing a factor with B (gcd > 1), B/2 when even (chains of
// length 2), the default round(0.15·B) and B − 1.
std::vector<int> offsets_for(int bins) {
  std::vector<int> ks = {1, 2, 3, static_cast<int>(std::lround(0.15 * bins)), bins - 1};
  if (bins == 15) ks.insert(ks.end(), {5, 6, 10});
  if (bins == 16) ks.insert(ks.end(), {4, 6, 8, 12});
  if (bins == 64) ks.insert(ks.end(), {16, 24, 32});
  if (bins == 100) ks.insert(ks.end(), {15, 25, 50, 75});
  return ks;
}

const int kBinCounts[] = {15, 16, 64, 100};
const double kAlphas[] = {1e-4, 0.2, 1.0, 1e3};

TEST(PoissonSolver, ChainStructure) {
  auto a = PoissonSolver::create(64, 10, 0.2);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->chains(), 2);
  EXPECT_EQ(a->chain_length(), 32);
  auto b = PoissonSolver::create(16, 8, 0.2);
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(b->chains(), 8);
  EXPECT_EQ(b->chain_length(), 2);
  auto c = PoissonSolver::create(15, 14, 0.2);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->chains(), 1);
  EXPECT_EQ(c->chain_length(), 15);
}

// Bound: the solver works in double and rounds once to float. Rounding contributes at most
// 2^-24·|Î[b]| <= 2^-24·max|Î|. The double solve is backward stable (two contracting
// recurrences per chain), so its forward error is at most a modest multiple of
// B·κ·2^-53·max|Î|, κ = (α + 4)/α being the condition number of αI + DᵀD (eigenvalues
// α + |d_j|² in [α, α + 4]); 16·B·κ·2^-53 covers it with room, and the oracle's long-double
// error is ~2^-11 times smaller still. Any mistake in the factorisation, the chain order, the
// sign of D or the corner terms is an O(1) relative error.
TEST(PoissonSolver, MatchesDftOracle) {
  std::mt19937_64 rng(0x5eed);
  int cases = 0;
  for (int bins : kBinCounts) {
    for (int k : offsets_for(bins)) {
      for (double alpha : kAlphas) {
        auto solver = PoissonSolver::create(bins, k, alpha);
        ASSERT_TRUE(solver.ok()) << solver.status();
        const double kappa = (alpha + 4.0) / alpha;
        const double bound = std::ldexp(1.0, -24) + 16.0 * bins * kappa * std::ldexp(1.0, -53);
        for (int trial = 0; trial < 3; ++trial) {
          const std::vector<float> primal = random_values(rng, bins, -0.5f, 2.0f);
          const std::vector<float> gradient = random_values(rng, bins, -1.0f, 1.0f);
          std::vector<float> out(bins);
          ASSERT_TRUE(solver->solve_l2(primal, gradient, out).ok());
          const std::vector<long double> expected = oracle(primal, gradient, k, alpha);
          long double scale = 0, error = 0;
          for (int b = 0; b < bins; ++b) {
            scale = std::max(scale, std::abs(expected[b]));
            error = std::max(error, std::abs(static_cast<long double>(out[b]) - expected[b]));
          }
          ASSERT_GT(scale, 0);
          EXPECT_LE(error / scale, bound)
              << "B " << bins << " k " << k << " alpha " << alpha << " trial " << trial;
          ++cases;
        }
      }
    }
  }
  EXPECT_GT(cases, 300);
}

// The batched path (16 pixels at a time, then single pixels) gives the same bits as one pixel
// at a time, so tiles and rows can be solved independently, and so does every SIMD kernel the
// CPU has (on a CPU without one, the fallback is tested twice).
TEST(PoissonSolver, BatchedEqualsPerPixel) {
  std::mt19937_64 rng(7);
  for (auto [bins, kernel] : {std::pair{15, PoissonKernel::kAuto},
                              {64, PoissonKernel::kAuto},
                              {64, PoissonKernel::kSse2},
                              {64, PoissonKernel::kAvx2},
                              {100, PoissonKernel::kAvx512},
                              {100, PoissonKernel::kSse2}}) {
    auto solver =
        PoissonSolver::create(bins, static_cast<int>(std::lround(0.15 * bins)), 0.2, kernel);
    ASSERT_TRUE(solver.ok());
    EXPECT_NE(solver->kernel(), PoissonKernel::kAuto);
    if (kernel != PoissonKernel::kAuto && solver->kernel() != kernel) {
      std::cout << "kernel " << to_string(kernel) << " unavailable, tested "
                << to_string(solver->kernel()) << "\n";
    }
    const int pixels = 35;  // two batches and a tail of three
    const std::vector<float> primal = random_values(rng, pixels * bins, 0.0f, 4.0f);
    const std::vector<float> gradient = random_values(rng, pixels * bins, -2.0f, 2.0f);
    for (job::PoissonNorm norm : {job::PoissonNorm::kL2, job::PoissonNorm::kL1}) {
      std::vector<float> batched(primal.size());
      ASSERT_TRUE(solver->solve_pixels(norm, primal, gradient, batched).ok());
      for (int p = 0; p < pixels; ++p) {
        std::vector<float> single(bins);
        const auto in = std::span(primal).subspan(p * bins, bins);
        const auto grad = std::span(gradient).subspan(p * bins, bins);
        const absl::Status status = norm == job::PoissonNorm::kL2
                                        ? solver->solve_l2(in, grad, single)
                                        : solver->solve_l1(in, grad, single);
        ASSERT_TRUE(status.ok());
        for (int b = 0; b < bins; ++b) {
          EXPECT_EQ(batched[p * bins + b], single[b]) << "pixel " << p << " bin " << b;
        }
      }
    }
  }
}

// G = DI exactly: then Î = I solves the normal equations. Values in [1, 2) make every float
// difference I[b+k] − I[b] exact (Sterbenz), and the double solution lies within ~κ·2^-50 of
// I[b], far inside half an ulp of the float I[b], so it rounds back to exactly I[b].
TEST(PoissonSolver, ConsistentGradientsReturnThePrimal) {
  std::mt19937_64 rng(11);
  for (int bins : kBinCounts) {
    for (int k : offsets_for(bins)) {
      for (double alpha : kAlphas) {
        auto solver = PoissonSolver::create(bins, k, alpha);
        ASSERT_TRUE(solver.ok());
        const std::vector<float> primal = random_values(rng, bins, 1.0f, 2.0f);
        std::vector<float> gradient(bins);
        for (int b = 0; b < bins; ++b) gradient[b] = primal[(b + k) % bins] - primal[b];
        std::vector<float> l2(bins), l1(bins);
        ASSERT_TRUE(solver->solve_l2(primal, gradient, l2).ok());
        ASSERT_TRUE(solver->solve_l1(primal, gradient, l1).ok());
        for (int b = 0; b < bins; ++b) {
          EXPECT_EQ(l2[b], primal[b]) << "B " << bins << " k " << k << " alpha " << alpha;
          // L1 reweights by residuals of size ~2^-50 (rounding), still a consistent system:
          // the same argument gives I to within rounding of the reweighted solve.
          EXPECT_NEAR(l1[b], primal[b], 4 * std::ldexp(1.0f, -23))
              << "B " << bins << " k " << k << " alpha " << alpha;
        }
      }
    }
  }
}

// Σ_b Î = Σ_b I: summing the normal equations, ΣDᵀ(·) = 0. In floats: the solve's double error
// is negligible, and rounding Î to float moves the sum by at most 2^-24·Σ|Î|.
TEST(PoissonSolver, PreservesTheSum) {
  std::mt19937_64 rng(13);
  for (int bins : kBinCounts) {
    for (int k : offsets_for(bins)) {
      for (double alpha : kAlphas) {
        auto solver = PoissonSolver::create(bins, k, alpha);
        ASSERT_TRUE(solver.ok());
        const std::vector<float> primal = random_values(rng, bins, 0.0f, 3.0f);
        const std::vector<float> gradient = random_values(rng, bins, -5.0f, 5.0f);
        std::vector<float> out(bins);
        ASSERT_TRUE(solver->solve_l2(primal, gradient, out).ok());
        double sum_in = 0, sum_out = 0, sum_abs = 0;
        for (int b = 0; b < bins; ++b) {
          sum_in += primal[b];
          sum_out += out[b];
          sum_abs += std::abs(out[b]);
        }
        const double kappa = (alpha + 4.0) / alpha;
        EXPECT_NEAR(sum_out, sum_in,
                    sum_abs * (std::ldexp(1.0, -24) + 16.0 * bins * kappa * std::ldexp(1.0, -53)))
            << "B " << bins << " k " << k << " alpha " << alpha;
      }
    }
  }
}

// Scaling I and G by a power of two scales every intermediate exactly, so the result scales
// bit for bit; for L1 this checks that σ makes the objective scale-equivariant.
TEST(PoissonSolver, ScalesWithTheInput) {
  std::mt19937_64 rng(17);
  auto solver = PoissonSolver::create(64, 10, 0.2);
  ASSERT_TRUE(solver.ok());
  const std::vector<float> primal = random_values(rng, 64, 0.0f, 3.0f);
  const std::vector<float> gradient = random_values(rng, 64, -1.0f, 1.0f);
  std::vector<float> p2(64), g2(64);
  for (int b = 0; b < 64; ++b) {
    p2[b] = std::ldexp(primal[b], 10);
    g2[b] = std::ldexp(gradient[b], 10);
  }
  for (job::PoissonNorm norm : {job::PoissonNorm::kL2, job::PoissonNorm::kL1}) {
    std::vector<float> a(64), b(64);
    ASSERT_TRUE(solver->solve_pixels(norm, primal, gradient, a).ok());
    ASSERT_TRUE(solver->solve_pixels(norm, p2, g2, b).ok());
    for (int i = 0; i < 64; ++i) EXPECT_EQ(b[i], std::ldexp(a[i], 10)) << to_string(norm);
  }
}

// A real robustness property: the truth T, a noisy primal I = T + noise and exact gradients DT
// with one gradient corrupted by a large outlier. L2 spreads the outlier over the chain; L1
// down-weights it, so its result is closer to T, in every trial.
TEST(PoissonSolver, L1IsRobustToAnOutlierGradient) {
  std::mt19937_64 rng(19);
  std::normal_distribution<float> noise(0.0f, 0.05f);
  for (int bins : {15, 64}) {
    for (int k : {static_cast<int>(std::lround(0.15 * bins)), 1}) {
      auto solver = PoissonSolver::create(bins, k, 0.2);
      ASSERT_TRUE(solver.ok());
      for (int trial = 0; trial < 10; ++trial) {
        const std::vector<float> truth = random_values(rng, bins, 0.5f, 1.5f);
        std::vector<float> primal(bins), gradient(bins);
        for (int b = 0; b < bins; ++b) {
          primal[b] = truth[b] + noise(rng);
          gradient[b] = truth[(b + k) % bins] - truth[b];
        }
        gradient[trial % bins] += 5.0f;
        std::vector<float> l2(bins), l1(bins);
        ASSERT_TRUE(solver->solve_l2(primal, gradient, l2).ok());
        ASSERT_TRUE(solver->solve_l1(primal, gradient, l1).ok());
        double e1 = 0, e2 = 0;
        for (int b = 0; b < bins; ++b) {
          e1 += std::pow(l1[b] - truth[b], 2.0);
          e2 += std::pow(l2[b] - truth[b], 2.0);
        }
        EXPECT_LT(e1, e2) << "B " << bins << " k " << k << " trial " << trial;
      }
    }
  }
}

TEST(PoissonSolver, RefusesBadParameters) {
  struct Bad {
    int bins, k;
    double alpha;
    const char* message;
  };
  const Bad bad[] = {
      {64, 10, 0.0, "alpha = 0"},
      {64, 10, -0.2, "alpha = -0.2"},
      {64, 10, std::nan(""), "alpha = nan"},
      {64, 10, std::numeric_limits<double>::infinity(), "alpha = inf"},
      {64, 10, 1e-9, "alpha = 1e-09"},
      {64, 10, 1e9, "alpha = 1e+09"},
      {64, 0, 0.2, "k = 0"},
      {64, -3, 0.2, "k = -3"},
      {64, 64, 0.2, "k = 64"},
      {64, 70, 0.2, "k = 70"},
      {3, 1, 0.2, "bins = 3"},
      {4097, 10, 0.2, "bins = 4097"},
  };
  for (const Bad& b : bad) {
    auto solver = PoissonSolver::create(b.bins, b.k, b.alpha);
    ASSERT_FALSE(solver.ok()) << b.message;
    EXPECT_EQ(solver.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(solver.status().message().find(b.message), std::string::npos)
        << solver.status().message();
  }
  EXPECT_TRUE(PoissonSolver::create(4, 3, job::kMinPoissonAlpha).ok());
  EXPECT_TRUE(PoissonSolver::create(4096, 1, job::kMaxPoissonAlpha).ok());
}

TEST(PoissonSolver, RefusesBadInput) {
  auto solver = PoissonSolver::create(16, 3, 0.2);
  ASSERT_TRUE(solver.ok());
  std::vector<float> primal(16, 1.0f), gradient(16, 0.0f), out(16), short_out(15);

  absl::Status sizes = solver->solve_l2(primal, gradient, short_out);
  EXPECT_EQ(sizes.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(sizes.message().find("16, 16 and 15 values"), std::string::npos) << sizes;
  EXPECT_EQ(solver->solve_l1(primal, gradient, short_out).code(),
            absl::StatusCode::kInvalidArgument);
  std::vector<float> two(32);
  EXPECT_EQ(solver->solve_pixels(job::PoissonNorm::kL2, two, two, out).code(),
            absl::StatusCode::kInvalidArgument);

  for (job::PoissonNorm norm : {job::PoissonNorm::kL2, job::PoissonNorm::kL1}) {
    std::vector<float> bad_primal = primal;
    bad_primal[5] = std::nanf("");
    absl::Status s = solver->solve_pixels(norm, bad_primal, gradient, out);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(s.message().find("pixel 0 primal[5] = nan"), std::string::npos) << s;

    std::vector<float> bad_gradient = gradient;
    bad_gradient[3] = -std::numeric_limits<float>::infinity();
    s = solver->solve_pixels(norm, primal, bad_gradient, out);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(s.message().find("gradient[3] = -inf"), std::string::npos) << s;

    // Pixel 21 of 40: inside the second batch of the L2 path.
    std::vector<float> many(40 * 16, 1.0f), many_g(40 * 16, 0.0f), many_out(40 * 16);
    many_g[21 * 16 + 7] = std::numeric_limits<float>::infinity();
    s = solver->solve_pixels(norm, many, many_g, many_out);
    EXPECT_NE(s.message().find("pixel 21 gradient[7] = inf"), std::string::npos) << s;

    // Finite input whose reconstruction exceeds the float range: the mean stays at the
    // primal's 3.4e38 (sum preservation) while the gradients along the chain (b = 3j mod 16)
    // alternate ±1e38, asking for a zigzag around that mean, so half the bins rise above it.
    std::vector<float> huge(16, 3.4e38f), zigzag(16);
    for (int j = 0; j < 16; ++j) zigzag[(3 * j) % 16] = j % 2 == 0 ? 1e38f : -1e38f;
    s = solver->solve_pixels(norm, huge, zigzag, out);
    EXPECT_EQ(s.code(), absl::StatusCode::kOutOfRange) << s;
  }
  EXPECT_EQ(solver->solve_l2(primal, gradient, out).code(), absl::StatusCode::kOk);
}

TEST(PoissonImage, MatchesPerPixelAndNamesBadPixels) {
  std::mt19937_64 rng(23);
  const int w = 13, h = 5, bins = 16;
  auto solver = PoissonSolver::create(bins, 2, 0.2);
  ASSERT_TRUE(solver.ok());
  auto primal = image::SpectralImage::from_data(w, h, bins, random_values(rng, w * h * bins, 0, 1));
  auto gradient =
      image::SpectralImage::from_data(w, h, bins, random_values(rng, w * h * bins, -1, 1));
  ASSERT_TRUE(primal.ok() && gradient.ok());
  for (job::PoissonNorm norm : {job::PoissonNorm::kL2, job::PoissonNorm::kL1}) {
    auto out = reconstruct_image(*solver, norm, *primal, *gradient);
    ASSERT_TRUE(out.ok()) << out.status();
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        std::vector<float> single(bins);
        ASSERT_TRUE(
            solver->solve_pixels(norm, primal->pixel(x, y), gradient->pixel(x, y), single).ok());
        for (int b = 0; b < bins; ++b) ASSERT_EQ(out->value(x, y, b), single[b]);
      }
    }
  }
  image::SpectralImage bad = *gradient;
  bad.value(2, 3, 4) = std::nanf("");
  auto refused = reconstruct_image(*solver, job::PoissonNorm::kL2, *primal, bad);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("pixel (2, 3) gradient[4] = nan"), std::string::npos)
      << refused.status();

  auto other = image::SpectralImage::create(w, h + 1, bins);
  auto mismatch = reconstruct_image(*solver, job::PoissonNorm::kL2, *primal, *other);
  EXPECT_EQ(mismatch.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(mismatch.status().message().find("13x5 with 16 bins but gradient is 13x6"),
            std::string::npos)
      << mismatch.status();
  auto wrong_bins = image::SpectralImage::create(w, h, 15);
  auto bins_refused = reconstruct_image(*solver, job::PoissonNorm::kL2, *wrong_bins, *wrong_bins);
  EXPECT_NE(bins_refused.status().message().find("15 bins but the solver was built for 16"),
            std::string::npos)
      << bins_refused.status();
}

// The weighted oracle: the normal equations (A + DᵀWD)Î = A·I + DᵀW·G of
// Σ_b a_b(Î[b] − I[b])² + Σ_b w_b((DÎ)[b] − G[b])², with the weights the header specifies
// (a_b = 1/max(v_I[b], f·mean v_I), w_b = 1/max(v_G[b], f·mean v_G)), assembled as a dense
// B×B matrix and solved by Gaussian elimination with partial pivoting in long double. It shares
// nothing with the solver's chain decomposition or its cyclic elimination.
std::vector<long double> weighted_oracle(const std::vector<float>& primal,
                                         const std::vector<float>& gradient,
                                         const std::vector<float>& var_i,
                                         const std::vector<float>& var_g, int k) {
  const int B = static_cast<int>(primal.size());
  const long double f = PoissonSolver::kVarianceFloor;
  long double mean_i = 0, mean_g = 0;
  for (int b = 0; b < B; ++b) {
    mean_i += var_i[b];
    mean_g += var_g[b];
  }
  mean_i /= B;
  mean_g /= B;
  std::vector<std::vector<long double>> m(B, std::vector<long double>(B + 1, 0.0L));
  for (int b = 0; b < B; ++b) {
    const long double a = 1.0L / std::max<long double>(var_i[b], f * mean_i);
    m[b][b] += a;
    m[b][B] += a * primal[b];
    // The term w(Î[b+k] − Î[b] − G[b])²: its gradient in Î[b+k] and Î[b].
    const long double w = 1.0L / std::max<long double>(var_g[b], f * mean_g);
    const int up = (b + k) % B;
    m[up][up] += w;
    m[up][b] -= w;
    m[up][B] += w * gradient[b];
    m[b][b] += w;
    m[b][up] -= w;
    m[b][B] -= w * gradient[b];
  }
  for (int c = 0; c < B; ++c) {
    int pivot = c;
    for (int r = c + 1; r < B; ++r) {
      if (std::abs(m[r][c]) > std::abs(m[pivot][c])) pivot = r;
    }
    std::swap(m[c], m[pivot]);
    for (int r = c + 1; r < B; ++r) {
      const long double factor = m[r][c] / m[c][c];
      for (int j = c; j <= B; ++j) m[r][j] -= factor * m[c][j];
    }
  }
  std::vector<long double> x(B);
  for (int r = B - 1; r >= 0; --r) {
    long double sum = m[r][B];
    for (int j = r + 1; j < B; ++j) sum -= m[r][j] * x[j];
    x[r] = sum / m[r][r];
  }
  return x;
}

TEST(PoissonSolver, WeightedMatchesDenseOracle) {
  std::mt19937_64 rng(31);
  for (int bins : kBinCounts) {
    for (int k : offsets_for(bins)) {
      auto solver = PoissonSolver::create(bins, k, 0.2);
      ASSERT_TRUE(solver.ok());
      for (int trial = 0; trial < 3; ++trial) {
        const std::vector<float> primal = random_values(rng, bins, 0.0f, 2.0f);
        const std::vector<float> gradient = random_values(rng, bins, -1.0f, 1.0f);
        // Variances over four decades, some bins below the floor and some exactly 0.
        std::vector<float> var_i = random_values(rng, bins, -4.0f, 0.0f);
        std::vector<float> var_g = random_values(rng, bins, -4.0f, 0.0f);
        for (float& v : var_i) v = std::pow(10.0f, v);
        for (float& v : var_g) v = std::pow(10.0f, v);
        var_i[trial % bins] = 0;
        var_g[(trial + 1) % bins] = 0;
        std::vector<float> out(bins);
        ASSERT_TRUE(solver->solve_weighted(primal, gradient, var_i, var_g, out).ok());
        const std::vector<long double> want = weighted_oracle(primal, gradient, var_i, var_g, k);
        long double scale = 0;
        for (long double v : want) scale = std::max(scale, std::abs(v));
        for (int b = 0; b < bins; ++b) {
          // The weights' ratio is at most 1/kVarianceFloor times the variances' spread (1e4):
          // κ ≲ 1e6, so the double solve is good to ~1e-9 relative; the float result rounds.
          EXPECT_NEAR(out[b], double(want[b]), 2e-7 * double(scale) + 1e-30)
              << "B " << bins << " k " << k << " trial " << trial << " bin " << b;
        }
      }
    }
  }
}

// Equal variances everywhere make the weighted objective the global one with α = v_G / v_I.
TEST(PoissonSolver, WeightedWithEqualVariancesIsTheL2Solve) {
  std::mt19937_64 rng(37);
  for (int bins : kBinCounts) {
    for (int k : offsets_for(bins)) {
      const std::vector<float> primal = random_values(rng, bins, 0.0f, 2.0f);
      const std::vector<float> gradient = random_values(rng, bins, -1.0f, 1.0f);
      const std::vector<float> var_i(bins, 0.25f), var_g(bins, 0.5f);
      auto weighted = PoissonSolver::create(bins, k, 0.2);
      auto global = PoissonSolver::create(bins, k, 2.0);
      ASSERT_TRUE(weighted.ok() && global.ok());
      std::vector<float> a(bins), b(bins);
      ASSERT_TRUE(weighted->solve_weighted(primal, gradient, var_i, var_g, a).ok());
      ASSERT_TRUE(global->solve_l2(primal, gradient, b).ok());
      for (int i = 0; i < bins; ++i) {
        EXPECT_NEAR(a[i], b[i], 1e-6) << "B " << bins << " k " << k << " bin " << i;
      }
    }
  }
}

// Consistent gradients (G = DI) make I the exact minimum whatever the weights; scaling all the
// variances by one factor changes no weight ratio and so not the result; a pixel with no
// variance (one sample, or nothing varies) returns I.
TEST(PoissonSolver, WeightedKeepsConsistentInputAndScales) {
  std::mt19937_64 rng(41);
  for (int bins : kBinCounts) {
    for (int k : offsets_for(bins)) {
      auto solver = PoissonSolver::create(bins, k, 0.2);
      ASSERT_TRUE(solver.ok());
      const std::vector<float> primal = random_values(rng, bins, 1.0f, 2.0f);
      std::vector<float> consistent(bins);
      for (int b = 0; b < bins; ++b) consistent[b] = primal[(b + k) % bins] - primal[b];
      std::vector<float> var_i = random_values(rng, bins, 1e-3f, 1.0f);
      std::vector<float> var_g = random_values(rng, bins, 1e-3f, 1.0f);
      std::vector<float> out(bins);
      ASSERT_TRUE(solver->solve_weighted(primal, consistent, var_i, var_g, out).ok());
      for (int b = 0; b < bins; ++b) {
        EXPECT_NEAR(out[b], primal[b], 4 * std::ldexp(1.0f, -23)) << "B " << bins << " k " << k;
      }

      const std::vector<float> gradient = random_values(rng, bins, -1.0f, 1.0f);
      std::vector<float> once(bins), scaled(bins);
      ASSERT_TRUE(solver->solve_weighted(primal, gradient, var_i, var_g, once).ok());
      std::vector<float> var_i4 = var_i, var_g4 = var_g;
      for (float& v : var_i4) v *= 4;  // exact in binary
      for (float& v : var_g4) v *= 4;
      ASSERT_TRUE(solver->solve_weighted(primal, gradient, var_i4, var_g4, scaled).ok());
      EXPECT_EQ(once, scaled) << "B " << bins << " k " << k;

      const std::vector<float> zero(bins, 0.0f);
      ASSERT_TRUE(solver->solve_weighted(primal, gradient, zero, var_g, out).ok());
      EXPECT_EQ(out, primal);
      ASSERT_TRUE(solver->solve_weighted(primal, gradient, var_i, zero, out).ok());
      EXPECT_EQ(out, primal);
    }
  }
}

TEST(PoissonSolver, WeightedRefusesBadInput) {
  auto solver = PoissonSolver::create(16, 3, 0.2);
  ASSERT_TRUE(solver.ok());
  std::vector<float> primal(16, 1.0f), gradient(16, 0.0f), var(16, 0.1f), out(16);
  std::vector<float> short_var(15, 0.1f);
  absl::Status s = solver->solve_weighted(primal, gradient, short_var, var, out);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("15 primal and 16 gradient variances"), std::string::npos) << s;

  std::vector<float> negative = var;
  negative[4] = -0.5f;
  s = solver->solve_weighted(primal, gradient, var, negative, out);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("variance[4] = 0.1 / -0.5"), std::string::npos) << s;
  std::vector<float> nan = var;
  nan[9] = std::nanf("");
  s = solver->solve_weighted(primal, gradient, nan, var, out);
  EXPECT_NE(s.message().find("variance[9] = nan"), std::string::npos) << s;

  std::vector<float> bad_primal = primal;
  bad_primal[2] = std::numeric_limits<float>::infinity();
  s = solver->solve_weighted(bad_primal, gradient, var, var, out);
  EXPECT_NE(s.message().find("primal[2] = inf"), std::string::npos) << s;

  std::vector<float> all(16 * 4, 1.0f), all_out(16 * 4);
  s = solver->solve_pixels(job::PoissonNorm::kWeighted, all, all, all_out);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("use solve_weighted"), std::string::npos) << s;
}

}  // namespace
}  // namespace prism::coordinator
