// Deterministic randomness from geometry: a splitmix64 (Steele, Lea and Flood 2014) hash of the
// bit patterns of some floats, for the decisions pbrt-v4 draws from hashes of a ray or a hit
// (a mix material's component, an alpha test, a layered BSDF's random walk). Every input bit
// passes a full finaliser, so two inputs that differ in one bit give unrelated numbers; the same
// inputs always give the same bits, whatever thread asks.
#pragma once

#include <bit>
#include <cstdint>
#include <initializer_list>

namespace prism::worker {

inline constexpr std::uint64_t kGoldenGamma = 0x9E3779B97F4A7C15ull;

// The splitmix64 finaliser (Stafford's variant 13): every input bit affects every output bit.
// The samplers (sampler.h) hash with it too.
inline constexpr std::uint64_t mix64(std::uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// A hash of `seed` and the floats' bit patterns.
inline std::uint64_t hash_floats(std::uint64_t seed, std::initializer_list<float> values) {
  std::uint64_t h = mix64(seed * kGoldenGamma);
  for (float v : values)
    h = mix64(h ^ (std::uint64_t{std::bit_cast<std::uint32_t>(v)} + kGoldenGamma));
  return h;
}

// 24 bits of a hash as a float uniform on [0, 1 − 2⁻²⁴] (exact, never 1).
inline float unit_float(std::uint64_t hash) {
  return float(hash >> 40) * 0x1p-24f;
}

}  // namespace prism::worker
