#include "worker/sampler.h"

#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <vector>

namespace prism::worker {
namespace {

SampleKey key(std::uint32_t sample, std::uint32_t px = 3, std::uint32_t py = 5,
              std::uint64_t seed = 7) {
  return SampleKey{seed, 1, px, py, sample};
}

TEST(SamplerTest, PureFunctionOfKeyAndDimension) {
  for (job::SamplerKind kind : {job::SamplerKind::kIndependent, job::SamplerKind::kSobol}) {
    Sampler a(kind, key(11));
    Sampler b(kind, key(11));
    b.set_dimension(40);
    float tail = b.get1d();
    for (int d = 0; d < 40; ++d) a.get1d();
    EXPECT_EQ(a.get1d(), tail);
    // Any field of the key changes the numbers.
    Sampler other_pixel(kind, key(11, 4));
    Sampler other_seed(kind, key(11, 3, 5, 8));
    Sampler other_pass(kind, SampleKey{7, 2, 3, 5, 11});
    Sampler base(kind, key(11));
    EXPECT_NE(base.at(0), other_pixel.at(0));
    EXPECT_NE(base.at(0), other_seed.at(0));
    EXPECT_NE(base.at(0), other_pass.at(0));
  }
}

TEST(SamplerTest, ValuesInUnitInterval) {
  EXPECT_EQ(bits_to_unit_float(0), 0.0f);
  EXPECT_LT(bits_to_unit_float(0xffffffffu), 1.0f);
  for (job::SamplerKind kind : {job::SamplerKind::kIndependent, job::SamplerKind::kSobol}) {
    for (std::uint32_t s = 0; s < 256; ++s) {
      Sampler sampler(kind, key(s));
      for (int d = 0; d < 64; ++d) {
        float u = sampler.get1d();
        ASSERT_GE(u, 0.0f);
        ASSERT_LT(u, 1.0f);
      }
    }
  }
}

TEST(SamplerTest, SobolGeneratorMatchesKnownPoints) {
  // The first points of the Sobol (0,2)-sequence: (0,0), (.5,.5), (.75,.25), (.25,.75), ...
  const double expected[][2] = {{0, 0},         {0.5, 0.5},     {0.25, 0.75},   {0.75, 0.25},
                                {0.125, 0.625}, {0.625, 0.125}, {0.375, 0.375}, {0.875, 0.875}};
  for (std::uint32_t i = 0; i < 8; ++i) {
    EXPECT_DOUBLE_EQ(sobol_dimension0(i) * 0x1p-32, expected[i][0]) << i;
    EXPECT_DOUBLE_EQ(sobol_dimension1(i) * 0x1p-32, expected[i][1]) << i;
  }
}

TEST(SamplerTest, ScrambleIsABijectionPreservingPrefixBlocks) {
  // Owen scrambling keeps each dyadic interval's points inside one dyadic interval.
  for (std::uint32_t seed : {0u, 1u, 0xdeadbeefu}) {
    std::set<std::uint32_t> tops;
    for (std::uint32_t top = 0; top < 256; ++top) {
      std::uint32_t x = top << 24;
      std::uint32_t y = nested_uniform_scramble(x, seed);
      std::uint32_t y2 = nested_uniform_scramble(x | 0x00ffffffu, seed);
      EXPECT_EQ(y >> 24, y2 >> 24) << "interval split by the scramble";
      tops.insert(y >> 24);
    }
    EXPECT_EQ(tops.size(), 256u);
  }
}

// Every one of the 2^m elementary intervals of each shape (2^a x 2^(m-a)) holds exactly one of
// the first 2^m points of a dimension pair: the (0,m,2)-net property, per pixel, per pair.
TEST(SamplerTest, SobolPairsAreNetsInEveryPixel) {
  constexpr int kM = 8;
  constexpr std::uint32_t kN = 1u << kM;
  for (std::uint32_t px : {0u, 17u}) {
    for (std::uint32_t pair : {0u, 1u, 9u}) {
      std::vector<std::pair<float, float>> points;
      for (std::uint32_t s = 0; s < kN; ++s) {
        Sampler sampler(job::SamplerKind::kSobol, key(s, px));
        points.emplace_back(sampler.at(2 * pair), sampler.at(2 * pair + 1));
      }
      for (int a = 0; a <= kM; ++a) {
        std::set<std::pair<int, int>> cells;
        for (auto [u, v] : points) {
          cells.emplace(static_cast<int>(u * (1 << a)), static_cast<int>(v * (1 << (kM - a))));
        }
        EXPECT_EQ(cells.size(), kN) << "pixel " << px << " pair " << pair << " shape " << a;
      }
    }
  }
}

// Pearson chi-square of 1D marginals in 64 cells over 64k draws; reject at p < 1e-4 (critical
// value of chi-square with 63 degrees of freedom: 114.3).
TEST(SamplerTest, IndependentMarginalsAreUniform) {
  constexpr int kCells = 64;
  constexpr int kDraws = 1 << 16;
  for (std::uint32_t dim : {0u, 1u, 7u, 100u}) {
    std::vector<int> counts(kCells, 0);
    for (int s = 0; s < kDraws; ++s) {
      Sampler sampler(job::SamplerKind::kIndependent, key(s, s % 13, s % 7));
      ++counts[static_cast<int>(sampler.at(dim) * kCells)];
    }
    double chi2 = 0;
    const double expected = double(kDraws) / kCells;
    for (int c : counts) chi2 += (c - expected) * (c - expected) / expected;
    EXPECT_LT(chi2, 114.3) << "dimension " << dim;
  }
}

// Different dimension pairs of the padded Sobol sampler must not be correlated: the sample
// correlation of u(dim 0) and u(dim 2) over many pixels and samples is near 0 (|r| < 5/sqrt(n)).
TEST(SamplerTest, SobolPairsAreDecorrelated) {
  constexpr int kN = 1 << 14;
  double su = 0, sv = 0, suu = 0, svv = 0, suv = 0;
  for (int i = 0; i < kN; ++i) {
    Sampler sampler(job::SamplerKind::kSobol, key(i % 64, i / 64, 0));
    double u = sampler.at(0), v = sampler.at(2);
    su += u, sv += v, suu += u * u, svv += v * v, suv += u * v;
  }
  double cov = suv / kN - (su / kN) * (sv / kN);
  double r = cov / std::sqrt((suu / kN - su * su / kN / kN) * (svv / kN - sv * sv / kN / kN));
  EXPECT_LT(std::abs(r), 5.0 / std::sqrt(double(kN)));
}

// Scrambled Sobol integrates a smooth 2D function with far lower error than independent samples
// at equal count (averaged over pixels as independent scrambles).
TEST(SamplerTest, SobolConvergesFasterThanIndependent) {
  auto f = [](double u, double v) { return std::sin(3 * u) * std::exp(v); };
  const double exact = (1 - std::cos(3.0)) / 3 * (std::exp(1.0) - 1);
  auto rmse = [&](job::SamplerKind kind) {
    double sq = 0;
    for (std::uint32_t px = 0; px < 64; ++px) {
      double sum = 0;
      for (std::uint32_t s = 0; s < 256; ++s) {
        Sampler sampler(kind, key(s, px));
        sum += f(sampler.at(4), sampler.at(5));
      }
      sq += (sum / 256 - exact) * (sum / 256 - exact);
    }
    return std::sqrt(sq / 64);
  };
  EXPECT_LT(rmse(job::SamplerKind::kSobol), 0.2 * rmse(job::SamplerKind::kIndependent));
}

}  // namespace
}  // namespace prism::worker

namespace prism::worker {
namespace {

// The table-driven second Sobol dimension equals the direct product with its generator matrix.
TEST(SamplerTest, SobolDimensionOneTablesMatchTheGeneratorMatrix) {
  auto direct = [](std::uint32_t index) {
    std::uint32_t result = 0;
    for (std::uint32_t v = 1u << 31; index != 0; index >>= 1, v ^= v >> 1) {
      if (index & 1u) result ^= v;
    }
    return result;
  };
  std::uint32_t x = 12345;
  for (int i = 0; i < 100000; ++i) {
    x = x * 1664525u + 1013904223u;
    ASSERT_EQ(sobol_dimension1(x), direct(x)) << x;
    ASSERT_EQ(sobol_dimension1(std::uint32_t(i)), direct(std::uint32_t(i)));
  }
}

}  // namespace
}  // namespace prism::worker

namespace prism::worker {
namespace {

TEST(SamplerTest, PairsEqualTwoSingleDimensions) {
  for (job::SamplerKind kind : {job::SamplerKind::kIndependent, job::SamplerKind::kSobol}) {
    for (std::uint32_t s = 0; s < 64; ++s) {
      Sampler sampler(kind, key(s));
      for (std::uint32_t d = 0; d < 40; d += 2) {
        Point2 p = sampler.at2(d);
        ASSERT_EQ(p.u0, sampler.at(d));
        ASSERT_EQ(p.u1, sampler.at(d + 1));
      }
    }
  }
}

// The sampler's arithmetic (reversals cancelled, reversed tables) gives exactly the bits of the
// definition written with the building blocks, for every dimension of many pixel samples.
TEST(SamplerTest, SobolEqualsItsDefinitionBitForBit) {
  constexpr std::uint64_t kGolden = 0x9e3779b97f4a7c15ull;
  auto definition = [&](const SampleKey& key, std::uint32_t d) {
    const std::uint64_t base = hash_key({key.seed, key.pass, key.px, key.py, 0});
    const std::uint64_t pair_hash = mix64(base ^ mix64(std::uint64_t(d >> 1) + kGolden));
    const std::uint32_t shuffled =
        nested_uniform_scramble(key.sample, static_cast<std::uint32_t>(pair_hash));
    const std::uint32_t point = (d & 1u) ? sobol_dimension1(shuffled) : sobol_dimension0(shuffled);
    const auto seed = static_cast<std::uint32_t>(mix64(pair_hash ^ (d & 1u)) >> 32);
    return bits_to_unit_float(nested_uniform_scramble(point, seed));
  };
  for (std::uint32_t i = 0; i < 2000; ++i) {
    const SampleKey key{i * 2654435761u, i % 3, i % 37, i / 37, i * 7919u};
    const SobolSampler sampler(key);
    for (std::uint32_t d = 0; d < 24; ++d) {
      ASSERT_EQ(sampler.sample(d), definition(key, d)) << "key " << i << " dimension " << d;
    }
  }
  // Up to dimension 300: past the index-hash table (128) too.
  for (std::uint32_t i = 0; i < 20; ++i) {
    const SampleKey key{i * 977u, i % 3, i % 5, i / 5, i * 31u};
    const SobolSampler sampler(key);
    for (std::uint32_t d = 200; d < 300; ++d) {
      ASSERT_EQ(sampler.sample(d), definition(key, d)) << "key " << i << " dimension " << d;
    }
  }
  for (std::uint32_t x : {0u, 1u, 0x80000000u, 0x12345678u, 0xdeadbeefu, 0xffffffffu}) {
    std::uint32_t r = 0;
    for (int b = 0; b < 32; ++b) r |= ((x >> b) & 1u) << (31 - b);
    EXPECT_EQ(reverse_bits(x), r) << x;
  }
}

}  // namespace
}  // namespace prism::worker
