// The coordinator's persistent job store: jobs, their planned tasks, per-worker failure counts
// and registered workers, in one SQLite file (WAL) under the data directory. After a crash or a
// restart the coordinator reopens the file and resumes every job that is not in a terminal
// state; a task recorded as done is never rendered again.
//
// Invariants kept by the store (each change runs in one transaction, so they hold after a crash
// at any point):
//  - job ids are "j-" + a zero-padded decimal that only grows, also across restarts; a failed
//    create does not consume an id;
//  - a client token names at most one job, forever: submitting again with the same token
//    returns the job created the first time;
//  - a job's tasks are numbered 0..n-1 in plan order; tasks_done/samples_done equal the counts
//    and samples of its done tasks;
//  - a done task keeps the hash of its first accepted result; a different hash for it later is
//    refused (renders are deterministic, so it means corruption or a bug, not a retry);
//  - job states only move along the transition table in `is_valid_transition`.
// The job spec is stored as opaque bytes (the serialized proto); the store never parses it.
// One JobStore is used by one thread at a time (the caller serialises access, as for Database).
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/image/tile.h"
#include "services/store/database.h"

namespace prism::store {

// The numeric values equal prism.v1.JobState, so the rpc layer converts with a checked cast.
enum class JobState : int {
  kQueued = 1,
  kPrepass = 2,
  kRendering = 3,
  kFinalising = 4,
  kDone = 5,
  kFailed = 6,
  kCancelled = 7,
};

// "QUEUED", "PREPASS", ... ("UNKNOWN(n)" for a value outside the enum).
std::string to_string(JobState state);
bool is_terminal(JobState state);
// FAILED or CANCELLED: a job that will never have outputs, which gives up its client token to
// the next submission with it (JobStore::create_job), so that the same render can be asked for
// again.
bool gives_up_client_token(JobState state);
// QUEUED → PREPASS | RENDERING; PREPASS → RENDERING; RENDERING → FINALISING;
// FINALISING → DONE; any non-terminal state → FAILED | CANCELLED. Nothing leaves a terminal
// state. Staying in the same state is not a transition (see set_job_state).
bool is_valid_transition(JobState from, JobState to);

// The numeric values equal prism.v1.Pass.
enum class TaskPass : int { kPrepass = 1, kFinal = 2 };

// Leases live in the coordinator's memory and die with it, so a task is either still to be
// rendered (pending, whether or not some worker holds a lease on it) or done.
// kSkipped: a later prepass the coordinator decided not to render (the prepass stopped early);
// it counts as finished in the progress and has no result.
enum class TaskState : int { kPending = 0, kDone = 1, kSkipped = 2 };

struct JobProgress {
  std::uint64_t tasks_total = 0;
  std::uint64_t tasks_done = 0;
  std::uint64_t samples_total = 0;  // pixel samples: sum over tasks of rect area × range count
  std::uint64_t samples_done = 0;
  friend bool operator==(const JobProgress&, const JobProgress&) = default;
};

struct JobRecord {
  std::string id;            // assigned by create_job
  std::string client_token;  // empty: no idempotency key
  std::string spec;          // serialized prism.v1.JobSpec, opaque to the store
  // Hex SHA-256 of the request as submitted (before defaults were filled in), compared when its
  // client token comes again; empty for jobs stored before schema 5.
  std::string request_hash;
  std::string bundle_hash;
  JobState state = JobState::kQueued;
  std::string error;              // why the job FAILED (or was CANCELLED), verbatim
  std::int64_t submitted_ms = 0;  // Unix milliseconds; 0 = not yet
  std::int64_t started_ms = 0;    // first left QUEUED
  std::int64_t finished_ms = 0;   // entered a terminal state
  std::string report_json;        // empty until set_report
  JobProgress progress;
};

struct TaskRecord {
  int index = 0;  // 0..n-1 within the job, plan order
  TaskPass pass = TaskPass::kFinal;
  int pass_index = 0;  // k for prepass k, 0 for the final pass
  int tile_index = 0;  // raster order of the tile plan
  image::TileRect rect;
  image::SampleRange samples;
  TaskState state = TaskState::kPending;
  int attempts = 0;         // leases handed out for this task so far
  std::string result_hash;  // hex hash of the accepted result; empty while pending
  // Where the result is kept: bytes [result_offset, result_offset + result_size) of the job's
  // result pack, or the blob store (under result_hash) when result_offset is -1.
  std::int64_t result_offset = -1;
  std::uint64_t result_size = 0;
  friend bool operator==(const TaskRecord&, const TaskRecord&) = default;
};

// Where mark_task_done records a result is kept (TaskRecord::result_offset).
struct ResultLocation {
  std::int64_t offset = -1;  // in the job's result pack; -1: the blob store
  std::uint64_t size = 0;
};

struct WorkerRecord {
  std::string id;  // "w-000001"; assigned by register_worker when empty
  std::string host;
  std::string version;
  int threads = 0;
  std::vector<std::string> capabilities;  // each non-empty, printable, without newlines
  std::int64_t last_seen_ms = 0;
  std::int64_t left_ms = 0;  // when it left cleanly (Leave); 0: it has not (registering clears it)
  friend bool operator==(const WorkerRecord&, const WorkerRecord&) = default;
};

struct CreateJobResult {
  JobRecord job;
  bool existed = false;  // true: the client token was known and nothing was inserted
};

class JobStore {
 public:
  // The schema version this build writes; open() migrates older files up to it.
  static constexpr int kSchemaVersion = 5;

  // Opens or creates the store file and applies pending migrations, each in its own
  // transaction with its user_version bump. FAILED_PRECONDITION when the file has a newer
  // schema than this build understands (it is left untouched) or cannot be opened.
  static absl::StatusOr<JobStore> open(const std::filesystem::path& file);

  // Stores a new job in QUEUED with its planned tasks (indices 0..n-1 in order, valid rects and
  // ranges, state pending: INVALID_ARGUMENT otherwise) and returns it with its new id; the id
  // and state in `job` are ignored and the progress totals are computed from `tasks`. When
  // job.client_token is already known, returns that job with existed = true and changes
  // nothing: the spec and tasks of the repeated request are ignored; unless that job FAILED or
  // was CANCELLED (gives_up_client_token): then it loses the token and the new job is stored
  // with it, in the same transaction.
  absl::StatusOr<CreateJobResult> create_job(JobRecord job, std::span<const TaskRecord> tasks);

  // Appends tasks to a non-terminal job (the rest of a large plan, stored in parts); their
  // indices must continue the job's numbering. Updates the totals. `commit`: see
  // Database::Commit (a later durable commit, such as the job's next state, covers a deferred one).
  absl::Status add_tasks(std::string_view job_id, std::span<const TaskRecord> tasks,
                         Database::Commit commit = Database::Commit::kDurable);

  // NOT_FOUND naming the id when there is no such job.
  absl::StatusOr<JobRecord> get_job(std::string_view job_id);
  absl::StatusOr<JobRecord> find_by_client_token(std::string_view client_token);

  // Newest first; `limit` 0 means all; an empty `states` means every state.
  absl::StatusOr<std::vector<JobRecord>> list_jobs(std::size_t limit,
                                                   std::span<const JobState> states = {});

  // Moves a job to `to` at time now_ms and returns the updated record. Sets started_ms when it
  // first leaves QUEUED and finished_ms when it enters a terminal state; stores `error` when it
  // is not empty. Setting the state the job is already in changes nothing and succeeds (a
  // restarted coordinator repeats its last step). FAILED_PRECONDITION for a transition outside
  // the table, or for DONE while tasks are pending.
  absl::StatusOr<JobRecord> set_job_state(std::string_view job_id, JobState to, std::int64_t now_ms,
                                          std::string_view error = "");

  // Stores the job's JSON report (written before the job becomes DONE).
  absl::Status set_report(std::string_view job_id, std::string_view report_json);

  // Every task of the job in index order; NOT_FOUND for an unknown job.
  absl::StatusOr<std::vector<TaskRecord>> tasks_of(std::string_view job_id);
  // The distinct result hashes of the job's done tasks that no task of another unfinished job
  // (not DONE, FAILED or CANCELLED) also has: blobs the coordinator may delete once this job is
  // over (identical jobs submitted twice share their content-addressed results). NOT_FOUND for
  // an unknown job.
  absl::StatusOr<std::vector<std::string>> unshared_results(std::string_view job_id);
  // The tasks not yet done, in index order.
  absl::StatusOr<std::vector<TaskRecord>> pending_tasks(std::string_view job_id);

  // Records a task's accepted result. Returns true when the task became done now, false for a
  // duplicate with the same hash (harmless: nothing changes). DATA_LOSS when the task is
  // already done with a different hash; FAILED_PRECONDITION when the job is FAILED or
  // CANCELLED; NOT_FOUND for an unknown job or task; INVALID_ARGUMENT for an empty hash.
  // The commit is deferred (Database::Commit): it is visible at once, and durable only after
  // sync(), which a caller must wait for before acknowledging it.
  absl::StatusOr<bool> mark_task_done(std::string_view job_id, int task_index,
                                      std::string_view result_hash, ResultLocation location = {});
  // Undoes a task's DONE (back to PENDING, its result and progress forgotten): for a result a
  // restarted coordinator finds missing or damaged after a power loss. Its record reached the
  // disk before its bytes did, so it was never acknowledged (an acknowledgement waits for both).
  // OK when the task is not DONE; NOT_FOUND for an unknown job or task.
  absl::Status reopen_task(std::string_view job_id, int task_index);

  // Marks the tasks [first, last) SKIPPED (TaskState) and counts them, and their samples, as
  // finished in the progress. Tasks already SKIPPED stay so (a restarted coordinator repeats the
  // step). INVALID_ARGUMENT for a range outside the job's tasks; FAILED_PRECONDITION when one of
  // them is DONE or the job is FAILED or CANCELLED; NOT_FOUND for an unknown job.
  absl::Status skip_tasks(std::string_view job_id, int first, int last);

  // Counts one more lease handed out for the task and returns the new attempt number (1 for
  // the first lease). Deferred like mark_task_done: a lease is no acknowledgement, and an
  // attempt lost with the machine's power only undercounts.
  absl::StatusOr<int> record_attempt(std::string_view job_id, int task_index);

  // Counts one more failure of `worker_id` on the job and returns the new count.
  absl::StatusOr<int> record_worker_failure(std::string_view job_id, std::string_view worker_id);
  // Failure counts of every worker that failed the job.
  absl::StatusOr<std::map<std::string, int>> worker_failures(std::string_view job_id);

  absl::StatusOr<JobProgress> progress(std::string_view job_id);
  // The job's tiles with final-pass tasks, and those whose final-pass tasks are all done: what a
  // job that ended early (cancelled, failed) had finished. {0, 0} for a job with no final pass
  // planned yet.
  struct TileCounts {
    std::int64_t done = 0;
    std::int64_t total = 0;
    friend bool operator==(const TileCounts&, const TileCounts&) = default;
  };
  absl::StatusOr<TileCounts> final_tile_counts(std::string_view job_id);
  // The tile indices (ascending) whose final-pass tasks are all done.
  absl::StatusOr<std::vector<int>> done_final_tiles(std::string_view job_id);
  // How many jobs are in each state (states with none are absent): for the coordinator's metrics.
  absl::StatusOr<std::map<JobState, std::int64_t>> count_jobs_by_state();

  // Every job not in a terminal state, oldest first: what a restarted coordinator resumes.
  absl::StatusOr<std::vector<JobRecord>> jobs_to_resume();

  // Registers a worker (assigning a new id when record.id is empty) or updates a known one
  // (a worker reattaching after a restart keeps its id). Returns the stored record.
  absl::StatusOr<WorkerRecord> register_worker(WorkerRecord record);
  // NOT_FOUND for an unknown worker. Deferred like record_attempt (last_seen_ms is advice).
  absl::Status touch_worker(std::string_view worker_id, std::int64_t now_ms);
  // Records that the worker left cleanly, now (left_ms and last_seen_ms); NOT_FOUND if unknown.
  absl::Status mark_worker_left(std::string_view worker_id, std::int64_t now_ms);
  // Deletes the records of workers last seen before `seen_before_ms`, except those in `keep`
  // (the live ones); returns how many. A worker that comes back later registers anew.
  absl::StatusOr<int> forget_workers(std::int64_t seen_before_ms,
                                     const std::vector<std::string>& keep);
  absl::StatusOr<WorkerRecord> get_worker(std::string_view worker_id);
  // In registration order.
  absl::StatusOr<std::vector<WorkerRecord>> list_workers();

  // Makes every write so far durable, the deferred ones included: thread-safe, see
  // Database::sync_wal.
  absl::Status sync() const { return db_.sync_wal(); }

  // The underlying connection, for inspection and tests.
  Database& database() { return db_; }

 private:
  explicit JobStore(Database db) : db_(std::move(db)) {}
  absl::Status migrate(const std::filesystem::path& file);
  absl::StatusOr<std::string> allocate_id(std::string_view counter, std::string_view prefix);
  absl::StatusOr<std::vector<JobRecord>> query_jobs(std::string_view where_and_order,
                                                    const std::vector<SqlValue>& params);
  absl::StatusOr<JobRecord> get_job_row(std::string_view job_id);
  absl::Status insert_tasks(std::string_view job_id, std::span<const TaskRecord> tasks,
                            int first_index);
  absl::StatusOr<std::vector<TaskRecord>> query_tasks(std::string_view job_id, bool pending_only);

  Database db_;
};

}  // namespace prism::store
