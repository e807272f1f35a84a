#include "worker/sampler.h"

#include <bit>

namespace prism::worker {
namespace {

constexpr std::uint64_t kGolden = 0x9e3779b97f4a7c15ull;

std::uint32_t laine_karras_permutation(std::uint32_t x, std::uint32_t seed) {
  // Burley 2020, "Practical Hash-based Owen Scrambling": a hash whose low bits never depend on
  // higher ones, i.e. an Owen scramble of the bit-reversed value. Constants from that paper.
  x += seed;
  x ^= x * 0x6c50b47cu;
  x ^= x * 0xb82f1e52u;
  x ^= x * 0xc7afe638u;
  x ^= x * 0x8d22f6e6u;
  return x;
}

}  // namespace

std::uint64_t mix64(std::uint64_t x) {
  // SplitMix64's finaliser (Stafford's variant 13).
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ull;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebull;
  x ^= x >> 31;
  return x;
}

std::uint64_t hash_key(const SampleKey& key) {
  std::uint64_t h = mix64(key.seed + kGolden);
  h = mix64(h ^ (static_cast<std::uint64_t>(key.pass) + kGolden));
  h = mix64(h ^ ((static_cast<std::uint64_t>(key.px) << 32) | key.py));
  h = mix64(h ^ (static_cast<std::uint64_t>(key.sample) + kGolden));
  return h;
}

float bits_to_unit_float(std::uint32_t bits) {
  // The top 24 bits give exactly representable floats in [0, 1).
  return static_cast<float>(bits >> 8) * 0x1p-24f;
}

float IndependentSampler::sample(std::uint32_t dimension) const {
  std::uint64_t h = mix64(base_ ^ mix64(static_cast<std::uint64_t>(dimension) + kGolden));
  return bits_to_unit_float(static_cast<std::uint32_t>(h >> 32));
}

std::uint32_t reverse_bits(std::uint32_t x) {
  x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
  x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
  x = ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
  x = ((x >> 8) & 0x00ff00ffu) | ((x & 0x00ff00ffu) << 8);
  return (x >> 16) | (x << 16);
}

std::uint32_t sobol_dimension0(std::uint32_t index) {
  return reverse_bits(index);
}

namespace {

// Generator matrix of Sobol's second dimension (primitive polynomial x + 1): its columns are
// v_{k+1} = v_k ^ (v_k >> 1) starting from the top bit. Multiplying by it is linear over GF(2),
// so the product splits into four byte tables.
constexpr std::uint32_t sobol_dimension1_slow(std::uint32_t index) {
  std::uint32_t result = 0;
  for (std::uint32_t v = 1u << 31; index != 0; index >>= 1, v ^= v >> 1) {
    if (index & 1u) result ^= v;
  }
  return result;
}

struct Sobol1Tables {
  std::uint32_t byte[4][256];
};

constexpr Sobol1Tables make_sobol1_tables() {
  Sobol1Tables t{};
  for (int k = 0; k < 4; ++k) {
    for (std::uint32_t b = 0; b < 256; ++b) t.byte[k][b] = sobol_dimension1_slow(b << (8 * k));
  }
  return t;
}

constexpr Sobol1Tables kSobol1 = make_sobol1_tables();

}  // namespace

std::uint32_t sobol_dimension1(std::uint32_t index) {
  return kSobol1.byte[0][index & 255u] ^ kSobol1.byte[1][(index >> 8) & 255u] ^
         kSobol1.byte[2][(index >> 16) & 255u] ^ kSobol1.byte[3][index >> 24];
}

std::uint32_t nested_uniform_scramble(std::uint32_t x, std::uint32_t seed) {
  return reverse_bits(laine_karras_permutation(reverse_bits(x), seed));
}

namespace {

struct PairSeeds {
  std::uint32_t shuffled_index;
  std::uint64_t pair_hash;
};

PairSeeds pair_seeds(std::uint64_t base, std::uint32_t index, std::uint32_t pair) {
  std::uint64_t pair_hash = mix64(base ^ mix64(static_cast<std::uint64_t>(pair) + kGolden));
  // Shuffling the index by an Owen scramble keeps every power-of-two prefix a net while
  // decorrelating pairs; the two halves of the hash seed shuffle and scramble independently.
  return {nested_uniform_scramble(index, static_cast<std::uint32_t>(pair_hash)), pair_hash};
}

float scrambled(const PairSeeds& seeds, std::uint32_t within) {
  auto scramble_seed = static_cast<std::uint32_t>(mix64(seeds.pair_hash ^ within) >> 32);
  std::uint32_t point =
      within ? sobol_dimension1(seeds.shuffled_index) : sobol_dimension0(seeds.shuffled_index);
  return bits_to_unit_float(nested_uniform_scramble(point, scramble_seed));
}

}  // namespace

float SobolSampler::sample(std::uint32_t dimension) const {
  return scrambled(pair_seeds(base_, index_, dimension >> 1), dimension & 1u);
}

Point2 SobolSampler::sample_pair(std::uint32_t pair) const {
  PairSeeds seeds = pair_seeds(base_, index_, pair);
  return {scrambled(seeds, 0), scrambled(seeds, 1)};
}

Sampler::Sampler(job::SamplerKind kind, const SampleKey& key)
    : generator_(kind == job::SamplerKind::kSobol
                     ? std::variant<IndependentSampler, SobolSampler>(SobolSampler(key))
                     : std::variant<IndependentSampler, SobolSampler>(IndependentSampler(key))) {}

}  // namespace prism::worker
