#include "services/image/tile_codec.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <limits>
#include <random>
#include <span>
#include <utility>
#include <vector>

#include "services/base/check.h"

namespace prism::image {
namespace {

TileResult random_result(std::uint64_t seed, const TileBuffers& buffers) {
  auto result = TileResult::create({16, 32, 21, 35}, {64, 128}, 7, buffers);
  PRISM_CHECK(result.ok());
  std::mt19937_64 rng(seed);
  // Arbitrary bit patterns, including NaN payloads, infinities and denormals.
  for (double& v : result->mutable_sums()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_sum_squares()) v = std::bit_cast<double>(rng());
  for (std::uint64_t& v : result->mutable_counts()) v = rng();
  for (double& v : result->mutable_gradients()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_gradient_squares()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_half_sums()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_half_sum_squares()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_half_gradients()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_half_gradient_squares()) v = std::bit_cast<double>(rng());
  for (std::uint64_t& v : result->mutable_half_counts()) v = rng();
  for (double& v : result->mutable_rgb_sums()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_rgb_squares()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_filtered_sums()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_filtered_rgb_sums()) v = std::bit_cast<double>(rng());
  for (double& v : result->mutable_offsets()) v = std::bit_cast<double>(rng());
  for (float& v : result->mutable_depth()) v = std::bit_cast<float>(std::uint32_t(rng()));
  for (float& v : result->mutable_normals()) v = std::bit_cast<float>(std::uint32_t(rng()));
  for (float& v : result->mutable_albedo()) v = std::bit_cast<float>(std::uint32_t(rng()));
  for (std::uint64_t& v : result->mutable_counters()) v = rng();
  result->mutable_sums()[0] = std::numeric_limits<double>::denorm_min();
  result->mutable_sums()[1] = -0.0;
  result->mutable_sums()[2] = std::numeric_limits<double>::max();
  return std::move(result).value();
}

// Every buffer of `parsed` holds the bits of `original`'s (NaNs compare unequal as doubles but
// must survive unchanged).
void expect_same_bits(const TileResult& parsed, const TileResult& original) {
  EXPECT_EQ(parsed.rect(), original.rect());
  EXPECT_EQ(parsed.samples(), original.samples());
  EXPECT_EQ(parsed.buffers(), original.buffers());
  for (auto [a, b] : {std::pair{parsed.sums(), original.sums()},
                      std::pair{parsed.sum_squares(), original.sum_squares()},
                      std::pair{parsed.gradients(), original.gradients()},
                      std::pair{parsed.gradient_squares(), original.gradient_squares()},
                      std::pair{parsed.half_sums(), original.half_sums()},
                      std::pair{parsed.half_sum_squares(), original.half_sum_squares()},
                      std::pair{parsed.half_gradients(), original.half_gradients()},
                      std::pair{parsed.half_gradient_squares(), original.half_gradient_squares()},
                      std::pair{parsed.rgb_sums(), original.rgb_sums()},
                      std::pair{parsed.rgb_squares(), original.rgb_squares()},
                      std::pair{parsed.filtered_sums(), original.filtered_sums()},
                      std::pair{parsed.filtered_rgb_sums(), original.filtered_rgb_sums()},
                      std::pair{parsed.offsets(), original.offsets()}}) {
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(std::memcmp(a.data(), b.data(), b.size_bytes()), 0);
  }
  for (auto [a, b] : {std::pair{parsed.depth(), original.depth()},
                      std::pair{parsed.normals(), original.normals()},
                      std::pair{parsed.albedo(), original.albedo()}}) {
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(std::memcmp(a.data(), b.data(), b.size_bytes()), 0);
  }
  EXPECT_TRUE(std::ranges::equal(parsed.counts(), original.counts()));
  EXPECT_TRUE(std::ranges::equal(parsed.half_counts(), original.half_counts()));
  EXPECT_TRUE(std::ranges::equal(parsed.counters(), original.counters()));
}

const std::vector<TileBuffers>& every_buffer_set() {
  static const std::vector<TileBuffers> sets = {
      TileBuffers{},
      TileBuffers{true, false, {}},
      TileBuffers{true, true, {"rays", "shifts"}},
      TileBuffers{true, false, {"rays"}, true},
      TileBuffers{false, false, {}, false, true},
      TileBuffers{true, true, {"rays"}, true, true},
      TileBuffers{false, false, {}, false, true, true},
      TileBuffers{false, true, {}, false, true, false, true}};
  return sets;
}

TEST(TileCodec, RoundTripIsExact) {
  for (const TileBuffers& buffers : every_buffer_set()) {
    TileResult original = random_result(7, buffers);
    std::string bytes = serialise_tile(original);
    auto parsed = parse_tile(bytes);
    ASSERT_TRUE(parsed.ok()) << parsed.status();
    expect_same_bits(*parsed, original);
    EXPECT_EQ(serialise_tile(*parsed), bytes);
  }
}

// Flags are the u32 at byte 12.
std::uint32_t flags_of(const std::string& bytes) {
  return std::uint8_t(bytes[12]) | std::uint32_t(std::uint8_t(bytes[13])) << 8 |
         std::uint32_t(std::uint8_t(bytes[14])) << 16 |
         std::uint32_t(std::uint8_t(bytes[15])) << 24;
}

// random_result with the buffers of sums (all double buffers but offsets) holding doubles within
// float32's range and 53 significant bits, plus a quiet NaN, an infinity and -0.
TileResult result_in_float_range(std::uint64_t seed, const TileBuffers& buffers) {
  TileResult result = random_result(seed, buffers);
  std::mt19937_64 rng(seed + 1);
  std::uniform_real_distribution<double> mantissa(-1.0, 1.0);
  std::uniform_int_distribution<int> exponent(-140, 120);
  for (std::span<double> buffer : result.mutable_sum_buffers()) {
    for (double& v : buffer) v = std::ldexp(mantissa(rng), exponent(rng));
  }
  result.mutable_sums()[0] = std::numeric_limits<double>::quiet_NaN();
  result.mutable_sums()[1] = -0.0;
  result.mutable_sums()[2] = std::numeric_limits<double>::infinity();
  return result;
}

TEST(TileCodec, Float32SumsAreStoredInHalfTheBytesAndStayExact) {
  for (const TileBuffers& buffers : every_buffer_set()) {
    const TileResult doubles = result_in_float_range(11, buffers);
    const std::string wide = serialise_tile(doubles);
    EXPECT_EQ(flags_of(wide) & (1u << 6), 0u);

    TileResult rounded = doubles;
    rounded.round_to_float32();
    const std::string narrow = serialise_tile(rounded);
    EXPECT_EQ(flags_of(narrow), flags_of(wide) | (1u << 6));
    // Every buffer of sums (all double buffers but offsets) halves.
    const std::uint64_t area = std::uint64_t(doubles.rect().area());
    const std::uint64_t bins = std::uint64_t(doubles.bins());
    std::uint64_t sums = area * bins * 2;
    if (buffers.gradients) sums += area * bins;
    if (buffers.halves) sums += area * bins * 5;
    if (buffers.rgb) sums += area * 3 * 2;
    if (buffers.filtered) sums += area * bins + area * 3;
    EXPECT_EQ(wide.size() - narrow.size(), sums * 4);

    auto parsed = parse_tile(narrow);
    ASSERT_TRUE(parsed.ok()) << parsed.status();
    expect_same_bits(*parsed, rounded);
    EXPECT_EQ(serialise_tile(*parsed), narrow);
    // Offsets are never rounded.
    EXPECT_EQ(std::memcmp(rounded.offsets().data(), doubles.offsets().data(),
                          doubles.offsets().size_bytes()),
              0);
  }
}

TEST(TileCodec, OneValueFloat32CannotHoldKeepsTheResultInDoubles) {
  TileResult result = result_in_float_range(3, TileBuffers{true, false, {}, true, false, false});
  result.round_to_float32();
  ASSERT_NE(flags_of(serialise_tile(result)) & (1u << 6), 0u);
  for (double beyond : {1e39, -1e300, 0.1}) {
    TileResult widened = result;
    widened.mutable_half_gradient_squares().back() = beyond;
    widened.round_to_float32();
    const std::string bytes = serialise_tile(widened);
    // 0.1 rounds to a float32 value; the finite values beyond float32's range stay as they are.
    EXPECT_EQ((flags_of(bytes) & (1u << 6)) != 0, beyond == 0.1) << beyond;
    auto parsed = parse_tile(bytes);
    ASSERT_TRUE(parsed.ok()) << parsed.status();
    expect_same_bits(*parsed, widened);
  }
}

void put_u32(std::string& bytes, std::size_t offset, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) bytes[offset + i] = char((v >> (8 * i)) & 0xff);
}

// A 100x40 light-task-like result over samples [8, 12): zeros and a count of 4 everywhere but
// in the pixels given, where every buffer holds something.
TileResult mostly_empty(const TileBuffers& buffers,
                        std::initializer_list<std::pair<int, int>> lit) {
  auto result = TileResult::create({200, 300, 300, 340}, {8, 12}, 5, buffers);
  PRISM_CHECK(result.ok());
  std::ranges::fill(result->mutable_counts(), 4u);
  for (auto [x, y] : lit) {
    const std::size_t p = std::size_t(y - 300) * 100 + std::size_t(x - 200);
    for (std::span<double> buffer :
         {result->mutable_sums(), result->mutable_sum_squares(), result->mutable_gradients(),
          result->mutable_rgb_sums(), result->mutable_rgb_squares(),
          result->mutable_filtered_sums(), result->mutable_filtered_rgb_sums(),
          result->mutable_offsets()}) {
      const std::size_t k = buffer.size() / 4000;
      for (std::size_t j = 0; j < k; ++j) buffer[p * k + j] = 0.25 + double(x + y + j);
    }
    for (std::span<float> buffer :
         {result->mutable_depth(), result->mutable_normals(), result->mutable_albedo()}) {
      const std::size_t k = buffer.size() / 4000;
      for (std::size_t j = 0; j < k; ++j) buffer[p * k + j] = 1.5f;
    }
    const std::size_t n = result->mutable_counters().size() / 4000;
    for (std::size_t j = 0; j < n; ++j) result->mutable_counters()[p * n + j] = 3;
  }
  return *std::move(result);
}

TEST(TileCodec, ASparseResultCarriesOnlyTheBlocksItTouched) {
  const TileBuffers all{true, true, {"rays"}, false, true, true, true};
  for (const TileBuffers& buffers : {TileBuffers{}, all}) {
    // Lit: blocks (0,0), (5,1) and (6,2): the last column (x 296..299) and row (y 332..339) of
    // blocks are clipped to 4 and 8 pixels.
    const TileResult result =
        mostly_empty(buffers, {{200, 300}, {215, 315}, {290, 317}, {299, 339}});
    const std::string bytes = serialise_tile(result);
    EXPECT_NE(flags_of(bytes) & (1u << 7), 0u);
    const TileResult empty = mostly_empty(buffers, {});
    const std::string no_pixels = serialise_tile(empty);
    // Present pixels 16x16 + 16x16 + 4x8, at 48 bytes each (5 bins of float32 sums and squares,
    // a count), or 200 with every buffer (gradients 20, RGB 24, filtered 32, offsets 48 as
    // doubles, guides 20, a counter 8).
    const std::size_t per_pixel = buffers == TileBuffers{} ? 48 : 200;
    EXPECT_EQ(bytes.size() - no_pixels.size(), (16 * 16 + 16 * 16 + 4 * 8) * per_pixel);
    auto parsed = parse_tile(bytes);
    ASSERT_TRUE(parsed.ok()) << parsed.status();
    expect_same_bits(*parsed, result);
    EXPECT_EQ(serialise_tile(*parsed), bytes);
    // Nothing lit: a header, a bitmap and no payload at all.
    auto nothing = parse_tile(no_pixels);
    ASSERT_TRUE(nothing.ok()) << nothing.status();
    expect_same_bits(*nothing, empty);
  }
  // The per-pixel size: two present blocks cost twice one.
  const std::size_t none = serialise_tile(mostly_empty({}, {})).size();
  const std::size_t one = serialise_tile(mostly_empty({}, {{200, 300}})).size();
  const std::size_t two = serialise_tile(mostly_empty({}, {{200, 300}, {216, 300}})).size();
  EXPECT_EQ(two - none, 2 * (one - none));
  EXPECT_EQ(one - none, 16u * 16u * (5 * 4 * 2 + 8));  // float32 sums and squares, a count
}

TEST(TileCodec, OnlyAllZeroBitsAndTheRangesCountLeaveABlockOut) {
  const TileResult lit = mostly_empty({}, {{200, 300}});
  const std::size_t one = serialise_tile(lit).size();
  // -0.0 is not zero bits; a count other than the range's is not the default.
  TileResult negative_zero = lit;
  negative_zero.mutable_sums()[5 * (100 * 20 + 40)] = -0.0;
  TileResult other_count = lit;
  other_count.mutable_counts()[100 * 20 + 40] = 3;
  for (const TileResult* r : {&negative_zero, &other_count}) {
    const std::string bytes = serialise_tile(*r);
    EXPECT_GT(bytes.size(), one);
    auto parsed = parse_tile(bytes);
    ASSERT_TRUE(parsed.ok()) << parsed.status();
    expect_same_bits(*parsed, *r);
  }
  // Every block touched: dense, no bitmap.
  TileResult full = lit;
  for (std::size_t p = 0; p < 4000; ++p) full.mutable_sums()[p * 5] = 1.0;
  EXPECT_EQ(flags_of(serialise_tile(full)) & (1u << 7), 0u);
  // Halves are never sparse (their counts differ per pixel).
  auto halves = TileResult::create({0, 0, 40, 40}, {0, 2}, 3, TileBuffers{true, false, {}, true});
  ASSERT_TRUE(halves.ok());
  std::ranges::fill(halves->mutable_counts(), 2u);
  EXPECT_EQ(flags_of(serialise_tile(*halves)) & (1u << 7), 0u);
}

TEST(TileCodec, BadSparseHeadersAreRefused) {
  const std::string good = serialise_tile(mostly_empty({}, {{200, 300}}));
  // No counter names: the payload size is at 56, the block side at 64, the bitmap (21 blocks,
  // 3 bytes) at 68.
  ASSERT_EQ(good[64], 16);
  auto refused = [](std::string bytes, const std::string& needle) {
    auto parsed = parse_tile(bytes);
    ASSERT_FALSE(parsed.ok());
    EXPECT_NE(parsed.status().message().find(needle), std::string::npos) << parsed.status();
  };
  std::string bad = good;
  put_u32(bad, 64, 0);
  refused(bad, "block");
  bad = good;
  bad[70] = char(0x80);  // block 23 of 21
  refused(bad, "bitmap sets block 23");
  bad = good;
  bad[68] = char(3);  // a second block the payload does not hold
  refused(bad, "payload");
  refused(good.substr(0, 69), "bitmap");
  bad = good;
  put_u32(bad, 12, (1u << 7) | 4 | 1);  // sparse with halves
  refused(bad, "halves");
}

TEST(TileCodec, HeaderIsLittleEndianAndVersioned) {
  auto result = TileResult::create({0, 0, 1, 1}, {0, 1}, 1);
  std::string bytes = serialise_tile(*result);
  EXPECT_EQ(bytes.substr(0, 8), "PRSMTILE");
  EXPECT_EQ(bytes[8], 1);
  EXPECT_EQ(bytes[9], 0);
  // Header (8+4+4+16+16+4+4+8 = 64 bytes) + sums, squares (float32: zeros are) and counts of
  // one pixel and one bin.
  EXPECT_EQ(bytes.size(), 64u + 16u);
}

TEST(TileCodec, EveryTruncationIsRefused) {
  std::string bytes = serialise_tile(random_result(3, {true, true, {"rays"}}));
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    auto parsed = parse_tile(std::string_view(bytes).substr(0, n));
    EXPECT_EQ(parsed.status().code(), absl::StatusCode::kInvalidArgument) << "length " << n;
  }
  EXPECT_FALSE(parse_tile(bytes + "x").ok());
}

TEST(TileCodec, CorruptedHeadersAreRefusedWithClearErrors) {
  std::string good = serialise_tile(random_result(5, {true, true, {"rays"}}));
  auto refused = [](std::string bytes, const std::string& needle) {
    auto parsed = parse_tile(bytes);
    ASSERT_FALSE(parsed.ok());
    EXPECT_NE(parsed.status().message().find(needle), std::string::npos) << parsed.status();
  };
  std::string bad = good;
  bad[0] = 'X';
  refused(bad, "magic");
  bad = good;
  put_u32(bad, 8, 2);
  refused(bad, "version");
  bad = good;
  put_u32(bad, 12, 256);  // the first bit no version-1 writer sets
  refused(bad, "flags");
  bad = good;
  put_u32(bad, 12, 3 | 64);  // float32 flag set: the payload is now too long
  refused(bad, "payload");
  bad = good;
  put_u32(bad, 12, 2 | 16);  // filtered flag set: the payload is now too short
  refused(bad, "payload");
  bad = good;
  put_u32(bad, 12, 2 | 8);  // rgb flag set: the payload is now too short
  refused(bad, "payload");
  bad = good;
  put_u32(bad, 12, 4);  // halves alone
  refused(bad, "halves (variance buffers) but no gradients");
  bad = good;
  put_u32(bad, 12, 1);  // guides flag cleared: the payload is now too long
  refused(bad, "payload");
  bad = good;
  put_u32(bad, 24, 10);  // x1 < x0
  refused(bad, "tile rect");
  bad = good;
  put_u32(bad, 24, 0x7fffffff);  // a huge tile
  refused(bad, "tile rect");
  bad = good;
  put_u32(bad, 48, 0);  // bins
  refused(bad, "bins");
  bad = good;
  put_u32(bad, 48, 1u << 30);
  refused(bad, "bins");
  bad = good;
  put_u32(bad, 52, 1000);  // counter count
  refused(bad, "counters");
  bad = good;
  put_u32(bad, 56, 0xffffffff);  // counter name length
  refused(bad, "counter name");
  bad = good;
  bad[64] ^= 1;  // declared payload size, after the name "rays" and its length
  refused(bad, "payload");
}

TEST(TileCodec, RandomCorruptionNeverCrashes) {
  TileResult narrow = result_in_float_range(9, {false, true, {"a"}});
  narrow.round_to_float32();
  const std::string goods[3] = {serialise_tile(random_result(9, {false, true, {"a"}})),
                                serialise_tile(narrow),
                                serialise_tile(mostly_empty({false, true, {"a"}}, {{230, 310}}))};
  std::mt19937_64 rng(11);
  for (int trial = 0; trial < 6000; ++trial) {
    std::string bytes = goods[trial % 3];
    // Header bytes (and a few float64 payload bytes of the first, whose every bit pattern
    // round-trips; a float32 signalling NaN would come back quiet).
    const std::size_t header[3] = {72, 69, 76};
    int flips = 1 + int(rng() % 4);
    for (int i = 0; i < flips; ++i) bytes[rng() % header[trial % 3]] = char(rng());
    if (rng() % 2) bytes.resize(rng() % bytes.size());
    auto parsed = parse_tile(bytes);
    if (parsed.ok()) {
      EXPECT_EQ(serialise_tile(*parsed), bytes);
    }
  }
}

}  // namespace
}  // namespace prism::image
