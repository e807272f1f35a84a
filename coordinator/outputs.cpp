#include "coordinator/outputs.h"

#include <sys/resource.h>
#include <unistd.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <system_error>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "services/base/atomic_file.h"
#include "services/base/check.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/image/png.h"
#include "services/spectral/wavelength_grid.h"

#ifndef PRISM_VERSION
#error "PRISM_VERSION must be defined by the build"
#endif

namespace prism::coordinator {
namespace fs = std::filesystem;
namespace {

fs::path with_suffix(const fs::path& stem, const char* suffix) {
  return fs::path(stem.string() + suffix);
}

double per_second(double amount, double seconds) {
  return seconds > 0 ? amount / seconds : std::nan("");
}

}  // namespace

const char* prism_version() {
  return PRISM_VERSION;
}

absl::StatusOr<OutputPaths> output_paths(const std::optional<fs::path>& output,
                                         const std::optional<fs::path>& json,
                                         const std::string& film_filename) {
  fs::path spectral;
  if (output.has_value()) {
    if (output->empty() || !output->has_filename() || output->filename() == "." ||
        output->filename() == "..") {
      return absl::InvalidArgumentError(
          absl::StrCat("--output '", output->string(), "': want a file name such as out.exr"));
    }
    const std::string extension = absl::AsciiStrToLower(output->extension().string());
    if (extension.empty()) {
      spectral = with_suffix(*output, ".exr");
    } else if (extension == ".exr") {
      spectral = *output;
    } else {
      return absl::InvalidArgumentError(
          absl::StrCat("--output '", output->string(),
                       "': the spectral output is an OpenEXR file; give a name ending in .exr"));
    }
  } else {
    std::string stem = fs::path(film_filename).filename().stem().string();
    if (stem.empty() || stem == "." || stem == "..") stem = "render";
    spectral = fs::path(stem + ".exr");
  }
  fs::path stem = spectral.parent_path() / spectral.stem();
  OutputPaths paths;
  paths.spectral_exr = spectral;
  paths.rgb_exr = with_suffix(stem, ".rgb.exr");
  paths.png = with_suffix(stem, ".png");
  paths.primal_exr = with_suffix(stem, ".primal.exr");
  paths.gradient_exr = with_suffix(stem, ".gradient.exr");
  if (json.has_value()) {
    if (json->empty() || !json->has_filename() || json->filename() == "." ||
        json->filename() == "..") {
      return absl::InvalidArgumentError(
          absl::StrCat("--json '", json->string(), "': want a file name such as report.json"));
    }
    paths.json = *json;
  } else {
    paths.json = with_suffix(stem, ".json");
  }
  const fs::path* all[] = {&paths.spectral_exr, &paths.rgb_exr,    &paths.png,
                           &paths.json,         &paths.primal_exr, &paths.gradient_exr};
  for (int i = 0; i < 6; ++i) {
    for (int j = i + 1; j < 6; ++j) {
      if (fs::absolute(*all[i]).lexically_normal() == fs::absolute(*all[j]).lexically_normal()) {
        return absl::InvalidArgumentError(absl::StrCat("two outputs would both be written to '",
                                                       all[i]->string(),
                                                       "': choose a different --json or -o name"));
      }
    }
  }
  return paths;
}

absl::Status check_output_locations(const OutputPaths& paths) {
  for (const fs::path* path : {&paths.spectral_exr, &paths.rgb_exr, &paths.png, &paths.json}) {
    fs::path dir = path->parent_path();
    if (dir.empty()) dir = ".";
    std::error_code ec;
    if (!fs::exists(dir, ec)) {
      return absl::NotFoundError(absl::StrCat("cannot write '", path->string(), "': directory '",
                                              dir.string(), "' does not exist"));
    }
    if (!fs::is_directory(dir, ec)) {
      return absl::InvalidArgumentError(absl::StrCat("cannot write '", path->string(), "': '",
                                                     dir.string(), "' is not a directory"));
    }
    if (::access(dir.c_str(), W_OK) != 0) {
      return absl::PermissionDeniedError(absl::StrCat(
          "cannot write '", path->string(), "': directory '", dir.string(), "' is not writable"));
    }
    if (fs::is_directory(*path, ec)) {
      return absl::InvalidArgumentError(
          absl::StrCat("cannot write '", path->string(), "': it is a directory"));
    }
  }
  return absl::OkStatus();
}

BinStatisticsAccumulator::BinStatisticsAccumulator(std::size_t tiles, int bins)
    : bins_(bins), tiles_(tiles) {
  PRISM_CHECK(bins >= 1);
}

void BinStatisticsAccumulator::add_tile(std::size_t tile_index, const image::TileResult& merged) {
  PRISM_CHECK(tile_index < tiles_.size());
  PRISM_CHECK(merged.bins() == bins_);
  TileSums& t = tiles_[tile_index];
  PRISM_CHECK(!t.present);
  t.present = true;
  t.mean_sum.assign(bins_, 0.0);
  t.error_sum.assign(bins_, 0.0);
  t.variance_sum.assign(bins_, 0.0);
  std::span<const double> sums = merged.sums();
  std::span<const double> squares = merged.sum_squares();
  std::span<const std::uint64_t> counts = merged.counts();
  t.pixels = counts.size();
  for (std::size_t p = 0; p < counts.size(); ++p) {
    const std::uint64_t n = counts[p];
    if (n == 0) continue;
    const double nd = static_cast<double>(n);
    for (int b = 0; b < bins_; ++b) {
      const double mean = sums[p * bins_ + b] / nd;
      t.mean_sum[b] += mean;
      if (n >= 2) {
        // Cancellation can make the difference slightly negative for constant samples.
        const double variance =
            std::max(0.0, (squares[p * bins_ + b] - nd * mean * mean) / (nd - 1.0));
        t.error_sum[b] += std::sqrt(variance / nd);
        t.variance_sum[b] += variance / nd;
      }
    }
    if (n >= 2) ++t.pixels_with_error;
  }
}

BinStatistics BinStatisticsAccumulator::finish() const {
  BinStatistics out;
  out.mean.assign(bins_, 0.0);
  out.standard_error.assign(bins_, 0.0);
  out.variance_of_mean.assign(bins_, 0.0);
  std::uint64_t pixels = 0;
  for (const TileSums& t : tiles_) {
    PRISM_CHECK_MSG(t.present, "every tile must be added before finish()");
    for (int b = 0; b < bins_; ++b) {
      out.mean[b] += t.mean_sum[b];
      out.standard_error[b] += t.error_sum[b];
      out.variance_of_mean[b] += t.variance_sum[b];
    }
    pixels += t.pixels;
    out.pixels_with_error += t.pixels_with_error;
  }
  for (int b = 0; b < bins_; ++b) {
    out.mean[b] = pixels > 0 ? out.mean[b] / static_cast<double>(pixels) : 0.0;
    const double with_error = static_cast<double>(out.pixels_with_error);
    out.standard_error[b] = with_error > 0 ? out.standard_error[b] / with_error : std::nan("");
    out.variance_of_mean[b] = with_error > 0 ? out.variance_of_mean[b] / with_error : std::nan("");
  }
  return out;
}

absl::StatusOr<image::RgbImage> to_linear_srgb(const image::SpectralImage& spectral,
                                               const spectral::ColorMatching& cmf) {
  PRISM_ASSIGN_OR_RETURN(spectral::WavelengthGrid grid,
                         spectral::WavelengthGrid::create(spectral.bins()));
  const spectral::XyzBinWeights weights = cmf.bin_weights(grid);
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb,
                         image::RgbImage::create(spectral.width(), spectral.height()));
  // pbrt-v4's default `cie1931` sensor (imaging ratio 1) records XYZ = ∫ CMF(λ)·L(λ) dλ, with no
  // division by the CIE Y integral; lights are normalised by their photometric sum, so a light of
  // `scale` s seen directly has Y = s there. XyzBinWeights divides by kCieYIntegral, which this
  // undoes, so Prism's RGB output has pbrt-v4's brightness.
  constexpr double kSensor = spectral::kCieYIntegral;
  for (int y = 0; y < spectral.height(); ++y) {
    for (int x = 0; x < spectral.width(); ++x) {
      spectral::Xyz xyz = weights.to_xyz(spectral.pixel(x, y));
      xyz.x *= kSensor;
      xyz.y *= kSensor;
      xyz.z *= kSensor;
      const spectral::Rgb c = spectral::xyz_to_linear_srgb(xyz);
      rgb.value(x, y, 0) = static_cast<float>(c.r);
      rgb.value(x, y, 1) = static_cast<float>(c.g);
      rgb.value(x, y, 2) = static_cast<float>(c.b);
    }
  }
  return rgb;
}

absl::StatusOr<image::RgbImage> tile_rgb(const image::TileResult& merged,
                                         const image::SpectralImage& finalised, bool reconstructed,
                                         const spectral::ColorMatching& cmf) {
  const image::TileRect& rect = merged.rect();
  if (finalised.width() != rect.width() || finalised.height() != rect.height()) {
    return absl::InvalidArgumentError(absl::StrCat("the finished tile is ", finalised.width(), "x",
                                                   finalised.height(), ", its result ",
                                                   image::to_string(rect)));
  }
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb, to_linear_srgb(finalised, cmf));
  if (!merged.has_rgb()) return rgb;
  std::optional<image::RgbImage> plain;
  if (reconstructed) {
    PRISM_ASSIGN_OR_RETURN(plain, to_linear_srgb(image::finalise(merged), cmf));
  }
  const std::span<const double> sums = merged.rgb_sums();
  const std::span<const std::uint64_t> counts = merged.counts();
  for (int y = 0; y < rect.height(); ++y) {
    for (int x = 0; x < rect.width(); ++x) {
      const std::size_t p = std::size_t(y) * rect.width() + x;
      const double n = double(counts[p]);
      for (int k = 0; k < 3; ++k) {
        double v = n > 0 ? sums[p * 3 + k] / n : 0.0;
        if (plain.has_value()) v += double(rgb.value(x, y, k)) - double(plain->value(x, y, k));
        rgb.value(x, y, k) = static_cast<float>(v);
      }
    }
  }
  return rgb;
}

absl::StatusOr<image::RgbImage> tile_rgb_standard_error(const image::TileResult& merged) {
  if (!merged.has_rgb()) {
    return absl::FailedPreconditionError(absl::StrCat(
        "tile ", image::to_string(merged.rect()), " has no RGB buffers: no RGB standard errors"));
  }
  const image::TileRect& rect = merged.rect();
  PRISM_ASSIGN_OR_RETURN(image::RgbImage out, image::RgbImage::create(rect.width(), rect.height()));
  const std::span<const double> sums = merged.rgb_sums();
  const std::span<const double> squares = merged.rgb_squares();
  const std::span<const std::uint64_t> counts = merged.counts();
  for (int y = 0; y < rect.height(); ++y) {
    for (int x = 0; x < rect.width(); ++x) {
      const std::size_t p = std::size_t(y) * rect.width() + x;
      const double n = double(counts[p]);
      for (int c = 0; c < 3; ++c) {
        const double mean = n > 0 ? sums[p * 3 + c] / n : 0.0;
        const double variance =
            n >= 2 ? std::max(0.0, squares[p * 3 + c] / n - mean * mean) / (n - 1) : std::nan("");
        out.value(x, y, c) = static_cast<float>(std::sqrt(variance));
      }
    }
  }
  return out;
}

namespace {

// A whole image as the row bands write_spectral_exr_rows asks for (valid while `image` lives).
image::SpectralRows rows_of(const image::SpectralImage& image) {
  const std::size_t row_values = std::size_t(image.width()) * std::size_t(image.bins());
  return [&image, row_values](int y0, int) -> absl::StatusOr<const float*> {
    return image.data().data() + y0 * row_values;
  };
}

// A float job setting as the shortest decimal that reads back as it (0.15, not 0.1500000059).
double shortest(float value) {
  return std::isfinite(value) ? std::stod(absl::StrCat(value)) : std::nan("");
}

}  // namespace

std::string prepass_summary(const PrepassReport& p) {
  const double total = p.seconds + p.final_seconds;
  const PrepassOutcome& o = p.outcome;
  std::string what;
  if (o.stopped_early) {
    what = absl::StrFormat("stopped after pass 1: predicted gain %.1f %%, default everywhere",
                           100.0 * o.first_pass_gain);
  } else if (o.dropped) {
    what = absl::StrFormat("%d passes, predicted gain %.1f %%: tables dropped, default everywhere",
                           o.passes_run, 100.0 * o.predicted_gain);
  } else {
    what = absl::StrFormat("%d passes, predicted gain %.1f %%, %.1f %% of pixels learned",
                           o.passes_run, 100.0 * o.predicted_gain,
                           100.0 * (1.0 - o.fallback_fraction));
  }
  return absl::StrFormat("%.2f s of prepass (%.1f %% of the time; %s)", p.seconds,
                         total > 0 ? 100.0 * p.seconds / total : 0.0, what);
}

std::string format_report_json(const RenderReport& r, const OutputPaths& paths) {
  nlohmann::ordered_json j;
  j["prism_version"] = prism_version();
  j["scene"] = r.scene;
  j["width"] = r.width;
  j["height"] = r.height;
  j["spp"] = r.spp;
  j["bins"] = r.bins;
  j["integrator"] = r.integrator;
  j["spectral_pdf"] = r.spectral_pdf;
  j["emitter_pdf"] = r.emitter_pdf;
  j["light_selection"] = r.light_selection;
  j["spectral_light_selection"] = r.spectral_light_selection;
  j["max_depth"] = r.max_depth;
  j["threads"] = r.threads;
  j["tile_size"] = r.tile_size;
  j["seed"] = r.seed;
  j["wall_seconds"] = r.wall_seconds;
  j["render_seconds"] = r.render_seconds;
  j["samples"] = r.samples;
  j["samples_per_second"] = per_second(static_cast<double>(r.samples), r.render_seconds);
  j["samples_per_second_per_core"] =
      r.threads > 0 ? per_second(static_cast<double>(r.samples), r.render_seconds) / r.threads
                    : std::nan("");
  j["rays"] = r.rays;
  j["rays_per_second"] = per_second(static_cast<double>(r.rays), r.render_seconds);
  j["peak_memory_bytes"] = r.peak_memory_bytes;
  nlohmann::ordered_json counters = nlohmann::ordered_json::object();
  for (const auto& [name, value] : r.counters) counters[name] = value;
  j["counters"] = counters;
  nlohmann::ordered_json centres = nlohmann::ordered_json::array();
  for (double c : image::bin_centres_nm(r.bins)) centres.push_back(c);
  j["bin_centres_nm"] = centres;
  j["bin_mean"] = r.statistics.mean;
  j["bin_standard_error"] = r.statistics.standard_error;
  j["bin_variance_of_mean"] = r.statistics.variance_of_mean;
  j["pixels_with_error_estimate"] = r.statistics.pixels_with_error;
  if (r.gradient.has_value()) {
    const GradientReport& g = *r.gradient;
    auto fraction = [](std::uint64_t part, std::uint64_t whole) {
      return whole > 0 ? double(part) / double(whole) : std::nan("");
    };
    j["gradient"] = {{"offset_bins", g.offset_bins},
                     {"delta", shortest(g.delta)},
                     {"tau", shortest(g.tau)},
                     {"alpha", shortest(g.alpha)},
                     {"poisson", g.norm},
                     // The spectral gradient paper's Table 1: how many base paths were shifted, and
                     // how many shifts were wasted because the offset did not pass the threshold.
                     {"shifted_path_fraction", fraction(g.shifted_paths, g.base_paths)},
                     {"wasted_shift_fraction", fraction(g.wasted_shifts, g.shifts)},
                     {"failed_shift_fraction", fraction(g.failed_shifts, g.shifts)},
                     {"base_paths", g.base_paths},
                     {"shifted_paths", g.shifted_paths},
                     {"shifts", g.shifts},
                     {"failed_shifts", g.failed_shifts},
                     {"wasted_shifts", g.wasted_shifts}};
    j["gradient"]["tau_source"] = g.tau_pilot.has_value() ? "pilot" : "given";
    if (g.tau_pilot.has_value()) {
      const job::TauPilotReport& t = *g.tau_pilot;
      nlohmann::ordered_json pilot = {
          {"epsilon", shortest(t.epsilon)},
          {"pixels", t.pixels},
          {"spp", t.spp},
          {"events", t.events},
          {"shifted_event_fraction", shortest(t.shifted_event_fraction)},
          {"shifted_square_fraction", shortest(t.shifted_square_fraction)},
          {"lost_benefit_fraction", shortest(t.lost_benefit_fraction)},
          {"predicted_offset_work_fraction", shortest(t.offset_vertex_fraction)},
          {"predicted_second_moment_rise", shortest(t.second_moment_rise)}};
      if (t.seconds.has_value()) pilot["seconds"] = *t.seconds;
      j["gradient"]["tau_pilot"] = pilot;
    }
  }
  if (r.prepass.has_value()) {
    const PrepassReport& p = *r.prepass;
    j["prepass"] = {
        {"passes", p.passes},
        {"pass_spp", p.pass_spp},
        {"pass_resolution", p.pass_resolution},
        {"mode", p.image_scaled ? "image" : "samples"},
        {"epsilon", shortest(p.epsilon)},
        {"fallback", shortest(p.fallback)},
        {"sigma_s", shortest(p.sigma_s)},
        {"sigma_r", shortest(p.sigma_r)},
        {"passes_run", p.outcome.passes_run},
        {"stopped_early", p.outcome.stopped_early},
        {"tables_dropped", p.outcome.dropped},
        {"prepass_seconds", p.seconds},
        {"reconstruction_seconds", p.outcome.reconstruction_seconds},
        {"final_pass_seconds", p.final_seconds},
        {"time_share",
         p.seconds + p.final_seconds > 0 ? p.seconds / (p.seconds + p.final_seconds) : 0.0},
        {"first_pass_predicted_gain", p.outcome.first_pass_gain},
        {"predicted_gain", p.outcome.predicted_gain},
        {"fallback_pixel_fraction", p.outcome.fallback_fraction}};
    nlohmann::ordered_json alphas = nlohmann::ordered_json::array();
    for (int a = 0; a < kAlphaChoices; ++a) {
      alphas.push_back({{"alpha", shortest(float(p.outcome.alpha_values[a]))},
                        {"pixels", p.outcome.alpha_histogram[a]}});
    }
    j["prepass"]["alpha_histogram"] = alphas;
    j["prepass"]["learned_shapes"] = {{"second_moment", p.outcome.shape_histogram[0]},
                                      {"within_lane", p.outcome.shape_histogram[1]}};
  }
  // Where the image is not pbrt-v4's: every substitution (--allow-unsupported), approximation
  // and ignored setting, so a reference says what it is a reference of.
  nlohmann::ordered_json features = {{"substituted", nlohmann::ordered_json::array()},
                                     {"approximated", nlohmann::ordered_json::array()},
                                     {"ignored", nlohmann::ordered_json::array()}};
  for (const SceneFeatureNote& f : r.scene_features) {
    nlohmann::ordered_json entry = {
        {"feature", f.feature}, {"where", f.where}, {"uses", f.uses}, {"note", f.note}};
    if (f.status == "refused") {
      entry["substitution"] = f.substitution;
      features["substituted"].push_back(entry);
    } else if (f.status == "approximated" || f.status == "ignored") {
      features[f.status].push_back(entry);
    }
  }
  j["scene_features"] = features;
  if (r.auto_choice.has_value()) {
    const job::AutoReport& a = *r.auto_choice;
    nlohmann::ordered_json candidates = nlohmann::ordered_json::array();
    for (const job::AutoReport::Candidate& c : a.candidates) {
      candidates.push_back({{"method", c.method},
                            {"rel_mse_per_sample", c.rel_mse_per_sample},
                            {"rays_per_sample", c.rays_per_sample},
                            {"relative_efficiency", c.relative_efficiency}});
    }
    j["auto"] = {{"choice", a.choice},
                 {"reason", a.reason},
                 {"pilot_seconds", a.seconds},
                 {"candidates", candidates}};
  }
  if (r.target_error.has_value()) {
    const TargetErrorOutcome& t = *r.target_error;
    j["target_error"] = {{"target", t.target},
                         {"scope", t.image_scope ? "image" : "pixel"},
                         {"met", t.met},
                         {"rounds", t.rounds},
                         {"rounds_planned", t.rounds_planned},
                         {"reached",
                          {{"pixel_max", t.pixel_max},
                           {"pixel_mean", t.pixel_mean},
                           {"pixel_p99", t.pixel_p99},
                           {"image", t.image_error}}},
                         {"spp", {{"min", t.min_spp}, {"mean", t.mean_spp}, {"max", t.max_spp}}}};
  }
  nlohmann::ordered_json outputs = {{"spectral_exr", paths.spectral_exr.string()},
                                    {"rgb_exr", paths.rgb_exr.string()},
                                    {"png", paths.png.string()},
                                    {"json", paths.json.string()}};
  if (r.gradient.has_value() && r.gradient->with_primal_and_gradients) {
    outputs["primal_exr"] = paths.primal_exr.string();
    outputs["gradient_exr"] = paths.gradient_exr.string();
  }
  j["outputs"] = outputs;
  return j.dump(2) + "\n";
}

absl::Status write_outputs(const image::SpectralImage& spectral, const spectral::ColorMatching& cmf,
                           const RenderReport& report, const OutputPaths& paths,
                           const OutputOptions& options) {
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb, to_linear_srgb(spectral, cmf));
  return write_outputs(spectral.bins(), spectral.height(), rows_of(spectral), rgb, report, paths,
                       options);
}

absl::Status write_outputs(const image::SpectralImage& spectral, const image::RgbImage& rgb,
                           const RenderReport& report, const OutputPaths& paths,
                           const OutputOptions& options) {
  if (rgb.width() != spectral.width() || rgb.height() != spectral.height()) {
    return absl::InvalidArgumentError(absl::StrCat("the RGB image is ", rgb.width(), "x",
                                                   rgb.height(), ", the spectral image ",
                                                   spectral.width(), "x", spectral.height()));
  }
  return write_outputs(spectral.bins(), spectral.height(), rows_of(spectral), rgb, report, paths,
                       options);
}

void fill_gradient_counters(const std::vector<std::pair<std::string, std::uint64_t>>& counters,
                            GradientReport& report) {
  for (const auto& [name, value] : counters) {
    if (name == "camera_rays") report.base_paths = value;
    if (name == "gradient_shifted_paths") report.shifted_paths = value;
    if (name == "gradient_shifts") report.shifts = value;
    if (name == "gradient_shifts_failed") report.failed_shifts = value;
    if (name == "gradient_shifts_wasted") report.wasted_shifts = value;
  }
}

namespace {

image::ExrMetadata output_metadata(const RenderReport& report) {
  image::ExrMetadata metadata;
  metadata[std::string(image::kMetaSpp)] = absl::StrCat(report.spp);
  metadata[std::string(image::kMetaIntegrator)] = report.integrator;
  metadata[std::string(image::kMetaSeed)] = absl::StrCat(report.seed);
  metadata["bins"] = absl::StrCat(report.bins);
  metadata["scene"] = report.scene;
  metadata["version"] = prism_version();
  metadata["spectral_pdf"] = report.spectral_pdf;
  metadata["emitter_pdf"] = report.emitter_pdf;
  metadata["light_selection"] = report.light_selection;
  metadata["spectral_light_selection"] = report.spectral_light_selection ? "on" : "off";
  metadata["max_depth"] = absl::StrCat(report.max_depth);
  if (report.gradient.has_value()) {
    metadata[std::string(image::kMetaGradientOffsetBins)] =
        absl::StrCat(report.gradient->offset_bins);
    metadata[std::string(image::kMetaGradientDelta)] = absl::StrCat(report.gradient->delta);
    metadata["gradient_tau"] = absl::StrCat(report.gradient->tau);
  }
  if (report.prepass.has_value()) {
    metadata["prepass_passes"] = absl::StrCat(report.prepass->passes);
  }
  if (report.target_error.has_value()) {
    metadata["target_error"] = absl::StrCat(report.target_error->target);
    metadata["target_error_scope"] = report.target_error->image_scope ? "image" : "pixel";
    metadata["target_error_met"] = report.target_error->met ? "yes" : "no";
    metadata["target_error_spp_max"] = absl::StrCat(report.target_error->max_spp);
  }
  return metadata;
}

}  // namespace

absl::Status write_outputs(int bins, int band_rows, const image::SpectralRows& rows,
                           const image::RgbImage& rgb, const RenderReport& report,
                           const OutputPaths& paths, const OutputOptions& options) {
  image::ExrMetadata metadata = output_metadata(report);
  if (report.gradient.has_value()) {
    // The reconstruction records how it was made (exr_spectral.h).
    metadata[std::string(image::kMetaPoissonAlpha)] = absl::StrCat(report.gradient->alpha);
    metadata[std::string(image::kMetaPoissonNorm)] = report.gradient->norm;
  }

  absl::Status first;
  std::string failures;
  auto record = [&](const fs::path& path, const absl::Status& status) {
    if (status.ok()) return;
    if (first.ok()) first = status;
    absl::StrAppend(&failures, failures.empty() ? "" : "; ", "could not write '", path.string(),
                    "': ", status.message());
  };
  record(paths.spectral_exr,
         image::write_spectral_exr_rows(paths.spectral_exr, image::bin_centres_nm(bins),
                                        rgb.width(), rgb.height(), band_rows, rows, rgb, metadata));
  record(paths.rgb_exr,
         image::write_rgb_exr(paths.rgb_exr, rgb, image::ExrPixelType::kFloat, metadata));
  record(paths.png, image::write_png_preview(paths.png, rgb, options.exposure_stops));
  const std::string json = format_report_json(report, paths);
  record(paths.json, base::write_file_atomic(paths.json, std::span<const char>(json)));
  if (first.ok()) return first;
  return absl::Status(first.code(), failures);
}

absl::Status write_primal_and_gradient(int bins, int band_rows, const image::SpectralRows& primal,
                                       const image::RgbImage& primal_rgb,
                                       const image::SpectralRows& gradient,
                                       const image::RgbImage& gradient_rgb,
                                       const RenderReport& report, const OutputPaths& paths) {
  const image::ExrMetadata metadata = output_metadata(report);
  const std::vector<double> centres = image::bin_centres_nm(bins);
  absl::Status status =
      image::write_spectral_exr_rows(paths.primal_exr, centres, primal_rgb.width(),
                                     primal_rgb.height(), band_rows, primal, primal_rgb, metadata);
  if (!status.ok()) {
    return absl::Status(status.code(), absl::StrCat("could not write '", paths.primal_exr.string(),
                                                    "': ", status.message()));
  }
  status = image::write_spectral_exr_rows(paths.gradient_exr, centres, gradient_rgb.width(),
                                          gradient_rgb.height(), band_rows, gradient, gradient_rgb,
                                          metadata);
  if (!status.ok()) {
    return absl::Status(
        status.code(),
        absl::StrCat("could not write '", paths.gradient_exr.string(), "': ", status.message()));
  }
  return absl::OkStatus();
}

absl::Status write_primal_and_gradient(const image::SpectralImage& primal,
                                       const image::SpectralImage& gradient,
                                       const spectral::ColorMatching& cmf,
                                       const RenderReport& report, const OutputPaths& paths) {
  PRISM_ASSIGN_OR_RETURN(image::RgbImage primal_rgb, to_linear_srgb(primal, cmf));
  PRISM_ASSIGN_OR_RETURN(image::RgbImage gradient_rgb, to_linear_srgb(gradient, cmf));
  return write_primal_and_gradient(primal.bins(), primal.height(), rows_of(primal), primal_rgb,
                                   rows_of(gradient), gradient_rgb, report, paths);
}

std::uint64_t peak_memory_bytes() {
  rusage usage{};
  if (getrusage(RUSAGE_SELF, &usage) != 0) return 0;
  return static_cast<std::uint64_t>(usage.ru_maxrss) * 1024;  // Linux reports kilobytes
}

std::string target_error_summary(const TargetErrorOutcome& t) {
  auto percent = [](double v) { return absl::StrFormat("%.3g %%", 100 * v); };
  return absl::StrCat("to ", percent(t.target),
                      t.image_scope ? " of the image's mean: " : " per pixel: ",
                      t.met ? "met" : "not met (max spp reached)", " in ", t.rounds, " of ",
                      t.rounds_planned, " rounds (image ", percent(t.image_error), "; pixels max ",
                      percent(t.pixel_max), ", p99 ", percent(t.pixel_p99), ", mean ",
                      percent(t.pixel_mean), "), ", t.min_spp, "..", t.max_spp, " spp");
}

}  // namespace prism::coordinator
