#include "worker/sampler.h"

#include <bit>

namespace prism::worker {
namespace {

constexpr std::uint64_t kGolden = kGoldenGamma;

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

// mix64(i + kGolden) for the first dimensions and pairs, which every sample hashes again: the
// same numbers from a table.
constexpr int kHashedIndices = 128;
struct IndexHashes {
  std::uint64_t value[kHashedIndices];
};
constexpr IndexHashes make_index_hashes() {
  IndexHashes h{};
  for (int i = 0; i < kHashedIndices; ++i) h.value[i] = mix64(std::uint64_t(i) + kGolden);
  return h;
}
constexpr IndexHashes kIndexHashes = make_index_hashes();

std::uint64_t index_hash(std::uint32_t i) {
  return i < std::uint32_t(kHashedIndices) ? kIndexHashes.value[i]
                                           : mix64(std::uint64_t(i) + kGolden);
}

}  // namespace

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
  std::uint64_t h = mix64(base_ ^ index_hash(dimension));
  return bits_to_unit_float(static_cast<std::uint32_t>(h >> 32));
}

std::uint32_t reverse_bits(std::uint32_t x) {
  // The bytes' order by one byte swap, then the bits within each byte.
  x = __builtin_bswap32(x);
  x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
  x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
  return ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
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

constexpr std::uint32_t reverse_bits_slow(std::uint32_t x) {
  std::uint32_t r = 0;
  for (int i = 0; i < 32; ++i) r |= ((x >> i) & 1u) << (31 - i);
  return r;
}

// reversed: the bit-reversed products (bit reversal is linear over GF(2) too).
constexpr Sobol1Tables make_sobol1_tables(bool reversed) {
  Sobol1Tables t{};
  for (int k = 0; k < 4; ++k) {
    for (std::uint32_t b = 0; b < 256; ++b) {
      const std::uint32_t v = sobol_dimension1_slow(b << (8 * k));
      t.byte[k][b] = reversed ? reverse_bits_slow(v) : v;
    }
  }
  return t;
}

constexpr Sobol1Tables kSobol1 = make_sobol1_tables(false);
constexpr Sobol1Tables kSobol1Reversed = make_sobol1_tables(true);

std::uint32_t by_bytes(const Sobol1Tables& t, std::uint32_t index) {
  return t.byte[0][index & 255u] ^ t.byte[1][(index >> 8) & 255u] ^
         t.byte[2][(index >> 16) & 255u] ^ t.byte[3][index >> 24];
}

}  // namespace

std::uint32_t sobol_dimension1(std::uint32_t index) {
  return by_bytes(kSobol1, index);
}

std::uint32_t nested_uniform_scramble(std::uint32_t x, std::uint32_t seed) {
  return reverse_bits(laine_karras_permutation(reverse_bits(x), seed));
}

namespace {

// One pair of dimensions of a pixel sample, as
//   shuffled = nested_uniform_scramble(index, h)              (h: low half of the pair's hash)
//   u_j = nested_uniform_scramble(sobol_dimension_j(shuffled), s_j)
// with s_j from the pair's hash and j, written so that bit reversals cancel: with R the bit
// reversal and P the Laine-Karras permutation, nested_uniform_scramble(x, s) = R(P(R(x), s)),
// sobol_dimension0 = R, so u_0 = R(P(shuffled, s_0)), and u_1 = R(P(R(sobol1(shuffled)), s_1))
// with R∘sobol1 one table lookup. Four reversals instead of seven, the same bits.
struct PairSeeds {
  std::uint32_t shuffled_index;
  std::uint64_t pair_hash;
};

PairSeeds pair_seeds(std::uint64_t base, std::uint32_t index, std::uint32_t pair) {
  std::uint64_t pair_hash = mix64(base ^ index_hash(pair));
  // Shuffling the index by an Owen scramble keeps every power-of-two prefix a net while
  // decorrelating pairs; the two halves of the hash seed shuffle and scramble independently.
  return {reverse_bits(
              laine_karras_permutation(reverse_bits(index), static_cast<std::uint32_t>(pair_hash))),
          pair_hash};
}

float scrambled(const PairSeeds& seeds, std::uint32_t within) {
  auto scramble_seed = static_cast<std::uint32_t>(mix64(seeds.pair_hash ^ within) >> 32);
  const std::uint32_t reversed_point =
      within ? by_bytes(kSobol1Reversed, seeds.shuffled_index) : seeds.shuffled_index;
  return bits_to_unit_float(reverse_bits(laine_karras_permutation(reversed_point, scramble_seed)));
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
