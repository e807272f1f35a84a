#include "coordinator/outputs.h"

#include <sys/resource.h>
#include <unistd.h>

#include <cmath>
#include <system_error>
#include <thread>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/check.h"
#include "services/base/decimal.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/image/png.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::coordinator {
namespace fs = std::filesystem;
namespace {

fs::path with_suffix(const fs::path& stem, const char* suffix) {
  return fs::path(stem.string() + suffix);
}

}  // namespace

absl::StatusOr<OutputPaths> output_paths(const std::optional<fs::path>& output,
                                         const std::optional<fs::path>& json,
                                         const std::string& film_filename) {
  fs::path spectral;
  auto default_name = [&film_filename]() {
    std::string stem = fs::path(film_filename).filename().stem().string();
    if (stem.empty() || stem == "." || stem == "..") stem = "render";
    return fs::path(stem + ".exr");
  };
  std::error_code ec;
  if (output.has_value() && !output->empty() &&
      (!output->has_filename() || fs::is_directory(*output, ec))) {
    // A directory: the default name inside it.
    spectral = *output / default_name();
  } else if (output.has_value()) {
    if (output->empty() || output->filename() == "." || output->filename() == ".." ||
        output->stem().empty() || output->stem() == ".exr" || output->stem() == ".EXR") {
      return absl::InvalidArgumentError(
          absl::StrCat("--output '", output->string(), "': want a file name such as out.exr"));
    }
    const std::string extension = absl::AsciiStrToLower(output->extension().string());
    // A name without .exr is a stem; one that is a device or another special file (-o /dev/null
    // to discard the outputs) would have put out.exr and its siblings beside it, in /dev.
    PRISM_RETURN_IF_ERROR(check_not_special_file(*output));
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
    spectral = default_name();
  }
  fs::path stem = spectral.parent_path() / spectral.stem();
  OutputPaths paths;
  paths.spectral_exr = spectral;
  paths.rgb_exr = with_suffix(stem, ".rgb.exr");
  paths.png = with_suffix(stem, ".png");
  paths.primal_exr = with_suffix(stem, ".primal.exr");
  paths.gradient_exr = with_suffix(stem, ".gradient.exr");
  paths.filtered_exr = with_suffix(stem, ".filtered.exr");
  paths.filtered_png = with_suffix(stem, ".filtered.png");
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
  const fs::path* all[] = {&paths.spectral_exr, &paths.rgb_exr,     &paths.png,
                           &paths.json,         &paths.primal_exr,  &paths.gradient_exr,
                           &paths.filtered_exr, &paths.filtered_png};
  constexpr int kOutputs = sizeof(all) / sizeof(all[0]);
  for (int i = 0; i < kOutputs; ++i) {
    for (int j = i + 1; j < kOutputs; ++j) {
      if (fs::absolute(*all[i]).lexically_normal() == fs::absolute(*all[j]).lexically_normal()) {
        return absl::InvalidArgumentError(absl::StrCat("two outputs would both be written to '",
                                                       all[i]->string(),
                                                       "': choose a different --json or -o name"));
      }
    }
  }
  return paths;
}

namespace {
constexpr std::size_t kMaxOutputName = 220;
}  // namespace

absl::Status check_not_special_file(const fs::path& path) {
  std::error_code ec;
  // Followed through links: /dev/stdout is a link to a pipe or terminal.
  const fs::file_status status = fs::status(path, ec);
  if (ec || status.type() == fs::file_type::not_found || status.type() == fs::file_type::regular ||
      status.type() == fs::file_type::directory) {
    return absl::OkStatus();
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "cannot write '", path.string(),
      "': it is a device or other special file (outputs are written to a temporary file and "
      "renamed over the name, which would replace it); give a file name"));
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
    PRISM_RETURN_IF_ERROR(check_not_special_file(*path));
    // Each output is written to a temporary name beside it first (".NAME.tmp.PID.N",
    // base/atomic_file.h), which must fit the file system's 255 bytes too.
    if (const std::size_t length = path->filename().string().size(); length > kMaxOutputName) {
      return absl::InvalidArgumentError(absl::StrCat(
          "cannot write '", path->string(), "': its name is ", length, " bytes, over the ",
          kMaxOutputName, " an output may have (255 with its temporary name)"));
    }
  }
  return absl::OkStatus();
}

absl::Status check_not_a_scene_file(const fs::path& output, const fs::path& root,
                                    const std::vector<std::string>& files) {
  std::error_code ec;
  if (!fs::exists(output, ec)) return absl::OkStatus();  // inputs exist
  for (const std::string& file : files) {
    if (fs::equivalent(output, root / file, ec)) {
      return absl::InvalidArgumentError(absl::StrCat("cannot write '", output.string(),
                                                     "': it is the scene's own file '", file,
                                                     "'; choose another output name"));
    }
  }
  return absl::OkStatus();
}

absl::Status check_outputs_spare_scene(const OutputPaths& paths, const fs::path& root,
                                       const std::vector<std::string>& files) {
  for (const fs::path* path :
       {&paths.spectral_exr, &paths.rgb_exr, &paths.png, &paths.json, &paths.primal_exr,
        &paths.gradient_exr, &paths.filtered_exr, &paths.filtered_png}) {
    PRISM_RETURN_IF_ERROR(check_not_a_scene_file(*path, root, files));
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

absl::StatusOr<image::RgbImage> filtered_tile_rgb(const image::TileResult& merged) {
  if (!merged.has_filtered()) {
    return absl::FailedPreconditionError(absl::StrCat("tile ", image::to_string(merged.rect()),
                                                      " has no filtered sums: no filtered image"));
  }
  const image::TileRect& rect = merged.rect();
  PRISM_ASSIGN_OR_RETURN(image::RgbImage out, image::RgbImage::create(rect.width(), rect.height()));
  const std::span<const double> sums = merged.filtered_rgb_sums();
  const std::span<const std::uint64_t> counts = merged.counts();
  for (int y = 0; y < rect.height(); ++y) {
    for (int x = 0; x < rect.width(); ++x) {
      const std::size_t p = std::size_t(y) * rect.width() + x;
      const double n = double(counts[p]);
      for (int c = 0; c < 3; ++c) out.value(x, y, c) = float(n > 0 ? sums[p * 3 + c] / n : 0.0);
    }
  }
  return out;
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
}  // namespace

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
  if (report.light_caustics) {
    metadata["caustics"] = "light";
    if (report.caustic_paths < 1.0f) {
      metadata["caustic_paths"] = base::shortest_decimal(report.caustic_paths);
    }
  }
  metadata["max_depth"] = absl::StrCat(report.max_depth);
  if (report.gradient.has_value()) {
    metadata[std::string(image::kMetaGradientOffsetBins)] =
        absl::StrCat(report.gradient->offset_bins);
    metadata[std::string(image::kMetaGradientDelta)] =
        base::shortest_decimal(report.gradient->delta);
    metadata["gradient_tau"] = base::shortest_decimal(report.gradient->tau);
    // How the reconstruction was made (exr_spectral.h), on the raw pair too: what `prism
    // reconstruct` of the pair takes to give this image again.
    metadata[std::string(image::kMetaPoissonAlpha)] =
        base::shortest_decimal(report.gradient->alpha);
    metadata[std::string(image::kMetaPoissonNorm)] = report.gradient->norm;
    // The image is the reconstruction (the raw pair overrides this with its own labels), so
    // `prism reconstruct` does not take it for a primal.
    metadata[std::string(image::kMetaContent)] = "reconstruction";
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
  return write_outputs(
      [&](const fs::path& path, const image::ExrMetadata& metadata) {
        return image::write_spectral_exr_rows(path, image::bin_centres_nm(bins), rgb.width(),
                                              rgb.height(), band_rows, rows, rgb, metadata,
                                              options.exr);
      },
      rgb, report, paths, options);
}

absl::Status write_outputs(const std::function<absl::Status(const std::filesystem::path&,
                                                            const image::ExrMetadata&)>& spectral,
                           const image::RgbImage& rgb, const RenderReport& report,
                           const OutputPaths& paths, const OutputOptions& options) {
  image::ExrMetadata metadata = output_metadata(report);

  absl::Status first;
  std::string failures;
  auto record = [&](const fs::path& path, const absl::Status& status) {
    if (status.ok()) return;
    if (first.ok()) first = status;
    absl::StrAppend(&failures, failures.empty() ? "" : "; ", "could not write '", path.string(),
                    "': ", status.message());
  };
  // The RGB EXR and the PNG read only `rgb`: they are written beside the spectral EXR, whose
  // band reads and copies leave the cores idle part of the time.
  absl::Status rgb_written, png_written;
  std::thread beside([&] {
    rgb_written = image::write_rgb_exr(paths.rgb_exr, rgb, image::ExrPixelType::kFloat, metadata,
                                       options.exr);
    png_written = image::write_png_preview(paths.png, rgb, options.exposure_stops);
  });
  const absl::Status spectral_written = spectral(paths.spectral_exr, metadata);
  beside.join();
  record(paths.spectral_exr, spectral_written);
  record(paths.rgb_exr, rgb_written);
  record(paths.png, png_written);
  const std::string json = format_report_json(report, paths);
  record(paths.json, base::write_file_atomic(paths.json, std::span<const char>(json)));
  if (first.ok()) return first;
  return absl::Status(first.code(), failures);
}

absl::Status write_primal_and_gradient(int bins, int band_rows, const image::SpectralRows& primal,
                                       const image::RgbImage& primal_rgb,
                                       const image::SpectralRows& gradient,
                                       const image::RgbImage& gradient_rgb,
                                       const RenderReport& report, const OutputPaths& paths,
                                       const OutputOptions& options) {
  image::ExrMetadata metadata = output_metadata(report);
  const std::vector<double> centres = image::bin_centres_nm(bins);
  metadata[std::string(image::kMetaContent)] = "primal";
  if (report.gradient.has_value()) {
    // Exactly, for `prism reconstruct` of the pair.
    metadata[std::string(image::kMetaPoissonAlpha)] =
        base::shortest_decimal(report.gradient->alpha);
  }
  // The primal's pixels hashed as they are written (bands in order from the top, each once), for
  // the gradient file to name the primal it belongs with (prism reconstruct checks it).
  base::Sha256 primal_hash;
  int next_row = 0;
  const std::size_t row_floats = std::size_t(primal_rgb.width()) * std::size_t(bins);
  const image::SpectralRows hashed = [&](int y0, int rows) -> absl::StatusOr<const float*> {
    PRISM_ASSIGN_OR_RETURN(const float* band, primal(y0, rows));
    if (y0 != next_row) {
      return absl::InternalError(absl::StrCat("the primal's rows came out of order (", y0,
                                              " where ", next_row, " was next)"));
    }
    primal_hash.update(std::string_view(reinterpret_cast<const char*>(band),
                                        row_floats * std::size_t(rows) * sizeof(float)));
    next_row = y0 + rows;
    return band;
  };
  absl::Status status = image::write_spectral_exr_rows(
      paths.primal_exr, centres, primal_rgb.width(), primal_rgb.height(), band_rows, hashed,
      primal_rgb, metadata, options.exr);
  if (!status.ok()) {
    return absl::Status(status.code(), absl::StrCat("could not write '", paths.primal_exr.string(),
                                                    "': ", status.message()));
  }
  metadata[std::string(image::kMetaContent)] = "gradient";
  metadata[std::string(image::kMetaPrimalSha256)] = primal_hash.hex();
  status = image::write_spectral_exr_rows(paths.gradient_exr, centres, gradient_rgb.width(),
                                          gradient_rgb.height(), band_rows, gradient, gradient_rgb,
                                          metadata, options.exr);
  if (!status.ok()) {
    return absl::Status(
        status.code(),
        absl::StrCat("could not write '", paths.gradient_exr.string(), "': ", status.message()));
  }
  return absl::OkStatus();
}

absl::Status write_primal_and_gradient(const image::SpectralImage& primal,
                                       const image::RgbImage& primal_rgb,
                                       const image::SpectralImage& gradient,
                                       const spectral::ColorMatching& cmf,
                                       const RenderReport& report, const OutputPaths& paths,
                                       const OutputOptions& options) {
  PRISM_ASSIGN_OR_RETURN(image::RgbImage gradient_rgb, to_linear_srgb(gradient, cmf));
  return write_primal_and_gradient(primal.bins(), primal.height(), rows_of(primal), primal_rgb,
                                   rows_of(gradient), gradient_rgb, report, paths, options);
}

absl::Status write_filtered(int bins, int band_rows, const image::SpectralRows& filtered,
                            const image::RgbImage& filtered_rgb, const RenderReport& report,
                            const OutputPaths& paths, const OutputOptions& options) {
  image::ExrMetadata metadata = output_metadata(report);
  metadata["filtered"] = "differential splatting (biased; the unbiased image is the main output)";
  if (report.filtered.has_value()) {
    metadata["splat_width_nm"] = absl::StrCat(report.filtered->width_nm);
  }
  absl::Status status = image::write_spectral_exr_rows(
      paths.filtered_exr, image::bin_centres_nm(bins), filtered_rgb.width(), filtered_rgb.height(),
      band_rows, filtered, filtered_rgb, metadata, options.exr);
  if (!status.ok()) {
    return absl::Status(
        status.code(),
        absl::StrCat("could not write '", paths.filtered_exr.string(), "': ", status.message()));
  }
  status = image::write_png_preview(paths.filtered_png, filtered_rgb, options.exposure_stops);
  if (!status.ok()) {
    std::error_code ec;
    fs::remove(paths.filtered_exr, ec);
    return absl::Status(
        status.code(),
        absl::StrCat("could not write '", paths.filtered_png.string(), "': ", status.message()));
  }
  return absl::OkStatus();
}

absl::Status write_filtered(const image::SpectralImage& filtered,
                            const image::RgbImage& filtered_rgb, const RenderReport& report,
                            const OutputPaths& paths, const OutputOptions& options) {
  return write_filtered(filtered.bins(), filtered.height(), rows_of(filtered), filtered_rgb, report,
                        paths, options);
}

std::uint64_t peak_memory_bytes() {
  rusage usage{};
  if (getrusage(RUSAGE_SELF, &usage) != 0) return 0;
  return static_cast<std::uint64_t>(usage.ru_maxrss) * 1024;  // Linux reports kilobytes
}

}  // namespace prism::coordinator
