// The canonical byte form of a TileResult: what workers stream to the coordinator, what the
// farm hashes to check that a retried task gave the same answer, and what the coordinator
// keeps on disk. One TileResult has exactly one encoding, so equal results give equal bytes.
//
// Version 1, all integers and floats little-endian, floats as their exact IEEE-754 bits:
//   bytes 0..7   magic "PRSMTILE"
//   u32          version (1)
//   u32          flags: bit 0 gradients present, bit 1 guides present, bit 2 halves present
//                (only with bit 0), bit 3 rgb present, bit 4 filtered present, bit 5 offsets
//                present, bit 6 sums as float32, bit 7 sparse (not with bit 2); other bits
//                zero
//   i32 x4       rect x0, y0, x1, y1
//   u64 x2       sample range s0, s1
//   u32          bins
//   u32          n = number of counters, then n times: u32 length, that many name bytes
//   u64          payload byte count (must equal what the fields above imply)
//   (if flag bit 7) u32 block side B, then a bitmap of ceil(n/8) bytes for the n blocks of B x B
//                pixels that tile the rect row-major (the last row and column clipped): bit i
//                (byte i/8, bit i%8) says block i is in the payload; bits past n are zero
//   payload, in this order, each in the TileResult layout documented in tile.h:
//     f64 sums[area*bins], f64 sum_squares[area*bins], u64 counts[area],
//     f64 gradients[area*bins]               (if flag bit 0)
//     f64 gradient_squares[area*bins], f64 half_sums[area*bins], f64 half_sum_squares[area*bins],
//     f64 half_gradients[area*bins], f64 half_gradient_squares[area*bins],
//     u64 half_counts[area]                  (if flag bit 2)
//     f64 rgb_sums[area*3], f64 rgb_squares[area*3]            (if flag bit 3)
//     f64 filtered_sums[area*bins], f64 filtered_rgb_sums[area*3] (if flag bit 4)
//     f64 offsets[area*6]                    (if flag bit 5)
//     f32 depth[area], f32 normals[area*3], f32 albedo[area]   (if flag bit 1)
//     u64 counters[area*n]
//   With flag bit 6 every f64 buffer above but offsets is stored as f32 instead. serialise_tile
//   sets it exactly when every one of their values is a float32 value (TileResult::
//   round_to_float32), so the encoding stays lossless: equal results, equal bytes.
//   With flag bit 7 each buffer holds only the pixels of the blocks the bitmap sets, block by
//   block, each block's rows top to bottom; every other pixel has all values zero and a count
//   equal to the sample range's. serialise_tile sets it exactly when a block of 16 x 16 pixels
//   is like that (a light-tracing task's dark regions, a tile of black background), so a task
//   result costs only the pixels it touched.
// The parser treats its input as untrusted: it checks every field against the limits of
// TileResult::create and requires the input to be exactly as long as the header implies
// before it allocates or reads any payload, so it never reads out of bounds.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "services/image/tile.h"

namespace prism::image {

inline constexpr std::string_view kTileMagic = "PRSMTILE";
inline constexpr std::uint32_t kTileFormatVersion = 1;

// The canonical encoding of `result`.
std::string serialise_tile(const TileResult& result);

// A task's result as a worker sends it: its sums rounded to float32 (TileResult::
// round_to_float32, as the coordinator merges them), then encoded.
std::string serialise_task_result(TileResult result);

// Decodes bytes produced by serialise_tile. INVALID_ARGUMENT (naming the offending field and
// offset) for a wrong magic, unknown version or flags, out-of-range header values, truncated
// input or trailing bytes.
absl::StatusOr<TileResult> parse_tile(std::string_view bytes);

}  // namespace prism::image
