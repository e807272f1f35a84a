// Fixed-width little-endian integers in byte strings: the on-disk and wire records (tile codec,
// bundles, finished-tile and convergence records) all write their integers and IEEE-754 bits
// this way, whatever the host's byte order.
#pragma once

#include <cstdint>
#include <string>

namespace prism::base {

// The low `bytes` bytes of `value` at out[0..bytes).
inline void put_le(char* out, std::uint64_t value, int bytes) {
  for (int i = 0; i < bytes; ++i) out[i] = static_cast<char>((value >> (8 * i)) & 0xff);
}

// The low `bytes` bytes of `value` appended to `out`.
inline void append_le(std::string& out, std::uint64_t value, int bytes) {
  for (int i = 0; i < bytes; ++i) out.push_back(static_cast<char>((value >> (8 * i)) & 0xff));
}

// The `bytes`-byte integer at in[0..bytes).
inline std::uint64_t get_le(const char* in, int bytes) {
  std::uint64_t value = 0;
  for (int i = 0; i < bytes; ++i) {
    value |= std::uint64_t{static_cast<unsigned char>(in[i])} << (8 * i);
  }
  return value;
}

}  // namespace prism::base
