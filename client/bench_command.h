// `prism bench SCENE...`: error against time for the rendering methods on the user's own scenes.
// Each scene is rendered by each method at each budget (seconds, or samples per pixel) with
// several seeds and compared with a reference over the whole image and any insets. It writes
//   DIR/results.csv   one row per scene, method, budget, seed and region;
//   DIR/report.md     mean errors and the equal-time ratio of each method to a baseline;
//   DIR/<scene>.svg, DIR/<scene>.png   log–log relMSE against seconds, a curve per method, the
//                     insets dashed, drawn by gnuplot (its script and data beside them).
//
// Timing: a method's seconds are its τ pilot, its prepass, its final pass and its
// reconstruction, on the chosen clock (wall, or process CPU); building the scene (the BVH,
// lights) is the same for every method and is left out. A budget in seconds is met by choosing
// the spp: from a short calibration render, corrected once from the first seed's run; the rows
// record the seconds actually spent, and the equal-time ratios interpolate the baseline's curve
// at them (client/evaluation.h).
//
// On the farm (`--coordinator`): every render, the reference's halves included, is a farm job
// submitted as `prism submit --wait` submits it (auto and the τ pilot run in this process first,
// as there), with a client token of its own so that no earlier job is reused, and timed on the
// wall clock from the submission to the fetched outputs: what the farm costs a user, scheduling
// and transfers included. The farm's outputs are byte for byte the local ones, so the errors
// are those a local bench measures and the reference cache is shared.
//
// Reference: `--reference REF.exr` (its noise is known when a REF.half.exr from an independent
// half of its samples lies beside it, as the ones prism bench renders have), or one rendered by
// hero without a prepass, in two independent halves, at `--reference-spp` or at about four times
// the largest budget (the power of two nearest to it, so reruns share it), or to
// `--reference-error` (each half to √2 times it, by the target-error rounds), and cached by the
// scene bundle's hash and the render options. MSE and relMSE are reported minus the reference's
// noise floor where it is known (the floor columns say how much), SSIM as measured.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "client/farm_commands.h"
#include "services/image/metrics.h"
#include "worker/embree_device.h"

namespace prism::client {

struct BenchOptions {
  std::vector<std::filesystem::path> scenes;
  // Instead of rendering: the rows of earlier runs' results.csv (all from one reference cache),
  // those of --methods only, into one report.md (with auto against the best of the others).
  std::vector<std::filesystem::path> results;
  std::string methods = "uniform,hero,hero+prepass,gradient,auto";
  std::string budgets;  // "10s,30s,90s" (s or m suffix; plain numbers are seconds)
  std::string spp;      // "64,256,1024"; exclusive with budgets; neither: budgets 10s,30s
  std::int64_t seeds = 2;
  std::vector<std::filesystem::path> references;  // one per scene, or none
  std::optional<std::int64_t> reference_spp;
  // Render the reference to this relative standard error per pixel (--target-error) instead of
  // to a fixed spp; --reference-spp is then its max spp (default 65536).
  std::optional<double> reference_error;
  std::optional<std::filesystem::path> reference_cache;  // unset: ~/.cache/prism/references
  std::vector<std::string> insets;                       // "x,y,w,h" each
  std::optional<std::string> resolution;
  std::optional<std::int64_t> bins;
  std::optional<std::int64_t> threads;
  std::string clock = "wall";  // or "cpu"
  std::string baseline = "hero";
  std::filesystem::path output = "bench";
  bool allow_unsupported = false;
  // Render on the farm instead of in this process (wall clock only; the workers' threads).
  std::optional<FarmConnection> farm;
  std::ostream* log = nullptr;  // one line per render; null: quiet
};

// "10s,30s,1.5m,90" -> seconds, strictly increasing and positive; INVALID_ARGUMENT otherwise.
absl::StatusOr<std::vector<double>> parse_budgets(const std::string& text);

// One measurement: a render of a scene by a method at a budget and seed, compared over a region.
struct BenchRow {
  std::string scene;  // its file stem
  std::string method;
  std::string budget;  // "10s" or "64spp"
  int seed = 0;
  std::string region;  // "image" or "x,y,w,h"
  std::string ran;     // the method that ran: auto's choice, else the method
  std::uint64_t spp = 0;
  double seconds = 0;  // on the bench's clock
  double wall_seconds = 0;
  double cpu_seconds = 0;
  image::ErrorMetrics metrics;  // mse and rel_mse minus the floors below
  double mse_floor = 0;         // the reference's noise in mse (0 when unknown)
  double rel_mse_floor = 0;
  bool floor_known = false;
};

// The CSV text: a header and one line per row, numbers in full precision.
std::string bench_csv(const std::vector<BenchRow>& rows);
// The rows of such a text (`name` for errors); INVALID_ARGUMENT naming name:line and the column
// when a line is not one of bench_csv's.
absl::StatusOr<std::vector<BenchRow>> parse_bench_csv(const std::string& text,
                                                      const std::string& name);

// Lines (markdown list items) for the scenes and regions where the reference's own noise is
// more than half the error some row measured (its floor subtracted; a negative relMSE is named):
// its figures say more about the reference than the method. Empty when there are none.
std::string reference_warnings(const std::vector<BenchRow>& rows);

// The markdown report: for each scene and region, each method's mean relMSE and seconds per
// budget, and its equal-time ratio to `baseline` (relMSE ÷ the baseline's relMSE interpolated at
// the same seconds; < 1 is better); with `auto` among the methods, also auto's ratio to the best
// of the others at its own seconds. `header` is prepended.
std::string bench_report(const std::vector<BenchRow>& rows, const std::string& baseline,
                         const std::string& header);

// The gnuplot script that draws `scene`'s rows (mean over seeds) from `data_file` (written by
// bench_plot_data) to `svg` and `png`.
struct BenchPlot {
  std::string data;    // the data file's text
  std::string script;  // the gnuplot script's text
};
BenchPlot bench_plot(const std::vector<BenchRow>& rows, const std::string& scene,
                     const std::string& clock, const std::filesystem::path& data_file,
                     const std::filesystem::path& svg, const std::filesystem::path& png);

// Runs the benchmark and writes DIR; returns the summary (one line per scene and the files).
// Errors: the flags' (naming the flag), a scene's (file:line:column), a reference that does
// not match the render, FAILED_PRECONDITION when gnuplot is missing (the CSV and the report are
// written first).
absl::StatusOr<std::string> run_bench(const BenchOptions& options, worker::EmbreeDevice& device);

}  // namespace prism::client
