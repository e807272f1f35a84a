#include "worker/tile_renderer.h"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <chrono>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/spectral/color.h"

namespace prism::worker {

TileRenderer::TileRenderer(const RenderScene& scene) : scene_(scene), integrator_(scene) {
  if (scene.options().integrator == job::IntegratorKind::kGradient) gradient_.emplace(scene);
  if (scene.options().traces_light_paths()) light_.emplace(scene);
}

absl::StatusOr<image::TileResult> TileRenderer::render(const RenderTask& task, TileStats* stats,
                                                       const std::atomic<bool>* cancel,
                                                       std::atomic<std::uint64_t>* progress) const {
  if (light_.has_value() && !task.prepass) return render_light(task, stats, cancel, progress);
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
  // A prepass traces with the hero path tracer whatever the job's integrator, so a gradient
  // job's prepass has no gradients.
  const GradientIntegrator* gradient =
      gradient_.has_value() && !task.prepass ? &*gradient_ : nullptr;
  const TraceOptions trace_options{task.prepass ? job::kPrepassLanes : 0, task.early_stop};
  image::TileBuffers buffers;
  // Gathering's final pass records the caustic events' offsets, and the guides its filter's
  // bilateral weights compare.
  const bool gathers = scene_.options().gathers() && !task.prepass && !gradient_.has_value();
  const bool want_guides = task.want_guides || gathers;
  buffers.guides = want_guides;
  buffers.offsets = gathers;
  buffers.gradients = gradient != nullptr;
  buffers.halves = gradient != nullptr && scene_.options().gradient_variances;
  // The final pass's RGB comes from each sample's exact wavelengths, not from the bins.
  buffers.rgb = !task.prepass;
  auto created = image::TileResult::create(task.tile, task.samples, bins, buffers);
  if (!created.ok()) return created.status();
  image::TileResult result = std::move(*created);
  if (task.samples.s1 > std::uint64_t{1} << 32) {
    return absl::InvalidArgumentError(
        absl::StrCat("sample range ends at ", task.samples.s1, ", beyond 2^32 samples per pixel"));
  }
  const auto start = std::chrono::steady_clock::now();
  const int width = rect.width();
  const spectral::WavelengthDistribution& job_pdf = scene_.wavelength_pdf();

  tbb::combinable<TraceCounters> counters;
  std::atomic<bool> cancelled{false};
  auto sums = result.mutable_sums();
  auto squares = result.mutable_sum_squares();
  auto counts = result.mutable_counts();
  auto gradients = result.mutable_gradients();
  auto gradient_squares = result.mutable_gradient_squares();
  auto half_sums = result.mutable_half_sums();
  auto half_squares = result.mutable_half_sum_squares();
  auto half_gradients = result.mutable_half_gradients();
  auto half_gradient_squares = result.mutable_half_gradient_squares();
  auto half_counts = result.mutable_half_counts();
  auto rgb_sums = result.mutable_rgb_sums();
  auto rgb_squares = result.mutable_rgb_squares();
  auto offsets = result.mutable_offsets();

  // Each pixel is owned by one thread and its samples are added in index order, so every
  // double in the result is the same whatever the scheduling.
  tbb::parallel_for(
      tbb::blocked_range<std::int64_t>(0, rect.area(), 1),
      [&](const tbb::blocked_range<std::int64_t>& range) {
        TraceCounters& local = counters.local();
        std::vector<double> sample_values(bins, 0.0);
        for (std::int64_t index = range.begin(); index != range.end(); ++index) {
          if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) {
            cancelled.store(true, std::memory_order_relaxed);
            return;
          }
          const int x = rect.x0 + int(index % width);
          const int y = rect.y0 + int(index / width);
          // A prepass skips the pixels that fell back to the default distribution in an earlier
          // pass (docs/estimators.md §4): their all-zero row says so; they keep no samples.
          if (task.prepass && task.tables != nullptr &&
              task.tables->uses_default(x - rect.x0, y - rect.y0)) {
            if (progress != nullptr) {
              progress->fetch_add(task.samples.count(), std::memory_order_relaxed);
            }
            continue;
          }
          const spectral::WavelengthPdfView lambda_pdf =
              task.tables != nullptr
                  ? task.tables->view(x - rect.x0, y - rect.y0, job_pdf, scene_.binned_shape())
                  : spectral::WavelengthPdfView(job_pdf);
          double* pixel_sums = &sums[std::size_t(index) * bins];
          double* pixel_squares = &squares[std::size_t(index) * bins];
          // A sample's R, G, B into the pixel's sums (in sample order, like the bins).
          auto add_rgb = [&](const double* rgb) {
            if (!buffers.rgb) return;
            const std::size_t o = std::size_t(index) * 3;
            for (int c = 0; c < 3; ++c) {
              rgb_sums[o + c] += rgb[c];
              rgb_squares[o + c] += rgb[c] * rgb[c];
            }
          };
          std::uint64_t guide_count = 0;
          float depth_sum = 0, albedo_sum = 0;
          Vec3f normal_sum;
          for (std::uint64_t s = task.samples.s0; s < task.samples.s1; ++s) {
            GuideValues guide;
            if (gradient != nullptr) {
              GradientSample g = gradient->trace(x, y, task.pass, std::uint32_t(s), lambda_pdf,
                                                 local, want_guides ? &guide : nullptr);
              if (g.primal != 0.0f) {
                const double v = g.primal;
                pixel_sums[g.bin] += v;
                pixel_squares[g.bin] += v * v;
              }
              add_rgb(g.rgb);
              double* pixel_gradients = &gradients[std::size_t(index) * bins];
              pixel_gradients[g.bin] += g.gradient;
              pixel_gradients[g.bin_below] += g.gradient_below;
              if (buffers.halves) {
                // bin and bin_below differ (1 <= k < bins): each is one per-sample value.
                const std::size_t o = std::size_t(index) * bins;
                const double g2 = double(g.gradient) * g.gradient;
                const double g2_below = double(g.gradient_below) * g.gradient_below;
                gradient_squares[o + g.bin] += g2;
                gradient_squares[o + g.bin_below] += g2_below;
                // The halves split by the sample's global index, so they do not depend on how
                // the samples were cut into tasks.
                if (s % 2 == 0) {
                  const double v = g.primal;
                  half_sums[o + g.bin] += v;
                  half_squares[o + g.bin] += v * v;
                  half_gradients[o + g.bin] += g.gradient;
                  half_gradients[o + g.bin_below] += g.gradient_below;
                  half_gradient_squares[o + g.bin] += g2;
                  half_gradient_squares[o + g.bin_below] += g2_below;
                }
              }
              if (want_guides) {
                depth_sum += guide.depth;
                normal_sum += guide.normal;
                albedo_sum += guide.albedo;
                ++guide_count;
              }
              continue;
            }
            SampleContribution c =
                integrator_.trace(x, y, task.pass, std::uint32_t(s), lambda_pdf, local,
                                  want_guides ? &guide : nullptr, trace_options);
            add_rgb(c.rgb);
            if (gathers && c.offset[0] > 0) {
              const std::size_t o = std::size_t(index) * image::kOffsetValues;
              for (int i = 0; i < image::kOffsetValues; ++i) offsets[o + i] += c.offset[i];
            }
            // Lanes that land in the same bin form one value of this sample for that bin, so
            // the sum of squares is that of per-sample bin values.
            for (int lane = 0; lane < c.lanes; ++lane) sample_values[c.bin[lane]] += c.value[lane];
            for (int lane = 0; lane < c.lanes; ++lane) {
              double& v = sample_values[c.bin[lane]];
              if (v != 0.0) {
                pixel_sums[c.bin[lane]] += v;
                pixel_squares[c.bin[lane]] += v * v;
                v = 0.0;
              }
            }
            if (want_guides) {
              depth_sum += guide.depth;
              normal_sum += guide.normal;
              albedo_sum += guide.albedo;
              ++guide_count;
            }
          }
          counts[std::size_t(index)] = task.samples.count();
          if (buffers.halves) {
            // The even indices in [s0, s1).
            half_counts[std::size_t(index)] = (task.samples.s1 + 1) / 2 - (task.samples.s0 + 1) / 2;
          }
          if (want_guides && guide_count > 0) {
            result.add_guides(x, y, depth_sum, normal_sum.x, normal_sum.y, normal_sum.z,
                              albedo_sum);
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
