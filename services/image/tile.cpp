#include "services/image/tile.h"

#include <bit>
#include <cmath>
#include <limits>
#include <new>
#include <set>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::image {
namespace {

absl::Status validate_image_size(int width, int height, int channels, const char* what) {
  if (width < 1 || height < 1 || width > kMaxImageSide || height > kMaxImageSide) {
    return absl::InvalidArgumentError(absl::StrCat(what, " size ", width, "x", height,
                                                   " is out of range: each side must be in [1, ",
                                                   kMaxImageSide, "]"));
  }
  if (channels < 1 || channels > kMaxChannels) {
    return absl::InvalidArgumentError(
        absl::StrCat(what, " has ", channels, " bins; allowed are 1..", kMaxChannels));
  }
  std::uint64_t values = std::uint64_t(width) * std::uint64_t(height) * std::uint64_t(channels);
  if (values > kMaxImageValues) {
    return absl::ResourceExhaustedError(absl::StrCat(what, " of ", width, "x", height, "x",
                                                     channels, " values exceeds the limit of ",
                                                     kMaxImageValues, " values"));
  }
  return absl::OkStatus();
}

absl::Status validate_region(const TileRect& rect, int width, int height, const char* what) {
  if (!rect.valid() || rect.empty() || !TileRect{0, 0, width, height}.contains(rect)) {
    return absl::InvalidArgumentError(absl::StrCat(what, " ", to_string(rect),
                                                   " must be non-empty and inside the ", width, "x",
                                                   height, " image"));
  }
  return absl::OkStatus();
}

// A zeroed buffer for a whole image; RESOURCE_EXHAUSTED instead of std::bad_alloc when the
// allocation fails (admission control plans memory so that it does not, resource_plan.h).
absl::StatusOr<std::vector<float>> zeros(std::size_t values, const char* what) {
  try {
    return std::vector<float>(values, 0.0f);
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(
        absl::StrCat("cannot allocate the ", what, " (", values * sizeof(float), " bytes)"));
  }
}

// Copies rows of `channels`-interleaved float pixels between two images of the same layout.
void copy_rows(std::span<const float> src, int src_width, int sx0, int sy0, std::span<float> dst,
               int dst_width, int dx0, int dy0, int w, int h, int channels) {
  for (int row = 0; row < h; ++row) {
    auto from = src.begin() + (std::size_t(sy0 + row) * src_width + sx0) * channels;
    auto to = dst.begin() + (std::size_t(dy0 + row) * dst_width + dx0) * channels;
    std::copy(from, from + std::size_t(w) * channels, to);
  }
}

template <typename T>
void add_vectors(std::vector<T>& into, const std::vector<T>& from) {
  for (std::size_t i = 0; i < into.size(); ++i) into[i] += from[i];
}

}  // namespace

TileRect TileRect::intersect(const TileRect& other) const {
  TileRect r{std::max(x0, other.x0), std::max(y0, other.y0), std::min(x1, other.x1),
             std::min(y1, other.y1)};
  if (r.empty()) return {};
  return r;
}

std::string to_string(const TileRect& rect) {
  return absl::StrCat("[", rect.x0, ",", rect.x1, ")x[", rect.y0, ",", rect.y1, ")");
}

absl::StatusOr<SpectralImage> SpectralImage::create(int width, int height, int bins) {
  if (auto s = validate_image_size(width, height, bins, "spectral image"); !s.ok()) return s;
  PRISM_ASSIGN_OR_RETURN(std::vector<float> data,
                         zeros(std::size_t(width) * height * bins, "spectral image"));
  return SpectralImage(width, height, bins, std::move(data));
}

absl::StatusOr<SpectralImage> SpectralImage::from_data(int width, int height, int bins,
                                                       std::vector<float> data) {
  if (auto s = validate_image_size(width, height, bins, "spectral image"); !s.ok()) return s;
  if (data.size() != std::size_t(width) * height * bins) {
    return absl::InvalidArgumentError(absl::StrCat("spectral image ", width, "x", height, "x", bins,
                                                   " needs ", std::size_t(width) * height * bins,
                                                   " values, got ", data.size()));
  }
  return SpectralImage(width, height, bins, std::move(data));
}

std::size_t SpectralImage::index(int x, int y, int b) const {
  PRISM_CHECK(x >= 0 && x < width_ && y >= 0 && y < height_ && b >= 0 && b < bins_);
  return (std::size_t(y) * width_ + x) * bins_ + b;
}

absl::StatusOr<SpectralImage> SpectralImage::crop(const TileRect& rect) const {
  if (auto s = validate_region(rect, width_, height_, "crop"); !s.ok()) return s;
  SpectralImage out(rect.width(), rect.height(), bins_,
                    std::vector<float>(std::size_t(rect.area()) * bins_));
  copy_rows(data_, width_, rect.x0, rect.y0, out.data_, out.width_, 0, 0, rect.width(),
            rect.height(), bins_);
  return out;
}

absl::Status SpectralImage::paste(const SpectralImage& tile, int x0, int y0) {
  if (tile.bins_ != bins_) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot paste a tile with ", tile.bins_, " bins into an image with ", bins_));
  }
  TileRect target{x0, y0, x0 + tile.width_, y0 + tile.height_};
  if (auto s = validate_region(target, width_, height_, "paste target"); !s.ok()) return s;
  copy_rows(tile.data_, tile.width_, 0, 0, data_, width_, x0, y0, tile.width_, tile.height_, bins_);
  return absl::OkStatus();
}

absl::StatusOr<RgbImage> RgbImage::create(int width, int height) {
  if (auto s = validate_image_size(width, height, 3, "RGB image"); !s.ok()) return s;
  PRISM_ASSIGN_OR_RETURN(std::vector<float> data,
                         zeros(std::size_t(width) * height * 3, "RGB image"));
  return RgbImage(width, height, std::move(data));
}

absl::StatusOr<RgbImage> RgbImage::from_data(int width, int height, std::vector<float> data) {
  if (auto s = validate_image_size(width, height, 3, "RGB image"); !s.ok()) return s;
  if (data.size() != std::size_t(width) * height * 3) {
    return absl::InvalidArgumentError(absl::StrCat("RGB image ", width, "x", height, " needs ",
                                                   std::size_t(width) * height * 3, " values, got ",
                                                   data.size()));
  }
  return RgbImage(width, height, std::move(data));
}

std::size_t RgbImage::index(int x, int y, int c) const {
  PRISM_CHECK(x >= 0 && x < width_ && y >= 0 && y < height_ && c >= 0 && c < 3);
  return (std::size_t(y) * width_ + x) * 3 + c;
}

absl::StatusOr<RgbImage> RgbImage::crop(const TileRect& rect) const {
  if (auto s = validate_region(rect, width_, height_, "crop"); !s.ok()) return s;
  RgbImage out(rect.width(), rect.height(), std::vector<float>(std::size_t(rect.area()) * 3));
  copy_rows(data_, width_, rect.x0, rect.y0, out.data_, out.width_, 0, 0, rect.width(),
            rect.height(), 3);
  return out;
}

absl::Status RgbImage::paste(const RgbImage& tile, int x0, int y0) {
  TileRect target{x0, y0, x0 + tile.width_, y0 + tile.height_};
  if (auto s = validate_region(target, width_, height_, "paste target"); !s.ok()) return s;
  copy_rows(tile.data_, tile.width_, 0, 0, data_, width_, x0, y0, tile.width_, tile.height_, 3);
  return absl::OkStatus();
}

absl::Status TileResult::validate(const TileRect& rect, const SampleRange& samples, int bins,
                                  const TileBuffers& buffers) {
  if (!rect.valid() || rect.empty() || rect.x0 < 0 || rect.y0 < 0 || rect.x1 > kMaxImageSide ||
      rect.y1 > kMaxImageSide) {
    return absl::InvalidArgumentError(absl::StrCat("tile rect ", to_string(rect),
                                                   " must be non-empty and inside [0, ",
                                                   kMaxImageSide, ") on both axes"));
  }
  if (rect.area() > kMaxTileArea) {
    return absl::InvalidArgumentError(absl::StrCat("tile rect ", to_string(rect), " has ",
                                                   rect.area(), " pixels, over the limit of ",
                                                   kMaxTileArea));
  }
  if (!samples.valid()) {
    return absl::InvalidArgumentError(
        absl::StrCat("sample range [", samples.s0, ",", samples.s1, ") is reversed"));
  }
  if (bins < 1 || bins > kMaxChannels) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile has ", bins, " bins; allowed are 1..", kMaxChannels));
  }
  if (buffers.halves && !buffers.gradients) {
    return absl::InvalidArgumentError("tile has halves (variance buffers) but no gradients");
  }
  if (buffers.counter_names.size() > std::size_t(kMaxCounters)) {
    return absl::InvalidArgumentError(absl::StrCat("tile has ", buffers.counter_names.size(),
                                                   " counters; at most ", kMaxCounters,
                                                   " are allowed"));
  }
  std::set<std::string> seen;
  for (const std::string& name : buffers.counter_names) {
    bool printable =
        std::all_of(name.begin(), name.end(), [](char c) { return c > 0x20 && c < 0x7f; });
    if (name.empty() || name.size() > std::size_t(kMaxCounterNameLength) || !printable) {
      return absl::InvalidArgumentError(absl::StrCat("counter name \"", name, "\" must be 1..",
                                                     kMaxCounterNameLength,
                                                     " printable ASCII characters without spaces"));
    }
    if (!seen.insert(name).second) {
      return absl::InvalidArgumentError(absl::StrCat("counter name \"", name, "\" is repeated"));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<TileResult> TileResult::create(const TileRect& rect, const SampleRange& samples,
                                              int bins, const TileBuffers& buffers) {
  if (auto status = validate(rect, samples, bins, buffers); !status.ok()) return status;
  TileResult r;
  r.rect_ = rect;
  r.samples_ = samples;
  r.bins_ = bins;
  r.buffers_ = buffers;
  std::size_t area = std::size_t(rect.area());
  r.sums_.assign(area * bins, 0.0);
  r.sum_squares_.assign(area * bins, 0.0);
  r.counts_.assign(area, 0);
  if (buffers.gradients) r.gradients_.assign(area * bins, 0.0);
  if (buffers.halves) {
    for (std::vector<double>* v : {&r.gradient_squares_, &r.half_sums_, &r.half_sum_squares_,
                                   &r.half_gradients_, &r.half_gradient_squares_}) {
      v->assign(area * bins, 0.0);
    }
    r.half_counts_.assign(area, 0);
  }
  if (buffers.rgb) {
    r.rgb_sums_.assign(area * 3, 0.0);
    r.rgb_squares_.assign(area * 3, 0.0);
  }
  if (buffers.filtered) {
    r.filtered_sums_.assign(area * bins, 0.0);
    r.filtered_rgb_sums_.assign(area * 3, 0.0);
  }
  if (buffers.offsets) r.offsets_.assign(area * kOffsetValues, 0.0);
  if (buffers.guides) {
    r.depth_.assign(area, 0.0f);
    r.normals_.assign(area * 3, 0.0f);
    r.albedo_.assign(area, 0.0f);
  }
  r.counters_.assign(area * buffers.counter_names.size(), 0);
  return r;
}

std::size_t TileResult::pixel_index(int x, int y) const {
  PRISM_CHECK(rect_.contains(x, y));
  return std::size_t(y - rect_.y0) * rect_.width() + (x - rect_.x0);
}

std::size_t TileResult::value_index(int x, int y, int b) const {
  PRISM_CHECK(b >= 0 && b < bins_);
  return pixel_index(x, y) * bins_ + b;
}

void TileResult::add_sample(int x, int y, std::span<const double> spectrum) {
  PRISM_CHECK(spectrum.size() == std::size_t(bins_));
  std::size_t base = pixel_index(x, y) * bins_;
  for (int b = 0; b < bins_; ++b) {
    sums_[base + b] += spectrum[b];
    sum_squares_[base + b] += spectrum[b] * spectrum[b];
  }
  counts_[pixel_index(x, y)] += 1;
}

void TileResult::add_gradient(int x, int y, int b, double value) {
  PRISM_CHECK(buffers_.gradients);
  gradients_[value_index(x, y, b)] += value;
}

void TileResult::add_guides(int x, int y, float depth, float nx, float ny, float nz, float albedo) {
  PRISM_CHECK(buffers_.guides);
  std::size_t p = pixel_index(x, y);
  depth_[p] += depth;
  normals_[p * 3 + 0] += nx;
  normals_[p * 3 + 1] += ny;
  normals_[p * 3 + 2] += nz;
  albedo_[p] += albedo;
}

void TileResult::add_counter(int x, int y, int c, std::uint64_t amount) {
  PRISM_CHECK(c >= 0 && c < counter_count());
  counters_[pixel_index(x, y) * counter_count() + c] += amount;
}

double TileResult::gradient(int x, int y, int b) const {
  PRISM_CHECK(buffers_.gradients);
  return gradients_[value_index(x, y, b)];
}

std::uint64_t TileResult::counter(int x, int y, int c) const {
  PRISM_CHECK(c >= 0 && c < counter_count());
  return counters_[pixel_index(x, y) * counter_count() + c];
}

absl::Status TileResult::add(const TileResult& other) {
  if (other.rect_ != rect_) {
    return absl::InvalidArgumentError(absl::StrCat("cannot merge tile ", to_string(other.rect_),
                                                   " into tile ", to_string(rect_)));
  }
  if (other.bins_ != bins_) {
    return absl::InvalidArgumentError(absl::StrCat("cannot merge a tile with ", other.bins_,
                                                   " bins into one with ", bins_, " bins"));
  }
  if (other.buffers_ != buffers_) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot merge tile results of ", to_string(rect_),
                     " with different optional buffers (gradients, "
                     "halves, rgb, filtered, offsets, guides or counter names "
                     "differ)"));
  }
  SampleRange merged;
  if (other.samples_.s0 == samples_.s1) {
    merged = {samples_.s0, other.samples_.s1};
  } else if (other.samples_.s1 == samples_.s0) {
    merged = {other.samples_.s0, samples_.s1};
  } else {
    return absl::InvalidArgumentError(absl::StrCat("cannot merge samples [", other.samples_.s0, ",",
                                                   other.samples_.s1, ") of tile ",
                                                   to_string(rect_), " into [", samples_.s0, ",",
                                                   samples_.s1, "): the ranges must be adjacent"));
  }
  samples_ = merged;
  add_vectors(sums_, other.sums_);
  add_vectors(sum_squares_, other.sum_squares_);
  add_vectors(counts_, other.counts_);
  add_vectors(gradients_, other.gradients_);
  add_vectors(gradient_squares_, other.gradient_squares_);
  add_vectors(half_sums_, other.half_sums_);
  add_vectors(half_sum_squares_, other.half_sum_squares_);
  add_vectors(half_gradients_, other.half_gradients_);
  add_vectors(half_gradient_squares_, other.half_gradient_squares_);
  add_vectors(half_counts_, other.half_counts_);
  add_vectors(rgb_sums_, other.rgb_sums_);
  add_vectors(rgb_squares_, other.rgb_squares_);
  add_vectors(filtered_sums_, other.filtered_sums_);
  add_vectors(filtered_rgb_sums_, other.filtered_rgb_sums_);
  add_vectors(offsets_, other.offsets_);
  add_vectors(depth_, other.depth_);
  add_vectors(normals_, other.normals_);
  add_vectors(albedo_, other.albedo_);
  add_vectors(counters_, other.counters_);
  return absl::OkStatus();
}

std::array<std::span<const double>, TileResult::kSumBuffers> TileResult::sum_buffers() const {
  return {sums_,      sum_squares_,      gradients_,      gradient_squares_,
          half_sums_, half_sum_squares_, half_gradients_, half_gradient_squares_,
          rgb_sums_,  rgb_squares_,      filtered_sums_,  filtered_rgb_sums_};
}

std::array<std::span<double>, TileResult::kSumBuffers> TileResult::mutable_sum_buffers() {
  return {sums_,      sum_squares_,      gradients_,      gradient_squares_,
          half_sums_, half_sum_squares_, half_gradients_, half_gradient_squares_,
          rgb_sums_,  rgb_squares_,      filtered_sums_,  filtered_rgb_sums_};
}

bool TileResult::round_to_float32() {
  constexpr double kLargest = std::numeric_limits<float>::max();
  constexpr double kLargestDouble = std::numeric_limits<double>::max();
  std::uint64_t changed = 0;
  for (std::span<double> buffer : mutable_sum_buffers()) {
    // Branch-free, so the compiler vectorises it: at 64 bins and 1 spp this pass was a tenth
    // of a render's CPU time.
    for (double& v : buffer) {
      const double x = v;
      const double rounded = static_cast<float>(x);
      const double a = std::abs(x);
      const double kept = a > kLargest && a <= kLargestDouble ? x : rounded;
      changed |= std::bit_cast<std::uint64_t>(kept) ^ std::bit_cast<std::uint64_t>(x);
      v = kept;
    }
  }
  return changed != 0;
}

absl::Status merge_into(const TileResult& src, TileResult& dst) {
  return dst.add(src);
}

namespace {

// Per-pixel means sums/count of one area·bins buffer of `result`, rounded once to float.
SpectralImage means_of(const TileResult& result, std::span<const double> sums) {
  const TileRect& rect = result.rect();
  int bins = result.bins();
  std::vector<float> means(std::size_t(rect.area()) * bins, 0.0f);
  std::span<const std::uint64_t> counts = result.counts();
  for (std::size_t p = 0; p < counts.size(); ++p) {
    if (counts[p] == 0) continue;
    double n = static_cast<double>(counts[p]);
    for (int b = 0; b < bins; ++b) {
      means[p * bins + b] = static_cast<float>(sums[p * bins + b] / n);
    }
  }
  auto image = SpectralImage::from_data(rect.width(), rect.height(), bins, std::move(means));
  PRISM_CHECK_MSG(image.ok(), "a valid TileResult always has a valid image size");
  return std::move(image).value();
}

}  // namespace

SpectralImage finalise(const TileResult& result) {
  return means_of(result, result.sums());
}

SpectralImage finalise_gradients(const TileResult& result) {
  PRISM_CHECK(result.has_gradients());
  return means_of(result, result.gradients());
}

SpectralImage finalise_filtered(const TileResult& result) {
  PRISM_CHECK(result.has_filtered());
  return means_of(result, result.filtered_sums());
}

absl::Status paste_tile(const SpectralImage& tile, const TileRect& rect, SpectralImage& image) {
  if (tile.width() != rect.width() || tile.height() != rect.height()) {
    return absl::InvalidArgumentError(absl::StrCat("tile of ", tile.width(), "x", tile.height(),
                                                   " does not match its rect ", to_string(rect)));
  }
  return image.paste(tile, rect.x0, rect.y0);
}

}  // namespace prism::image
