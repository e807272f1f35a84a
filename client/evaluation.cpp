#include "client/evaluation.h"

#include <sys/resource.h>

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <numeric>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "coordinator/outputs.h"
#include "services/base/atomic_file.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/job/job_parameters.h"
#include "services/scene/bundle.h"
#include "services/scene/scene_loader.h"

namespace prism::evaluation {
namespace {

// This program's own build: the first 16 hex digits of its executable's SHA-256 (empty where
// /proc/self/exe cannot be read). Kept with a rendered reference, so that one a different build
// rendered is named as such when it is taken from the cache.
const std::string& renderer_build() {
  static const std::string build = [] {
    std::ifstream in("/proc/self/exe", std::ios::binary);
    if (!in) return std::string();
    const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    return in.bad() || bytes.empty() ? std::string() : base::sha256_hex(bytes).substr(0, 16);
  }();
  return build;
}

double mean_of(const std::vector<double>& v) {
  return v.empty() ? 0.0 : std::accumulate(v.begin(), v.end(), 0.0) / double(v.size());
}

// Everything about the reference render that changes its pixels.
std::string describe(const coordinator::LocalRenderOptions& o) {
  const job::RenderOptions& r = o.render;
  return absl::StrCat(
      o.width, "x", o.height, "|spp ", o.spp, "|", job::name(r.integrator), "|",
      job::name(r.spectral_pdf), "|", job::name(r.emitter_pdf), "|", job::name(r.light_selection),
      "|", r.spectral_light_selection,
      r.light_caustics ? absl::StrCat("|caustics light ", r.caustic_paths) : "", "|",
      static_cast<int>(r.sampler), "|bins ", r.bins, "|depth ", r.max_depth, "|rr ", r.rr_min_depth,
      "|seed ", r.seed, "|eps ", r.defensive_epsilon, "|k ", r.gradient_offset_bins, "|tau ",
      r.gradient_tau, "|prepass ", o.prepass.has_value(), "|alpha ", o.poisson_alpha, "|per task ",
      o.samples_per_task, "|target ",
      o.target_error.has_value() ? absl::StrCat(o.target_error->relative, " ",
                                                o.target_error->image_scope ? "image" : "pixel",
                                                " ", o.target_error->max_spp)
                                 : std::string("none"));
}

absl::Status write_image(const std::filesystem::path& path, const image::SpectralImage& image,
                         const image::ExrMetadata& metadata) {
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb, coordinator::to_linear_srgb(image, cmf));
  return image::write_spectral_exr(path, image, rgb, metadata);
}

}  // namespace

double process_cpu_seconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return double(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
         1e-6 * double(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

absl::StatusOr<BenchScene> load_bench_scene(const std::filesystem::path& path,
                                            bool allow_unsupported) {
  BenchScene out;
  PRISM_ASSIGN_OR_RETURN(spectral::SpectrumLibrary library,
                         spectral::SpectrumLibrary::load_builtin());
  out.library = std::make_unique<spectral::SpectrumLibrary>(std::move(library));
  scene::LoadOptions load = scene::with_library_names(*out.library);
  load.allow_unsupported = allow_unsupported;
  PRISM_ASSIGN_OR_RETURN(scene::LoadedScene loaded, scene::load_scene(path, load));
  PRISM_ASSIGN_OR_RETURN(scene::Bundle bundle, scene::make_bundle(loaded.root, loaded.scene_relpath,
                                                                  loaded.description.files));
  out.description = std::move(loaded.description);
  out.name = path.filename().string();
  out.bundle_hash = bundle.content_hash;
  out.scene_relpath = loaded.scene_relpath;
  return out;
}

absl::StatusOr<TimedRender> timed_render(worker::EmbreeDevice& device, const BenchScene& scene,
                                         const coordinator::LocalRenderOptions& options) {
  PRISM_ASSIGN_OR_RETURN(auto renderer, coordinator::LocalRender::create(device, scene.description,
                                                                         *scene.library, options));
  const double cpu_start = process_cpu_seconds();
  const auto wall_start = std::chrono::steady_clock::now();
  absl::StatusOr<coordinator::LocalRenderResult> result = renderer->render();
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  const double cpu = process_cpu_seconds() - cpu_start;
  if (!result.ok()) return result.status();
  return TimedRender{*std::move(result), wall, cpu};
}

absl::StatusOr<image::ErrorMetrics> Reference::floor(const std::optional<image::Crop>& crop) const {
  return image::compare_spectral(half, image, crop);
}

absl::StatusOr<Reference> cached_reference(worker::EmbreeDevice& device, const BenchScene& scene,
                                           const coordinator::LocalRenderOptions& options,
                                           const std::filesystem::path& cache_dir,
                                           const std::string& tag,
                                           const HalfRenderer& render_half) {
  const std::string key = base::sha256_hex(absl::StrCat(scene.bundle_hash, "|", scene.scene_relpath,
                                                        "|", describe(options)))
                              .substr(0, 16);
  const std::filesystem::path average_path =
      cache_dir / absl::StrCat("prism-bench-", tag, "-reference-", key, ".exr");
  const std::filesystem::path half_path =
      cache_dir / absl::StrCat("prism-bench-", tag, "-reference-", key, ".half.exr");
  if (std::filesystem::exists(average_path) && std::filesystem::exists(half_path)) {
    PRISM_ASSIGN_OR_RETURN(image::SpectralExr average, image::read_spectral_exr(average_path));
    PRISM_ASSIGN_OR_RETURN(image::SpectralExr half, image::read_spectral_exr(half_path));
    auto seconds = average.metadata.find("reference_seconds");
    auto variance = average.metadata.find("reference_variance_of_mean");
    if (seconds != average.metadata.end() && variance != average.metadata.end()) {
      std::fprintf(stderr, "%s: reference %s cached in %s\n", tag.c_str(), scene.name.c_str(),
                   average_path.c_str());
      auto build = average.metadata.find("reference_renderer");
      const std::string cached_by = build == average.metadata.end() ? "" : build->second;
      if (cached_by != renderer_build()) {
        std::fprintf(stderr,
                     "%s: warning: that reference was made by another build of prism (%s; "
                     "this one is %s). If the renderer changed what this scene renders, delete "
                     "%s and %s or pass --reference-cache a new directory\n",
                     tag.c_str(), cached_by.empty() ? "unrecorded" : cached_by.c_str(),
                     renderer_build().empty() ? "unknown" : renderer_build().c_str(),
                     average_path.c_str(), half_path.filename().c_str());
      }
      // The spp it was rendered with (to a target error, more than the first round's).
      std::uint64_t spp = options.spp;
      if (auto recorded = average.metadata.find("spp"); recorded != average.metadata.end()) {
        std::uint64_t value = 0;
        if (absl::SimpleAtoi(recorded->second, &value) && value > 0) spp = value;
      }
      return Reference{std::move(average.spectral), std::move(half.spectral), spp,
                       std::stod(seconds->second), std::stod(variance->second)};
    }
  }
  coordinator::LocalRenderOptions half_options = options;
  if (options.target_error.has_value()) {
    // Each half to √2 times the target, so that their average meets it; the halves may stop
    // at different rounds per tile, and their average is still unbiased.
    job::TargetError& t = *half_options.target_error;
    t.relative = std::min(job::kMaxTargetError, t.relative * std::sqrt(2.0));
    t.max_spp = std::max(options.spp, t.max_spp / 2);
    std::fprintf(stderr,
                 "%s: rendering the reference of %s to %.3g %% in two halves (cached in %s)\n",
                 tag.c_str(), scene.name.c_str(), 100 * options.target_error->relative,
                 average_path.c_str());
  } else {
    if (options.spp < 2) {
      return absl::InvalidArgumentError("a reference needs at least 2 spp (two halves)");
    }
    half_options.spp = options.spp / 2;
    std::fprintf(stderr,
                 "%s: rendering the reference of %s, %llu spp in two halves (cached in %s)\n",
                 tag.c_str(), scene.name.c_str(), static_cast<unsigned long long>(options.spp),
                 average_path.c_str());
  }
  auto render = [&](const coordinator::LocalRenderOptions& o) -> absl::StatusOr<TimedRender> {
    if (render_half) return render_half(o);
    return timed_render(device, scene, o);
  };
  PRISM_ASSIGN_OR_RETURN(TimedRender a, render(half_options));
  half_options.render.seed = options.render.seed + 1;
  PRISM_ASSIGN_OR_RETURN(TimedRender b, render(half_options));
  if (a.result.image.data().size() != b.result.image.data().size()) {
    return absl::InternalError("the reference's two halves differ in size");
  }
  if (half_options.target_error.has_value() &&
      (!a.result.stats.target_error.has_value() || !b.result.stats.target_error.has_value())) {
    return absl::InternalError("a target-error half of the reference did not report its spp");
  }

  image::SpectralImage average = a.result.image;
  std::span<float> out = average.data();
  std::span<const float> other = b.result.image.data();
  for (std::size_t i = 0; i < out.size(); ++i) out[i] = 0.5f * (out[i] + other[i]);
  const double variance = 0.25 * (mean_of(a.result.statistics.variance_of_mean) +
                                  mean_of(b.result.statistics.variance_of_mean));
  const double seconds = a.wall_seconds + b.wall_seconds;
  const std::uint64_t spp =
      half_options.target_error.has_value()
          ? a.result.stats.target_error->max_spp + b.result.stats.target_error->max_spp
          : 2 * half_options.spp;
  Reference reference{std::move(average), std::move(a.result.image), spp, seconds, variance};
  const image::ExrMetadata metadata{
      {"spp", absl::StrCat(reference.spp)},
      {"reference_seconds", absl::StrFormat("%.17g", seconds)},
      {"reference_variance_of_mean", absl::StrFormat("%.17g", variance)},
      {"reference_options", describe(options)},
      {"reference_renderer", renderer_build()}};
  std::error_code ec;
  std::filesystem::create_directories(cache_dir, ec);
  if (ec) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot create the cache directory ", cache_dir.string(), ": ", ec.message()));
  }
  // The half first: a crash between the two writes leaves no average, so nothing half-made is
  // ever taken from the cache.
  PRISM_RETURN_IF_ERROR(write_image(half_path, reference.half, {}));
  PRISM_RETURN_IF_ERROR(write_image(average_path, reference.image, metadata));
  std::fprintf(stderr, "%s: reference %s took %.1f s\n", tag.c_str(), scene.name.c_str(), seconds);
  return reference;
}

std::optional<double> error_at_time(std::span<const ConvergencePoint> points, double t,
                                    bool* extrapolated) {
  std::vector<ConvergencePoint> usable;
  for (const ConvergencePoint& p : points) {
    if (p.error > 0 && p.seconds > 0 && std::isfinite(p.error)) usable.push_back(p);
  }
  if (usable.empty() || !(t > 0)) return std::nullopt;
  std::sort(usable.begin(), usable.end(), [](const ConvergencePoint& a, const ConvergencePoint& b) {
    return a.seconds < b.seconds;
  });
  if (extrapolated != nullptr) *extrapolated = false;
  if (t <= usable.front().seconds || t >= usable.back().seconds) {
    const ConvergencePoint& p = t <= usable.front().seconds ? usable.front() : usable.back();
    if (extrapolated != nullptr) *extrapolated = t != p.seconds;
    return p.error * p.seconds / t;
  }
  for (std::size_t i = 1; i < usable.size(); ++i) {
    const ConvergencePoint& lo = usable[i - 1];
    const ConvergencePoint& hi = usable[i];
    if (t > hi.seconds) continue;
    if (hi.seconds == lo.seconds) return std::sqrt(lo.error * hi.error);
    const double f = std::log(t / lo.seconds) / std::log(hi.seconds / lo.seconds);
    return std::exp(std::log(lo.error) + f * std::log(hi.error / lo.error));
  }
  return usable.back().error;
}

absl::StatusOr<std::vector<std::uint64_t>> parse_spp_list(const std::string& text) {
  std::vector<std::uint64_t> out;
  for (absl::string_view part : absl::StrSplit(text, ',')) {
    std::uint64_t value = 0;
    auto [end, ec] = std::from_chars(part.data(), part.data() + part.size(), value);
    if (ec != std::errc() || end != part.data() + part.size() || value < 1 ||
        (!out.empty() && value <= out.back())) {
      return absl::InvalidArgumentError(
          absl::StrCat("spp list '", text, "': want increasing positive integers, e.g. 8,16,32"));
    }
    if (value > job::kMaxJobSpp) {
      return absl::InvalidArgumentError(absl::StrCat(
          "spp list '", text, "': ", part, " is more than a job takes (1..", job::kMaxJobSpp, ")"));
    }
    out.push_back(value);
  }
  return out;
}

}  // namespace prism::evaluation
