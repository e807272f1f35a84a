// A job the farm is running, in memory: its stages in task order (prepass 1..K when it has a
// prepass, then the final pass, or with a target error the final pass's rounds), the assemblers
// that merge each stage's task results, and what the finished tiles have added up to (the RGB
// image, the per-bin statistics, progress). Task indices are global over the stages; the
// Scheduler is given a stage's tasks once the stage before it is merged and reconstructed
// (Scheduler::add_tasks), the store has them all from the start.
//
// Everything here is a pure function of the job's explicit parameters and the results added,
// so a coordinator that restarts rebuilds the same stages and task numbers (FarmCoordinator
// feeds the stored results back in). Not thread-safe: FarmCoordinator holds its mutex around
// every use, the assemblers' callbacks included.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "coordinator/convergence.h"
#include "coordinator/finished_tiles.h"
#include "coordinator/outputs.h"
#include "coordinator/prepass_run.h"
#include "coordinator/result_pack.h"
#include "coordinator/scheduler.h"
#include "coordinator/target_error.h"
#include "coordinator/tile_merge.h"
#include "coordinator/tile_plan.h"
#include "prism/v1/types.pb.h"
#include "services/image/tile.h"
#include "services/job/job_parameters.h"
#include "services/scene/scene_description.h"
#include "services/spectral/color.h"
#include "services/spectral/named_spectra.h"
#include "services/store/job_store.h"

namespace prism::coordinator {

struct ActiveJob {
  // A final-pass result in the result pack (final_results below).
  struct FinalResult {
    store::ResultLocation location;
    std::optional<std::array<std::uint8_t, 32>> sha256;  // of its bytes
    bool exact = false;  // its sums were float32 already: merged, it is its own bytes
  };

  // Builds the stages, plans, assemblers and image from explicit parameters; `scene` gives a
  // prepass its emitter spectra and the report its features. `library` and `cmf` must outlive
  // the job.
  static absl::StatusOr<std::unique_ptr<ActiveJob>> create(const job::JobParameters& params,
                                                           const prism::v1::JobSpec& spec,
                                                           const scene::SceneDescription& scene,
                                                           const spectral::SpectrumLibrary& library,
                                                           const spectral::ColorMatching& cmf);

  // The last stage's index: the final pass's, or with a target error its last round's.
  int final_stage() const { return static_cast<int>(stage_first.size()) - 2; }
  // The first stage of the final pass (the number of prepasses).
  int first_final_stage() const { return static_cast<int>(prepass_assemblers.size()); }
  // The stage of a task index, and its tile index within the stage's plan.
  int stage_of(int task_index) const;
  int tile_of(int task_index) const;
  // The task indices [first, last) of tile `tile` in stage `stage`.
  std::pair<int, int> tile_tasks(int stage, int tile) const;
  // The tasks of one stage (0-based: prepass k is stage k − 1), and of every stage in order.
  std::vector<TaskSpec> stage_specs(int stage) const;
  std::vector<TaskSpec> task_specs() const;
  // A final-pass result into the convergence tracker (created on first use); the estimate after
  // it, `seconds` into the job's rendering.
  ConvergencePoint track_convergence(const image::TileResult& result, double seconds);
  // Task `index` of task_specs() (`specs`) as the store records it.
  store::TaskRecord task_record(const std::vector<TaskSpec>& specs, int index) const;

  // Opens the job's finished-tile directory and, beside it, its result pack; before any
  // result is added.
  absl::Status attach_tiles(const std::filesystem::path& dir);
  // Records where a final-pass result of tile `tile` is stored (a pack range; blob-store results
  // are not recorded), so the tile can link to it or release it once the tile is stored.
  void note_final_result(int tile, const FinalResult& result);
  // A finished tile's contribution to the statistics, the RGB image and progress.
  absl::Status absorb_tile(int tile, const image::TileResult& merged,
                           const image::SpectralImage& finalised);
  // Target-error jobs: ends the round that stage `stage` ran; its tiles that are done are
  // stored and absorbed.
  absl::Status finish_round();

  job::JobParameters params;
  prism::v1::JobSpec spec;
  // What admission control planned for it (resource_plan.h): counted against the coordinator's
  // memory and disk budgets while the job is unfinished.
  std::uint64_t planned_memory = 0;
  std::uint64_t planned_disk = 0;
  TilePlan plan;                             // the final pass
  std::unique_ptr<TileAssembler> assembler;  // the final pass
  TileFinaliser finalise;
  std::optional<PrepassRun> prepass;
  std::vector<std::unique_ptr<TileAssembler>> prepass_assemblers;  // per prepass
  std::vector<int> stage_first;  // first task index of each stage, then the task count
  int stage = 0;                 // the last stage handed to the Scheduler
  std::map<std::string, std::uint64_t> counters;  // the final pass's, summed
  double prepass_seconds = 0;  // submit (or resume) to the final pass's start, wall clock
  // Set by attach_tiles before any result is added; shared with the janitor, which syncs it
  // before it releases range results (FarmCoordinator::reclaim_locked).
  std::shared_ptr<FinishedTiles> tiles;
  // The task results, in <dir>/../results.pack (set by attach_tiles too).
  std::shared_ptr<ResultPack> results;
  // Final-pass results in the pack, by tile, until the tile is stored (note_final_result). A
  // tile of one range whose result needed no rounding is stored as a link to it
  // (FinishedTiles::put_link); otherwise its ranges move to `reclaimable`, which the farm hands
  // to its janitor. Not for target-error jobs, whose restart replays every round from the
  // range results.
  std::vector<std::vector<FinalResult>> final_results;
  std::vector<store::ResultLocation> reclaimable;
  std::unique_ptr<image::RgbImage> rgb;  // finished tiles' linear sRGB
  std::unique_ptr<BinStatisticsAccumulator> statistics;
  int tiles_finalised = 0;
  std::vector<std::uint8_t> tile_done;              // by final-pass tile: finalised (absorb_tile)
  std::unique_ptr<ConvergenceTracker> convergence;  // from the first final-pass result
  std::optional<ConvergenceLog> convergence_log;    // its series on disk (convergence.h)
  double convergence_seconds_at_start = 0;          // the series' last time when resumed
  double render_seconds = 0;                        // summed over workers
  // The final pass's results by worker id (since the job started or was resumed).
  struct WorkerShare {
    std::uint64_t tasks = 0;
    std::uint64_t samples = 0;  // pixel samples
    double seconds = 0;         // its render seconds, summed
  };
  std::map<std::string, WorkerShare> worker_shares;
  // The final pass's span: the first of its results' render starts (completion less render
  // seconds) to the last completion, as `prism render` times its final pass.
  std::optional<std::chrono::steady_clock::time_point> final_begin, final_end;
  std::uint64_t rays = 0;
  std::chrono::steady_clock::time_point started;
  std::uint64_t samples_at_start = 0;            // done before this incarnation (resumed)
  bool resumed = false;                          // by a restarted coordinator (farm_resume.cpp)
  std::vector<SceneFeatureNote> scene_features;  // for the report
  std::string film_filename;                     // the scene Film's "filename", for the report
  // Rendering to a target error: the final pass runs as rounds, the stages after the
  // prepasses, each with its own plan (every tile, the round's samples) and assembler; the
  // tracker sums each tile's rounds and decides which tiles go on (target_error.h). A tile
  // that is done has its later rounds' tasks skipped.
  std::optional<TargetErrorTracker> target;
  std::vector<TilePlan> round_plans;
  std::vector<std::unique_ptr<TileAssembler>> round_assemblers;

 private:
  ActiveJob() = default;
  // The plan of a final-pass stage: the final pass's, or its round's.
  const TilePlan& stage_plan(int stage) const;

  const spectral::ColorMatching* cmf_ = nullptr;
};

}  // namespace prism::coordinator
