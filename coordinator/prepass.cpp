#include "coordinator/prepass.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"
#include "services/spectral/pixel_tables.h"

namespace prism::coordinator {
namespace {

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

namespace {

// The candidates build_tables chooses from: the default, then each shape with each α > 0.
constexpr int kCandidates = 1 + kTableShapes * (kAlphaChoices - 1);
constexpr TableShape candidate_shape(int c) {
  return TableShape((c - 1) / (kAlphaChoices - 1));
}
constexpr int candidate_alpha(int c) {
  return c == 0 ? 0 : 1 + (c - 1) % (kAlphaChoices - 1);
}

// One pixel's moments (2·bins values) as the tables use them: sensor-weighted K and U, zero where
// D_b = 0. False when a value is not finite.
bool pixel_moments(const float* m, std::span<const double> d, std::span<const double> sensor,
                   std::vector<double>& k, std::vector<double>& u) {
  const std::size_t nb = k.size();
  for (std::size_t b = 0; b < nb; ++b) {
    if (!std::isfinite(m[b]) || !std::isfinite(m[nb + b])) return false;
    const double s2 = sensor.empty() ? 1.0 : sensor[b] * sensor[b];
    k[b] = d[b] > 0.0 ? s2 * double(m[b]) : 0.0;
    u[b] = d[b] > 0.0 ? s2 * double(m[nb + b]) : 0.0;
  }
  return true;
}

// The learned shapes (TableShape) of one pixel's moments: masses ∝ sqrt of r·K_b or of
// max(0, r·K_b − U_b/C); has[s] false when shape s is zero everywhere.
void learned_shapes(const std::vector<double>& k, const std::vector<double>& u,
                    const VarianceModel& model, std::vector<double> (&shapes)[kTableShapes],
                    bool (&has)[kTableShapes]) {
  for (int s = 0; s < kTableShapes; ++s) {
    double sum = 0.0;
    for (std::size_t b = 0; b < k.size(); ++b) {
      const double g = TableShape(s) == TableShape::kSecondMoment
                           ? double(model.prepass_lanes) / model.final_lanes * k[b]
                           : model.divided(k[b], u[b]);
      shapes[s][b] = g > 0.0 ? std::sqrt(g) : 0.0;
      sum += shapes[s][b];
    }
    has[s] = sum > 0.0 && std::isfinite(sum);
    if (has[s]) {
      for (double& v : shapes[s]) v /= sum;
    }
  }
}

// Σ_b V_b(m) of one pixel for the masses m = α·shape + (1 − α)·d.
double pixel_variance(const std::vector<double>& k, const std::vector<double>& u,
                      const std::vector<double>& d, const std::vector<double>* shape, double alpha,
                      const VarianceModel& model) {
  double v = 0.0;
  for (std::size_t b = 0; b < k.size(); ++b) {
    if (!(d[b] > 0.0)) continue;
    const double m = shape != nullptr ? alpha * (*shape)[b] + (1.0 - alpha) * d[b] : d[b];
    v += model.bin_variance(k[b], u[b], m);
  }
  return v;
}

}  // namespace

absl::StatusOr<PixelTableImage> build_tables(const image::SpectralImage& moments,
                                             const GuideImage& guides,
                                             const job::PrepassParameters& params,
                                             std::span<const double> default_masses,
                                             std::span<const double> sensor_weights,
                                             const VarianceModel& model,
                                             const PixelTableImage* previous) {
  if (absl::Status s = params.validate(); !s.ok()) return s;
  const int w = moments.width(), h = moments.height(), bins = moments.bins() / 2;
  if (moments.bins() % 2 != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("prepass moments have 2 channels per bin, got ", moments.bins(), " channels"));
  }
  if (bins < 1 || bins > spectral::WavelengthDistribution::kMaxCells) {
    return absl::InvalidArgumentError(absl::StrCat("prepass tables support 1 to ",
                                                   spectral::WavelengthDistribution::kMaxCells,
                                                   " bins, the moments have ", bins));
  }
  const std::size_t nb = std::size_t(bins);
  if (default_masses.size() != nb || (!sensor_weights.empty() && sensor_weights.size() != nb)) {
    return absl::InvalidArgumentError(absl::StrCat("prepass tables of ", bins, " bins: got ",
                                                   default_masses.size(), " default masses and ",
                                                   sensor_weights.size(), " sensor weights"));
  }
  double default_total = 0.0;
  for (std::size_t b = 0; b < nb; ++b) {
    const double s = sensor_weights.empty() ? 1.0 : sensor_weights[b];
    if (!(default_masses[b] >= 0.0) || !std::isfinite(default_masses[b]) || !(s >= 0.0) ||
        !std::isfinite(s)) {
      return absl::InvalidArgumentError(absl::StrCat("prepass tables: default mass ",
                                                     default_masses[b], " or sensor weight ", s,
                                                     " of bin ", b, " is negative or not finite"));
    }
    default_total += default_masses[b];
  }
  if (!(default_total > 0.0)) {
    return absl::InvalidArgumentError("the job's default distribution has no mass in any bin");
  }
  if (previous != nullptr &&
      (previous->width() != w || previous->height() != h || previous->cells() != bins)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "the previous pass's tables are ", previous->width(), "x", previous->height(), " with ",
        previous->cells(), " cells, the moments ", w, "x", h, " with ", bins, " bins"));
  }
  std::vector<double> d(nb);
  for (std::size_t b = 0; b < nb; ++b) d[b] = default_masses[b] / default_total;
  std::array<double, kAlphaChoices> alphas;
  for (int a = 0; a < kAlphaChoices; ++a) alphas[a] = alpha_choice(a, params.epsilon);

  // The learned shape of every pixel from its filtered neighbourhood, and the same without the
  // pixel itself for the validation below.
  PRISM_ASSIGN_OR_RETURN(image::SpectralImage leave_one_out,
                         image::SpectralImage::create(w, h, 2 * bins));
  PRISM_ASSIGN_OR_RETURN(
      image::SpectralImage filtered,
      filter_estimate(moments, guides, params.sigma_s, params.sigma_r, nullptr, &leave_one_out));

  // Validation: each pixel's own (raw) moments judge the candidates its neighbours' moments would
  // give it (build_tables in prepass.h). Non-finite where the pixel has no usable moments, so the
  // smoothing skips it.
  PRISM_ASSIGN_OR_RETURN(image::SpectralImage validation,
                         image::SpectralImage::create(w, h, kCandidates));
  for_each_row(h, [&](int y0, int y1) {
    std::vector<double> k(nb), u(nb), k_loo(nb), u_loo(nb);
    std::vector<double> shapes[kTableShapes] = {std::vector<double>(nb), std::vector<double>(nb)};
    bool has[kTableShapes] = {false, false};
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < w; ++x) {
        float* v = validation.pixel(x, y).data();
        if (!guides.valid(x, y) ||
            !pixel_moments(moments.pixel(x, y).data(), d, sensor_weights, k, u)) {
          std::fill(v, v + kCandidates, std::numeric_limits<float>::quiet_NaN());
          continue;
        }
        if (pixel_moments(leave_one_out.pixel(x, y).data(), d, sensor_weights, k_loo, u_loo)) {
          learned_shapes(k_loo, u_loo, model, shapes, has);
        } else {
          has[0] = has[1] = false;
        }
        v[0] = float(pixel_variance(k, u, d, nullptr, 0.0, model));
        for (int c = 1; c < kCandidates; ++c) {
          const int s = int(candidate_shape(c));
          v[c] = has[s]
                     ? float(pixel_variance(k, u, d, &shapes[s], alphas[candidate_alpha(c)], model))
                     : v[0];
        }
      }
    }
  });
  // Each pixel's choice rests on its similar neighbours' validations and not on its own, which
  // then judges the choice without bias: the image's predicted gain is the sum of the pixels' own
  // validations of their choices (an unbiased estimate of the chosen tables' variance, where the
  // same validations deciding and judging would make the best of several noisy estimates look
  // better than it is).
  PRISM_ASSIGN_OR_RETURN(image::SpectralImage judged,
                         image::SpectralImage::create(w, h, kCandidates));
  PRISM_RETURN_IF_ERROR(
      filter_estimate(validation, guides, params.sigma_s, params.sigma_r, nullptr, &judged)
          .status());

  PixelTableImage tables(w, h, bins);
  for_each_row(h, [&](int y0, int y1) {
    std::vector<double> k(nb), u(nb), r(nb);
    std::vector<double> shapes[kTableShapes] = {std::vector<double>(nb), std::vector<double>(nb)};
    bool has[kTableShapes] = {false, false};
    spectral::WavelengthDistribution::QuantiseScratch scratch;
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < w; ++x) {
        const std::size_t i = tables.index(x, y);
        if (previous != nullptr && previous->source(x, y) != PixelSource::kLearned) {
          tables.sources_[i] = previous->source(x, y);
          tables.variance_default_[i] = previous->variance_default_[i];
          tables.variance_chosen_[i] = previous->variance_chosen_[i];
          tables.judged_default_[i] = previous->judged_default_[i];
          tables.judged_chosen_[i] = previous->judged_chosen_[i];
          continue;
        }
        const float* v = judged.pixel(x, y).data();
        const float* own = validation.pixel(x, y).data();
        bool finite = true;
        for (int c = 0; c < kCandidates; ++c) {
          finite = finite && std::isfinite(v[c]) && std::isfinite(own[c]);
        }
        if (!finite || !pixel_moments(filtered.pixel(x, y).data(), d, sensor_weights, k, u)) {
          tables.sources_[i] = PixelSource::kNoEstimate;
          continue;
        }
        learned_shapes(k, u, model, shapes, has);
        if (!has[0] && !has[1]) {
          tables.sources_[i] = PixelSource::kNoEstimate;
          continue;
        }
        int best = 0;
        for (int c = 1; c < kCandidates; ++c) {
          if (has[int(candidate_shape(c))] && v[c] < v[best]) best = c;
        }
        tables.variance_default_[i] = own[0];
        tables.judged_default_[i] = v[0];
        if (!(v[0] > 0.0f) || best == 0 ||
            !(double(v[best]) <= (1.0 - params.fallback) * double(v[0]))) {
          tables.sources_[i] = PixelSource::kMatchesDefault;
          tables.variance_chosen_[i] = own[0];
          tables.judged_chosen_[i] = v[0];
          continue;
        }
        const int a = candidate_alpha(best);
        const TableShape shape = candidate_shape(best);
        tables.sources_[i] = PixelSource::kLearned;
        tables.alpha_[i] = std::uint8_t(a);
        tables.shape_[i] = shape;
        tables.variance_chosen_[i] = own[best];
        tables.judged_chosen_[i] = v[best];
        for (std::size_t b = 0; b < nb; ++b) {
          r[b] = alphas[a] * shapes[int(shape)][b] + (1.0 - alphas[a]) * d[b];
        }
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
      out.alpha_[to] = tables.alpha_[from];
      out.shape_[to] = tables.shape_[from];
      out.variance_default_[to] = tables.variance_default_[from];
      out.variance_chosen_[to] = tables.variance_chosen_[from];
      out.judged_default_[to] = tables.judged_default_[from];
      out.judged_chosen_[to] = tables.judged_chosen_[from];
      std::copy_n(tables.cdf_.begin() + std::ptrdiff_t(from * stride), stride,
                  out.cdf_.begin() + std::ptrdiff_t(to * stride));
    }
  }
  return out;
}

}  // namespace prism::coordinator
