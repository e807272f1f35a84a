// Sample generators (docs/estimators.md §7). Every number is a pure function of
// (job seed, pass, pixel, sample index, dimension): no state is shared between pixels, threads or
// tiles, so a tile rendered by any worker, in any order, with any thread count, sees the same
// numbers and produces the same bytes.
//
// Two generators, a closed set:
//  - IndependentSampler: a counter-based hash of the key; uncorrelated across dimensions.
//  - SobolSampler: Owen-scrambled Sobol (0,2)-sequence padded in dimension pairs. Each pair of
//    dimensions (2j, 2j+1) uses the first two Sobol dimensions with the sample index shuffled and
//    the points nested-uniform scrambled, each by hashes of (key, j). Within a pixel the first
//    2^m samples of a pair form a (0,m,2)-net; different pairs are decorrelated by their seeds.
//    This needs no direction-number tables and stays well distributed at any dimension count.
#pragma once

#include <cstdint>
#include <variant>

#include "services/job/render_options.h"
#include "worker/float_hash.h"

namespace prism::worker {

struct Point2 {
  float u0 = 0, u1 = 0;
};

// Identifies one pixel sample of one pass of one job.
struct SampleKey {
  std::uint64_t seed = 0;
  std::uint32_t pass = 0;
  std::uint32_t px = 0;
  std::uint32_t py = 0;
  std::uint32_t sample = 0;
};

// Hash of a whole key, the base of both generators.
std::uint64_t hash_key(const SampleKey& key);

// Maps 32 random bits to a float in [0, 1): never returns 1.
float bits_to_unit_float(std::uint32_t bits);

class IndependentSampler {
 public:
  explicit IndependentSampler(const SampleKey& key) : base_(hash_key(key)) {}
  float sample(std::uint32_t dimension) const;
  Point2 sample_pair(std::uint32_t pair) const { return {sample(2 * pair), sample(2 * pair + 1)}; }

 private:
  std::uint64_t base_;
};

class SobolSampler {
 public:
  explicit SobolSampler(const SampleKey& key)
      : base_(hash_key({key.seed, key.pass, key.px, key.py, 0})), index_(key.sample) {}
  float sample(std::uint32_t dimension) const;
  // Dimensions 2·pair and 2·pair + 1 together (the index shuffle is shared, so this is cheaper
  // than two sample() calls and returns the same numbers).
  Point2 sample_pair(std::uint32_t pair) const;

 private:
  std::uint64_t base_;  // per pixel: the sample index is scrambled, not hashed
  std::uint32_t index_;
};

// A pixel sample's stream of numbers: get1d/get2d consume dimensions in order. Cheap to copy.
class Sampler {
 public:
  Sampler(job::SamplerKind kind, const SampleKey& key);

  float get1d() { return at(dimension_++); }
  void get2d(float& u0, float& u1) {
    u0 = at(dimension_++);
    u1 = at(dimension_++);
  }
  // Jumps to a fixed dimension, so path vertex k can start at a known offset and the
  // light/BSDF decisions of one bounce never shift the numbers of the next.
  void set_dimension(std::uint32_t dimension) { dimension_ = dimension; }
  std::uint32_t dimension() const { return dimension_; }

  float at(std::uint32_t dimension) const {
    return std::visit([dimension](const auto& s) { return s.sample(dimension); }, generator_);
  }
  // Dimensions d and d + 1 for an even d: equal to {at(d), at(d + 1)}.
  Point2 at2(std::uint32_t dimension) const {
    return std::visit([dimension](const auto& s) { return s.sample_pair(dimension >> 1); },
                      generator_);
  }

 private:
  std::variant<IndependentSampler, SobolSampler> generator_;
  std::uint32_t dimension_ = 0;
};

// Building blocks, exposed for tests.
std::uint32_t reverse_bits(std::uint32_t x);
std::uint32_t sobol_dimension0(std::uint32_t index);  // van der Corput, bit-reversed index
std::uint32_t sobol_dimension1(std::uint32_t index);  // second Sobol dimension
std::uint32_t nested_uniform_scramble(std::uint32_t x, std::uint32_t seed);

}  // namespace prism::worker
