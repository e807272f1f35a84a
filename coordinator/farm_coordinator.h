// The coordinator daemon's domain: jobs, bundles, tasks, results and outputs, with no RPC in it.
// The gRPC adapters (coordinator/rpc/) convert messages, call these methods and map the
// absl::Status they return.
//
// State and persistence (everything under the data directory):
//   jobs.sqlite          the JobStore: jobs, planned tasks, done tasks with their result's hash
//                        and place in the job's result pack
//   jobs/<job id>/results.pack  a running job's task results end to end (result_pack.h)
//   jobs/<job id>/tiles/ a running job's finished tiles (finished_tiles.h)
//   blobs/               task results of jobs from before result packs, content-addressed
//   convergence/<job id> a job's error-against-time series for the dashboard (convergence.h)
//   bundles/<hash>       packed scene bundles, named by their content hash
//   scenes/<hash>/       the extracted bundle the scene loader checked
//   outputs/<job id>/    the finished job's spectral EXR, RGB EXR, PNG and JSON report
// A task is marked done in the store only with its result's bytes written, and CompleteTask
// answers only once both are synced (group commit: one flush serves every result that arrived
// during the previous one), so a restarted coordinator resumes every unfinished job from the
// store alone: it re-plans (plans are pure functions of the job), gives the Scheduler the done
// indices (never leased again) and feeds their stored results into a fresh TileAssembler.
// Outputs are written atomically before the job becomes DONE.
//
// Memory is bounded by the tiles in flight: a running job holds the partial results of its
// unfinished tiles (TileAssembler) and its linear sRGB image (3 floats per pixel, for previews
// and the RGB outputs); finished tiles go to disk and the spectral EXR is streamed from them.
// When a job is over (done, failed or cancelled) its tile files, result pack and the blobs no
// other unfinished job shares are deleted, so the data directory keeps only bundles and outputs.
//
// Bundles are checked before anything else uses them (bundle_store.h).
//
// Composition: FarmCoordinator holds the parts and the one locking story. BundleStore
// (bundle_store.h) keeps the bundles; an ActiveJob (active_job.h) per running job its stages,
// assemblers and image; the Scheduler (scheduler.h) the leases; JobStore and BlobStore what
// survives a restart. Its definitions are split by concern: farm_coordinator.cpp (lifecycle,
// submit, job queries), farm_resume.cpp (restart), farm_housekeeping.cpp (clean-up, janitor),
// farm_stages.cpp (stages handed on, events), farm_outputs.cpp (outputs, previews) and
// farm_workers.cpp (registration, leases, results).
// What monitoring reads is the read-only FarmView (farm_view.h) it implements.
//
// Threading: one mutex guards all state; a background thread calls Scheduler::tick(). Long
// polls (acquire) and watches wait on a condition variable signalled on every change. The
// bundle store needs no lock (its state is files, published atomically).
#pragma once

#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
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
#include "coordinator/active_job.h"
#include "coordinator/bundle_store.h"
#include "coordinator/farm_metrics.h"
#include "coordinator/farm_view.h"
#include "coordinator/finished_tiles.h"
#include "coordinator/outputs.h"
#include "coordinator/prepass_run.h"
#include "coordinator/resource_plan.h"
#include "coordinator/result_pack.h"
#include "coordinator/scheduler.h"
#include "coordinator/target_error.h"
#include "coordinator/tile_merge.h"
#include "coordinator/tile_plan.h"
#include "prism/v1/types.pb.h"
#include "services/base/file_lock.h"
#include "services/image/tile.h"
#include "services/job/job_spec.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/color.h"
#include "services/spectral/named_spectra.h"
#include "services/store/blob_store.h"
#include "services/store/group_commit.h"
#include "services/store/job_store.h"

namespace prism::coordinator {

struct FarmOptions {
  std::filesystem::path data_dir;
  std::uint64_t max_bundle_bytes = std::uint64_t{1} << 30;
  std::uint64_t max_result_bytes = std::uint64_t{1} << 32;
  std::size_t max_queued_jobs = 1000;  // jobs not yet in a terminal state
  // Admission control (resource_plan.h): the memory the unfinished jobs' plans may add up to,
  // besides what the coordinator held when it started (0: the machine's budget, the smallest
  // of its memory and the process's limits), and the disk they may add up to (0: no sum is
  // kept). A job is also refused when its own disk plan exceeds the data dir's free space.
  std::uint64_t max_memory_bytes = 0;
  std::uint64_t max_disk_bytes = 0;
  // Threads compressing a finished job's EXR outputs (OpenEXR's pool); the bytes do not
  // depend on it.
  int output_threads = 1;
  SchedulerOptions scheduler;
  Millis tick_interval{200};
  // Milliseconds since the Unix epoch; injectable for tests.
  std::function<Millis()> clock;
  // Fault injection for tests: called under the lock just before a submitted job's tasks are
  // stored (a slow store or a huge plan stalls the coordinator there).
  std::function<void()> before_store_job;
  // A job's tasks are stored this many at a time, the lock released between parts.
  std::size_t tasks_per_store_part = 4096;
  // Fault injection for tests: called without the lock between the parts of a large job's
  // tasks being stored (after the job's first part); an error makes submit return it at once,
  // leaving the store as a crash there would.
  std::function<absl::Status(const std::string& job_id)> between_task_parts;
  // Fault injection for tests: called by the finaliser thread, without the lock, before a
  // finished job's outputs are written.
  std::function<void()> before_write_outputs;
  // A job whose outputs could not be written for want of disk space stays FINALISING and is
  // written again after this delay, doubled at each failure up to 5 minutes.
  Millis finalise_retry_delay{10'000};
  // Fault injection for tests: a write to the data directory that fails (a full disk). Asked
  // before each such write named by `what`: "result" (a completed task's bytes, without the
  // lock), "cancel" (the job store's record of a cancel; asked again after the disk reserve is
  // released), "outputs" (a finished job's outputs, after before_write_outputs); an error
  // stands for that write's outcome.
  std::function<absl::Status(std::string_view what)> disk_fault;
  // The data directory's free bytes (tests pretend a small disk); null: the file system's.
  std::function<absl::StatusOr<std::uint64_t>(const std::filesystem::path&)> free_disk;
  // The "coordinator" logger (main creates it); null: a logger that drops everything.
  std::shared_ptr<spdlog::logger> logger;
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

class FarmCoordinator : public FarmView {
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
  bool has_bundle(const std::string& hash) const override;
  // The packed bundle; NOT_FOUND for an unknown hash.
  absl::StatusOr<std::string> bundle_bytes(const std::string& hash) const;

  // Jobs. Submitting again with a known client token returns the first job unchanged.
  absl::StatusOr<JobStatus> submit(const prism::v1::JobSpec& spec, const std::string& client_token);
  absl::StatusOr<JobStatus> job(const std::string& job_id) override;
  absl::StatusOr<std::vector<JobStatus>> jobs(std::size_t limit,
                                              const std::vector<store::JobState>& states) override;
  absl::StatusOr<JobStatus> cancel(const std::string& job_id);
  // The job's explicit spec (as stored).
  absl::StatusOr<prism::v1::JobSpec> job_spec(const std::string& job_id);
  // The monitoring reads (farm_view.h).
  absl::StatusOr<std::vector<OutputFile>> result_files(
      const std::string& job_id, const std::vector<OutputKind>& kinds) override;
  absl::StatusOr<TileMapStatus> tile_map(const std::string& job_id) override;
  absl::StatusOr<std::vector<ConvergencePoint>> convergence(const std::string& job_id) override;
  absl::StatusOr<std::string> preview_png(const std::string& job_id, float exposure_stops) override;
  std::uint64_t change_counter() const override;
  std::uint64_t wait_for_change(std::uint64_t seen, Millis timeout) override;

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
  absl::StatusOr<std::vector<WorkerStatus>> workers() override;
  // A drained worker leaves: leases it still holds go back unpenalised, and it is listed as
  // `left` (not `lost`) until it registers again. NOT_FOUND for a worker never registered.
  absl::Status leave(const std::string& worker_id);

  absl::StatusOr<FarmSnapshot> snapshot() override;
  absl::StatusOr<std::string> metrics_text() override;

  // Stops the tick thread and wakes every waiter (the server is shutting down).
  void shutdown();

 private:
  explicit FarmCoordinator(FarmOptions options);
  Millis now() const { return options_.clock(); }
  absl::Status start();
  // Restart (farm_resume.cpp): rebuilds a stored job and replays its stored results.
  struct Replay;
  absl::Status resume_locked(const store::JobRecord& record);
  // The job's stored tasks, checked against its plan; the tasks a submission had not stored
  // when the coordinator stopped are stored now.
  absl::StatusOr<std::vector<store::TaskRecord>> stored_tasks_locked(
      const store::JobRecord& record, const ActiveJob& job, const std::vector<TaskSpec>& specs);
  // Task `index`'s stored result; nothing when it is not done or its bytes were lost (then it
  // is reopened, to render again).
  absl::StatusOr<std::optional<image::TileResult>> stored_result_locked(Replay& replay, int index);
  // Stages first..last are skipped: their tasks count as done.
  absl::Status skip_stages_locked(Replay& replay, int first, int last);
  // Each returns the stage the job goes on at.
  absl::StatusOr<int> replay_prepasses_locked(Replay& replay);
  absl::StatusOr<int> replay_rounds_locked(Replay& replay);
  // The final pass's finished tiles (from their records) and done tasks (merged again).
  absl::Status restore_final_pass_locked(Replay& replay);
  // Target-error jobs: hands the round of stage job.stage to the Scheduler, skipping the tiles
  // that are done (ActiveJob::finish_round ended the round before).
  absl::Status hand_round_locked(ActiveJob& job, const std::string& job_id);
  // A stage's tasks are all done: a prepass is reconstructed and the next stage's tasks go to
  // the Scheduler; after the final pass the job is finalised.
  absl::Status advance_locked(const std::string& job_id);
  // Deletes what a job that is over no longer needs: its tile files and unshared result blobs.
  // Under the lock they are only moved into <data dir>/trash (renames: O(1) per file, whatever
  // the bytes); the janitor thread frees the space without the lock.
  void clean_up_locked(const std::string& job_id);
  // A MiB the data directory holds back (kDiskReserveFile) so that the job store can still
  // record a cancel when the disk is full: released for that write, made again by the janitor
  // once there is room.
  void keep_disk_reserve() const;
  bool release_disk_reserve() const;
  mutable std::atomic<bool> disk_reserve_missing_{false};
  // Hands the job's reclaimable range results (ActiveJob::reclaimable) to the janitor, which
  // syncs the tile pack and then releases their bytes from the result pack.
  void reclaim_locked(const std::string& job_id, ActiveJob& job);
  void janitor_loop();
  std::filesystem::path tiles_dir(const std::string& job_id) const;
  void process_events_locked();
  // A job whose last stage is done: marked FINALISING and queued for the finaliser thread,
  // which writes its outputs without the lock (a big job's take tens of seconds) and then
  // marks it DONE (or FAILED), unless it was cancelled meanwhile (its outputs are removed).
  absl::Status finalise_locked(const std::string& job_id);
  struct Finalising {
    std::string job_id;
    std::shared_ptr<ActiveJob> job;  // shared: a cancel may drop it from active_ meanwhile
    RenderReport report;
    OutputPaths paths;
  };
  // Without the lock: reads only the job's finished tiles, RGB and parameters, which nothing
  // changes once its last stage is done.
  absl::Status write_job_outputs(const ActiveJob& job, RenderReport& report,
                                 const OutputPaths& paths) const;
  void finish_finalise_locked(Finalising& item, const absl::Status& written);
  void finaliser_loop();
  // Admission control for a job of `params` (resource_plan.h): RESOURCE_EXHAUSTED with the
  // numbers, else the plan's bytes are reserved until release_locked.
  absl::Status admit_locked(const job::JobParameters& params, std::uint64_t* memory,
                            std::uint64_t* disk);
  void release_locked(std::uint64_t memory, std::uint64_t disk);
  void fail_job_locked(const std::string& job_id, const std::string& message);
  JobStatus status_locked(const store::JobRecord& record);
  std::filesystem::path output_dir(const std::string& job_id) const;
  OutputPaths output_paths_of(const std::string& job_id) const;
  void changed_locked();
  // Waits, without the lock, until the result bytes and store records written before `ticket`
  // (commit_->note_write) are durable; a failed sync is logged and returned (UNAVAILABLE: the
  // caller retries, and every later wait fails too until the coordinator is restarted).
  absl::Status make_durable(std::uint64_t ticket);
  // A done task's result: from the job's pack, or the blob store for a task from before packs.
  absl::StatusOr<std::string> result_bytes(const ActiveJob& job, const store::TaskRecord& task);
  // The data directory's size, walked by the janitor thread every kDataDirBytesInterval and
  // read by /metrics from data_dir_bytes_.
  std::uint64_t count_data_dir_bytes() const;
  // The dashboard's convergence series (farm_outputs.cpp): a job's file under convergence/ is
  // opened when it starts or resumes (its points so far into convergence_), appended to with
  // every accepted final-pass result, and rewritten thinned by the janitor when the job is over
  // (finish_convergence, without the lock).
  std::filesystem::path convergence_path(const std::string& job_id) const;
  void open_convergence_locked(const std::string& job_id, ActiveJob& job);
  void record_convergence_locked(const std::string& job_id, ActiveJob& job,
                                 const ConvergencePoint& point);
  void close_convergence_locked(const std::string& job_id);
  void finish_convergence(const std::string& job_id,
                          std::optional<std::vector<ConvergencePoint>> points) const;
  void tick_loop();
  // Deletes the records of workers not seen for kForgetWorkersAfter (none live), so that the
  // worker list, the dashboard and /metrics do not grow with every worker process ever seen
  // (an autoscaler's pods come and go). Run by the tick thread, hourly.
  void forget_old_workers_locked();

  FarmOptions options_;
  // One coordinator per data directory (<data dir>/coordinator.lock): a second one on the same
  // directory would share its store and leave its jobs to workers that never see them. Declared
  // first of the state, so it is released after everything else is closed.
  std::optional<base::FileLock> data_dir_lock_;
  spectral::SpectrumLibrary library_;
  spectral::ColorMatching cmf_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  // The ticker's own wake-up (stop only): waking it on every change ran a tick per result.
  std::condition_variable tick_wake_;
  std::uint64_t change_counter_ = 0;
  std::optional<store::JobStore> store_;
  std::optional<store::BlobStore> blobs_;  // results of jobs from before result packs
  // Group commit of results (make_durable): the packs written since the last flush, then the
  // store's WAL.
  DirtyPacks dirty_packs_;
  std::unique_ptr<store::GroupCommit> commit_;
  std::optional<BundleStore> bundles_;
  Scheduler scheduler_;
  std::map<std::string, std::shared_ptr<ActiveJob>> active_;
  std::map<std::string, std::uint64_t> tasks_completed_;    // by worker
  std::map<std::string, std::uint64_t> samples_completed_;  // by worker
  std::map<std::string, std::int64_t> left_;                // workers that left cleanly, when
  // The newest jobs' convergence series (by job id); older ones are read from their files.
  static constexpr std::size_t kConvergenceJobsInMemory = 256;
  static constexpr std::chrono::seconds kDataDirBytesInterval{10};
  static constexpr std::chrono::hours kForgetWorkersAfter{24};
  std::atomic<std::uint64_t> data_dir_bytes_{0};
  std::map<std::string, std::vector<ConvergencePoint>> convergence_;
  // Admission control: the budgets, what the coordinator held at start, and the plans of
  // submissions between their check and their job's creation.
  MemoryBudget memory_budget_;
  std::uint64_t baseline_memory_ = 0;
  std::uint64_t reserved_memory_ = 0;
  std::uint64_t reserved_disk_ = 0;
  FarmMetrics metrics_;
  std::uint64_t temp_counter_ = 0;
  bool stopping_ = false;
  std::thread ticker_;
  // The janitor empties trash_dir() when woken (and at start: a crash may have left trash).
  std::filesystem::path trash_dir() const { return options_.data_dir / "trash"; }
  std::mutex janitor_mutex_;
  std::condition_variable janitor_wake_;
  bool janitor_pending_ = true;
  bool janitor_stopping_ = false;
  // Finished jobs' convergence series to rewrite thinned (their points, or none: read the file),
  // off the farm's lock.
  std::vector<std::pair<std::string, std::optional<std::vector<ConvergencePoint>>>> janitor_series_;
  // Range results whose tiles are stored, to release (reclaim_locked).
  struct Reclaim {
    std::string job_id;
    std::shared_ptr<const FinishedTiles> tiles;
    std::shared_ptr<const ResultPack> results;
    std::vector<store::ResultLocation> ranges;
  };
  std::vector<Reclaim> janitor_reclaim_;
  bool reclaim_unsupported_ = false;  // the file system cannot punch holes (janitor thread only)
  std::thread janitor_;
  std::deque<Finalising> finalising_;  // under mutex_
  // Jobs whose outputs met a full disk, by job id: written again once `due` (the ticker).
  struct FinaliseRetry {
    Finalising item;
    std::chrono::steady_clock::time_point due;
    Millis delay{0};
    std::string problem;
  };
  std::map<std::string, FinaliseRetry> finalise_retries_;  // under mutex_
  std::string last_unstored_;  // why the last result could not be stored (under mutex_)
  void requeue_due_finalises_locked();
  std::condition_variable finaliser_wake_;
  std::thread finaliser_;
};

}  // namespace prism::coordinator
