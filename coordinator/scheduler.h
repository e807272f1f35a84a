// The coordinator's lease scheduler: which worker renders which task, and when a result counts.
// Pure domain logic: no threads, no RPC, no storage. Time is injected (`now` on every call, in
// milliseconds since an epoch the caller picks; the daemon passes Unix time), so the same call
// sequence always gives the same leases, directives, outcomes and events. The caller serialises
// calls (the daemon holds one mutex) and persists what it must from the replies and events.
//
// Tasks. A job is an ordered list of tasks {pass, tile rect, sample range}, numbered from 0 in
// the order given. Jobs are served in submission order (FIFO): acquire() hands out the lowest
// pending task index of the oldest running job the worker may take. A task is pending, leased
// (exactly one current lease) or done; done is final and is never leased again, which is also
// how a restarted coordinator resumes: add_job() takes the indices already done.
//
// Leases and fencing. A lease {id, attempt, deadline, task} is current from acquire() until it
// completes, fails, expires, its worker is lost or its job ends. Only the current lease of a task
// can complete it: a result for any other lease is STALE, with the reason. A result for a task
// already done is a harmless DUPLICATE when its hash equals the accepted one (samples are a pure
// function of the task, so retries give identical bytes) and STALE otherwise. Lease ids are
// `lease_prefix` + a counter from 1 and are never reused within one Scheduler; give each
// coordinator incarnation its own prefix so a reattaching worker's old ids cannot collide.
//
// Liveness. A worker is alive from register_worker() while it calls in: every call from it counts
// as a sign of life. tick() declares it LOST once more than `lost_after_missed` heartbeat
// intervals have passed without one, forgets it and requeues its leases. Heartbeats extend the
// leases they list to now + lease_duration; a lease left past its deadline is expired by tick().
//
// Failures (the attempt of a lease is 1 + the task's counted failures):
//  - kScene: the scene cannot be rendered; the job fails at once with the worker's message, its
//    pending tasks are dropped and its other leases get CANCEL_TASK on their next heartbeat.
//  - kWorker, an expired lease, a lost worker: a worker fault. Counted: the task is requeued
//    with attempt + 1, preferring another worker; the job fails when a task reaches
//    max_attempts counted failures, with a message naming the task, the count and the last
//    fault. The faulty worker's count on that job goes up, and at block_after_faults it is
//    blocked from the job (it still gets other jobs' tasks). An expired lease is a worker fault
//    because the worker stopped heartbeating it while staying (or having been) reachable: a
//    hung or overloaded worker must not keep a task forever and must not be given it again
//    first.
//  - kInfrastructure: transient (disk, network); requeued without counting, up to
//    max_free_retries per task so that a persistent environment fault still ends the job.
//  - kReturned: a draining worker hands the lease back; requeued, never counted.
//
// Retry preference. A task requeued after a worker fault is not given back to the worker that
// faulted while another live worker that is not blocked from the job exists, for at most
// retry_preference after the fault; after that anyone not blocked may take it (no starvation).
// A blocked worker never gets the job's tasks; a job whose every worker is blocked waits for a
// new worker (progress() shows it).
//
// Cancellation and draining. cancel_job() drops pending tasks and ends the job's leases: the
// workers holding them get CANCEL_TASK on their next heartbeat, so they stop within one
// heartbeat interval. While the coordinator drains, acquire() hands out nothing and every
// heartbeat carries DRAIN.
//
// Events. Job completion (every task done), job failure and lost workers are queued as events
// in the order they happen; the caller takes them with take_events() and acts on them
// (finalise the job's outputs, record the failure).
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/image/tile.h"

namespace prism::coordinator {

// Milliseconds since the caller's epoch; also used for durations.
using Millis = std::chrono::milliseconds;

struct SchedulerOptions {
  Millis heartbeat_interval{1000};  // what workers are told to use; > 0
  int lost_after_missed = 3;        // intervals without a call before a worker is LOST; >= 1
  Millis lease_duration{10000};     // a lease's deadline is acquire/heartbeat time + this; > 0
  int max_attempts = 4;             // counted failures of one task that fail its job; >= 1
  int block_after_faults = 3;       // worker faults on one job that block the worker; >= 1
  int max_free_retries = 100;       // infrastructure failures of one task that fail its job
  Millis retry_preference{5000};    // how long a faulted task waits for another worker; >= 0
  // A task whose result the coordinator could not keep waits this long before it is handed out
  // again, doubled at each such failure up to 30 s (hold_back).
  Millis unstored_retry_delay{1000};
  std::string lease_prefix = "l-";  // lease ids are lease_prefix + a counter from 1
};

enum class Pass { kPrepass, kFinal };

// One unit of work as planned: a sample range of one tile in one pass.
struct TaskSpec {
  Pass pass = Pass::kFinal;
  int pass_index = 0;  // k for prepass k, 0 for the final pass
  image::TileRect tile;
  image::SampleRange samples;
  friend bool operator==(const TaskSpec&, const TaskSpec&) = default;
};

// A task as handed to a worker: its job, its index in the job and what to render.
struct Task {
  std::string job_id;
  int index = 0;
  TaskSpec spec;
  friend bool operator==(const Task&, const Task&) = default;
};

struct Lease {
  std::string id;
  std::string worker_id;
  int attempt = 1;  // 1 + counted (worker) failures of the task before this lease
  Millis deadline{0};
  Millis granted{0};  // when acquire() handed it out
  Task task;
  friend bool operator==(const Lease&, const Lease&) = default;
};

enum class DirectiveKind { kCancelTask, kDrain, kReregister };

struct Directive {
  DirectiveKind kind = DirectiveKind::kCancelTask;
  std::string lease_id;  // for kCancelTask
  friend bool operator==(const Directive&, const Directive&) = default;
};

struct HeartbeatReply {
  std::vector<Directive> directives;
  std::optional<Millis> lease_deadline;  // the extended deadline, when a lease was extended
};

enum class CompleteOutcome { kAccepted, kDuplicate, kStale };

struct CompleteReply {
  CompleteOutcome outcome = CompleteOutcome::kStale;
  std::string reason;        // for kStale: why the result was refused
  std::optional<Task> task;  // the lease's task, when the lease is known
};

enum class FailureClass { kScene, kWorker, kInfrastructure, kReturned };

enum class JobState { kRunning, kDone, kFailed, kCancelled };

struct JobProgress {
  JobState state = JobState::kRunning;
  int total = 0;
  int done = 0;
  int leased = 0;
  int pending = 0;
  int held_back = 0;  // pending tasks whose result the coordinator could not keep (hold_back)
  std::vector<std::string> blocked_workers;  // sorted
  std::string message;                       // why the job failed
  std::string last_fault;                    // the last worker fault of one of its tasks
};

struct SchedulerEvent {
  enum class Kind { kJobDone, kJobFailed, kWorkerLost };
  Kind kind = Kind::kJobDone;
  std::string job_id;     // kJobDone, kJobFailed
  std::string worker_id;  // kWorkerLost
  std::string message;    // kJobFailed: the failure; kWorkerLost: what was requeued
  friend bool operator==(const SchedulerEvent&, const SchedulerEvent&) = default;
};

// Running totals since the Scheduler was made, for the coordinator's metrics.
struct SchedulerCounters {
  std::uint64_t leases_granted = 0;
  std::uint64_t lease_expiries = 0;  // leases that ran past their deadline
  std::uint64_t workers_lost = 0;
  // Tasks put back in the queue after their lease ended, by why: a worker fault (including
  // expiries and lost workers), an infrastructure failure, or a draining worker handing it back.
  std::uint64_t retries_worker = 0;
  std::uint64_t retries_infrastructure = 0;
  std::uint64_t retries_returned = 0;
};

// Tasks of the running jobs as they stand now.
struct TaskCounts {
  std::uint64_t pending = 0;
  std::uint64_t leased = 0;
  std::uint64_t done = 0;
};

struct WorkerInfo {
  std::string id;
  int threads = 0;
  Millis last_seen{0};
  int leases = 0;              // current leases held
  std::vector<Lease> current;  // those leases, oldest first
};

const char* to_string(DirectiveKind kind);
const char* to_string(CompleteOutcome outcome);
const char* to_string(FailureClass failure_class);
const char* to_string(JobState state);

class Scheduler {
 public:
  // The options must be in the documented ranges (PRISM_CHECK: they come from validated config).
  explicit Scheduler(SchedulerOptions options = {});

  const SchedulerOptions& options() const { return options_; }

  // Adds a job behind every job added before. `done` lists the task indices already finished
  // (restart resume): they are never leased. A job with no task left is done at once (a kJobDone
  // event is queued). ALREADY_EXISTS for a known job id; INVALID_ARGUMENT for an empty id, an
  // invalid rect or sample range, or a done index out of range (nothing is added on error).
  absl::Status add_job(const std::string& job_id, const std::vector<TaskSpec>& tasks,
                       const std::vector<int>& done = {});
  // Appends tasks to a running or done job (a later pass once the previous one is merged); a
  // done job runs again, in its original place in the FIFO order. Returns the index of the first
  // new task. NOT_FOUND, FAILED_PRECONDITION
  // for a failed or cancelled job, INVALID_ARGUMENT as for add_job. With `skipped` the tasks are
  // added as done and are never leased (a later prepass the coordinator decided not to render);
  // they keep the job's task numbering.
  absl::StatusOr<int> add_tasks(const std::string& job_id, const std::vector<TaskSpec>& tasks,
                                bool skipped = false);
  // Cancels a job: pending tasks are dropped, its leases end (CANCEL_TASK at their next
  // heartbeat). Idempotent for a cancelled job; NOT_FOUND; FAILED_PRECONDITION for a job that is
  // already done or failed.
  absl::Status cancel_job(const std::string& job_id);
  // Forgets a finished (done, failed or cancelled) job and its leases, to bound memory once the
  // caller has recorded it; later calls about its leases see unknown leases. NOT_FOUND,
  // FAILED_PRECONDITION for a running job.
  absl::Status remove_job(const std::string& job_id);

  // Registers (or re-registers, keeping its leases) a worker. `threads` is informational
  // (workers()): a worker pulls one lease per acquire() and decides itself how many to hold.
  void register_worker(const std::string& worker_id, int threads, Millis now);
  // The next task for the worker, or nothing: unknown worker (its next heartbeat says
  // REREGISTER), draining coordinator, or no task it may take.
  std::optional<Lease> acquire(const std::string& worker_id, Millis now);
  // The worker lists the leases it works on. Each current lease of this worker is extended to
  // now + lease_duration; every other listed id (unknown, stale, another worker's, or of a job
  // that was cancelled or failed) gets CANCEL_TASK. DRAIN while draining; only REREGISTER for
  // an unknown worker.
  HeartbeatReply heartbeat(const std::string& worker_id, const std::vector<std::string>& lease_ids,
                           Millis now);
  // A result for a lease, identified by the hash of its bytes. ACCEPTED: the lease was current,
  // the task is now done (and the job too when it was the last: kJobDone event). DUPLICATE: the
  // task was already done with the same hash. STALE otherwise, with the reason.
  CompleteReply complete(const std::string& worker_id, const std::string& lease_id,
                         const std::string& result_hash, Millis now);
  // The coordinator could not keep the lease's result (its disk is full): the task goes back to
  // the queue counted as an infrastructure retry but against no cap (the farm waits for space;
  // the job does not end for it), and is held back for unstored_retry_delay, doubling, so that
  // workers do not render it again every second meanwhile. FAILED_PRECONDITION as fail().
  absl::Status hold_back(const std::string& worker_id, const std::string& lease_id, Millis now);
  // A failure reported for a lease (classes in the header comment; `message` is the worker's
  // own). FAILED_PRECONDITION naming the reason when the lease is not this worker's current
  // lease: nothing changes.
  absl::Status fail(const std::string& worker_id, const std::string& lease_id,
                    FailureClass failure_class, const std::string& message, Millis now);
  // Expires leases whose deadline is before now, then declares lost the workers silent for
  // more than lost_after_missed intervals. Call it about once per heartbeat interval.
  void tick(Millis now);

  // The coordinator could not listen for `unheard` (a long operation held its lock, the process
  // was stopped): nobody's silence in that time is their fault. Every worker's last_seen and
  // every current lease's deadline move later by `unheard`, so the next tick() neither expires
  // a lease nor declares a worker lost for heartbeats the coordinator could not take.
  void forgive(Millis unheard);

  // A worker leaves cleanly (it drained): its current leases are requeued as returned (not
  // counted) and it is forgotten, with no kWorkerLost event. Unknown workers: nothing happens.
  // Returns how many leases were requeued.
  int remove_worker(const std::string& worker_id, Millis now);

  // While draining, acquire() returns nothing and heartbeats carry DRAIN.
  void set_draining(bool draining) { draining_ = draining; }
  bool draining() const { return draining_; }

  // Events since the last call, in the order they happened.
  std::vector<SchedulerEvent> take_events();

  bool knows_worker(const std::string& worker_id) const { return workers_.contains(worker_id); }
  std::optional<JobProgress> progress(const std::string& job_id) const;
  // The lease as handed out (deadline as last extended), also after it stopped being current.
  std::optional<Lease> lease(const std::string& lease_id) const;
  // Registered workers, by id.
  std::vector<WorkerInfo> workers() const;
  const SchedulerCounters& counters() const { return counters_; }
  // Summed over the running jobs: O(jobs).
  TaskCounts task_counts() const;

 private:
  enum class TaskState { kPending, kLeased, kDone, kDropped };
  struct TaskRecord {
    TaskSpec spec;
    TaskState state = TaskState::kPending;
    int counted_failures = 0;
    int free_retries = 0;
    std::string current_lease;
    std::string result_hash;
    std::string avoid_worker;  // the worker that faulted it last, while avoid_until is ahead
    Millis avoid_until{0};
    int unstored = 0;      // results of it the coordinator could not keep (hold_back)
    Millis not_before{0};  // held back until then
  };
  struct JobRecord {
    std::uint64_t order = 0;
    JobState state = JobState::kRunning;
    std::vector<TaskRecord> tasks;
    std::set<int> pending;  // task indices, served lowest first
    int done = 0;
    int leased = 0;
    std::map<std::string, int> worker_faults;
    std::set<std::string> blocked;
    std::string message;
    std::string last_fault;  // the last worker fault of one of its tasks, for progress()
  };
  struct LeaseRecord {
    Lease lease;
    std::uint64_t seq = 0;
    bool current = true;
    std::string ended;  // why it stopped being current
  };
  struct WorkerRecord {
    int threads = 0;
    Millis last_seen{0};
    std::set<std::uint64_t> leases;  // current leases by sequence number
  };

  static absl::Status validate(const std::string& job_id, const std::vector<TaskSpec>& tasks,
                               int first_index);
  bool eligible(const JobRecord& job, const TaskRecord& task, const std::string& worker_id,
                Millis now) const;
  // Forgets a worker: its current leases end ("its worker <id> <what>") and their tasks are
  // requeued as `failure_class`. Returns how many.
  int end_worker(const std::string& worker_id, FailureClass failure_class, const std::string& what,
                 Millis now);
  // Ends a current lease: it stops being current, leaves its worker and its task's slot.
  void end_lease(LeaseRecord& record, std::string why);
  // Puts a task back in its job's pending set after its lease ended for `failure_class`.
  void requeue(JobRecord& job, const std::string& job_id, int index, FailureClass failure_class,
               const std::string& worker_id, const std::string& detail, Millis now);
  // Worker fault bookkeeping for the job (block after block_after_faults).
  void count_worker_fault(JobRecord& job, const std::string& worker_id);
  // Ends the job (failed or cancelled): pending dropped, current leases ended.
  void end_job(JobRecord& job, const std::string& job_id, JobState state, std::string message);
  void finish_if_done(JobRecord& job, const std::string& job_id);
  std::string describe(const std::string& job_id, int index, const TaskSpec& spec) const;

  SchedulerOptions options_;
  bool draining_ = false;
  std::uint64_t next_job_order_ = 0;
  std::uint64_t next_lease_seq_ = 1;
  std::map<std::string, JobRecord> jobs_;
  std::map<std::uint64_t, std::string> job_order_;  // running jobs, oldest first
  std::map<std::string, LeaseRecord> leases_;
  std::map<std::uint64_t, std::string> current_leases_;  // by sequence number
  std::map<std::string, WorkerRecord> workers_;
  std::vector<SchedulerEvent> events_;
  SchedulerCounters counters_;
};

}  // namespace prism::coordinator
