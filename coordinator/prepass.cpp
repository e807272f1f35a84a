#include "coordinator/prepass.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/spectral/pixel_tables.h"

namespace prism::coordinator {
namespace {

// Large enough for any sensible filter (the paper uses 1–2 px), small enough that a job cannot
// ask the coordinator for a window of millions of pixels per pixel.
constexpr double kMaxSigmaS = 64.0;

absl::Status bad_field(const std::string& field, double value, const std::string& allowed) {
  return absl::InvalidArgumentError(
      absl::StrCat("prepass ", field, " is ", value, "; it must be ", allowed));
}

absl::Status check_size(int width, int height, const std::string& what) {
  if (width < 1 || height < 1 || width > image::kMaxImageSide || height > image::kMaxImageSide) {
    return absl::InvalidArgumentError(absl::StrCat(what, " must be 1 to ", image::kMaxImageSide,
                                                   " pixels on each side, got ", width, "x",
                                                   height));
  }
  return absl::OkStatus();
}

// Rows in parallel; grain 1 row because a row is already thousands of pixel operations.
template <typename RowFn>
void for_each_row(int height, const RowFn& row_fn) {
  tbb::parallel_for(tbb::blocked_range<int>(0, height, 1),
                    [&](const tbb::blocked_range<int>& rows) { row_fn(rows.begin(), rows.end()); });
}

double squared_distance(const GuideFeatures& a, const GuideFeatures& b) {
  const double d0 = double(a.depth) - b.depth, d1 = double(a.nx) - b.nx,
               d2 = double(a.ny) - b.ny, d3 = double(a.nz) - b.nz,
               d4 = double(a.albedo) - b.albedo;
  return d0 * d0 + d1 * d1 + d2 * d2 + d3 * d3 + d4 * d4;
}

}  // namespace

absl::Status PrepassParameters::validate() const {
  if (passes < 1 || passes > kMaxPasses) {
    return bad_field("passes", passes, absl::StrCat("1 to ", kMaxPasses));
  }
  if (spp < 1) return bad_field("spp", spp, "at least 1");
  if (!(std::isfinite(epsilon) && epsilon > 0.0 && epsilon < 1.0)) {
    return bad_field("epsilon", epsilon, "in (0, 1)");
  }
  if (!(std::isfinite(fallback) && fallback >= 0.0)) {
    return bad_field("fallback", fallback, "finite and >= 0");
  }
  if (!(std::isfinite(sigma_s) && sigma_s > 0.0 && sigma_s <= kMaxSigmaS)) {
    return bad_field("sigma_s", sigma_s, absl::StrCat("in (0, ", kMaxSigmaS, "] pixels"));
  }
  if (!(std::isfinite(sigma_r) && sigma_r > 0.0)) {
    return bad_field("sigma_r", sigma_r, "finite and > 0");
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<PrepassPass>> prepass_schedule(const PrepassParameters& params,
                                                          int width, int height) {
  if (absl::Status s = params.validate(); !s.ok()) return s;
  if (absl::Status s = check_size(width, height, "the prepass film"); !s.ok()) return s;
  std::vector<PrepassPass> passes;
  for (int k = 1; k <= params.passes; ++k) {
    const int steps = params.passes - k;  // how many times this pass is quartered
    PrepassPass p;
    p.index = k;
    if (params.image_scaled) {
      p.spp = params.spp;
      p.scale = std::ldexp(1.0, -steps);
      // ⌈W / 2^steps⌉ in integers: never 0 and exactly reproducible.
      p.width = int((std::int64_t{width} + (std::int64_t{1} << steps) - 1) >> steps);
      p.height = int((std::int64_t{height} + (std::int64_t{1} << steps) - 1) >> steps);
    } else {
      p.spp = std::max<std::uint32_t>(1, params.spp >> (2 * steps));
      p.width = width;
      p.height = height;
    }
    passes.push_back(p);
  }
  return passes;
}

GuideImage::GuideImage(int width, int height)
    : width_(width),
      height_(height),
      features_(std::size_t(width) * std::size_t(height)),
      valid_(std::size_t(width) * std::size_t(height), 0) {}

absl::StatusOr<GuideImage> GuideImage::create(int width, int height) {
  if (absl::Status s = check_size(width, height, "a guide image"); !s.ok()) return s;
  return GuideImage(width, height);
}

std::size_t GuideImage::index(int x, int y) const {
  PRISM_CHECK(x >= 0 && x < width_ && y >= 0 && y < height_);
  return std::size_t(y) * std::size_t(width_) + std::size_t(x);
}

void GuideImage::set(int x, int y, const GuideFeatures& features) {
  const std::size_t i = index(x, y);
  features_[i] = features;
  valid_[i] = 1;
}

absl::Status GuideImage::add_tile(const image::TileResult& merged) {
  const image::TileRect& r = merged.rect();
  if (!merged.has_guides()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "prepass tile ", image::to_string(r), " carries no guide buffers (want_guides unset)"));
  }
  if (r.empty() || !image::TileRect{0, 0, width_, height_}.contains(r)) {
    return absl::InvalidArgumentError(absl::StrCat("prepass tile ", image::to_string(r),
                                                   " is not inside the ", width_, "x", height_,
                                                   " guide image"));
  }
  const std::span<const float> depth = merged.depth(), normals = merged.normals(),
                               albedo = merged.albedo();
  for (int y = r.y0; y < r.y1; ++y) {
    for (int x = r.x0; x < r.x1; ++x) {
      const std::size_t p = std::size_t(y - r.y0) * std::size_t(r.width()) + std::size_t(x - r.x0);
      const std::uint64_t n = merged.count(x, y);
      const std::size_t i = index(x, y);
      if (n == 0) {
        valid_[i] = 0;
        continue;
      }
      const double inv = 1.0 / double(n);
      features_[i] = {float(depth[p] * inv), float(normals[3 * p] * inv),
                      float(normals[3 * p + 1] * inv), float(normals[3 * p + 2] * inv),
                      float(albedo[p] * inv)};
      valid_[i] = 1;
    }
  }
  return absl::OkStatus();
}

PixelTableImage::PixelTableImage(int width, int height, int cells)
    : width_(width),
      height_(height),
      cells_(cells),
      cdf_(std::size_t(width) * std::size_t(height) * (std::size_t(cells) + 1), 0),
      sources_(std::size_t(width) * std::size_t(height), PixelSource::kLearned) {}

std::size_t PixelTableImage::index(int x, int y) const {
  PRISM_CHECK(x >= 0 && x < width_ && y >= 0 && y < height_);
  return std::size_t(y) * std::size_t(width_) + std::size_t(x);
}

std::span<const std::uint16_t> PixelTableImage::cdf(int x, int y) const {
  const std::size_t stride = std::size_t(cells_) + 1;
  return {cdf_.data() + index(x, y) * stride, stride};
}

std::int64_t PixelTableImage::count(PixelSource source) const {
  return std::count(sources_.begin(), sources_.end(), source);
}

double PixelTableImage::fallback_fraction() const {
  return double(count(PixelSource::kMatchesDefault)) / double(sources_.size());
}

absl::StatusOr<std::string> PixelTableImage::encode_tile(const image::TileRect& rect) const {
  if (rect.empty() || !rect.valid() || !image::TileRect{0, 0, width_, height_}.contains(rect)) {
    return absl::InvalidArgumentError(absl::StrCat("cannot encode the tables of tile ",
                                                   image::to_string(rect), ": not a non-empty "
                                                   "rect inside the ", width_, "x", height_,
                                                   " image"));
  }
  std::string out;
  out.reserve(spectral::pixel_table_bytes(rect.width(), rect.height(), cells_));
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x) {
      if (source(x, y) == PixelSource::kMatchesDefault) {
        spectral::append_default_pixel(cells_, out);
      } else {
        spectral::append_pixel_table(cdf(x, y), out);
      }
    }
  }
  return out;
}

absl::StatusOr<image::SpectralImage> filter_estimate(const image::SpectralImage& estimate,
                                                     const GuideImage& guides, double sigma_s,
                                                     double sigma_r,
                                                     const PixelTableImage* previous) {
  const int w = estimate.width(), h = estimate.height(), bins = estimate.bins();
  if (guides.width() != w || guides.height() != h) {
    return absl::InvalidArgumentError(absl::StrCat("the prepass estimate is ", w, "x", h,
                                                   " but its guide image ", guides.width(), "x",
                                                   guides.height()));
  }
  if (previous != nullptr && (previous->width() != w || previous->height() != h)) {
    return absl::InvalidArgumentError(absl::StrCat("the prepass estimate is ", w, "x", h,
                                                   " but the previous pass's tables ",
                                                   previous->width(), "x", previous->height()));
  }
  if (!(std::isfinite(sigma_s) && sigma_s > 0.0 && sigma_s <= kMaxSigmaS)) {
    return bad_field("sigma_s", sigma_s, absl::StrCat("in (0, ", kMaxSigmaS, "] pixels"));
  }
  if (!(std::isfinite(sigma_r) && sigma_r > 0.0)) {
    return bad_field("sigma_r", sigma_r, "finite and > 0");
  }
  const int radius = int(std::ceil(3.0 * sigma_s));
  const int side = 2 * radius + 1;
  std::vector<double> spatial(std::size_t(side) * std::size_t(side));
  for (int dy = -radius; dy <= radius; ++dy) {
    for (int dx = -radius; dx <= radius; ++dx) {
      spatial[std::size_t(dy + radius) * side + std::size_t(dx + radius)] =
          std::exp(-double(dx * dx + dy * dy) / (2.0 * sigma_s * sigma_s));
    }
  }
  const double range_scale = 1.0 / (2.0 * sigma_r * sigma_r);
  // exp(−t) is below the smallest double's half beyond this: such neighbours weigh exactly 0.
  constexpr double kMaxExponent = 746.0;

  std::vector<std::uint8_t> usable(std::size_t(w) * std::size_t(h), 0);
  for_each_row(h, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < w; ++x) {
        bool ok = guides.valid(x, y) &&
                  (previous == nullptr || previous->source(x, y) != PixelSource::kMatchesDefault);
        for (float v : estimate.pixel(x, y)) ok = ok && std::isfinite(v);
        usable[std::size_t(y) * w + x] = ok ? 1 : 0;
      }
    }
  });

  absl::StatusOr<image::SpectralImage> out = image::SpectralImage::create(w, h, bins);
  if (!out.ok()) return out.status();
  image::SpectralImage& filtered = *out;
  const float* values = estimate.data().data();  // layout: image/tile.h
  for_each_row(h, [&](int y0, int y1) {
    std::vector<double> acc(static_cast<std::size_t>(bins));
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < w; ++x) {
        if (!usable[std::size_t(y) * w + x]) continue;
        const GuideFeatures& centre = guides.at(x, y);
        std::fill(acc.begin(), acc.end(), 0.0);
        double weight_sum = 0.0;
        for (int ny = std::max(0, y - radius); ny <= std::min(h - 1, y + radius); ++ny) {
          const double* spatial_row = &spatial[std::size_t(ny - y + radius) * side + radius];
          for (int nx = std::max(0, x - radius); nx <= std::min(w - 1, x + radius); ++nx) {
            if (!usable[std::size_t(ny) * w + nx]) continue;
            const double t = squared_distance(centre, guides.at(nx, ny)) * range_scale;
            if (t > kMaxExponent) continue;
            const double weight = spatial_row[nx - x] * std::exp(-t);
            const float* v = values + (std::size_t(ny) * w + nx) * std::size_t(bins);
            for (int b = 0; b < bins; ++b) acc[b] += weight * double(v[b]);
            weight_sum += weight;
          }
        }
        // The centre itself weighs 1, so weight_sum >= 1.
        const double inv = 1.0 / weight_sum;
        float* o = filtered.pixel(x, y).data();
        for (int b = 0; b < bins; ++b) o[b] = float(acc[b] * inv);
      }
    }
  });
  return out;
}

absl::StatusOr<PixelTableImage> build_tables(const image::SpectralImage& filtered,
                                             const PrepassParameters& params,
                                             const spectral::WavelengthDistribution& emitters,
                                             const spectral::WavelengthDistribution* sensor,
                                             const PixelTableImage* previous) {
  if (absl::Status s = params.validate(); !s.ok()) return s;
  const int w = filtered.width(), h = filtered.height(), bins = filtered.bins();
  if (bins > spectral::WavelengthDistribution::kMaxCells) {
    return absl::InvalidArgumentError(absl::StrCat("prepass tables support at most ",
                                                   spectral::WavelengthDistribution::kMaxCells,
                                                   " bins, the estimate has ", bins));
  }
  if (emitters.cells() != bins) {
    return absl::InvalidArgumentError(absl::StrCat(
        "the emitter mixture has ", emitters.cells(), " cells but the prepass estimate ", bins,
        " bins; build it with WavelengthDistribution::emitters(spectra, bins)"));
  }
  if (sensor != nullptr && sensor->cells() != bins) {
    return absl::InvalidArgumentError(absl::StrCat("the sensor distribution has ",
                                                   sensor->cells(), " cells but the prepass "
                                                   "estimate ", bins, " bins"));
  }
  if (previous != nullptr &&
      (previous->width() != w || previous->height() != h || previous->cells() != bins)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "the previous pass's tables are ", previous->width(), "x", previous->height(), " with ",
        previous->cells(), " cells, the estimate ", w, "x", h, " with ", bins, " bins"));
  }

  const std::size_t nb = std::size_t(bins);
  std::vector<double> mixture(nb), mixture_unit_mean(nb), uniform_support(nb), sensor_term(nb);
  int support = 0;
  double mixture_sum = 0.0;
  for (int b = 0; b < bins; ++b) {
    mixture[b] = emitters.cell_mass(b);
    mixture_sum += mixture[b];
    support += mixture[b] > 0.0 ? 1 : 0;
    sensor_term[b] = sensor != nullptr ? sensor->cell_mass(b) : 1.0;
  }
  if (support == 0) {
    return absl::InvalidArgumentError("the emitter mixture is zero in every bin: no p_ε support");
  }
  for (int b = 0; b < bins; ++b) {
    mixture_unit_mean[b] = mixture[b] * bins / mixture_sum;
    uniform_support[b] = mixture[b] > 0.0 ? 1.0 / support : 0.0;
  }
  const double eps = params.epsilon, h_threshold = params.fallback;

  PixelTableImage tables(w, h, bins);
  for_each_row(h, [&](int y0, int y1) {
    std::vector<double> x_buf(nb), r(nb);
    spectral::WavelengthDistribution::QuantiseScratch scratch;
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < w; ++x) {
        const std::size_t i = tables.index(x, y);
        if (previous != nullptr && previous->source(x, y) == PixelSource::kMatchesDefault) {
          tables.sources_[i] = PixelSource::kMatchesDefault;
          continue;
        }
        const float* f = filtered.pixel(x, y).data();
        bool finite = true;
        double total = 0.0;
        for (int b = 0; b < bins; ++b) {
          finite = finite && std::isfinite(f[b]);
          x_buf[b] = f[b] > 0.0f ? double(f[b]) : 0.0;
          total += x_buf[b];
        }
        const double* spectrum = x_buf.data();
        PixelSource src = PixelSource::kLearned;
        if (!finite || !(total > 0.0) || !std::isfinite(total)) {
          src = PixelSource::kNoEstimate;
          spectrum = mixture.data();
        } else {
          const double inv_mean = bins / total;
          double msd = 0.0;
          for (int b = 0; b < bins; ++b) {
            const double d = x_buf[b] * inv_mean - mixture_unit_mean[b];
            msd += d * d;
          }
          if (msd / bins <= h_threshold) {
            tables.sources_[i] = PixelSource::kMatchesDefault;
            continue;
          }
        }
        double weighted = 0.0;
        for (int b = 0; b < bins; ++b) weighted += sensor_term[b] * spectrum[b];
        // A sensor term that is zero wherever the spectrum lives leaves only the defensive part.
        const double scale = weighted > 0.0 && std::isfinite(weighted) ? (1.0 - eps) / weighted
                                                                        : 0.0;
        for (int b = 0; b < bins; ++b) {
          r[b] = eps * uniform_support[b] + scale * sensor_term[b] * spectrum[b];
        }
        tables.sources_[i] = src;
        spectral::WavelengthDistribution::quantise_weights(
            r, std::span<std::uint16_t>(tables.cdf_.data() + i * (nb + 1), nb + 1), scratch);
      }
    }
  });
  return tables;
}

absl::StatusOr<PixelTableImage> upsample_tables(const PixelTableImage& tables, int width,
                                                int height) {
  if (absl::Status s = check_size(width, height, "upsampled prepass tables"); !s.ok()) return s;
  PixelTableImage out(width, height, tables.cells());
  const std::size_t stride = std::size_t(tables.cells()) + 1;
  for (int y = 0; y < height; ++y) {
    // ⌊(y + ½)·h/H⌋ = ⌊(2y + 1)·h / 2H⌋, in integers so every platform picks the same pixel.
    const int sy = int((2 * std::int64_t{y} + 1) * tables.height() / (2 * std::int64_t{height}));
    for (int x = 0; x < width; ++x) {
      const int sx = int((2 * std::int64_t{x} + 1) * tables.width() / (2 * std::int64_t{width}));
      const std::size_t from = tables.index(sx, sy), to = out.index(x, y);
      out.sources_[to] = tables.sources_[from];
      std::copy_n(tables.cdf_.begin() + std::ptrdiff_t(from * stride), stride,
                  out.cdf_.begin() + std::ptrdiff_t(to * stride));
    }
  }
  return out;
}

}  // namespace prism::coordinator
