#include "worker/tile_renderer.h"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <chrono>
#include <span>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/spectral/color.h"

namespace prism::worker {

TileRenderer::TileRenderer(const RenderScene& scene) : scene_(scene), integrator_(scene) {
  if (scene.options().integrator == job::IntegratorKind::kGradient) gradient_.emplace(scene);
  if (scene.options().traces_light_paths()) light_.emplace(scene);
}

namespace {

// One tile's output buffers (spans into its TileResult), and what each pixel's samples add to
// them. Every method touches the pixel `index` only, in sample order, so the doubles are the same
// whatever thread renders the pixel.
struct TileSums {
  TileSums(image::TileResult& result, const image::TileBuffers& buffers, int bins)
      : bins(bins),
        buffers(buffers),
        sums(result.mutable_sums()),
        squares(result.mutable_sum_squares()),
        counts(result.mutable_counts()),
        gradients(result.mutable_gradients()),
        gradient_squares(result.mutable_gradient_squares()),
        half_sums(result.mutable_half_sums()),
        half_squares(result.mutable_half_sum_squares()),
        half_gradients(result.mutable_half_gradients()),
        half_gradient_squares(result.mutable_half_gradient_squares()),
        half_counts(result.mutable_half_counts()),
        rgb_sums(result.mutable_rgb_sums()),
        rgb_squares(result.mutable_rgb_squares()),
        offsets(result.mutable_offsets()) {}

  // A sample's R, G, B into the pixel's sums (in sample order, like the bins).
  void add_rgb(std::int64_t index, const double* rgb) {
    if (!buffers.rgb) return;
    const std::size_t o = std::size_t(index) * 3;
    for (int c = 0; c < 3; ++c) {
      rgb_sums[o + c] += rgb[c];
      rgb_squares[o + c] += rgb[c] * rgb[c];
    }
  }

  // A gradient sample s: each of its bins' primal and gradient values (GradientSample::entry,
  // one per bin, so each is one per-sample value for the squares), and with halves the even
  // samples again into the half buffers.
  void add_gradient(std::int64_t index, std::uint64_t s, const GradientSample& g) {
    const std::size_t o = std::size_t(index) * bins;
    add_rgb(index, g.rgb);
    // The halves split by the sample's global index, so they do not depend on how the samples
    // were cut into tasks.
    const bool half = buffers.halves && s % 2 == 0;
    for (int e = 0; e < g.entries; ++e) {
      const GradientBinValue& v = g.entry[e];
      const std::size_t b = o + std::size_t(v.bin);
      const double p = v.primal, p2 = p * p;
      sums[b] += p;
      squares[b] += p2;
      gradients[b] += v.gradient;
      if (!buffers.halves) continue;
      const double g2 = double(v.gradient) * v.gradient;
      gradient_squares[b] += g2;
      if (!half) continue;
      half_sums[b] += p;
      half_squares[b] += p2;
      half_gradients[b] += v.gradient;
      half_gradient_squares[b] += g2;
    }
  }

  // A hero sample (fold_lanes).
  void add_hero(std::int64_t index, const SampleContribution& c, std::span<double> scratch) {
    add_rgb(index, c.rgb);
    if (buffers.offsets && c.offset[0] > 0) {
      const std::size_t o = std::size_t(index) * image::kOffsetValues;
      for (int i = 0; i < image::kOffsetValues; ++i) offsets[o + i] += c.offset[i];
    }
    fold_lanes(c, scratch, &sums[std::size_t(index) * bins], &squares[std::size_t(index) * bins]);
  }

  void set_counts(std::int64_t index, const image::SampleRange& samples) {
    counts[std::size_t(index)] = samples.count();
    // The even indices in [s0, s1).
    if (buffers.halves)
      half_counts[std::size_t(index)] = (samples.s1 + 1) / 2 - (samples.s0 + 1) / 2;
  }

  const int bins;
  const image::TileBuffers buffers;
  std::span<double> sums, squares;
  std::span<std::uint64_t> counts;
  std::span<double> gradients, gradient_squares, half_sums, half_squares, half_gradients,
      half_gradient_squares;
  std::span<std::uint64_t> half_counts;
  std::span<double> rgb_sums, rgb_squares, offsets;
};

// A pixel's guide features, summed over its samples.
struct GuideSums {
  void add(const GuideValues& guide) {
    depth += guide.depth;
    normal += guide.normal;
    albedo += guide.albedo;
    ++count;
  }
  std::uint64_t count = 0;
  float depth = 0, albedo = 0;
  Vec3f normal;
};

}  // namespace

absl::Status TileRenderer::check_task(const RenderTask& task) const {
  const int bins = scene_.grid().bins();
  const image::TileRect& rect = task.tile;
  if (task.early_stop && !task.prepass) {
    return absl::InvalidArgumentError(
        "early stop is for prepass tasks only: it truncates paths, which biases a final pass");
  }
  if (task.tables != nullptr &&
      (task.tables->width() != rect.width() || task.tables->height() != rect.height())) {
    return absl::InvalidArgumentError(absl::StrCat("the pdf tables are for ", task.tables->width(),
                                                   "x", task.tables->height(),
                                                   " pixels but the tile ", image::to_string(rect),
                                                   " has ", rect.width(), "x", rect.height()));
  }
  if (task.tables != nullptr && task.tables->cells() != bins) {
    return absl::InvalidArgumentError(absl::StrCat("the pdf tables have ", task.tables->cells(),
                                                   " cells per pixel but the job has ", bins,
                                                   " bins; a table holds one mass per bin"));
  }
  if (task.samples.s1 > std::uint64_t{1} << 32) {
    return absl::InvalidArgumentError(
        absl::StrCat("sample range ends at ", task.samples.s1, ", beyond 2^32 samples per pixel"));
  }
  return absl::OkStatus();
}

image::TileBuffers TileRenderer::buffers_for(const RenderTask& task) const {
  image::TileBuffers buffers;
  // A prepass traces with the hero path tracer whatever the job's integrator, so a gradient
  // job's prepass has no gradients.
  const bool gradient = gradient_.has_value() && !task.prepass;
  // Gathering's final pass records the caustic events' offsets, and the guides its filter's
  // bilateral weights compare.
  const bool gathers = scene_.options().gathers() && !task.prepass && !gradient_.has_value();
  buffers.guides = task.want_guides || gathers;
  buffers.offsets = gathers;
  buffers.gradients = gradient;
  buffers.halves = gradient && scene_.options().gradient_variances;
  // The final pass's RGB comes from each sample's exact wavelengths, not from the bins.
  buffers.rgb = !task.prepass;
  return buffers;
}

absl::StatusOr<image::TileResult> TileRenderer::render(const RenderTask& task, TileStats* stats,
                                                       const std::atomic<bool>* cancel,
                                                       std::atomic<std::uint64_t>* progress) const {
  if (light_.has_value() && !task.prepass) return render_light(task, stats, cancel, progress);
  if (absl::Status checked = check_task(task); !checked.ok()) return checked;
  const int bins = scene_.grid().bins();
  const image::TileRect& rect = task.tile;
  const image::TileBuffers buffers = buffers_for(task);
  auto created = image::TileResult::create(task.tile, task.samples, bins, buffers);
  if (!created.ok()) return created.status();
  image::TileResult result = std::move(*created);
  const auto start = std::chrono::steady_clock::now();
  const int width = rect.width();
  const spectral::WavelengthDistribution& job_pdf = scene_.wavelength_pdf();
  const GradientIntegrator* gradient = buffers.gradients ? &*gradient_ : nullptr;
  const TraceOptions trace_options{task.prepass ? job::kPrepassLanes : 0, task.early_stop};
  TileSums out(result, buffers, bins);

  tbb::combinable<TraceCounters> counters;
  std::atomic<bool> cancelled{false};
  // Each pixel is owned by one thread and its samples are added in index order, so every
  // double in the result is the same whatever the scheduling.
  tbb::parallel_for(
      tbb::blocked_range<std::int64_t>(0, rect.area(), 1),
      [&](const tbb::blocked_range<std::int64_t>& range) {
        TraceCounters& local = counters.local();
        std::vector<double> scratch(bins, 0.0);
        spectral::CompositeCdf composite;  // a table pixel's, rebuilt per pixel
        for (std::int64_t index = range.begin(); index != range.end(); ++index) {
          if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) {
            cancelled.store(true, std::memory_order_relaxed);
            return;
          }
          const int x = rect.x0 + int(index % width);
          const int y = rect.y0 + int(index / width);
          // A prepass skips the pixels that fell back to the default distribution in an earlier
          // pass (docs/estimators.md §4): their all-zero row says so; they keep no samples.
          const bool skipped = task.prepass && task.tables != nullptr &&
                               task.tables->uses_default(x - rect.x0, y - rect.y0);
          if (!skipped) {
            // A pixel with a table samples its lanes from the table's composite CDF (one search
            // per lane, for a build per pixel that its samples share) where the task renders
            // enough of its samples to pay for the build, else by the table's two searches.
            const spectral::QuantisedWavelengthCdf* table =
                task.tables != nullptr ? task.tables->table(x - rect.x0, y - rect.y0) : nullptr;
            const bool use_composite = table != nullptr && task.samples.s1 - task.samples.s0 >=
                                                               spectral::CompositeCdf::kMinSamples;
            if (use_composite) composite.assign(scene_.binned_shape(), *table);
            const spectral::WavelengthPdfView lambda_pdf =
                use_composite ? spectral::WavelengthPdfView(composite)
                : task.tables != nullptr
                    ? task.tables->view(x - rect.x0, y - rect.y0, job_pdf, scene_.binned_shape())
                    : spectral::WavelengthPdfView(job_pdf);
            GuideSums guides;
            for (std::uint64_t s = task.samples.s0; s < task.samples.s1; ++s) {
              GuideValues guide;
              GuideValues* want_guide = buffers.guides ? &guide : nullptr;
              if (gradient != nullptr) {
                out.add_gradient(index, s,
                                 gradient->trace(x, y, task.pass, std::uint32_t(s), lambda_pdf,
                                                 local, want_guide));
              } else {
                out.add_hero(index,
                             integrator_.trace(x, y, task.pass, std::uint32_t(s), lambda_pdf, local,
                                               want_guide, trace_options),
                             scratch);
              }
              if (want_guide != nullptr) guides.add(guide);
            }
            out.set_counts(index, task.samples);
            if (guides.count > 0) {
              result.add_guides(x, y, guides.depth, guides.normal.x, guides.normal.y,
                                guides.normal.z, guides.albedo);
            }
          }
          if (progress != nullptr)
            progress->fetch_add(task.samples.count(), std::memory_order_relaxed);
        }
      },
      tbb::simple_partitioner());
  if (cancelled.load()) return absl::CancelledError("task cancelled");
  record_stats(stats, counters, start);
  return result;
}

void TileRenderer::record_stats(TileStats* stats, tbb::combinable<TraceCounters>& counters,
                                std::chrono::steady_clock::time_point start) {
  if (stats == nullptr) return;
  stats->counters = TraceCounters();
  counters.combine_each([&](const TraceCounters& c) { stats->counters += c; });
  stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace prism::worker
