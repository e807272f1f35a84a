// TileRenderer::render_light: a light-tracing task (light_tracer.h). Sample s of the task is a
// batch of W·H light paths, path (x, y) of batch s drawing from pixel (x, y)'s stream of sample
// s, and the batch's splats, divided by W·H, are its one sample for every pixel: the pixel's
// sums, squares and counts then mean what an eye tracer's do, so merging, statistics and outputs
// need nothing new. Paths run in parallel in fixed chunks, each chunk keeps its splats in path
// order, and the chunks are added in chunk order, so the bytes do not depend on the threads.
// With --caustics light every pixel also takes its eye samples (the path tracer, which leaves
// the caustic paths to the light paths), after the batches and pixel by pixel like a tile: a
// pixel's sample s is then the sum l_s + e_s of two independent estimates, its sums Σl + Σe and
// its squares Σl² + Σe² + 2·Σl·Σe/n, whose expectation is that of Σ(l_s + e_s)² (the cross term
// of independent estimates), so the variance estimates stay unbiased.
// With --caustics light a batch may hold fewer paths than pixels (RenderOptions::caustic_paths):
// n paths, path k drawing from pixel k's stream, splats divided by n; still one sample of every
// pixel.
// With differential splatting (job spec splat_width, differential_splat.h) the task also sums a
// filtered image: the same splats and eye samples, except that each splat with a spectral
// differential is drawn as a line over ±Δλ_s, Δλ_s = splat_width·(s + 1)^(−1/5) for batch s
// (job::splat_width_at). Δλ depends on the batch's index only, so the sums do not depend on
// how the batches are split into tasks.
#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <chrono>
#include <cmath>
#include <optional>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "worker/differential_splat.h"
#include "worker/tile_renderer.h"

namespace prism::worker {

// One batch's per-pixel values before they become a sample: the bins and R, G, B, and the
// pixels touched in first-touch order (so only they are folded and cleared).
struct BatchImage {
  int width = 0, height = 0, bins = 0;
  std::vector<double> values, rgb;
  std::vector<std::uint8_t> touched;
  std::vector<std::int64_t> order;

  BatchImage(int w, int h, int b)
      : width(w),
        height(h),
        bins(b),
        values(std::size_t(w) * h * b, 0.0),
        rgb(std::size_t(w) * h * 3, 0.0),
        touched(std::size_t(w) * h, 0) {}

  void add(int x, int y, const LightSplat& s, double weight) {
    const std::int64_t p = std::int64_t(y) * width + x;
    if (!touched[std::size_t(p)]) {
      touched[std::size_t(p)] = 1;
      order.push_back(p);
    }
    values[std::size_t(p) * bins + s.bin] += s.value * weight;
    for (int c = 0; c < 3; ++c) rgb[std::size_t(p) * 3 + c] += s.rgb[c] * weight;
  }
};

namespace {

constexpr std::int64_t kPathsPerChunk = 1024;

// A splat into the pixels whose filter reaches it: weight f(offset from the centre) / ∫f, so that
// its share in each pixel is what an eye sample of that pixel at the same film position carries
// on average (pixel_filter.h).
void splat(const PixelFilter& filter, const LightSplat& s, double scale, BatchImage& batch) {
  for_each_filter_pixel(filter, s.raster, scale, batch.width, batch.height,
                        [&](int x, int y, double w) { batch.add(x, y, s, w); });
}

}  // namespace

void TileRenderer::add_eye_paths(const RenderTask& task, image::TileResult& result,
                                 FilteredSums* filtered, tbb::combinable<TraceCounters>& counters,
                                 const std::atomic<bool>* cancel,
                                 std::atomic<std::uint64_t>* progress) const {
  const spectral::WavelengthPdfView lambda_pdf(scene_.wavelength_pdf());
  const int width = task.tile.width(), bins = scene_.grid().bins();
  const std::uint64_t n = task.samples.count();
  auto sums = result.mutable_sums();
  auto squares = result.mutable_sum_squares();
  auto rgb_sums = result.mutable_rgb_sums();
  auto rgb_squares = result.mutable_rgb_squares();
  // Σl and Σl² of the light paths are in the result; Σ(l + e)² = Σl² + Σe² + 2·Σl·Σe/n in
  // expectation (l and e are independent), so the squares keep their meaning.
  auto combine = [n](double& sum, double& square, double e, double e2) {
    square += e2 + 2.0 * sum * e / double(n);
    sum += e;
  };
  // Each pixel is one thread's, its samples taken in index order, as in TileRenderer::render.
  tbb::parallel_for(
      tbb::blocked_range<std::int64_t>(0, task.tile.area(), 1),
      [&](const tbb::blocked_range<std::int64_t>& range) {
        TraceCounters& local = counters.local();
        // The pixel's Σe and Σe² per bin, then R, G, B and their squares; a lane scratch.
        std::vector<double> eye(2 * std::size_t(bins) + 6, 0.0), scratch(bins, 0.0);
        double* e_sums = eye.data();
        double* e_squares = e_sums + bins;
        double* e_rgb = e_squares + bins;
        for (std::int64_t p = range.begin(); p != range.end(); ++p) {
          if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) return;
          const int x = int(p % width), y = int(p / width);
          for (std::uint64_t s = task.samples.s0; s < task.samples.s1; ++s) {
            const SampleContribution c =
                integrator_.trace(x, y, 0, std::uint32_t(s), lambda_pdf, local);
            fold_lanes(c, scratch, e_sums, e_squares);
            for (int k = 0; k < 3; ++k) {
              e_rgb[k] += c.rgb[k];
              e_rgb[3 + k] += c.rgb[k] * c.rgb[k];
            }
          }
          const std::size_t o = std::size_t(p) * bins;
          for (int b = 0; b < bins; ++b) {
            if (e_sums[b] == 0.0 && e_squares[b] == 0.0) continue;
            combine(sums[o + b], squares[o + b], e_sums[b], e_squares[b]);
            if (filtered != nullptr) filtered->values[o + b] += e_sums[b];
          }
          for (int k = 0; k < 3; ++k) {
            combine(rgb_sums[std::size_t(p) * 3 + k], rgb_squares[std::size_t(p) * 3 + k], e_rgb[k],
                    e_rgb[3 + k]);
            if (filtered != nullptr) filtered->rgb[std::size_t(p) * 3 + k] += e_rgb[k];
          }
          std::fill(eye.begin(), eye.end(), 0.0);
          if (progress != nullptr) progress->fetch_add(n, std::memory_order_relaxed);
        }
      },
      tbb::simple_partitioner());
}

absl::StatusOr<image::TileResult> TileRenderer::render_light(
    const RenderTask& task, TileStats* stats, const std::atomic<bool>* cancel,
    std::atomic<std::uint64_t>* progress) const {
  const int width = scene_.camera().width(), height = scene_.camera().height();
  const int bins = scene_.grid().bins();
  using Probe = job::RenderOptions::CausticProbe;
  const Probe probe = scene_.options().caustic_probe;
  const bool with_eye_paths =
      scene_.options().light_caustics && (probe == Probe::kOff || probe == Probe::kEyeOnly);
  const bool with_light_paths = probe != Probe::kEyeOnly;
  if (task.tile != image::TileRect{0, 0, width, height}) {
    return absl::InvalidArgumentError(
        absl::StrCat("a light-tracing task covers the whole image (0,0)-(", width, ",", height,
                     "), not the tile ", image::to_string(task.tile)));
  }
  if (task.tables != nullptr || task.want_guides) {
    return absl::InvalidArgumentError(
        "a light-tracing task takes no wavelength tables and records no guides");
  }
  if (task.samples.s1 > std::uint64_t{1} << 32) {
    return absl::InvalidArgumentError(
        absl::StrCat("sample range ends at ", task.samples.s1, ", beyond 2^32 samples per pixel"));
  }
  image::TileBuffers buffers;
  buffers.rgb = true;
  const float splat_width = scene_.options().splat_width_nm;
  buffers.filtered = splat_width > 0.0f;
  PRISM_ASSIGN_OR_RETURN(image::TileResult result,
                         image::TileResult::create(task.tile, task.samples, bins, buffers));
  const auto start = std::chrono::steady_clock::now();
  const std::int64_t pixels = std::int64_t(width) * height;
  const std::int64_t paths = scene_.options().light_paths_per_batch(pixels);
  const std::int64_t chunks = (paths + kPathsPerChunk - 1) / kPathsPerChunk;
  std::vector<std::vector<LightSplat>> chunk_splats(static_cast<std::size_t>(chunks));
  BatchImage batch(width, height, bins);
  const double scale = 1.0 / double(paths);
  auto sums = result.mutable_sums();
  auto squares = result.mutable_sum_squares();
  auto rgb_sums = result.mutable_rgb_sums();
  auto rgb_squares = result.mutable_rgb_squares();
  tbb::combinable<TraceCounters> counters;
  std::atomic<bool> cancelled{false};
  // Differential splatting: the filtered image, summed straight into the result (it keeps no
  // squares), lines drawn in the same fixed order as the points.
  std::optional<ReceiverImage> receivers;
  std::optional<DifferentialSplatter> splatter;
  FilteredSums filtered{width, height, bins, result.mutable_filtered_sums(),
                        result.mutable_filtered_rgb_sums()};
  TraceCounters splat_counters;
  if (buffers.filtered) {
    receivers.emplace(scene_);
    splatter.emplace(scene_, *receivers);
  }
  for (std::uint64_t s = task.samples.s0; with_light_paths && s < task.samples.s1; ++s) {
    tbb::parallel_for(
        tbb::blocked_range<std::int64_t>(0, chunks, 1),
        [&](const tbb::blocked_range<std::int64_t>& range) {
          TraceCounters& local = counters.local();
          for (std::int64_t c = range.begin(); c != range.end(); ++c) {
            if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) {
              cancelled.store(true, std::memory_order_relaxed);
              return;
            }
            std::vector<LightSplat>& out = chunk_splats[std::size_t(c)];
            out.clear();
            const std::int64_t end = std::min(paths, (c + 1) * kPathsPerChunk);
            for (std::int64_t k = c * kPathsPerChunk; k < end; ++k) {
              light_->trace(int(k % width), int(k / width), std::uint32_t(s), out, local);
            }
          }
        },
        tbb::simple_partitioner());
    if (cancelled.load()) return absl::CancelledError("task cancelled");
    const double width_nm = job::splat_width_at(splat_width, s);
    for (const std::vector<LightSplat>& out : chunk_splats) {
      for (const LightSplat& splat_value : out) {
        splat(scene_.pixel_filter(), splat_value, scale, batch);
        ++splat_counters.light_splats;
        if (splatter && splatter->splat(splat_value, width_nm, scale, filtered)) {
          ++splat_counters.splat_lines;
        }
      }
    }
    // The batch is one sample of every pixel: its sums and squares (untouched pixels add 0).
    for (std::int64_t p : batch.order) {
      for (int b = 0; b < bins; ++b) {
        double& v = batch.values[std::size_t(p) * bins + b];
        if (v != 0.0) {
          sums[std::size_t(p) * bins + b] += v;
          squares[std::size_t(p) * bins + b] += v * v;
          v = 0.0;
        }
      }
      for (int c = 0; c < 3; ++c) {
        double& v = batch.rgb[std::size_t(p) * 3 + c];
        rgb_sums[std::size_t(p) * 3 + c] += v;
        rgb_squares[std::size_t(p) * 3 + c] += v * v;
        v = 0.0;
      }
      batch.touched[std::size_t(p)] = 0;
    }
    batch.order.clear();
    // With eye paths, progress counts their pixels' samples (most of the time) instead.
    if (progress != nullptr && !with_eye_paths) {
      progress->fetch_add(std::uint64_t(pixels), std::memory_order_relaxed);
    }
  }
  if (with_eye_paths) {
    add_eye_paths(task, result, splatter ? &filtered : nullptr, counters, cancel, progress);
    if (cancel != nullptr && cancel->load()) return absl::CancelledError("task cancelled");
  }
  auto counts = result.mutable_counts();
  std::fill(counts.begin(), counts.end(), task.samples.count());
  counters.local() += splat_counters;
  record_stats(stats, counters, start);
  return result;
}

}  // namespace prism::worker
