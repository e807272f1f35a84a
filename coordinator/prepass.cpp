#include "coordinator/prepass.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "coordinator/prepass_internal.h"
#include "services/base/check.h"
#include "services/base/status.h"
#include "services/spectral/pixel_tables.h"

namespace prism::coordinator {
namespace {

using prepass_internal::check_size;
using prepass_internal::for_each_row;

absl::Status bad_field(const std::string& field, double value, const std::string& allowed) {
  return absl::InvalidArgumentError(
      absl::StrCat("prepass ", field, " is ", value, "; it must be ", allowed));
}

double squared_distance(const GuideFeatures& a, const GuideFeatures& b) {
  const double d0 = double(a.depth) - b.depth, d1 = double(a.nx) - b.nx, d2 = double(a.ny) - b.ny,
               d3 = double(a.nz) - b.nz, d4 = double(a.albedo) - b.albedo;
  return d0 * d0 + d1 * d1 + d2 * d2 + d3 * d3 + d4 * d4;
}

}  // namespace

absl::StatusOr<std::vector<PrepassPass>> prepass_schedule(const job::PrepassParameters& params,
                                                          int width, int height) {
  if (absl::Status s = params.validate(); !s.ok()) return s;
  if (absl::Status s = check_size(width, height, "the prepass film"); !s.ok()) return s;
  std::vector<PrepassPass> passes;
  for (int k = 1; k <= params.passes; ++k) {
    const int steps = params.passes - k;  // how many times this pass is scaled down
    PrepassPass p;
    p.index = k;
    if (params.image_scaled) {
      p.spp = params.spp;
      p.scale = std::ldexp(1.0, -steps);
      // ⌈W / 2^steps⌉ in integers: never 0 and exactly reproducible.
      p.width = int((std::int64_t{width} + (std::int64_t{1} << steps) - 1) >> steps);
      p.height = int((std::int64_t{height} + (std::int64_t{1} << steps) - 1) >> steps);
    } else {
      p.spp = std::max<std::uint32_t>(1, params.spp >> (3 * steps));
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
      if (n == 0) continue;
      const double inv = 1.0 / double(n);
      features_[i] = {float(depth[p] * inv), float(normals[3 * p] * inv),
                      float(normals[3 * p + 1] * inv), float(normals[3 * p + 2] * inv),
                      float(albedo[p] * inv)};
      valid_[i] = 1;
    }
  }
  return absl::OkStatus();
}

double pairs_of_lanes(int lanes, double mass) {
  const double x = double(lanes) * mass;
  const double whole = std::floor(x), frac = x - whole;
  return whole * (whole - 1.0 + 2.0 * frac);
}

double alpha_choice(int index, double epsilon) {
  PRISM_CHECK(index >= 0 && index < kAlphaChoices);
  return index == kAlphaChoices - 1 ? 1.0 - epsilon : 0.25 * index;
}

PixelTableImage::PixelTableImage(int width, int height, int cells)
    : width_(width),
      height_(height),
      cells_(cells),
      cdf_(std::size_t(width) * std::size_t(height) * (std::size_t(cells) + 1), 0),
      sources_(std::size_t(width) * std::size_t(height), PixelSource::kNoEstimate),
      alpha_(std::size_t(width) * std::size_t(height), 0),
      shape_(std::size_t(width) * std::size_t(height), TableShape::kSecondMoment),
      variance_default_(std::size_t(width) * std::size_t(height), 0.0f),
      variance_chosen_(std::size_t(width) * std::size_t(height), 0.0f),
      judged_default_(std::size_t(width) * std::size_t(height), 0.0f),
      judged_chosen_(std::size_t(width) * std::size_t(height), 0.0f) {}

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
  return double(std::int64_t(sources_.size()) - count(PixelSource::kLearned)) /
         double(sources_.size());
}

std::array<std::int64_t, kAlphaChoices> PixelTableImage::alpha_histogram() const {
  std::array<std::int64_t, kAlphaChoices> h{};
  for (std::uint8_t a : alpha_) ++h[a];
  return h;
}

std::array<std::int64_t, kTableShapes> PixelTableImage::shape_histogram() const {
  std::array<std::int64_t, kTableShapes> h{};
  for (std::size_t i = 0; i < sources_.size(); ++i) {
    if (has_table(i)) ++h[std::size_t(shape_[i])];
  }
  return h;
}

namespace {

// 1 − Σ chosen / Σ by default: the fraction of the variance the choices remove.
double gain_of(const std::vector<float>& chosen, const std::vector<float>& by_default) {
  double c = 0.0, d = 0.0;
  for (std::size_t i = 0; i < chosen.size(); ++i) {
    c += chosen[i];
    d += by_default[i];
  }
  return d > 0.0 ? 1.0 - c / d : 0.0;
}

}  // namespace

double PixelTableImage::predicted_gain() const {
  return gain_of(variance_chosen_, variance_default_);
}

double PixelTableImage::decision_gain() const {
  return gain_of(judged_chosen_, judged_default_);
}

void PixelTableImage::reset_to_default() {
  for (std::size_t i = 0; i < sources_.size(); ++i) {
    if (sources_[i] == PixelSource::kLearned) sources_[i] = PixelSource::kMatchesDefault;
    alpha_[i] = 0;
    variance_chosen_[i] = variance_default_[i];
    judged_chosen_[i] = judged_default_[i];
  }
  std::fill(cdf_.begin(), cdf_.end(), std::uint16_t{0});
}

PixelTableImage PixelTableImage::with_tables(std::span<const std::uint16_t> cdf) const {
  PRISM_CHECK(cdf.size() == std::size_t(cells_) + 1);
  PixelTableImage out = *this;
  for (std::size_t i = 0; i < sources_.size(); ++i) {
    if (has_table(i)) std::copy(cdf.begin(), cdf.end(), out.cdf_.begin() + i * cdf.size());
  }
  return out;
}

absl::StatusOr<std::string> PixelTableImage::encode_tile(const image::TileRect& rect) const {
  if (rect.empty() || !rect.valid() || !image::TileRect{0, 0, width_, height_}.contains(rect)) {
    return absl::InvalidArgumentError(absl::StrCat("cannot encode the tables of tile ",
                                                   image::to_string(rect),
                                                   ": not a non-empty "
                                                   "rect inside the ",
                                                   width_, "x", height_, " image"));
  }
  std::string out;
  out.reserve(spectral::pixel_table_bytes(rect.width(), rect.height(), cells_));
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x) {
      if (!has_table(index(x, y))) {
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
                                                     const PixelTableImage* previous,
                                                     image::SpectralImage* leave_one_out) {
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
  if (!(std::isfinite(sigma_s) && sigma_s > 0.0 && sigma_s <= job::PrepassParameters::kMaxSigmaS)) {
    return bad_field("sigma_s", sigma_s,
                     absl::StrCat("in (0, ", job::PrepassParameters::kMaxSigmaS, "] pixels"));
  }
  if (!(std::isfinite(sigma_r) && sigma_r > 0.0)) {
    return bad_field("sigma_r", sigma_r, "finite and > 0");
  }
  const int radius = int(std::ceil(3.0 * sigma_s));
  const int side = 2 * radius + 1;
  std::vector<float> spatial(std::size_t(side) * std::size_t(side));
  for (int dy = -radius; dy <= radius; ++dy) {
    for (int dx = -radius; dx <= radius; ++dx) {
      spatial[std::size_t(dy + radius) * side + std::size_t(dx + radius)] =
          float(std::exp(-double(dx * dx + dy * dy) / (2.0 * sigma_s * sigma_s)));
    }
  }
  const double range_scale = 1.0 / (2.0 * sigma_r * sigma_r);
  // exp(−t) is below float's smallest normal beyond this: such neighbours weigh nothing.
  constexpr double kMaxExponent = 87.0;

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
  if (leave_one_out != nullptr) {
    PRISM_ASSIGN_OR_RETURN(*leave_one_out, image::SpectralImage::create(w, h, bins));
  }
  const float* values = estimate.data().data();  // layout: image/tile.h
  // Float sums (twice as many lanes per vector instruction as double) of the neighbours'
  // differences from the centre, in a fixed order: the result is the centre plus their weighted
  // mean, exactly the centre where the neighbours agree with it (a constant image stays
  // constant), and within a few float roundings of the differences elsewhere.
  for_each_row(h, [&](int y0, int y1) {
    std::vector<float> acc(static_cast<std::size_t>(bins));
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < w; ++x) {
        if (!usable[std::size_t(y) * w + x]) continue;
        const GuideFeatures& centre = guides.at(x, y);
        const float* c = values + (std::size_t(y) * w + x) * std::size_t(bins);
        std::fill(acc.begin(), acc.end(), 0.0f);
        double weight_sum = 0.0;  // of the neighbours; the centre's own weight is exactly 1
        for (int ny = std::max(0, y - radius); ny <= std::min(h - 1, y + radius); ++ny) {
          const float* spatial_row = &spatial[std::size_t(ny - y + radius) * side + radius];
          for (int nx = std::max(0, x - radius); nx <= std::min(w - 1, x + radius); ++nx) {
            if ((nx == x && ny == y) || !usable[std::size_t(ny) * w + nx]) continue;
            const double t = squared_distance(centre, guides.at(nx, ny)) * range_scale;
            if (t > kMaxExponent) continue;
            const float weight = spatial_row[nx - x] * std::exp(-float(t));
            const float* v = values + (std::size_t(ny) * w + nx) * std::size_t(bins);
            for (int b = 0; b < bins; ++b) acc[b] += weight * (v[b] - c[b]);
            weight_sum += weight;
          }
        }
        if (leave_one_out != nullptr && weight_sum > 1e-9) {
          const float inv_rest = float(1.0 / weight_sum);
          float* l = leave_one_out->pixel(x, y).data();
          for (int b = 0; b < bins; ++b) l[b] = c[b] + acc[b] * inv_rest;
        }
        const float inv = float(1.0 / (weight_sum + 1.0));
        float* o = filtered.pixel(x, y).data();
        for (int b = 0; b < bins; ++b) o[b] = c[b] + acc[b] * inv;
      }
    }
  });
  return out;
}

MomentImage::MomentImage(image::SpectralImage moments)
    : moments_(std::move(moments)),
      samples_(std::size_t(moments_.width()) * std::size_t(moments_.height()), 0.0) {}

absl::StatusOr<MomentImage> MomentImage::create(int width, int height, int bins) {
  if (bins < 1 || 2 * bins > image::kMaxChannels) {
    return absl::InvalidArgumentError(
        absl::StrCat("prepass moments need 1 to ", image::kMaxChannels / 2, " bins, got ", bins));
  }
  PRISM_ASSIGN_OR_RETURN(image::SpectralImage moments,
                         image::SpectralImage::create(width, height, 2 * bins));
  return MomentImage(std::move(moments));
}

absl::Status MomentImage::add_tile(const image::TileResult& merged,
                                   const PixelTableImage* sampled_with,
                                   std::span<const double> default_masses, int lanes) {
  const image::TileRect& r = merged.rect();
  const int nb = bins();
  if (r.empty() || !image::TileRect{0, 0, width(), height()}.contains(r)) {
    return absl::InvalidArgumentError(absl::StrCat("prepass tile ", image::to_string(r),
                                                   " is not inside the ", width(), "x", height(),
                                                   " moment image"));
  }
  if (merged.bins() != nb || default_masses.size() != std::size_t(nb)) {
    return absl::InvalidArgumentError(absl::StrCat("prepass moments of ", nb,
                                                   " bins: the tile has ", merged.bins(),
                                                   ", the default masses ", default_masses.size()));
  }
  if (sampled_with != nullptr &&
      (sampled_with->width() != width() || sampled_with->height() != height() ||
       sampled_with->cells() != nb)) {
    return absl::InvalidArgumentError("the tables a prepass sampled with do not match its film");
  }
  for (int y = r.y0; y < r.y1; ++y) {
    for (int x = r.x0; x < r.x1; ++x) {
      const std::uint64_t n = merged.count(x, y);
      if (n == 0) continue;
      std::span<const std::uint16_t> table;
      if (sampled_with != nullptr && sampled_with->source(x, y) == PixelSource::kLearned) {
        table = sampled_with->cdf(x, y);
      }
      const double inv_n = 1.0 / double(n);
      float* out = moments_.pixel(x, y).data();
      double& samples = samples_[std::size_t(y) * std::size_t(width()) + std::size_t(x)];
      const double keep = samples / (samples + double(n)), take = 1.0 - keep;
      for (int b = 0; b < nb; ++b) {
        const double mass = table.empty() ? default_masses[b]
                                          : (table[b + 1] - table[b]) /
                                                double(spectral::QuantisedWavelengthCdf::kTotal);
        const double mean = merged.sum(x, y, b) * inv_n;
        const double second = merged.sum_squares(x, y, b) * inv_n;
        const double square = n >= 2 ? mean * mean - (second - mean * mean) / double(n - 1) : 0.0;
        // Two lanes of a sample in one bin add the product of their values to its square:
        // E[X²] = E[L]·E[Y²] + E[L(L−1)]·E[Y]², E[Y] = μ/(C·m); take that part out, so that K is
        // C·m²·E[Y²] whatever the mass (VarianceModel).
        const double k = mass > 0.0 ? mass * second - pairs_of_lanes(lanes, mass) * square /
                                                          (double(lanes) * lanes * mass)
                                    : 0.0;
        out[b] = float(keep * out[b] + take * k);
        out[nb + b] = float(keep * out[nb + b] + take * square);
      }
      samples += double(n);
    }
  }
  return absl::OkStatus();
}

double VarianceModel::divided(double k, double u) const {
  return double(prepass_lanes) / double(final_lanes) * k - u / double(final_lanes);
}

double VarianceModel::bin_variance(double k, double u, double m) const {
  double v = divided(k, u) / m;
  if (!stratified) {
    const double lanes = double(final_lanes) * m;
    const double frac = lanes - std::floor(lanes);
    v += frac * (1.0 - frac) * u / (lanes * lanes);
  }
  return v;
}

}  // namespace prism::coordinator
