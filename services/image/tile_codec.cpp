#include "services/image/tile_codec.h"

#include <algorithm>
#include <bit>
#include <cstring>
#include <iterator>
#include <span>
#include <type_traits>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/little_endian.h"

namespace prism::image {
namespace {

constexpr std::uint32_t kFlagGradients = 1u << 0;
constexpr std::uint32_t kFlagGuides = 1u << 1;
constexpr std::uint32_t kFlagHalves = 1u << 2;
constexpr std::uint32_t kFlagRgb = 1u << 3;
constexpr std::uint32_t kFlagFiltered = 1u << 4;
constexpr std::uint32_t kFlagOffsets = 1u << 5;
constexpr std::uint32_t kFlagFloat32 = 1u << 6;
constexpr std::uint32_t kFlagSparse = 1u << 7;
constexpr std::uint32_t kKnownFlags = kFlagGradients | kFlagGuides | kFlagHalves | kFlagRgb |
                                      kFlagFiltered | kFlagOffsets | kFlagFloat32 | kFlagSparse;

// Values converted at a time between the float32 encoding and a double buffer.
constexpr std::size_t kConvertChunk = 4096;

class Writer {
 public:
  explicit Writer(std::string& out) : out_(out) {}
  void u32(std::uint32_t v) { put(v, 4); }
  void u64(std::uint64_t v) { put(v, 8); }
  void i32(std::int32_t v) { put(static_cast<std::uint32_t>(v), 4); }
  void f64(double v) { put(std::bit_cast<std::uint64_t>(v), 8); }
  void f32(float v) { put(std::bit_cast<std::uint32_t>(v), 4); }
  void bytes(std::string_view s) { out_.append(s); }
  // A whole array of doubles, floats or uint64s, little-endian: one copy on a little-endian host.
  template <typename Range>
  void values(const Range& range) {
    using T = std::remove_cvref_t<decltype(*std::data(range))>;
    static_assert(sizeof(T) == 4 || sizeof(T) == 8);
    if constexpr (std::endian::native == std::endian::little) {
      out_.append(reinterpret_cast<const char*>(std::data(range)), std::size(range) * sizeof(T));
    } else {
      using U = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;
      for (const T& v : range) put(std::bit_cast<U>(v), sizeof(T));
    }
  }
  // A buffer of sums: as doubles, or as the float32 values they hold.
  void sums(std::span<const double> range, bool float32) {
    if (!float32) return values(range);
    float chunk[kConvertChunk];
    for (std::size_t i = 0; i < range.size(); i += kConvertChunk) {
      const std::size_t n = std::min(kConvertChunk, range.size() - i);
      for (std::size_t k = 0; k < n; ++k) chunk[k] = static_cast<float>(range[i + k]);
      values(std::span<const float>(chunk, n));
    }
  }

 private:
  void put(std::uint64_t v, int n) { base::append_le(out_, v, n); }
  std::string& out_;
};

class Reader {
 public:
  explicit Reader(std::string_view in) : in_(in) {}
  std::size_t offset() const { return pos_; }
  std::size_t remaining() const { return in_.size() - pos_; }

  absl::Status need(std::size_t n, std::string_view field) const {
    if (remaining() < n) {
      return absl::InvalidArgumentError(absl::StrCat("tile result truncated: ", std::string(field),
                                                     " at byte ", pos_, " needs ", n, " bytes, ",
                                                     remaining(), " left"));
    }
    return absl::OkStatus();
  }
  absl::StatusOr<std::uint64_t> uint(int n, std::string_view field) {
    if (auto s = need(n, field); !s.ok()) return s;
    const std::uint64_t v = base::get_le(in_.data() + pos_, n);
    pos_ += n;
    return v;
  }
  absl::StatusOr<std::string_view> bytes(std::size_t n, std::string_view field) {
    if (auto s = need(n, field); !s.ok()) return s;
    std::string_view v = in_.substr(pos_, n);
    pos_ += n;
    return v;
  }
  // Payload reads: the caller has checked the exact total length beforehand. A whole array of
  // doubles, floats or uint64s, as Writer::values wrote it.
  template <typename Range>
  void raw_values(Range&& range) {
    using T = std::remove_cvref_t<decltype(*std::data(range))>;
    static_assert(sizeof(T) == 4 || sizeof(T) == 8);
    const std::size_t n = std::size(range) * sizeof(T);
    PRISM_CHECK(remaining() >= n);
    if constexpr (std::endian::native == std::endian::little) {
      if (n > 0) std::memcpy(std::data(range), in_.data() + pos_, n);
      pos_ += n;
    } else {
      using U = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;
      for (T& v : range) v = std::bit_cast<T>(static_cast<U>(raw(sizeof(T))));
    }
  }
  void raw_sums(std::span<double> range, bool float32) {
    if (!float32) return raw_values(range);
    float chunk[kConvertChunk];
    for (std::size_t i = 0; i < range.size(); i += kConvertChunk) {
      const std::size_t n = std::min(kConvertChunk, range.size() - i);
      raw_values(std::span<float>(chunk, n));
      for (std::size_t k = 0; k < n; ++k) range[i + k] = chunk[k];
    }
  }

 private:
  std::uint64_t raw(int n) {
    PRISM_CHECK(remaining() >= std::size_t(n));
    const std::uint64_t v = base::get_le(in_.data() + pos_, n);
    pos_ += n;
    return v;
  }
  std::string_view in_;
  std::size_t pos_ = 0;
};

std::uint64_t payload_bytes(std::uint64_t area, std::uint64_t bins, const TileBuffers& buffers,
                            std::uint64_t counters, bool float32) {
  const bool gradients = buffers.gradients, halves = buffers.halves, rgb = buffers.rgb,
             guides = buffers.guides;
  const std::uint64_t s = float32 ? 4 : 8;  // bytes of one value of sums
  std::uint64_t n = area * bins * s * 2 + area * 8;
  if (gradients) n += area * bins * s;
  if (halves) n += area * bins * s * 5 + area * 8;
  if (rgb) n += area * 3 * s * 2;
  if (buffers.filtered) n += area * bins * s + area * 3 * s;
  if (buffers.offsets) n += area * kOffsetValues * 8;
  if (guides) n += area * 4 * 5;
  n += area * counters * 8;
  return n;
}

// True when every value of the result's buffers of sums is a float32 value (bit for bit, so a
// NaN payload float32 cannot hold keeps the result in doubles).
bool sums_are_float32(const TileResult& result) {
  for (std::span<const double> buffer : result.sum_buffers()) {
    for (double v : buffer) {
      if (std::bit_cast<std::uint64_t>(static_cast<double>(static_cast<float>(v))) !=
          std::bit_cast<std::uint64_t>(v)) {
        return false;
      }
    }
  }
  return true;
}

// The pixels an encoding holds: all of them (dense), or with flag bit 7 the blocks of side x side
// pixels (row-major over the rect, the last ones clipped) that are set in a bitmap.
class Blocks {
 public:
  explicit Blocks(const TileRect& rect) : width_(rect.width()), height_(rect.height()) {}
  Blocks(const TileRect& rect, int side)
      : width_(rect.width()),
        height_(rect.height()),
        side_(side),
        across_((width_ + side - 1) / side),
        down_((height_ + side - 1) / side),
        present_(std::size_t(across_) * std::size_t(down_), 0) {}

  bool sparse() const { return side_ > 0; }
  int side() const { return side_; }
  std::size_t count() const { return present_.size(); }
  bool present(std::size_t block) const { return present_[block] != 0; }
  void set(std::size_t block) { present_[block] = 1; }
  // The block of pixel p (p = y*width + x).
  std::size_t block_of(std::size_t p) const {
    const std::size_t x = p % std::size_t(width_), y = p / std::size_t(width_);
    return (y / std::size_t(side_)) * std::size_t(across_) + x / std::size_t(side_);
  }
  std::uint64_t pixels() const {
    if (!sparse()) return std::uint64_t(width_) * std::uint64_t(height_);
    std::uint64_t n = 0;
    for (std::size_t b = 0; b < present_.size(); ++b) {
      if (present_[b] != 0) n += std::uint64_t(block_rect(b).area());
    }
    return n;
  }
  // Calls run(first, count) for each run of a buffer's values that the encoding holds, in its
  // order (`buffer_size` values over the rect's pixels).
  template <typename Run>
  void for_each_run(std::size_t buffer_size, Run&& run) const {
    if (buffer_size == 0) return;
    if (!sparse()) return run(std::size_t{0}, buffer_size);
    const std::size_t k = buffer_size / (std::size_t(width_) * std::size_t(height_));
    for (std::size_t b = 0; b < present_.size(); ++b) {
      if (present_[b] == 0) continue;
      const TileRect r = block_rect(b);
      for (int y = r.y0; y < r.y1; ++y) {
        run((std::size_t(y) * std::size_t(width_) + std::size_t(r.x0)) * k,
            std::size_t(r.width()) * k);
      }
    }
  }

 private:
  TileRect block_rect(std::size_t b) const {
    const int bx = int(b % std::size_t(across_)), by = int(b / std::size_t(across_));
    return {bx * side_, by * side_, std::min(width_, (bx + 1) * side_),
            std::min(height_, (by + 1) * side_)};
  }
  int width_, height_;
  int side_ = 0, across_ = 0, down_ = 0;
  std::vector<std::uint8_t> present_;
};

// Side of the blocks a sparse encoding leaves out.
constexpr int kSparseBlock = 16;

// The sparse blocks of `result`: those holding a pixel whose values are not all zero bits or
// whose count is not the result's sample count; the dense layout when every block does (or the
// result has halves, whose counts differ per pixel).
Blocks blocks_of(const TileResult& result) {
  const TileRect& rect = result.rect();
  if (result.has_halves()) return Blocks(rect);
  const std::size_t area = std::size_t(rect.area());
  std::vector<std::uint8_t> busy(area, 0);
  auto mark = [&](auto values) {
    if (values.empty()) return;
    const std::size_t k = values.size() / area;
    for (std::size_t p = 0; p < area; ++p) {
      if (busy[p] != 0) continue;
      for (std::size_t j = 0; j < k; ++j) {
        using T = std::remove_cvref_t<decltype(values[0])>;
        using U = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;
        if (std::bit_cast<U>(values[p * k + j]) != 0) {
          busy[p] = 1;
          break;
        }
      }
    }
  };
  for (std::span<const double> buffer : result.sum_buffers()) mark(buffer);
  mark(result.offsets());
  for (std::span<const float> buffer : {result.depth(), result.normals(), result.albedo()}) {
    mark(buffer);
  }
  mark(result.counters());
  const std::uint64_t samples = result.samples().count();
  std::span<const std::uint64_t> counts = result.counts();
  for (std::size_t p = 0; p < area; ++p) {
    if (counts[p] != samples) busy[p] = 1;
  }
  Blocks blocks(rect, kSparseBlock);
  for (std::size_t p = 0; p < area; ++p) {
    if (busy[p] != 0) blocks.set(blocks.block_of(p));
  }
  for (std::size_t b = 0; b < blocks.count(); ++b) {
    if (!blocks.present(b)) return blocks;  // one block left out: worth its bitmap
  }
  return Blocks(rect);
}

}  // namespace

std::string serialise_tile(const TileResult& result) {
  std::string out;
  const TileRect& rect = result.rect();
  const bool float32 = sums_are_float32(result);
  const Blocks blocks = blocks_of(result);
  std::uint64_t payload = payload_bytes(blocks.pixels(), result.bins(), result.buffers(),
                                        result.counter_count(), float32);
  out.reserve(64 + payload);
  Writer w(out);
  w.bytes(kTileMagic);
  w.u32(kTileFormatVersion);
  w.u32((result.has_gradients() ? kFlagGradients : 0) | (result.has_guides() ? kFlagGuides : 0) |
        (result.has_halves() ? kFlagHalves : 0) | (result.has_rgb() ? kFlagRgb : 0) |
        (result.has_filtered() ? kFlagFiltered : 0) | (result.has_offsets() ? kFlagOffsets : 0) |
        (float32 ? kFlagFloat32 : 0) | (blocks.sparse() ? kFlagSparse : 0));
  w.i32(rect.x0);
  w.i32(rect.y0);
  w.i32(rect.x1);
  w.i32(rect.y1);
  w.u64(result.samples().s0);
  w.u64(result.samples().s1);
  w.u32(static_cast<std::uint32_t>(result.bins()));
  w.u32(static_cast<std::uint32_t>(result.counter_count()));
  for (const std::string& name : result.buffers().counter_names) {
    w.u32(static_cast<std::uint32_t>(name.size()));
    w.bytes(name);
  }
  w.u64(payload);
  if (blocks.sparse()) {
    w.u32(static_cast<std::uint32_t>(blocks.side()));
    std::string bitmap((blocks.count() + 7) / 8, '\0');
    for (std::size_t b = 0; b < blocks.count(); ++b) {
      if (blocks.present(b)) bitmap[b / 8] = char(std::uint8_t(bitmap[b / 8]) | (1u << (b % 8)));
    }
    w.bytes(bitmap);
  }
  auto sums = [&](std::span<const double> values) {
    blocks.for_each_run(values.size(), [&](std::size_t first, std::size_t n) {
      w.sums(values.subspan(first, n), float32);
    });
  };
  auto plain = [&](auto values) {
    blocks.for_each_run(values.size(), [&](std::size_t first, std::size_t n) {
      w.values(values.subspan(first, n));
    });
  };
  sums(result.sums());
  sums(result.sum_squares());
  plain(result.counts());
  sums(result.gradients());
  sums(result.gradient_squares());
  sums(result.half_sums());
  sums(result.half_sum_squares());
  sums(result.half_gradients());
  sums(result.half_gradient_squares());
  plain(result.half_counts());
  sums(result.rgb_sums());
  sums(result.rgb_squares());
  sums(result.filtered_sums());
  sums(result.filtered_rgb_sums());
  plain(result.offsets());
  plain(result.depth());
  plain(result.normals());
  plain(result.albedo());
  plain(result.counters());
  return out;
}

std::string serialise_task_result(TileResult result) {
  result.round_to_float32();
  return serialise_tile(result);
}

absl::StatusOr<TileResult> parse_tile(std::string_view bytes) {
  Reader r(bytes);
  auto magic = r.bytes(kTileMagic.size(), "magic");
  if (!magic.ok()) return magic.status();
  if (*magic != kTileMagic) {
    return absl::InvalidArgumentError("not a Prism tile result: the magic bytes are wrong");
  }
  auto version = r.uint(4, "version");
  if (!version.ok()) return version.status();
  if (*version != kTileFormatVersion) {
    return absl::InvalidArgumentError(absl::StrCat("tile result has format version ", *version,
                                                   "; this build reads version ",
                                                   kTileFormatVersion));
  }
  auto flags = r.uint(4, "flags");
  if (!flags.ok()) return flags.status();
  if ((*flags & ~std::uint64_t{kKnownFlags}) != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile result has unknown flags 0x", absl::Hex(*flags)));
  }
  std::int32_t coords[4];
  const char* names[4] = {"x0", "y0", "x1", "y1"};
  for (int i = 0; i < 4; ++i) {
    auto v = r.uint(4, names[i]);
    if (!v.ok()) return v.status();
    coords[i] = static_cast<std::int32_t>(static_cast<std::uint32_t>(*v));
  }
  auto s0 = r.uint(8, "s0");
  if (!s0.ok()) return s0.status();
  auto s1 = r.uint(8, "s1");
  if (!s1.ok()) return s1.status();
  auto bins = r.uint(4, "bins");
  if (!bins.ok()) return bins.status();
  if (*bins < 1 || *bins > std::uint64_t(kMaxChannels)) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile result has ", *bins, " bins; allowed are 1..", kMaxChannels));
  }
  auto counter_count = r.uint(4, "counter count");
  if (!counter_count.ok()) return counter_count.status();
  if (*counter_count > std::uint64_t(kMaxCounters)) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile result has ", *counter_count, " counters; at most ", kMaxCounters));
  }
  TileBuffers buffers;
  buffers.gradients = (*flags & kFlagGradients) != 0;
  buffers.guides = (*flags & kFlagGuides) != 0;
  buffers.halves = (*flags & kFlagHalves) != 0;
  buffers.rgb = (*flags & kFlagRgb) != 0;
  buffers.filtered = (*flags & kFlagFiltered) != 0;
  buffers.offsets = (*flags & kFlagOffsets) != 0;
  const bool float32 = (*flags & kFlagFloat32) != 0;
  const bool sparse = (*flags & kFlagSparse) != 0;
  if (sparse && buffers.halves) {
    return absl::InvalidArgumentError("tile result is sparse and has halves; halves are dense");
  }
  for (std::uint64_t c = 0; c < *counter_count; ++c) {
    auto length = r.uint(4, "counter name length");
    if (!length.ok()) return length.status();
    if (*length < 1 || *length > std::uint64_t(kMaxCounterNameLength)) {
      return absl::InvalidArgumentError(absl::StrCat("counter name ", c, " has length ", *length,
                                                     "; allowed are 1..", kMaxCounterNameLength));
    }
    auto name = r.bytes(*length, "counter name");
    if (!name.ok()) return name.status();
    buffers.counter_names.emplace_back(*name);
  }
  auto declared = r.uint(8, "payload size");
  if (!declared.ok()) return declared.status();

  TileRect rect{coords[0], coords[1], coords[2], coords[3]};
  SampleRange samples{*s0, *s1};
  if (auto status = TileResult::validate(rect, samples, static_cast<int>(*bins), buffers);
      !status.ok()) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile result header is invalid: ", status.message()));
  }
  Blocks blocks(rect);
  if (sparse) {
    auto side = r.uint(4, "block side");
    if (!side.ok()) return side.status();
    if (*side < 1 || *side > std::uint64_t(kMaxImageSide)) {
      return absl::InvalidArgumentError(absl::StrCat("tile result has sparse blocks of side ",
                                                     *side, "; allowed are 1..", kMaxImageSide));
    }
    blocks = Blocks(rect, int(*side));
    auto bitmap = r.bytes((blocks.count() + 7) / 8, "block bitmap");
    if (!bitmap.ok()) return bitmap.status();
    for (std::size_t i = 0; i < bitmap->size() * 8; ++i) {
      if ((std::uint8_t((*bitmap)[i / 8]) >> (i % 8) & 1u) == 0) continue;
      if (i >= blocks.count()) {
        return absl::InvalidArgumentError(
            absl::StrCat("tile result's block bitmap sets block ", i, " of ", blocks.count()));
      }
      blocks.set(i);
    }
  }
  // Checked before anything is allocated, so a lying header cannot make us allocate.
  std::uint64_t expected = payload_bytes(blocks.pixels(), *bins, buffers, *counter_count, float32);
  if (*declared != expected) {
    return absl::InvalidArgumentError(absl::StrCat("tile result declares a payload of ", *declared,
                                                   " bytes but its header implies ", expected));
  }
  if (r.remaining() != expected) {
    return absl::InvalidArgumentError(absl::StrCat(
        "tile result payload at byte ", r.offset(), " is ", r.remaining(), " bytes, expected ",
        expected, r.remaining() < expected ? " (truncated)" : " (trailing bytes)"));
  }
  auto result = TileResult::create(rect, samples, static_cast<int>(*bins), buffers);
  PRISM_CHECK(result.ok());
  TileResult& t = *result;
  // Pixels a sparse encoding leaves out hold zeros and the range's sample count.
  if (blocks.sparse()) std::ranges::fill(t.mutable_counts(), samples.count());
  auto sums = [&](std::span<double> values) {
    blocks.for_each_run(values.size(), [&](std::size_t first, std::size_t n) {
      r.raw_sums(values.subspan(first, n), float32);
    });
  };
  auto plain = [&](auto values) {
    blocks.for_each_run(values.size(), [&](std::size_t first, std::size_t n) {
      r.raw_values(values.subspan(first, n));
    });
  };
  sums(t.mutable_sums());
  sums(t.mutable_sum_squares());
  plain(t.mutable_counts());
  sums(t.mutable_gradients());
  sums(t.mutable_gradient_squares());
  sums(t.mutable_half_sums());
  sums(t.mutable_half_sum_squares());
  sums(t.mutable_half_gradients());
  sums(t.mutable_half_gradient_squares());
  plain(t.mutable_half_counts());
  sums(t.mutable_rgb_sums());
  sums(t.mutable_rgb_squares());
  sums(t.mutable_filtered_sums());
  sums(t.mutable_filtered_rgb_sums());
  plain(t.mutable_offsets());
  plain(t.mutable_depth());
  plain(t.mutable_normals());
  plain(t.mutable_albedo());
  plain(t.mutable_counters());
  PRISM_CHECK(r.remaining() == 0);
  return result;
}

}  // namespace prism::image
