#include "coordinator/gather.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::coordinator {
namespace {

constexpr int kMaxTaps = 129;
constexpr int kWindow = 3;            // the offsets' neighbourhood: 7 x 7 pixels
constexpr double kDepthSigma = 0.02;  // relative
constexpr double kFullCoherence = 0.9, kNoCoherence = 0.5;

struct Guide {
  double depth = 0;
  double n[3] = {0, 0, 0};
  bool valid = false;
};

}  // namespace

GatherImages::GatherImages(int width, int height)
    : width_(width),
      counts_(std::size_t(width) * height),
      offsets_(std::size_t(width) * height * image::kOffsetValues),
      depth_(std::size_t(width) * height),
      normals_(std::size_t(width) * height * 3) {}

absl::Status GatherImages::add_tile(const image::TileResult& merged) {
  const image::TileRect& r = merged.rect();
  if (!merged.has_offsets() || !merged.has_guides()) {
    return absl::InternalError(
        absl::StrCat("tile ", image::to_string(r), " has no offsets or guides to gather with"));
  }
  if (r.x0 < 0 || r.y0 < 0 || r.x1 > width_ ||
      std::size_t(r.y1) * std::size_t(width_) > counts_.size()) {
    return absl::InternalError(absl::StrCat("tile ", image::to_string(r), " is outside the image"));
  }
  for (int y = r.y0; y < r.y1; ++y) {
    for (int x = r.x0; x < r.x1; ++x) {
      const std::size_t t = std::size_t(y - r.y0) * r.width() + (x - r.x0);
      const std::size_t p = std::size_t(y) * width_ + x;
      counts_[p] = merged.counts()[t];
      for (int i = 0; i < image::kOffsetValues; ++i) {
        offsets_[p * image::kOffsetValues + i] = merged.offsets()[t * image::kOffsetValues + i];
      }
      depth_[p] = merged.depth()[t];
      for (int i = 0; i < 3; ++i) normals_[p * 3 + i] = merged.normals()[t * 3 + i];
    }
  }
  return absl::OkStatus();
}

double gather_width_at(float width_nm, std::uint64_t spp) {
  return double(width_nm) * std::pow(double(std::max<std::uint64_t>(spp, 1)), -0.2);
}

absl::StatusOr<image::SpectralImage> gather_filter(const GatherInputs& in, double width_nm,
                                                   GatherStats* stats) {
  if (in.image == nullptr) return absl::InvalidArgumentError("gathering needs an image");
  const image::SpectralImage& image = *in.image;
  const int w = image.width(), h = image.height(), bins = image.bins();
  const std::size_t pixels = std::size_t(w) * h;
  if (in.counts.size() != pixels || in.offsets.size() != pixels * image::kOffsetValues ||
      in.depth.size() != pixels || in.normals.size() != pixels * 3) {
    return absl::InvalidArgumentError(
        absl::StrCat("gathering's inputs do not match the ", w, "x", h, " image (counts ",
                     in.counts.size(), ", offsets ", in.offsets.size(), ", depth ", in.depth.size(),
                     ", normals ", in.normals.size(), ")"));
  }
  if (!(width_nm > 0) || !std::isfinite(width_nm)) {
    return absl::InvalidArgumentError(absl::StrCat("gathering width ", width_nm, " nm"));
  }
  auto grid = spectral::WavelengthGrid::create(bins);
  if (!grid.ok()) return grid.status();
  std::vector<Guide> guides(pixels);
  for (std::size_t p = 0; p < pixels; ++p) {
    if (in.counts[p] == 0) continue;
    const double n = double(in.counts[p]);
    Guide& g = guides[p];
    g.depth = in.depth[p] / n;
    double len = 0;
    for (int i = 0; i < 3; ++i) {
      g.n[i] = in.normals[p * 3 + i] / n;
      len += g.n[i] * g.n[i];
    }
    len = std::sqrt(len);
    if (len > 1e-6) {
      for (double& c : g.n) c /= len;
      g.valid = true;
    }
  }
  // Per pixel: its caustic events' offset sums and its total energy, per sample.
  std::vector<double> per_sample(pixels * image::kOffsetValues, 0.0), totals(pixels, 0.0);
  for (std::size_t p = 0; p < pixels; ++p) {
    if (in.counts[p] == 0) continue;
    const double n = double(in.counts[p]);
    for (int i = 0; i < image::kOffsetValues; ++i) {
      per_sample[p * image::kOffsetValues + i] = in.offsets[p * image::kOffsetValues + i] / n;
    }
    double total = 0;
    for (int b = 0; b < bins; ++b) total += image.value(int(p % w), int(p / w), b);
    totals[p] = total * grid->bin_width();
  }
  // The guides' bilateral weight between pixels p and q (0 without guides).
  auto bilateral = [&](std::size_t p, std::size_t q) {
    const Guide& a = guides[p];
    const Guide& b = guides[q];
    if (!a.valid || !b.valid) return 0.0;
    const double rel = (b.depth - a.depth) / std::max(a.depth, 1e-4) / kDepthSigma;
    double c = std::abs(a.n[0] * b.n[0] + a.n[1] * b.n[1] + a.n[2] * b.n[2]);
    for (int i = 0; i < 5; ++i) c *= c;  // ^32
    return std::exp(-0.5 * rel * rel) * c;
  };
  image::SpectralImage out = image;
  std::atomic<std::uint64_t> with_offsets{0}, filtered{0}, incoherent{0};
  tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
    std::vector<double> tap_weight(kMaxTaps);
    std::vector<int> tap_pixel(kMaxTaps);
    std::vector<double> tap_t(kMaxTaps);
    for (int y = rows.begin(); y != rows.end(); ++y) {
      for (int x = 0; x < w; ++x) {
        const std::size_t p = std::size_t(y) * w + x;
        if (in.counts[p] == 0 || !guides[p].valid) continue;
        // The offsets vary smoothly (paper §6.1): their statistics over the neighbourhood on the
        // same surface, so that a pixel whose own samples found no caustic event still learns
        // the caustic's direction from its neighbours.
        double o[image::kOffsetValues] = {}, total = 0;
        for (int j = std::max(0, y - kWindow); j <= std::min(h - 1, y + kWindow); ++j) {
          for (int i = std::max(0, x - kWindow); i <= std::min(w - 1, x + kWindow); ++i) {
            const std::size_t q = std::size_t(j) * w + i;
            const double b = q == p ? 1.0 : bilateral(p, q);
            if (!(b > 0)) continue;
            for (int k = 0; k < image::kOffsetValues; ++k) {
              o[k] += b * per_sample[q * image::kOffsetValues + k];
            }
            total += b * totals[q];
          }
        }
        if (!(o[0] > 0)) continue;
        with_offsets.fetch_add(1, std::memory_order_relaxed);
        const double mx = o[1] / o[0], my = o[2] / o[0];
        const double second = (o[3] + o[4]) / o[0];
        const double coherence = second > 0 ? (mx * mx + my * my) / second : 0.0;
        const double agree =
            std::clamp((coherence - kNoCoherence) / (kFullCoherence - kNoCoherence), 0.0, 1.0);
        if (agree == 0.0) {
          incoherent.fetch_add(1, std::memory_order_relaxed);
          continue;
        }
        // The caustic's share of the neighbourhood's energy.
        const double share = total > 0 ? std::clamp(o[0] / total, 0.0, 1.0) : 0.0;
        const double alpha = agree * share;
        const double dx = mx * width_nm, dy = my * width_nm;
        const double length = std::sqrt(dx * dx + dy * dy);
        if (!(alpha > 0) || !std::isfinite(length)) continue;
        const int taps = int(std::clamp(std::ceil(4.0 * length) + 1.0, 1.0, double(kMaxTaps)));
        if (taps < 2) continue;
        int used = 0;
        for (int k = 0; k < taps; ++k) {
          const double t = -1.0 + 2.0 * (k + 0.5) / taps;
          const int qx = int(std::floor(x + 0.5 + t * dx)), qy = int(std::floor(y + 0.5 + t * dy));
          if (qx < 0 || qx >= w || qy < 0 || qy >= h) continue;
          const std::size_t q = std::size_t(qy) * w + qx;
          const double weight = q == p ? 1.0 : bilateral(p, q);
          if (!(weight > 0)) continue;
          tap_weight[std::size_t(used)] = weight;
          tap_pixel[std::size_t(used)] = int(q);
          tap_t[std::size_t(used)] = t;
          ++used;
        }
        if (used == 0) continue;
        filtered.fetch_add(1, std::memory_order_relaxed);
        for (int b = 0; b < bins; ++b) {
          const double centre = grid->centre(b);
          double sum = 0, weights = 0;
          for (int k = 0; k < used; ++k) {
            const int source = grid->bin_of(float(centre + tap_t[std::size_t(k)] * width_nm));
            if (source < 0) continue;
            const int q = tap_pixel[std::size_t(k)];
            sum += tap_weight[std::size_t(k)] * image.value(q % w, q / w, source);
            weights += tap_weight[std::size_t(k)];
          }
          if (!(weights > 0)) continue;
          const double v = image.value(x, y, b);
          out.value(x, y, b) = float((1.0 - alpha) * v + alpha * sum / weights);
        }
      }
    }
  });
  if (stats != nullptr) {
    stats->pixels_with_offsets = with_offsets.load();
    stats->pixels_filtered = filtered.load();
    stats->pixels_incoherent = incoherent.load();
  }
  return out;
}

}  // namespace prism::coordinator
