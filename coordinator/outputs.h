// A finished render's outputs: the spectral EXR (OpenEXR spectral layout plus R, G, B), an RGB
// EXR (float32), an 8-bit PNG preview and a JSON report. Colour follows docs/estimators.md §9:
// CIE 1931 XYZ as pbrt-v4's `cie1931` sensor records it (∫ CMF·L dλ, no division by the CIE Y
// integral), then linear sRGB (D65, no white balance). Renders take it from each sample's exact
// wavelengths (tile_rgb); to_linear_srgb converts bin averages (a reconstructed or loaded image).
//
// Naming: the spectral EXR is PATH (`-o`, else the scene Film's filename stem in the current
// directory, with `.exr`); the others sit beside it as <stem>.rgb.exr, <stem>.png and
// <stem>.json (or the --json path). Every file is written atomically, so an output is complete
// under its name or absent; callers write only after the render has finished, so a failed or
// cancelled render leaves nothing behind.
//
// Error estimates come from the per-pixel sums of squares: for a pixel with n >= 2 samples of
// bin values I, the standard error of its mean is sqrt((Σ I² − n·m²) / ((n − 1)·n)); the report
// averages it (and its square) over the pixels per bin. Statistics are reduced in tile order, so
// the report's numbers are as reproducible as the image.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/prepass_run.h"
#include "coordinator/target_error.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile.h"
#include "services/job/job_parameters.h"
#include "services/spectral/color.h"

namespace prism::coordinator {

// Where a render's outputs go.
struct OutputPaths {
  std::filesystem::path spectral_exr;
  std::filesystem::path rgb_exr;
  std::filesystem::path png;
  std::filesystem::path json;
  // Gradient jobs that ask for them: the raw primal I and gradient G (<stem>.primal.exr and
  // <stem>.gradient.exr), the pair `prism reconstruct` takes.
  std::filesystem::path primal_exr;
  std::filesystem::path gradient_exr;
  // Jobs with differential splatting: the filtered image (<stem>.filtered.exr, spectral with
  // R, G, B, and <stem>.filtered.png).
  std::filesystem::path filtered_exr;
  std::filesystem::path filtered_png;
};

// `output`: the -o path (an extension other than .exr is refused; none gets .exr); an existing
// directory, or a path ending in '/', means the default name inside it. Without it, the stem of
// `film_filename` (the scene Film's "filename", any directories dropped) in the current
// directory. `json`: the --json path, else <stem>.json. INVALID_ARGUMENT with the offending name
// when a path is empty or has no name before its extension (".exr"), or two outputs coincide.
absl::StatusOr<OutputPaths> output_paths(const std::optional<std::filesystem::path>& output,
                                         const std::optional<std::filesystem::path>& json,
                                         const std::string& film_filename);

// INVALID_ARGUMENT when `path` names a device, pipe, socket or a link to one (/dev/null,
// /dev/stdout): an output is renamed over its name, which would replace the device.
absl::Status check_not_special_file(const std::filesystem::path& path);

// Checked before rendering so a long render does not fail at the end: every output's directory
// exists (NOT_FOUND otherwise) and no output names an existing directory (INVALID_ARGUMENT) or a
// special file (check_not_special_file).
absl::Status check_output_locations(const OutputPaths& paths);

// INVALID_ARGUMENT when `output` is one of a scene's own files (`files`, relative to `root`, as
// SceneDescription::files lists them: the scene, its includes, meshes, textures and spectra), by
// fs::equivalent, so another spelling or a link to it is caught too: writing the output would
// destroy an input.
absl::Status check_not_a_scene_file(const std::filesystem::path& output,
                                    const std::filesystem::path& root,
                                    const std::vector<std::string>& files);
// The same for every output of `paths`.
absl::Status check_outputs_spare_scene(const OutputPaths& paths, const std::filesystem::path& root,
                                       const std::vector<std::string>& files);

// Per-bin image statistics for the report.
struct BinStatistics {
  std::vector<double> mean;            // average over all pixels of the pixel means
  std::vector<double> standard_error;  // average over pixels with >= 2 samples
  // Average over the same pixels of the squared standard error s²/n: the expected squared
  // error of a pixel's mean, e.g. the noise floor a reference image adds to an MSE.
  std::vector<double> variance_of_mean;
  std::uint64_t pixels_with_error = 0;
};

// Collects per-tile statistics from merged tile results (any order, any thread: each tile has
// its own slot) and reduces them in tile order.
class BinStatisticsAccumulator {
 public:
  BinStatisticsAccumulator(std::size_t tiles, int bins);
  // Called once per tile (PRISM_CHECK on a repeat or a bin mismatch).
  void add_tile(std::size_t tile_index, const image::TileResult& merged);
  // Requires every tile to have been added (PRISM_CHECK).
  BinStatistics finish() const;

 private:
  struct TileSums {
    bool present = false;
    std::vector<double> mean_sum;
    std::vector<double> error_sum;
    std::vector<double> variance_sum;
    std::uint64_t pixels = 0;
    std::uint64_t pixels_with_error = 0;
  };
  int bins_;
  std::vector<TileSums> tiles_;
};

// Linear sRGB of every pixel as pbrt-v4's default `cie1931` sensor records it: XYZ = ∫ CMF·L dλ
// (no division by the CIE Y integral), so pbrt-v4 scenes keep their brightness. INVALID_ARGUMENT
// when the image's bins are outside the spectral grid's range (4..256).
absl::StatusOr<image::RgbImage> to_linear_srgb(const image::SpectralImage& spectral,
                                               const spectral::ColorMatching& cmf);

// Spectral gradient sampling in the report: the job's settings and the paper's Table 1
// statistics from the workers' counters (worker::TraceCounters).
struct GradientReport {
  int offset_bins = 0;
  float delta = 0;  // float, as the job spec keeps them
  float tau = 0;
  std::optional<job::TauPilotReport> tau_pilot;  // τ was chosen by the pilot
  float alpha = 0;
  std::string norm;
  std::uint64_t base_paths = 0;     // camera samples
  std::uint64_t shifted_paths = 0;  // base paths with at least one shifted event
  std::uint64_t shifts = 0;         // offsets evaluated
  std::uint64_t failed_shifts = 0;  // of those, no valid offset path
  std::uint64_t wasted_shifts = 0;  // of those, the offset's own contribution was <= τ
  int lanes_requested = 0;          // the job's gradient lanes (0: by the scene)
  std::uint64_t samples = 0;        // gradient samples traced, and the sum of their lanes
  std::uint64_t lane_sum = 0;
  bool with_primal_and_gradients = false;
};

// The filtered image in the report. "splat" (worker/differential_splat.h): Δλ at the first and
// the last sample, Δλ_s = width·(s + 1)^(−exponent), and how many light-path splats were drawn
// as lines (from the counters light_splats and splat_lines). "gather" (gather.h): Δλ at the end,
// width·spp^(−exponent), and how many pixels had offsets, were filtered, or were left alone
// because their offsets disagreed.
struct FilteredReport {
  std::string method = "splat";
  float width_nm = 0;  // Δλ at sample 0 (float, as the job spec keeps it)
  double last_width_nm = 0;
  double exponent = 0.2;
  std::uint64_t splats = 0;
  std::uint64_t lines = 0;
  std::uint64_t pixels_with_offsets = 0;
  std::uint64_t pixels_filtered = 0;
  std::uint64_t pixels_incoherent = 0;
};

// The multi-pass prepass in the report.
struct PrepassReport {
  int passes = 0;
  std::vector<std::uint64_t> pass_spp;
  std::vector<std::string> pass_resolution;  // "WxH" per pass
  bool image_scaled = false;
  float epsilon = 0, fallback = 0, sigma_s = 0, sigma_r = 0;  // float, as the job spec keeps them
  double seconds = 0;        // the passes, wall clock, reconstruction included
  double final_seconds = 0;  // the final pass
  PrepassOutcome outcome;    // passes run, early stop, predicted gains, α histogram, fallback
};

// One line for a summary: "1.20 s of prepass (8.1 % of the time; 2 passes, predicted gain
// 31 %, 62 % of pixels learned)" or, after an early stop, "... stopped after pass 1: predicted
// gain 2 % ...".
std::string prepass_summary(const PrepassReport& prepass);

// What the JSON report records besides the image.
struct SceneFeatureNote {
  std::string status;  // "refused" (substituted), "approximated" or "ignored"
  std::string feature;
  std::string where;  // file:line:column of the first use
  int uses = 1;
  std::string note;
  std::string substitution;  // what was rendered instead ("refused" only)
};

struct RenderReport {
  std::string scene;
  // The scene Film's "filename": the outputs' default name (output_paths), also for
  // `prism fetch` of a farm job, which names its files after it.
  std::string film_filename;
  int width = 0;
  int height = 0;
  std::uint64_t spp = 0;
  int bins = 0;
  std::string integrator;
  std::string spectral_pdf;
  std::string emitter_pdf;
  std::string light_selection;
  bool spectral_light_selection = true;
  bool light_caustics = false;  // --caustics light
  float caustic_paths = 1.0f;   // its light paths per pixel and sample
  int max_depth = 0;
  int threads = 0;
  int tile_size = 0;
  std::uint64_t seed = 0;
  double wall_seconds = 0;    // loading the scene to the end of the render
  double render_seconds = 0;  // tracing only (the final pass; on the farm its wall clock)
  // The farm: the final pass's seconds summed over the workers that rendered it (0 locally).
  double worker_seconds = 0;
  // The farm: who rendered the final pass (`threads` is then the sum of theirs).
  struct WorkerShare {
    std::string id, host;
    int threads = 0;
    std::uint64_t tasks = 0, samples = 0;
    double seconds = 0;
  };
  std::vector<WorkerShare> workers;
  // The farm: the coordinator restarted during the job, and the counters, rays and seconds
  // cover the work since it resumed the job (the images are whole either way).
  bool resumed = false;
  bool farm = false;          // a farm job's report (worker_seconds and workers always there)
  std::uint64_t samples = 0;  // pixel samples taken
  // The samples render_seconds timed, which the rates divide: `samples`, or on a resumed farm
  // job those rendered since it resumed.
  std::uint64_t timed_samples = 0;
  std::uint64_t rays = 0;
  std::vector<std::pair<std::string, std::uint64_t>> counters;
  std::uint64_t peak_memory_bytes = 0;
  BinStatistics statistics;
  std::optional<GradientReport> gradient;
  std::optional<PrepassReport> prepass;
  std::optional<FilteredReport> filtered;
  // A job rendered to a target error: what it reached (target_error.h).
  std::optional<TargetErrorOutcome> target_error;
  // A job whose integrator `auto` chose.
  std::optional<job::AutoReport> auto_choice;
  // The scene's features that Prism did not render exactly as pbrt-v4 would
  // (services/scene/scene_features.h): substituted, approximated or ignored, in scene order.
  std::vector<SceneFeatureNote> scene_features;
};

// "to 1 % per pixel: met in 3 of 7 rounds (max 0.98 %, p99 0.71 %, mean 0.32 %), 16..64 spp"
std::string target_error_summary(const TargetErrorOutcome& outcome);

// The splat counts of a filtered report, taken from the named counters.
void fill_filtered_counters(const std::vector<std::pair<std::string, std::uint64_t>>& counters,
                            FilteredReport& report);

// The counters of a gradient job's Table 1, taken from the named counters.
void fill_gradient_counters(const std::vector<std::pair<std::string, std::uint64_t>>& counters,
                            GradientReport& report);

struct OutputOptions {
  float exposure_stops = 0.0f;  // PNG preview only
  // Every EXR: the job's compression and the threads that compress (the bytes do not depend on
  // the thread count).
  image::ExrWriteOptions exr;
};

// The linear sRGB of one finished tile, as the RGB EXR and the PNG show it. With RGB buffers
// (final-pass results) it is the mean of the samples' own R, G, B, taken at their exact
// wavelengths, so it does not depend on the bins (as pbrt-v4's RGB film); for a reconstructed
// tile (`reconstructed`: a gradient job) the reconstruction's change of the bins' RGB is added,
// RGB(finalised) − RGB(the bins' plain means). Without RGB buffers, the bins' RGB
// (to_linear_srgb of `finalised`). `finalised` must be the tile's finished bins (its rect's size).
absl::StatusOr<image::RgbImage> tile_rgb(const image::TileResult& merged,
                                         const image::SpectralImage& finalised, bool reconstructed,
                                         const spectral::ColorMatching& cmf);

// The filtered image's linear sRGB of one finished tile (TileBuffers::filtered): the means of
// its R, G, B sums. FAILED_PRECONDITION without them.
absl::StatusOr<image::RgbImage> filtered_tile_rgb(const image::TileResult& merged);

// The standard error of each pixel's RGB mean over its samples' own R, G, B (tile_rgb without a
// reconstruction's change), from the samples' RGB squares: sqrt((Σc²/n − c̄²)/(n − 1)). NaN for
// a pixel with fewer than 2 samples; FAILED_PRECONDITION without RGB buffers.
absl::StatusOr<image::RgbImage> tile_rgb_standard_error(const image::TileResult& merged);

// The report as a JSON document (non-finite numbers as null).
std::string format_report_json(const RenderReport& report, const OutputPaths& paths);

// Writes the four outputs. Each write is attempted; the error names every file that could not
// be written and why (INTERNAL or the underlying code of the first failure).
absl::Status write_outputs(const image::SpectralImage& spectral, const spectral::ColorMatching& cmf,
                           const RenderReport& report, const OutputPaths& paths,
                           const OutputOptions& options);
// The same with the image's RGB given (tile_rgb, pasted).
absl::Status write_outputs(const image::SpectralImage& spectral, const image::RgbImage& rgb,
                           const RenderReport& report, const OutputPaths& paths,
                           const OutputOptions& options);
// The same from an image that is never whole in memory: its spectral rows come in bands of
// `band_rows` (image::write_spectral_exr_rows) and `rgb` is its linear sRGB (to_linear_srgb).
absl::Status write_outputs(int bins, int band_rows, const image::SpectralRows& rows,
                           const image::RgbImage& rgb, const RenderReport& report,
                           const OutputPaths& paths, const OutputOptions& options);
// The same for a spectral EXR streamed while rendering (LocalRenderResult::stream): `spectral`
// writes it at the path with the metadata, the other outputs are written from `rgb`.
absl::Status write_outputs(const std::function<absl::Status(const std::filesystem::path&,
                                                            const image::ExrMetadata&)>& spectral,
                           const image::RgbImage& rgb, const RenderReport& report,
                           const OutputPaths& paths, const OutputOptions& options);

// The raw primal and gradient spectral EXRs of a gradient job (paths.primal_exr and
// paths.gradient_exr), streamed like the main output: the primal with its samples' exact R, G, B
// (tile_rgb without the reconstruction), so that `prism reconstruct` makes the render's RGB from
// the pair; the gradient with the R, G, B of its bins.
// The gradient file follows exr_spectral.h's convention (gradient_offset_bins, gradient_delta).
absl::Status write_primal_and_gradient(int bins, int band_rows, const image::SpectralRows& primal,
                                       const image::RgbImage& primal_rgb,
                                       const image::SpectralRows& gradient,
                                       const image::RgbImage& gradient_rgb,
                                       const RenderReport& report, const OutputPaths& paths,
                                       const OutputOptions& options);
// The same from whole images.
absl::Status write_primal_and_gradient(const image::SpectralImage& primal,
                                       const image::RgbImage& primal_rgb,
                                       const image::SpectralImage& gradient,
                                       const spectral::ColorMatching& cmf,
                                       const RenderReport& report, const OutputPaths& paths,
                                       const OutputOptions& options);

// The filtered image of a job with differential splatting (paths.filtered_exr, a spectral EXR
// with its R, G, B, and paths.filtered_png), streamed like the main output. Both or neither
// are written: a failed second write removes the first.
absl::Status write_filtered(int bins, int band_rows, const image::SpectralRows& filtered,
                            const image::RgbImage& filtered_rgb, const RenderReport& report,
                            const OutputPaths& paths, const OutputOptions& options);
absl::Status write_filtered(const image::SpectralImage& filtered,
                            const image::RgbImage& filtered_rgb, const RenderReport& report,
                            const OutputPaths& paths, const OutputOptions& options);

// The process's peak resident set size (getrusage ru_maxrss), in bytes.
std::uint64_t peak_memory_bytes();

// Prism's version string, as written into outputs.
const char* prism_version();

}  // namespace prism::coordinator
