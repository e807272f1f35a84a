// The prepass's tables (prepass.h, build_tables and upsample_tables): from the filtered moments,
// each pixel's candidate shapes and mixture weights, validated against its own moments, the
// choice and its quantisation.
#include <algorithm>
#include <cmath>
#include <vector>

#include "absl/strings/str_cat.h"
#include "coordinator/prepass.h"
#include "coordinator/prepass_internal.h"
#include "services/base/check.h"
#include "services/base/status.h"
#include "services/spectral/pixel_tables.h"

namespace prism::coordinator {

using prepass_internal::check_size;
using prepass_internal::for_each_row;

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
