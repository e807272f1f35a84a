// Tiles and images: the one place that documents how Prism lays out pixel memory.
//
//  - TileRect is a half-open pixel rectangle [x0,x1) x [y0,y1) in image coordinates; y grows
//    downwards (raster order). A rect is valid when x0 <= x1 and y0 <= y1; it may be empty.
//  - SampleRange is a half-open range [s0,s1) of sample indices of one pixel.
//  - SpectralImage: width x height pixels, `bins` float32 values per pixel, row-major and
//    pixel-interleaved: value(x,y,b) = data[(y*width + x)*bins + b]. Bin b is the average
//    spectral radiance over the b-th of `bins` equal bins of [360,830] nm.
//  - RgbImage: width x height pixels, 3 floats per pixel (linear R,G,B), row-major:
//    rgb(x,y,c) = data[(y*width + x)*3 + c].
//  - TileResult: what a worker returns for one task (tile rect x sample range). Every buffer is
//    indexed by the pixel's position inside the rect, p = (y - y0)*rect.width() + (x - x0):
//      sums        double, area*bins, sums[p*bins + b]       sum over samples of I[b]
//      sum_squares double, area*bins, sum_squares[p*bins + b] sum over samples of I[b]^2
//      counts      uint64, area,      counts[p]               samples taken in the pixel
//      gradients   double, area*bins, gradients[p*bins + b]   (optional) sum of G[b] estimates
//    (optional halves, with gradients: for the variance-weighted reconstruction)
//      gradient_squares       double, area*bins   sum over samples of G[b]^2 (per-sample values)
//      half_sums              double, area*bins   sums, sum_squares, gradients, gradient_squares
//      half_sum_squares       double, area*bins     and counts over the samples with an even
//      half_gradients         double, area*bins     index only (the odd half is the total minus
//      half_gradient_squares  double, area*bins     these)
//      half_counts            uint64, area
//    (optional rgb: final-pass tasks, for the RGB outputs)
//      rgb_sums    double, area*3,    rgb_sums[p*3 + c]       sum over samples of the sample's
//                                                             linear sRGB R, G, B (c = 0, 1, 2)
//                                                             from its exact wavelengths
//      rgb_squares double, area*3,    rgb_squares[p*3 + c]    sum over samples of their squares
//    (optional filtered: jobs with differential splatting, a second, biased image beside the
//    unbiased one, worker/light_task.cpp; divide by counts like sums)
//      filtered_sums     double, area*bins, filtered_sums[p*bins + b]
//      filtered_rgb_sums double, area*3,    filtered_rgb_sums[p*3 + c]
//    (optional offsets: eye-traced jobs with gathering, worker/integrator.h)
//      offsets     double, area*6,    offsets[p*6 + i]        over the caustic events found
//                                                             with a spectral offset (dx, dy)
//                                                             in pixels per nm, weight w:
//                                                             Σw, Σw·dx, Σw·dy, Σw·dx², Σw·dy²,
//                                                             Σw·dx·dy (i = 0..5)
//      depth       float,  area,      depth[p]                (optional guides) sum of depths
//      normals     float,  area*3,    normals[p*3 + i]        (optional guides) sum of normals
//      albedo      float,  area,      albedo[p]               (optional guides) sum of albedos
//      counters    uint64, area*n,    counters[p*n + c]       (optional) n named event counters
//    All buffers are sums, so results for adjacent sample ranges of the same tile merge by
//    addition; the caller adds them in a fixed order so that merged doubles are reproducible.
//    Guides are sums over the samples that recorded them; divide by the count for the mean.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"

namespace prism::image {

// Largest number of channels per pixel an image or tile may carry: spectral bins (at most
// spectral::WavelengthGrid::kMaxBins, 256) or derived channels such as the prepass's moments.
inline constexpr int kMaxChannels = 4096;
// Largest width or height of an image.
inline constexpr int kMaxImageSide = 1 << 16;
// Largest number of float values in one image (16 GiB of float32 is far beyond any job).
inline constexpr std::uint64_t kMaxImageValues = std::uint64_t{1} << 32;

struct TileRect {
  int x0 = 0;
  int y0 = 0;
  int x1 = 0;
  int y1 = 0;

  int width() const { return x1 - x0; }
  int height() const { return y1 - y0; }
  std::int64_t area() const { return std::int64_t{width()} * height(); }
  bool valid() const { return x0 <= x1 && y0 <= y1; }
  bool empty() const { return x0 >= x1 || y0 >= y1; }
  bool contains(int x, int y) const { return x >= x0 && x < x1 && y >= y0 && y < y1; }
  // True when every pixel of `other` lies inside this rect (an empty rect is inside anything).
  bool contains(const TileRect& other) const {
    return other.empty() || (other.x0 >= x0 && other.x1 <= x1 && other.y0 >= y0 && other.y1 <= y1);
  }
  // The common pixels; an empty intersection is returned as the rect {0,0,0,0}.
  TileRect intersect(const TileRect& other) const;
  friend bool operator==(const TileRect&, const TileRect&) = default;
};

std::string to_string(const TileRect& rect);

struct SampleRange {
  std::uint64_t s0 = 0;
  std::uint64_t s1 = 0;

  std::uint64_t count() const { return s1 > s0 ? s1 - s0 : 0; }
  bool valid() const { return s0 <= s1; }
  friend bool operator==(const SampleRange&, const SampleRange&) = default;
};

// A dense float32 spectral image (layout above). Construction validates the sizes, so every
// SpectralImage in existence has width, height >= 1, 1 <= bins <= kMaxChannels and
// data().size() == width*height*bins.
class SpectralImage {
 public:
  // Zero-filled image. INVALID_ARGUMENT for sizes out of range.
  static absl::StatusOr<SpectralImage> create(int width, int height, int bins);
  // Takes ownership of `data`, which must hold exactly width*height*bins values.
  static absl::StatusOr<SpectralImage> from_data(int width, int height, int bins,
                                                 std::vector<float> data);

  int width() const { return width_; }
  int height() const { return height_; }
  int bins() const { return bins_; }
  TileRect rect() const { return {0, 0, width_, height_}; }

  // Pixel and bin indices must be in range (PRISM_CHECK).
  float value(int x, int y, int b) const { return data_[index(x, y, b)]; }
  float& value(int x, int y, int b) { return data_[index(x, y, b)]; }
  std::span<const float> pixel(int x, int y) const {
    return {data_.data() + index(x, y, 0), static_cast<std::size_t>(bins_)};
  }
  std::span<float> pixel(int x, int y) {
    return {data_.data() + index(x, y, 0), static_cast<std::size_t>(bins_)};
  }
  std::span<const float> data() const { return data_; }
  std::span<float> data() { return data_; }

  // The pixels of `rect`, which must be non-empty and inside the image (INVALID_ARGUMENT).
  absl::StatusOr<SpectralImage> crop(const TileRect& rect) const;
  // Copies `tile` so that its pixel (0,0) lands on (x0,y0). The tile must fit inside this
  // image and have the same number of bins (INVALID_ARGUMENT otherwise; nothing is written).
  absl::Status paste(const SpectralImage& tile, int x0, int y0);

 private:
  SpectralImage(int width, int height, int bins, std::vector<float> data)
      : width_(width), height_(height), bins_(bins), data_(std::move(data)) {}
  std::size_t index(int x, int y, int b) const;

  int width_;
  int height_;
  int bins_;
  std::vector<float> data_;
};

// A dense linear RGB float image (layout above); same validation as SpectralImage with 3 bins.
class RgbImage {
 public:
  static absl::StatusOr<RgbImage> create(int width, int height);
  static absl::StatusOr<RgbImage> from_data(int width, int height, std::vector<float> data);

  int width() const { return width_; }
  int height() const { return height_; }
  TileRect rect() const { return {0, 0, width_, height_}; }
  float value(int x, int y, int c) const { return data_[index(x, y, c)]; }
  float& value(int x, int y, int c) { return data_[index(x, y, c)]; }
  std::span<const float> data() const { return data_; }
  std::span<float> data() { return data_; }

  absl::StatusOr<RgbImage> crop(const TileRect& rect) const;
  absl::Status paste(const RgbImage& tile, int x0, int y0);

 private:
  RgbImage(int width, int height, std::vector<float> data)
      : width_(width), height_(height), data_(std::move(data)) {}
  std::size_t index(int x, int y, int c) const;

  int width_;
  int height_;
  std::vector<float> data_;
};

// Which optional buffers a TileResult carries.
struct TileBuffers {
  bool gradients = false;
  bool guides = false;
  std::vector<std::string> counter_names;  // each 1..kMaxCounterNameLength printable chars
  // The squares of G and the even-indexed half's sums too (the variance-weighted
  // reconstruction needs them); only with gradients.
  bool halves = false;
  // Each sample's linear sRGB from its exact wavelengths (the RGB outputs do not depend on the
  // bins).
  bool rgb = false;
  // The filtered image's sums per bin and its R, G, B (differential splatting).
  bool filtered = false;
  // The spectral offsets of caustic events (gathering).
  bool offsets = false;
  friend bool operator==(const TileBuffers&, const TileBuffers&) = default;
};

inline constexpr int kMaxCounters = 64;
// Values per pixel of the offsets buffer (layout above).
inline constexpr int kOffsetValues = 6;
inline constexpr int kMaxCounterNameLength = 64;
// Largest tile a TileResult may describe (pixels).
inline constexpr std::int64_t kMaxTileArea = std::int64_t{1} << 22;

// Per-tile accumulation buffers (layout in the header comment). Invariant: every buffer has
// exactly the size the layout prescribes for rect(), bins() and buffers().
class TileResult {
 public:
  // INVALID_ARGUMENT when the rect is empty, invalid or larger than kMaxTileArea, the sample
  // range is reversed, bins is outside [1, kMaxChannels], or a counter name is malformed/repeated.
  static absl::StatusOr<TileResult> create(const TileRect& rect, const SampleRange& samples,
                                           int bins, const TileBuffers& buffers = {});
  // The checks of create without allocating anything.
  static absl::Status validate(const TileRect& rect, const SampleRange& samples, int bins,
                               const TileBuffers& buffers);

  const TileRect& rect() const { return rect_; }
  const SampleRange& samples() const { return samples_; }
  int bins() const { return bins_; }
  const TileBuffers& buffers() const { return buffers_; }
  bool has_gradients() const { return buffers_.gradients; }
  bool has_halves() const { return buffers_.halves; }
  bool has_guides() const { return buffers_.guides; }
  bool has_rgb() const { return buffers_.rgb; }
  bool has_filtered() const { return buffers_.filtered; }
  bool has_offsets() const { return buffers_.offsets; }
  int counter_count() const { return static_cast<int>(buffers_.counter_names.size()); }

  // Accumulation by a worker. (x,y) are image coordinates inside rect() (PRISM_CHECK).
  // One call per sample: adds I[b] and I[b]^2 for every bin and counts one sample.
  // `spectrum` must have bins() values.
  void add_sample(int x, int y, std::span<const double> spectrum);
  // Adds a gradient estimate to G[b] (needs gradients).
  void add_gradient(int x, int y, int b, double value);
  // Adds one set of guide features (needs guides).
  void add_guides(int x, int y, float depth, float nx, float ny, float nz, float albedo);
  // Adds `amount` to counter c of the pixel.
  void add_counter(int x, int y, int c, std::uint64_t amount);

  // Merges the result for an adjacent sample range of the same tile: the rects, bins and
  // buffers must match and other.samples() must start where samples() ends or end where it
  // starts. On mismatch returns INVALID_ARGUMENT and leaves this result unchanged.
  absl::Status add(const TileResult& other);

  // The buffers of sums: every double buffer but offsets, in the codec's order. These are what
  // round_to_float32 rounds and what the tile codec may store as float32.
  static constexpr std::size_t kSumBuffers = 12;
  std::array<std::span<const double>, kSumBuffers> sum_buffers() const;
  std::array<std::span<double>, kSumBuffers> mutable_sum_buffers();

  // Rounds every buffer of sums (each double buffer but offsets) to the nearest float32; a
  // finite value beyond float32's range is kept as it is. Task results and finished tiles are
  // rounded before they are stored or sent, so the tile codec keeps their sums as float32 (half
  // the bytes), and a local render and the farm merge the same values (tile_merge.h). Offsets
  // stay double: their second moments are differenced. True when a value changed.
  bool round_to_float32();

  double sum(int x, int y, int b) const { return sums_[value_index(x, y, b)]; }
  double sum_squares(int x, int y, int b) const { return sum_squares_[value_index(x, y, b)]; }
  std::uint64_t count(int x, int y) const { return counts_[pixel_index(x, y)]; }
  double gradient(int x, int y, int b) const;
  std::uint64_t counter(int x, int y, int c) const;

  std::span<const double> sums() const { return sums_; }
  std::span<const double> sum_squares() const { return sum_squares_; }
  std::span<const std::uint64_t> counts() const { return counts_; }
  std::span<const double> gradients() const { return gradients_; }
  std::span<const double> gradient_squares() const { return gradient_squares_; }
  std::span<const double> half_sums() const { return half_sums_; }
  std::span<const double> half_sum_squares() const { return half_sum_squares_; }
  std::span<const double> half_gradients() const { return half_gradients_; }
  std::span<const double> half_gradient_squares() const { return half_gradient_squares_; }
  std::span<const std::uint64_t> half_counts() const { return half_counts_; }
  std::span<const double> rgb_sums() const { return rgb_sums_; }
  std::span<const double> rgb_squares() const { return rgb_squares_; }
  std::span<const double> filtered_sums() const { return filtered_sums_; }
  std::span<const double> filtered_rgb_sums() const { return filtered_rgb_sums_; }
  std::span<const double> offsets() const { return offsets_; }
  std::span<const float> depth() const { return depth_; }
  std::span<const float> normals() const { return normals_; }
  std::span<const float> albedo() const { return albedo_; }
  std::span<const std::uint64_t> counters() const { return counters_; }
  // Mutable views for decoders; their sizes are fixed by the invariant.
  std::span<double> mutable_sums() { return sums_; }
  std::span<double> mutable_sum_squares() { return sum_squares_; }
  std::span<std::uint64_t> mutable_counts() { return counts_; }
  std::span<double> mutable_gradients() { return gradients_; }
  std::span<double> mutable_gradient_squares() { return gradient_squares_; }
  std::span<double> mutable_half_sums() { return half_sums_; }
  std::span<double> mutable_half_sum_squares() { return half_sum_squares_; }
  std::span<double> mutable_half_gradients() { return half_gradients_; }
  std::span<double> mutable_half_gradient_squares() { return half_gradient_squares_; }
  std::span<std::uint64_t> mutable_half_counts() { return half_counts_; }
  std::span<double> mutable_rgb_sums() { return rgb_sums_; }
  std::span<double> mutable_rgb_squares() { return rgb_squares_; }
  std::span<double> mutable_filtered_sums() { return filtered_sums_; }
  std::span<double> mutable_filtered_rgb_sums() { return filtered_rgb_sums_; }
  std::span<double> mutable_offsets() { return offsets_; }
  std::span<float> mutable_depth() { return depth_; }
  std::span<float> mutable_normals() { return normals_; }
  std::span<float> mutable_albedo() { return albedo_; }
  std::span<std::uint64_t> mutable_counters() { return counters_; }

  friend bool operator==(const TileResult&, const TileResult&) = default;

 private:
  TileResult() = default;
  std::size_t pixel_index(int x, int y) const;
  std::size_t value_index(int x, int y, int b) const;

  TileRect rect_;
  SampleRange samples_;
  int bins_ = 0;
  TileBuffers buffers_;
  std::vector<double> sums_;
  std::vector<double> sum_squares_;
  std::vector<std::uint64_t> counts_;
  std::vector<double> gradients_;
  std::vector<double> gradient_squares_;
  std::vector<double> half_sums_;
  std::vector<double> half_sum_squares_;
  std::vector<double> half_gradients_;
  std::vector<double> half_gradient_squares_;
  std::vector<std::uint64_t> half_counts_;
  std::vector<double> rgb_sums_;
  std::vector<double> rgb_squares_;
  std::vector<double> filtered_sums_;
  std::vector<double> filtered_rgb_sums_;
  std::vector<double> offsets_;
  std::vector<float> depth_;
  std::vector<float> normals_;
  std::vector<float> albedo_;
  std::vector<std::uint64_t> counters_;
};

// The worker-side name for the same buffers while they are being filled.
using TileAccumulator = TileResult;

// dst.add(src): merges src into dst (see TileResult::add).
absl::Status merge_into(const TileResult& src, TileResult& dst);

// Per-pixel, per-bin means sum/count as a rect-sized SpectralImage; pixels without samples
// are 0. Means are computed in double and rounded once to float.
SpectralImage finalise(const TileResult& result);
// The same for the gradient sums: per-pixel means of G[b]. The result must carry gradients
// (PRISM_CHECK).
SpectralImage finalise_gradients(const TileResult& result);
// The same for the filtered sums. The result must carry them (PRISM_CHECK).
SpectralImage finalise_filtered(const TileResult& result);

// Copies a finalised tile into the full image at result.rect(); INVALID_ARGUMENT when the
// rect does not fit or the bins differ.
absl::Status paste_tile(const SpectralImage& tile, const TileRect& rect, SpectralImage& image);

}  // namespace prism::image
