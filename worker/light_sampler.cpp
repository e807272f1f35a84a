#include "worker/light_sampler.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"

namespace prism::worker {
namespace {

// The spatial grid has at most 8 cells per axis, fewer when cells × bins × emitters would pass
// this many prefix entries (32 MB of doubles), so huge emitter counts stay within memory.
constexpr int kMaxSpatialResolution = 8;
constexpr double kMaxPrefixEntries = double(1 << 22);
// Fraction of each spatial cell's pmf spread uniformly over the emitting lights: an estimate can
// be 0 at every probe point of a cell (a one-sided light facing away, a spot aimed elsewhere)
// while some point of the cell still receives light, and NEE must be able to pick it there.
constexpr double kSpatialFloor = 0.1;
// Fixed probe samples per light and point: a (0,2)-sequence prefix, the same on every worker.
constexpr int kProbeSamples = 16;

float radical_inverse(std::uint32_t i, std::uint32_t base) {
  double inv = 1.0 / base, f = inv, r = 0;
  for (; i > 0; i /= base, f *= inv) r += f * (i % base);
  return float(r);
}

const char* kind_name(const Light& light) {
  switch (light.index()) {
    case 0:
      return "area light";
    case 1:
      return "point light";
    case 2:
      return "spot light";
    default:
      return "infinite light";
  }
}

// Scalar estimate of the light arriving at x from every direction, unoccluded and per unit of
// the light's spectral emission scale·∫S: the solid angle the emitting surface covers (area
// lights), 1/d² (points; d clamped to `min_distance` so a probe next to a point light does not
// swamp the cell), the spot falloff over d², 4π for the environment.
double probe(const Light& light, const Vec3f& x, float min_distance) {
  const double min_d2 = double(min_distance) * min_distance;
  if (const auto* area = std::get_if<AreaLight>(&light)) {
    SampledWavelengths lambda(1);
    lambda.set(0, 550.0f, 1.0f);
    LightContext ctx{x, {}};
    double solid_angle = 0;
    for (int i = 0; i < kProbeSamples; ++i) {
      Point2f u{(float(i) + 0.5f) / kProbeSamples, radical_inverse(std::uint32_t(i), 2)};
      auto s = area->sample(ctx, u, radical_inverse(std::uint32_t(i), 3), lambda);
      if (s && s->pdf > 0) solid_angle += 1.0 / s->pdf;
    }
    return solid_angle / kProbeSamples;
  }
  if (const auto* point = std::get_if<PointLight>(&light)) {
    return 1.0 / std::max(double(length_squared(point->position() - x)), min_d2);
  }
  if (const auto* spot = std::get_if<SpotLight>(&light)) {
    Vec3f d = x - spot->position();
    float d2 = length_squared(d);
    float f = d2 > 0 ? spot->falloff(d / std::sqrt(d2)) : 1.0f;
    return f / std::max(double(d2), min_d2);
  }
  // A distant light's irradiance is its radiance (one direction); the sky's gathers 4π of it.
  if (std::holds_alternative<DistantLight>(light)) return 1.0;
  return 4 * M_PI;
}

}  // namespace

absl::StatusOr<LightSampler> LightSampler::create(const std::vector<Light>& lights,
                                                  const Geometry& geometry,
                                                  const spectral::WavelengthGrid& grid,
                                                  job::LightSelectionKind base,
                                                  bool spectral_factor) {
  LightSampler s;
  s.lights_ = &lights;
  s.grid_ = grid;
  s.base_ = base;
  s.spectral_factor_ = spectral_factor;
  const int n = int(lights.size());
  const int bins = grid.bins();

  s.unit_emission_.assign(std::size_t(n), std::vector<float>(std::size_t(bins)));
  std::vector<double> emitted(static_cast<std::size_t>(n));  // scale·∫_Λ S
  for (int e = 0; e < n; ++e) {
    const spectral::Spectrum& spectrum = light_spectrum(lights[e]);
    std::vector<double> row(static_cast<std::size_t>(bins));
    double sum = 0;
    for (int b = 0; b < bins; ++b) {
      // Negative emission is meaningless; rounding of a table touching 0 must not make it so.
      row[b] = std::max(0.0, spectral::integrate(spectrum, grid.lower(b), grid.upper(b)));
      sum += row[b];
    }
    if (!std::isfinite(sum)) {
      return scene::location_error(
          light_location(lights[e]),
          absl::StrCat(kind_name(lights[e]), "'s spectrum integrates to ", sum,
                       " between 360 and 830 nm: too large to render (a value near float's "
                       "limit, 3.4e38?); give it a finite spectrum and set its brightness with "
                       "'float scale'"));
    }
    if (!(sum > 0)) {
      return scene::location_error(
          light_location(lights[e]),
          absl::StrCat(kind_name(lights[e]),
                       " emits no power between 360 and 830 nm (its spectrum is zero or outside "
                       "the rendered range); remove it or give it a visible spectrum"));
    }
    for (int b = 0; b < bins; ++b) s.unit_emission_[e][b] = float(row[b] / sum);
    emitted[e] = light_scale(lights[e]) * sum;
  }
  // Where every emitter has the same normalised spectrum (one light, or lights of one kind) the
  // spectral factor Ê[e][b] is the same for every e and cancels from q(e): the base pmf is the
  // same distribution without a lookup per lane on every shadow ray.
  if (std::all_of(s.unit_emission_.begin(), s.unit_emission_.end(),
                  [&](const std::vector<float>& row) { return row == s.unit_emission_.front(); })) {
    s.spectral_factor_ = false;
  }

  std::vector<double> power(static_cast<std::size_t>(n));
  int emitting = 0;
  for (int e = 0; e < n; ++e) {
    power[e] = light_power(lights[e]);
    if (!std::isfinite(power[e])) {
      return scene::location_error(light_location(lights[e]),
                                   absl::StrCat(kind_name(lights[e]), " has non-finite power"));
    }
    if (power[e] > 0) ++emitting;
  }

  // Base weights per cell, before normalisation.
  std::vector<std::vector<double>> weights;
  s.bounds_ = geometry.bounds();
  if (base == job::LightSelectionKind::kSpatial && n > 0) {
    double per_cell = double(bins + 1) * (n + 1);
    int res = int(std::cbrt(kMaxPrefixEntries / per_cell));
    s.resolution_ = std::clamp(res, 1, kMaxSpatialResolution);
  }
  const int res = s.resolution_;
  if (base != job::LightSelectionKind::kSpatial || n == 0) {
    std::vector<double> w(static_cast<std::size_t>(n));
    for (int e = 0; e < n; ++e) w[e] = base == job::LightSelectionKind::kUniform ? 1.0 : power[e];
    weights.push_back(std::move(w));
  } else {
    const Vec3f lo = s.bounds_.lo;
    Vec3f extent = s.bounds_.hi - s.bounds_.lo;
    for (int a = 0; a < 3; ++a) extent[a] = std::max(extent[a], 0.0f);
    Vec3f cell = extent / float(res);
    float min_distance = std::max(0.5f * length(cell), 1e-6f * std::max(1.0f, length(extent)));
    // Probe values at the lattice corners (shared by up to 8 cells) and at the cell centres.
    const int c1 = res + 1;
    std::vector<double> corner(std::size_t(c1) * c1 * c1 * n);
    for (int k = 0; k < c1; ++k) {
      for (int j = 0; j < c1; ++j) {
        for (int i = 0; i < c1; ++i) {
          Vec3f x = lo + Vec3f(cell.x * i, cell.y * j, cell.z * k);
          std::size_t base_index = ((std::size_t(k) * c1 + j) * c1 + i) * n;
          for (int e = 0; e < n; ++e) corner[base_index + e] = probe(lights[e], x, min_distance);
        }
      }
    }
    for (int k = 0; k < res; ++k) {
      for (int j = 0; j < res; ++j) {
        for (int i = 0; i < res; ++i) {
          Vec3f centre = lo + Vec3f(cell.x * (i + 0.5f), cell.y * (j + 0.5f), cell.z * (k + 0.5f));
          std::vector<double> est(static_cast<std::size_t>(n));
          double total = 0;
          for (int e = 0; e < n; ++e) {
            double sum = probe(lights[e], centre, min_distance);
            for (int c = 0; c < 8; ++c) {
              std::size_t idx =
                  ((std::size_t(k + (c >> 2)) * c1 + (j + ((c >> 1) & 1))) * c1 + (i + (c & 1))) *
                      n +
                  e;
              sum += corner[idx];
            }
            est[e] = power[e] > 0 ? emitted[e] * sum / 9.0 : 0.0;
            total += est[e];
          }
          std::vector<double> w(std::size_t(n), 0.0);
          for (int e = 0; e < n; ++e) {
            if (!(power[e] > 0)) continue;
            double floor = 1.0 / emitting;
            w[e] = total > 0 ? (1 - kSpatialFloor) * est[e] / total + kSpatialFloor * floor : floor;
          }
          weights.push_back(std::move(w));
        }
      }
    }
  }

  for (const std::vector<double>& w : weights) {
    double total = 0;
    for (double x : w) total += x;
    Cell c;
    c.base.resize(std::size_t(n));
    for (int e = 0; e < n; ++e) c.base[e] = total > 0 ? float(w[e] / total) : 0.0f;
    c.base_prefix.assign(std::size_t(n) + 1, 0.0);
    for (int e = 0; e < n; ++e) c.base_prefix[e + 1] = c.base_prefix[e] + c.base[e];
    if (s.spectral_factor_) {
      c.prefix.assign(std::size_t(bins), std::vector<double>(std::size_t(n) + 1, 0.0));
      for (int b = 0; b < bins; ++b) {
        for (int e = 0; e < n; ++e) {
          c.prefix[b][e + 1] = c.prefix[b][e] + double(c.base[e]) * s.unit_emission_[e][b];
        }
      }
    }
    s.cells_.push_back(std::move(c));
  }
  return s;
}

int LightSampler::cell_of(const Vec3f& p) const {
  if (resolution_ == 1) return 0;
  int idx[3];
  for (int a = 0; a < 3; ++a) {
    float extent = bounds_.hi[a] - bounds_.lo[a];
    float f = extent > 0 ? (p[a] - bounds_.lo[a]) / extent * float(resolution_) : 0.0f;
    // Points outside the bounds (a light beyond the geometry) use the nearest border cell; NaN
    // fails the comparison and lands in cell 0.
    idx[a] = f >= 0 ? int(std::min(f, float(resolution_ - 1))) : 0;
  }
  return (idx[2] * resolution_ + idx[1]) * resolution_ + idx[0];
}

namespace {

// Index i with prefix[i] <= target < prefix[i + 1] (so its weight is positive), for target in
// [0, prefix.back()); targets rounded up to the total fall back to the last positive weight.
int find_in_prefix(const std::vector<double>& prefix, double target) {
  const double total = prefix.back();
  if (!(target < total)) target = std::nextafter(total, 0.0);
  auto it = std::upper_bound(prefix.begin() + 1, prefix.end(), target);
  int i = int(it - (prefix.begin() + 1));
  return std::min(i, int(prefix.size()) - 2);
}

}  // namespace

std::optional<LightChoice> LightSampler::sample(const Vec3f& p, const SampledWavelengths& lambda,
                                                float u) const {
  if (lights_ == nullptr || lights_->empty()) return std::nullopt;
  const Cell& c = cells_[std::size_t(cell_of(p))];
  if (!spectral_factor_) {
    double total = c.base_prefix.back();
    if (!(total > 0)) return std::nullopt;
    int e = find_in_prefix(c.base_prefix, double(u) * total);
    return LightChoice{e, float(double(c.base[e]) / total)};
  }
  // Stage 1: a live lane s with probability T_s / Σ T, T_s = Σ_e q_base(e)·Ê[e][bin(λ_s)].
  // Stage 2: e with probability q_base(e)·Ê[e][b_s] / T_s. Marginally
  // P(e) = Σ_s q_base(e)·Ê[e][b_s] / Σ_s T_s, the q(e) of §3.
  double total = 0;
  int chosen_bin = -1;
  double chosen_target = 0;
  const double target = double(u);
  double lane_terms[spectral::kMaxLanes] = {};
  int lane_bins[spectral::kMaxLanes];
  for (int s = 0; s < lambda.count(); ++s) {
    lane_bins[s] = lambda.live(s) ? grid_.bin_of(lambda.lambda(s)) : -1;
    lane_terms[s] = lane_bins[s] >= 0 ? c.prefix[lane_bins[s]].back() : 0.0;
    total += lane_terms[s];
  }
  if (!(total > 0)) return std::nullopt;
  double scaled = target * total, running = 0;
  for (int s = 0; s < lambda.count(); ++s) {
    if (!(lane_terms[s] > 0)) continue;
    chosen_bin = lane_bins[s];
    chosen_target = scaled - running;
    if (scaled < running + lane_terms[s]) break;
    running += lane_terms[s];
  }
  int e = find_in_prefix(c.prefix[chosen_bin], std::max(0.0, chosen_target));
  double numerator = 0;
  for (int s = 0; s < lambda.count(); ++s) {
    if (lane_bins[s] >= 0) numerator += double(c.base[e]) * unit_emission_[e][lane_bins[s]];
  }
  return LightChoice{e, float(numerator / total)};
}

float LightSampler::pmf(const Vec3f& p, const SampledWavelengths& lambda, int light) const {
  if (lights_ == nullptr || light < 0 || light >= int(lights_->size())) return 0;
  const Cell& c = cells_[std::size_t(cell_of(p))];
  if (!spectral_factor_) {
    double total = c.base_prefix.back();
    return total > 0 ? float(double(c.base[light]) / total) : 0.0f;
  }
  double total = 0, numerator = 0;
  for (int s = 0; s < lambda.count(); ++s) {
    int b = lambda.live(s) ? grid_.bin_of(lambda.lambda(s)) : -1;
    if (b < 0) continue;
    total += c.prefix[b].back();
    numerator += double(c.base[light]) * unit_emission_[light][b];
  }
  return total > 0 ? float(numerator / total) : 0.0f;
}

}  // namespace prism::worker
