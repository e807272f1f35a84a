// The coordinator daemon's domain: jobs, bundles, tasks, results and outputs, with no RPC in it.
// The gRPC adapters (coordinator/rpc/) convert messages, call these methods and map the
// absl::Status they return.
//
// State and persistence (everything under the data directory):
//   jobs.sqlite          the JobStore: jobs, planned tasks, done tasks with their result hash
//   blobs/               task results (the tile codec's bytes), content-addressed
//   bundles/<hash>       packed scene bundles, named by their content hash
//   scenes/<hash>/       the extracted bundle the scene loader checked
//   jobs/<job id>/tiles/ a running job's finished tiles (finished_tiles.h)
//   outputs/<job id>/    the finished job's spectral EXR, RGB EXR, PNG and JSON report
// A task is marked done in the store only after its result blob is on disk, so a restarted
// coordinator resumes every unfinished job from the store alone: it re-plans (plans are pure
// functions of the job), gives the Scheduler the done indices (never leased again) and feeds
// their stored results into a fresh TileAssembler. Outputs are written atomically before the
// job becomes DONE.
//
// Memory is bounded by the tiles in flight: a running job holds the partial results of its
// unfinished tiles (TileAssembler) and its linear sRGB image (3 floats per pixel, for previews
// and the RGB outputs); finished tiles go to disk and the spectral EXR is streamed from them.
// When a job is over (done, failed or cancelled) its tile files and the result blobs no other
// unfinished job shares are deleted, so the data directory keeps only bundles and outputs.
//
// Bundles are checked before anything else uses them: unpack() validates the packed form, then
// the files are extracted to a fresh directory under the data directory and the scene loader
// (whose PathGuard refuses anything that escapes the scene's directory) loads it; only a bundle
// that loads is kept.
//
// Threading: one mutex guards all state; a background thread calls Scheduler::tick(). Long
// polls (acquire) and watches wait on a condition variable signalled on every change.
#pragma once

#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/finished_tiles.h"
#include "coordinator/outputs.h"
#include "coordinator/prepass_run.h"
#include "coordinator/scheduler.h"
#include "coordinator/target_error.h"
#include "coordinator/tile_merge.h"
#include "coordinator/tile_plan.h"
#include "prism/v1/types.pb.h"
#include "services/image/tile.h"
#include "services/job/job_spec.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/color.h"
#include "services/spectral/named_spectra.h"
#include "services/store/blob_store.h"
#include "services/store/job_store.h"

namespace prism::coordinator {

struct FarmOptions {
  std::filesystem::path data_dir;
  std::uint64_t max_bundle_bytes = std::uint64_t{1} << 30;
  std::uint64_t max_result_bytes = std::uint64_t{1} << 32;
  std::size_t max_queued_jobs = 1000;  // jobs not yet in a terminal state
  SchedulerOptions scheduler;
  Millis tick_interval{200};
  // Milliseconds since the Unix epoch; injectable for tests.
  std::function<Millis()> clock;
  // The "coordinator" logger (main creates it); null: a logger that drops everything.
  std::shared_ptr<spdlog::logger> logger;
};

// A job as the clients see it.
struct JobStatus {
  store::JobRecord record;
  int tiles_finalised = 0;
  int tiles_total = 0;
  double samples_per_second = 0;
  double eta_seconds = -1;
};

struct WorkerStatus {
  store::WorkerRecord record;
  std::string state;  // idle, busy, lost
  int leases = 0;
  std::vector<Lease> current;  // the leases it holds now, oldest first
  std::uint64_t tasks_completed = 0;
  std::int64_t last_seen_ms = 0;
};

// A lease as handed to a worker, with what it needs to render the task.
struct LeaseGrant {
  Lease lease;
  prism::v1::JobSpec spec;  // explicit (to_proto of the job's parameters)
  std::string bundle_hash;
  // The tile's per-pixel wavelength tables (pixel_tables.h wire layout, `table_cells` cells per
  // pixel), for prepasses after the first and for the final pass of a job with a prepass.
  std::optional<std::string> pdf_table;
  int table_cells = 0;
  bool want_guides = false;  // prepass tasks
  bool early_stop = false;   // prepass tasks
  int film_width = 0;        // the task's film when its pass renders another than the job's
  int film_height = 0;
};

enum class CompleteResult { kAccepted, kDuplicate };

enum class OutputKind {
  kSpectralExr = 1,
  kRgbExr = 2,
  kPng = 3,
  kReportJson = 4,
  kPrimalExr = 5,    // gradient jobs with primal_and_gradients
  kGradientExr = 6,  // likewise
};

struct OutputFile {
  OutputKind kind;
  std::filesystem::path path;
  std::string file_name;
};

class FarmCoordinator {
 public:
  // Opens (or creates) the data directory, resumes unfinished jobs and starts the tick thread.
  static absl::StatusOr<std::unique_ptr<FarmCoordinator>> open(FarmOptions options);
  ~FarmCoordinator();
  FarmCoordinator(const FarmCoordinator&) = delete;
  FarmCoordinator& operator=(const FarmCoordinator&) = delete;

  const FarmOptions& options() const { return options_; }

  // Bundles. `bytes` is a packed bundle whose content hash must equal `claimed_hash` (when not
  // empty). RESOURCE_EXHAUSTED over max_bundle_bytes; INVALID_ARGUMENT for a malformed bundle or
  // a scene that does not load (the loader's message). Returns the content hash.
  absl::StatusOr<std::string> upload_bundle(const std::string& claimed_hash,
                                            std::string_view bytes);
  bool has_bundle(const std::string& hash) const;
  // The packed bundle; NOT_FOUND for an unknown hash.
  absl::StatusOr<std::string> bundle_bytes(const std::string& hash) const;

  // Jobs. Submitting again with a known client token returns the first job unchanged.
  absl::StatusOr<JobStatus> submit(const prism::v1::JobSpec& spec, const std::string& client_token);
  absl::StatusOr<JobStatus> job(const std::string& job_id);
  absl::StatusOr<std::vector<JobStatus>> jobs(std::size_t limit,
                                              const std::vector<store::JobState>& states);
  absl::StatusOr<JobStatus> cancel(const std::string& job_id);
  // The job's explicit spec (as stored).
  absl::StatusOr<prism::v1::JobSpec> job_spec(const std::string& job_id);
  // The output files of a DONE job (all kinds when `kinds` is empty). FAILED_PRECONDITION
  // naming the state otherwise.
  absl::StatusOr<std::vector<OutputFile>> result_files(const std::string& job_id,
                                                       const std::vector<OutputKind>& kinds);
  // An 8-bit PNG of the image as far as it is finalised. FAILED_PRECONDITION before any tile.
  absl::StatusOr<std::string> preview_png(const std::string& job_id, float exposure_stops);

  // A counter that moves on every change of any job's state or progress, and a wait for it to
  // move past `seen` (returns the new value; `seen` on timeout).
  std::uint64_t change_counter() const;
  std::uint64_t wait_for_change(std::uint64_t seen, Millis timeout);

  // Workers.
  absl::StatusOr<store::WorkerRecord> register_worker(store::WorkerRecord record,
                                                      const std::string& previous_id);
  // A lease for the worker, waiting up to `wait` for one. Nothing for an unknown worker.
  absl::StatusOr<std::optional<LeaseGrant>> acquire(const std::string& worker_id, Millis wait);
  HeartbeatReply heartbeat(const std::string& worker_id, const std::vector<std::string>& lease_ids);
  // A task result (the tile codec's bytes, already checked against `sha256`). FAILED_PRECONDITION
  // with the Scheduler's reason for a stale lease; INVALID_ARGUMENT (and the lease fails as a
  // worker fault) for bytes that do not parse or do not match the task.
  // `counters`: the task's named event counters (worker::counter_list), summed for the report.
  absl::StatusOr<CompleteResult> complete(
      const std::string& worker_id, const std::string& lease_id, std::string bytes,
      const std::string& sha256, double render_seconds, std::uint64_t rays,
      const std::vector<std::pair<std::string, std::uint64_t>>& counters = {});
  absl::Status fail(const std::string& worker_id, const std::string& lease_id,
                    FailureClass failure_class, const std::string& message);
  absl::StatusOr<std::vector<WorkerStatus>> workers();

  // Stops the tick thread and wakes every waiter (the server is shutting down).
  void shutdown();

 private:
  // A job's stages in task order: prepass 1..K (when it has a prepass), then the final pass.
  // Task indices are global over the stages; the Scheduler is given a stage's tasks once the
  // stage before it is merged and reconstructed (Scheduler::add_tasks), the store has them all.
  struct ActiveJob {
    job::JobParameters params;
    prism::v1::JobSpec spec;
    TilePlan plan;                             // the final pass
    std::unique_ptr<TileAssembler> assembler;  // the final pass
    TileFinaliser finalise;
    std::optional<PrepassRun> prepass;
    std::vector<std::unique_ptr<TileAssembler>> prepass_assemblers;  // per prepass
    std::vector<int> stage_first;  // first task index of each stage, then the task count
    int stage = 0;                 // the last stage handed to the Scheduler
    std::map<std::string, std::uint64_t> counters;  // the final pass's, summed
    double prepass_seconds = 0;  // submit (or resume) to the final pass's start, wall clock
    std::unique_ptr<FinishedTiles> tiles;  // set by attach_tiles before any result is added
    std::unique_ptr<image::RgbImage> rgb;  // finished tiles' linear sRGB
    std::unique_ptr<BinStatisticsAccumulator> statistics;
    int tiles_finalised = 0;
    double render_seconds = 0;  // summed over workers
    std::uint64_t rays = 0;
    std::chrono::steady_clock::time_point started;
    std::uint64_t samples_at_start = 0;            // done before this incarnation (resumed)
    std::vector<SceneFeatureNote> scene_features;  // for the report
    // Rendering to a target error: the final pass runs as rounds, the stages after the
    // prepasses, each with its own plan (every tile, the round's samples) and assembler; the
    // tracker sums each tile's rounds and decides which tiles go on (target_error.h). A tile
    // that is done has its later rounds' tasks skipped.
    std::optional<TargetErrorTracker> target;
    std::vector<TilePlan> round_plans;
    std::vector<std::unique_ptr<TileAssembler>> round_assemblers;
  };

  explicit FarmCoordinator(FarmOptions options);
  Millis now() const { return options_.clock(); }
  absl::Status start();
  absl::Status resume_locked(const store::JobRecord& record);
  // Builds the in-memory job (plans, assemblers, image) from explicit parameters; `scene` gives
  // a prepass its emitter spectra.
  absl::StatusOr<std::unique_ptr<ActiveJob>> make_active(const job::JobParameters& params,
                                                         const prism::v1::JobSpec& spec,
                                                         const scene::SceneDescription& scene);
  // Loads the checked scene of a stored bundle.
  absl::StatusOr<scene::LoadedScene> load_bundle_scene(bool allow_unsupported,
                                                       const std::string& hash,
                                                       const std::string& scene_path) const;
  // The last stage's index: the final pass's, or with a target error its last round's.
  static int final_stage_of(const ActiveJob& job) {
    return static_cast<int>(job.stage_first.size()) - 2;
  }
  // The first stage of the final pass (the number of prepasses).
  static int first_final_stage(const ActiveJob& job) {
    return static_cast<int>(job.prepass_assemblers.size());
  }
  // Target-error jobs: ends the round that stage job.stage ran (its tiles that are done are
  // stored and absorbed), and hands the next round's tasks to the Scheduler, skipping the tiles
  // that are done.
  absl::Status finish_round_locked(ActiveJob& job);
  absl::Status hand_round_locked(ActiveJob& job, const std::string& job_id);
  // The task indices [first, last) of tile `tile` in stage `stage`.
  static std::pair<int, int> tile_tasks(const ActiveJob& job, int stage, int tile);
  // The stage of a task index, and its tile index within the stage's plan.
  static int stage_of(const ActiveJob& job, int task_index);
  static int tile_of(const ActiveJob& job, int task_index);
  // The tasks of one stage (0-based: prepass k is stage k − 1, the final pass is the last).
  std::vector<TaskSpec> stage_specs(const ActiveJob& job, int stage) const;
  // A stage's tasks are all done: a prepass is reconstructed and the next stage's tasks go to
  // the Scheduler; after the final pass the job is finalised.
  absl::Status advance_locked(const std::string& job_id);
  // Opens the job's finished-tile directory.
  absl::Status attach_tiles(ActiveJob& job, const std::string& job_id) const;
  // A finished tile's contribution to the job's statistics, RGB image and progress.
  absl::Status absorb_tile(ActiveJob& job, int tile, const image::TileResult& merged,
                           const image::SpectralImage& finalised) const;
  // Deletes what a job that is over no longer needs: its tile files and unshared result blobs.
  void clean_up_locked(const std::string& job_id);
  std::filesystem::path tiles_dir(const std::string& job_id) const;
  std::vector<TaskSpec> task_specs(const ActiveJob& job) const;
  void process_events_locked();
  absl::Status finalise_locked(const std::string& job_id);
  void fail_job_locked(const std::string& job_id, const std::string& message);
  JobStatus status_locked(const store::JobRecord& record) const;
  std::filesystem::path output_dir(const std::string& job_id) const;
  OutputPaths output_paths_of(const std::string& job_id) const;
  std::filesystem::path bundle_path(const std::string& hash) const;
  std::filesystem::path scene_dir(const std::string& hash) const;
  void changed_locked();
  void tick_loop();

  FarmOptions options_;
  spectral::SpectrumLibrary library_;
  spectral::ColorMatching cmf_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::uint64_t change_counter_ = 0;
  std::optional<store::JobStore> store_;
  std::optional<store::BlobStore> blobs_;
  Scheduler scheduler_;
  std::map<std::string, std::unique_ptr<ActiveJob>> active_;
  std::map<std::string, std::uint64_t> tasks_completed_;  // by worker
  std::uint64_t temp_counter_ = 0;
  bool stopping_ = false;
  std::thread ticker_;
};

}  // namespace prism::coordinator
