#include "coordinator/scheduler.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"

namespace prism::coordinator {

// Why a lease stops being current when its result is accepted (compared in complete()).
constexpr char kAcceptedReason[] = "its result was accepted";

const char* to_string(DirectiveKind kind) {
  switch (kind) {
    case DirectiveKind::kCancelTask:
      return "CANCEL_TASK";
    case DirectiveKind::kDrain:
      return "DRAIN";
    case DirectiveKind::kReregister:
      return "REREGISTER";
  }
  return "?";
}

const char* to_string(CompleteOutcome outcome) {
  switch (outcome) {
    case CompleteOutcome::kAccepted:
      return "ACCEPTED";
    case CompleteOutcome::kDuplicate:
      return "DUPLICATE";
    case CompleteOutcome::kStale:
      return "STALE";
  }
  return "?";
}

const char* to_string(FailureClass failure_class) {
  switch (failure_class) {
    case FailureClass::kScene:
      return "scene";
    case FailureClass::kWorker:
      return "worker";
    case FailureClass::kInfrastructure:
      return "infrastructure";
    case FailureClass::kReturned:
      return "returned";
  }
  return "?";
}

const char* to_string(JobState state) {
  switch (state) {
    case JobState::kRunning:
      return "running";
    case JobState::kDone:
      return "done";
    case JobState::kFailed:
      return "failed";
    case JobState::kCancelled:
      return "cancelled";
  }
  return "?";
}

Scheduler::Scheduler(SchedulerOptions options) : options_(std::move(options)) {
  PRISM_CHECK(options_.heartbeat_interval.count() > 0);
  PRISM_CHECK(options_.lost_after_missed >= 1);
  PRISM_CHECK(options_.lease_duration.count() > 0);
  PRISM_CHECK(options_.max_attempts >= 1);
  PRISM_CHECK(options_.block_after_faults >= 1);
  PRISM_CHECK(options_.max_free_retries >= 1);
  PRISM_CHECK(options_.retry_preference.count() >= 0);
}

absl::Status Scheduler::validate(const std::string& job_id, const std::vector<TaskSpec>& tasks,
                                 int first_index) {
  for (std::size_t i = 0; i < tasks.size(); ++i) {
    const TaskSpec& spec = tasks[i];
    const std::string where =
        absl::StrCat("task ", first_index + static_cast<int>(i), " of job ", job_id);
    if (!spec.tile.valid() || spec.tile.empty())
      return absl::InvalidArgumentError(
          absl::StrCat(where, " has an empty or reversed tile ", image::to_string(spec.tile)));
    if (!spec.samples.valid() || spec.samples.count() == 0)
      return absl::InvalidArgumentError(absl::StrCat(where, " has an empty sample range [",
                                                     spec.samples.s0, ",", spec.samples.s1, ")"));
    if (spec.pass_index < 0)
      return absl::InvalidArgumentError(
          absl::StrCat(where, " has a negative pass index ", spec.pass_index));
  }
  return absl::OkStatus();
}

absl::Status Scheduler::add_job(const std::string& job_id, const std::vector<TaskSpec>& tasks,
                                const std::vector<int>& done) {
  if (job_id.empty()) return absl::InvalidArgumentError("a job id must not be empty");
  if (jobs_.contains(job_id))
    return absl::AlreadyExistsError(absl::StrCat("job ", job_id, " already exists"));
  if (auto status = validate(job_id, tasks, 0); !status.ok()) return status;
  const int count = static_cast<int>(tasks.size());
  for (int index : done) {
    if (index < 0 || index >= count)
      return absl::InvalidArgumentError(absl::StrCat("done task index ", index, " of job ", job_id,
                                                     " is outside 0..", count - 1));
  }
  JobRecord job;
  job.order = next_job_order_++;
  job.tasks.reserve(tasks.size());
  for (const TaskSpec& spec : tasks) {
    job.tasks.emplace_back();
    job.tasks.back().spec = spec;
  }
  for (int index : done) {
    if (job.tasks[index].state != TaskState::kDone) ++job.done;
    job.tasks[index].state = TaskState::kDone;
  }
  for (int index = 0; index < count; ++index)
    if (job.tasks[index].state == TaskState::kPending) job.pending.insert(index);
  job_order_[job.order] = job_id;
  auto [it, inserted] = jobs_.emplace(job_id, std::move(job));
  PRISM_CHECK(inserted);
  finish_if_done(it->second, job_id);
  return absl::OkStatus();
}

absl::StatusOr<int> Scheduler::add_tasks(const std::string& job_id,
                                         const std::vector<TaskSpec>& tasks, bool skipped) {
  auto it = jobs_.find(job_id);
  if (it == jobs_.end()) return absl::NotFoundError(absl::StrCat("no job ", job_id));
  JobRecord& job = it->second;
  if (job.state == JobState::kFailed || job.state == JobState::kCancelled)
    return absl::FailedPreconditionError(
        absl::StrCat("job ", job_id, " is ", to_string(job.state), ": no tasks can be added"));
  const int first = static_cast<int>(job.tasks.size());
  if (auto status = validate(job_id, tasks, first); !status.ok()) return status;
  for (const TaskSpec& spec : tasks) {
    if (skipped) {
      ++job.done;
    } else {
      job.pending.insert(static_cast<int>(job.tasks.size()));
    }
    job.tasks.emplace_back();
    job.tasks.back().spec = spec;
    if (skipped) job.tasks.back().state = TaskState::kDone;
  }
  if (job.state == JobState::kDone && !tasks.empty() && !skipped) {
    job.state = JobState::kRunning;
    job_order_[job.order] = job_id;
  }
  return first;
}

absl::Status Scheduler::cancel_job(const std::string& job_id) {
  auto it = jobs_.find(job_id);
  if (it == jobs_.end()) return absl::NotFoundError(absl::StrCat("no job ", job_id));
  JobRecord& job = it->second;
  if (job.state == JobState::kCancelled) return absl::OkStatus();
  if (job.state != JobState::kRunning)
    return absl::FailedPreconditionError(
        absl::StrCat("job ", job_id, " is already ", to_string(job.state)));
  end_job(job, job_id, JobState::kCancelled, "cancelled");
  return absl::OkStatus();
}

absl::Status Scheduler::remove_job(const std::string& job_id) {
  auto it = jobs_.find(job_id);
  if (it == jobs_.end()) return absl::NotFoundError(absl::StrCat("no job ", job_id));
  if (it->second.state == JobState::kRunning)
    return absl::FailedPreconditionError(
        absl::StrCat("job ", job_id, " is running: cancel it before removing it"));
  std::erase_if(leases_,
                [&](const auto& entry) { return entry.second.lease.task.job_id == job_id; });
  jobs_.erase(it);
  return absl::OkStatus();
}

void Scheduler::register_worker(const std::string& worker_id, int threads, Millis now) {
  WorkerRecord& worker = workers_[worker_id];
  worker.threads = threads;
  worker.last_seen = now;
}

bool Scheduler::eligible(const JobRecord& job, const TaskRecord& task, const std::string& worker_id,
                         Millis now) const {
  if (task.avoid_worker != worker_id || now >= task.avoid_until) return true;
  // Hold the task back only while someone else could take it.
  for (const auto& [other, record] : workers_)
    if (other != worker_id && !job.blocked.contains(other)) return false;
  return true;
}

std::optional<Lease> Scheduler::acquire(const std::string& worker_id, Millis now) {
  auto worker_it = workers_.find(worker_id);
  if (worker_it == workers_.end()) return std::nullopt;
  worker_it->second.last_seen = now;
  if (draining_) return std::nullopt;
  for (const auto& [order, job_id] : job_order_) {
    JobRecord& job = jobs_.at(job_id);
    if (job.blocked.contains(worker_id)) continue;
    for (int index : job.pending) {
      TaskRecord& task = job.tasks[index];
      if (now < task.not_before || !eligible(job, task, worker_id, now)) continue;
      const std::uint64_t seq = next_lease_seq_++;
      Lease lease{.id = absl::StrCat(options_.lease_prefix, seq),
                  .worker_id = worker_id,
                  .attempt = task.counted_failures + 1,
                  .deadline = now + options_.lease_duration,
                  .granted = now,
                  .task = Task{.job_id = job_id, .index = index, .spec = task.spec}};
      ++counters_.leases_granted;
      task.state = TaskState::kLeased;
      task.current_lease = lease.id;
      job.pending.erase(index);
      ++job.leased;
      worker_it->second.leases.insert(seq);
      current_leases_[seq] = lease.id;
      LeaseRecord& record = leases_[lease.id];
      record.lease = lease;
      record.seq = seq;
      return lease;
    }
  }
  return std::nullopt;
}

HeartbeatReply Scheduler::heartbeat(const std::string& worker_id,
                                    const std::vector<std::string>& lease_ids, Millis now) {
  HeartbeatReply reply;
  auto worker_it = workers_.find(worker_id);
  if (worker_it == workers_.end()) {
    reply.directives.push_back({DirectiveKind::kReregister, ""});
    return reply;
  }
  worker_it->second.last_seen = now;
  for (const std::string& id : lease_ids) {
    auto it = leases_.find(id);
    if (it != leases_.end() && it->second.current && it->second.lease.worker_id == worker_id) {
      it->second.lease.deadline = now + options_.lease_duration;
      reply.lease_deadline = it->second.lease.deadline;
    } else {
      reply.directives.push_back({DirectiveKind::kCancelTask, id});
    }
  }
  if (draining_) reply.directives.push_back({DirectiveKind::kDrain, ""});
  return reply;
}

CompleteReply Scheduler::complete(const std::string& worker_id, const std::string& lease_id,
                                  const std::string& result_hash, Millis now) {
  CompleteReply reply;
  if (auto w = workers_.find(worker_id); w != workers_.end()) w->second.last_seen = now;
  auto it = leases_.find(lease_id);
  if (it == leases_.end()) {
    reply.reason = absl::StrCat("unknown lease ", lease_id);
    return reply;
  }
  LeaseRecord& record = it->second;
  reply.task = record.lease.task;
  if (record.lease.worker_id != worker_id) {
    reply.reason = absl::StrCat("lease ", lease_id, " belongs to worker ", record.lease.worker_id,
                                ", not ", worker_id);
    return reply;
  }
  const std::string& job_id = record.lease.task.job_id;
  JobRecord& job = jobs_.at(job_id);
  TaskRecord& task = job.tasks[record.lease.task.index];
  if (task.state == TaskState::kDone) {
    // Tasks done at add_job() were never leased here, so a done task reached through one of our
    // leases always has the hash of the result that was accepted.
    if (task.result_hash == result_hash) {
      reply.outcome = CompleteOutcome::kDuplicate;
      return reply;
    }
    // A different result from a lease that ended before another one's result was accepted is
    // stale, not evidence of non-determinism: say why the lease stopped counting.
    if (record.ended != kAcceptedReason) {
      reply.reason = absl::StrCat("lease ", lease_id, " is no longer current: ", record.ended);
      return reply;
    }
    reply.reason = absl::StrCat(describe(job_id, record.lease.task.index, task.spec),
                                " was already accepted with result hash ", task.result_hash,
                                ", this result has ", result_hash,
                                ": the worker's output is not deterministic");
    return reply;
  }
  if (!record.current) {
    reply.reason = absl::StrCat("lease ", lease_id, " is no longer current: ", record.ended);
    return reply;
  }
  end_lease(record, kAcceptedReason);
  task.state = TaskState::kDone;
  task.result_hash = result_hash;
  ++job.done;
  reply.outcome = CompleteOutcome::kAccepted;
  finish_if_done(job, job_id);
  return reply;
}

absl::Status Scheduler::hold_back(const std::string& worker_id, const std::string& lease_id,
                                  Millis now) {
  auto it = leases_.find(lease_id);
  if (it == leases_.end() || it->second.lease.worker_id != worker_id || !it->second.current) {
    return absl::FailedPreconditionError(
        absl::StrCat("lease ", lease_id, " is not a current lease of worker ", worker_id));
  }
  LeaseRecord& record = it->second;
  const std::string job_id = record.lease.task.job_id;
  const int index = record.lease.task.index;
  JobRecord& job = jobs_.at(job_id);
  end_lease(record, "the coordinator could not store its result");
  TaskRecord& task = job.tasks[index];
  task.state = TaskState::kPending;
  job.pending.insert(index);
  ++counters_.retries_infrastructure;
  const int doublings = std::min(task.unstored++, 5);
  task.not_before =
      now + std::min(Millis(30'000), Millis(options_.unstored_retry_delay.count() << doublings));
  return absl::OkStatus();
}

absl::Status Scheduler::fail(const std::string& worker_id, const std::string& lease_id,
                             FailureClass failure_class, const std::string& message, Millis now) {
  if (auto w = workers_.find(worker_id); w != workers_.end()) w->second.last_seen = now;
  auto it = leases_.find(lease_id);
  if (it == leases_.end())
    return absl::FailedPreconditionError(absl::StrCat("unknown lease ", lease_id));
  LeaseRecord& record = it->second;
  if (record.lease.worker_id != worker_id)
    return absl::FailedPreconditionError(absl::StrCat("lease ", lease_id, " belongs to worker ",
                                                      record.lease.worker_id, ", not ", worker_id));
  if (!record.current)
    return absl::FailedPreconditionError(
        absl::StrCat("lease ", lease_id, " is no longer current: ", record.ended));
  const std::string job_id = record.lease.task.job_id;
  const int index = record.lease.task.index;
  JobRecord& job = jobs_.at(job_id);
  end_lease(record, absl::StrCat("its worker reported a ", to_string(failure_class), " failure"));
  if (failure_class == FailureClass::kScene) {
    job.tasks[index].state = TaskState::kPending;
    job.pending.insert(index);
    end_job(job, job_id, JobState::kFailed,
            absl::StrCat("scene fault in ", describe(job_id, index, job.tasks[index].spec),
                         " on worker ", worker_id, ": ", message));
    return absl::OkStatus();
  }
  requeue(job, job_id, index, failure_class, worker_id,
          absl::StrCat("worker ", worker_id, " reported: ", message), now);
  return absl::OkStatus();
}

void Scheduler::tick(Millis now) {
  std::vector<std::string> expired;
  for (const auto& [seq, id] : current_leases_)
    if (leases_.at(id).lease.deadline < now) expired.push_back(id);
  for (const std::string& id : expired) {
    LeaseRecord& record = leases_.at(id);
    // Ending one job (attempt cap) ends its other leases, which may be further in the list.
    if (!record.current) continue;
    const Lease lease = record.lease;
    ++counters_.lease_expiries;
    end_lease(record, absl::StrCat("it expired at ", lease.deadline.count(), " ms"));
    requeue(jobs_.at(lease.task.job_id), lease.task.job_id, lease.task.index, FailureClass::kWorker,
            lease.worker_id,
            absl::StrCat("lease ", lease.id, " of worker ", lease.worker_id, " expired at ",
                         lease.deadline.count(), " ms"),
            now);
  }

  const Millis silence = options_.heartbeat_interval * options_.lost_after_missed;
  std::vector<std::string> lost;
  for (const auto& [id, worker] : workers_)
    if (now - worker.last_seen > silence) lost.push_back(id);
  for (const std::string& worker_id : lost) {
    const WorkerRecord worker = workers_.at(worker_id);
    const int requeued = end_worker(worker_id, FailureClass::kWorker, "was declared lost", now);
    ++counters_.workers_lost;
    events_.push_back(
        {.kind = SchedulerEvent::Kind::kWorkerLost,
         .job_id = "",
         .worker_id = worker_id,
         .message = absl::StrCat("worker ", worker_id, " silent since ", worker.last_seen.count(),
                                 " ms (more than ", options_.lost_after_missed,
                                 " heartbeat intervals); requeued ", requeued,
                                 requeued == 1 ? " lease" : " leases")});
  }
}

void Scheduler::forgive(Millis unheard) {
  if (unheard.count() <= 0) return;
  for (auto& [id, worker] : workers_) worker.last_seen += unheard;
  for (const auto& [seq, id] : current_leases_) leases_.at(id).lease.deadline += unheard;
}

int Scheduler::remove_worker(const std::string& worker_id, Millis now) {
  if (!workers_.contains(worker_id)) return 0;
  return end_worker(worker_id, FailureClass::kReturned, "left", now);
}

int Scheduler::end_worker(const std::string& worker_id, FailureClass failure_class,
                          const std::string& what, Millis now) {
  const WorkerRecord worker = workers_.at(worker_id);
  int requeued = 0;
  for (std::uint64_t seq : worker.leases) {
    auto current = current_leases_.find(seq);
    if (current == current_leases_.end()) continue;
    LeaseRecord& record = leases_.at(current->second);
    const Lease lease = record.lease;
    end_lease(record, absl::StrCat("its worker ", worker_id, " ", what));
    requeue(jobs_.at(lease.task.job_id), lease.task.job_id, lease.task.index, failure_class,
            worker_id, absl::StrCat("worker ", worker_id, " holding lease ", lease.id, " ", what),
            now);
    ++requeued;
  }
  workers_.erase(worker_id);
  return requeued;
}

TaskCounts Scheduler::task_counts() const {
  TaskCounts counts;
  for (const auto& [order, job_id] : job_order_) {
    const JobRecord& job = jobs_.at(job_id);
    counts.pending += job.pending.size();
    counts.leased += std::uint64_t(job.leased);
    counts.done += std::uint64_t(job.done);
  }
  return counts;
}

std::vector<SchedulerEvent> Scheduler::take_events() {
  return std::exchange(events_, {});
}

std::optional<JobProgress> Scheduler::progress(const std::string& job_id) const {
  auto it = jobs_.find(job_id);
  if (it == jobs_.end()) return std::nullopt;
  const JobRecord& job = it->second;
  const int held_back = static_cast<int>(std::count_if(
      job.pending.begin(), job.pending.end(), [&](int i) { return job.tasks[i].unstored > 0; }));
  return JobProgress{.state = job.state,
                     .total = static_cast<int>(job.tasks.size()),
                     .done = job.done,
                     .leased = job.leased,
                     .pending = static_cast<int>(job.pending.size()),
                     .held_back = held_back,
                     .blocked_workers = {job.blocked.begin(), job.blocked.end()},
                     .message = job.message,
                     .last_fault = job.last_fault};
}

std::optional<Lease> Scheduler::lease(const std::string& lease_id) const {
  auto it = leases_.find(lease_id);
  if (it == leases_.end()) return std::nullopt;
  return it->second.lease;
}

std::vector<WorkerInfo> Scheduler::workers() const {
  std::vector<WorkerInfo> out;
  out.reserve(workers_.size());
  for (const auto& [id, worker] : workers_) {
    WorkerInfo info{.id = id,
                    .threads = worker.threads,
                    .last_seen = worker.last_seen,
                    .leases = static_cast<int>(worker.leases.size()),
                    .current = {}};
    for (std::uint64_t seq : worker.leases) {
      info.current.push_back(leases_.at(current_leases_.at(seq)).lease);
    }
    out.push_back(std::move(info));
  }
  return out;
}

void Scheduler::end_lease(LeaseRecord& record, std::string why) {
  PRISM_CHECK(record.current);
  record.current = false;
  record.ended = std::move(why);
  current_leases_.erase(record.seq);
  if (auto w = workers_.find(record.lease.worker_id); w != workers_.end())
    w->second.leases.erase(record.seq);
  JobRecord& job = jobs_.at(record.lease.task.job_id);
  TaskRecord& task = job.tasks[record.lease.task.index];
  PRISM_CHECK(task.state == TaskState::kLeased && task.current_lease == record.lease.id);
  task.current_lease.clear();
  --job.leased;
}

void Scheduler::requeue(JobRecord& job, const std::string& job_id, int index,
                        FailureClass failure_class, const std::string& worker_id,
                        const std::string& detail, Millis now) {
  PRISM_CHECK(failure_class != FailureClass::kScene);
  TaskRecord& task = job.tasks[index];
  task.state = TaskState::kPending;
  job.pending.insert(index);
  switch (failure_class) {
    case FailureClass::kWorker:
      ++counters_.retries_worker;
      break;
    case FailureClass::kInfrastructure:
      ++counters_.retries_infrastructure;
      break;
    case FailureClass::kReturned:
      ++counters_.retries_returned;
      break;
    case FailureClass::kScene:
      break;
  }
  if (failure_class == FailureClass::kWorker) {
    job.last_fault = absl::StrCat(describe(job_id, index, task.spec), ": ", detail);
    ++task.counted_failures;
    task.avoid_worker = worker_id;
    task.avoid_until = now + options_.retry_preference;
    count_worker_fault(job, worker_id);
    if (task.counted_failures >= options_.max_attempts)
      end_job(job, job_id, JobState::kFailed,
              absl::StrCat(describe(job_id, index, task.spec), " failed ", task.counted_failures,
                           " times (the cap is ", options_.max_attempts, "); last: ", detail));
  } else if (failure_class == FailureClass::kInfrastructure) {
    ++task.free_retries;
    if (task.free_retries >= options_.max_free_retries)
      end_job(job, job_id, JobState::kFailed,
              absl::StrCat(describe(job_id, index, task.spec), " hit ", task.free_retries,
                           " infrastructure failures (the cap is ", options_.max_free_retries,
                           "); last: ", detail));
  }
}

void Scheduler::count_worker_fault(JobRecord& job, const std::string& worker_id) {
  if (++job.worker_faults[worker_id] >= options_.block_after_faults) job.blocked.insert(worker_id);
}

void Scheduler::end_job(JobRecord& job, const std::string& job_id, JobState state,
                        std::string message) {
  PRISM_CHECK(job.state == JobState::kRunning);
  PRISM_CHECK(state == JobState::kFailed || state == JobState::kCancelled);
  job.state = state;
  job_order_.erase(job.order);
  for (int index : job.pending) job.tasks[index].state = TaskState::kDropped;
  job.pending.clear();
  const std::string why = state == JobState::kCancelled
                              ? absl::StrCat("job ", job_id, " was cancelled")
                              : absl::StrCat("job ", job_id, " failed");
  for (TaskRecord& task : job.tasks) {
    if (task.state != TaskState::kLeased) continue;
    end_lease(leases_.at(task.current_lease), why);
    task.state = TaskState::kDropped;
  }
  if (state == JobState::kFailed) {
    job.message = message;
    events_.push_back({.kind = SchedulerEvent::Kind::kJobFailed,
                       .job_id = job_id,
                       .worker_id = "",
                       .message = std::move(message)});
  } else {
    job.message = std::move(message);
  }
}

void Scheduler::finish_if_done(JobRecord& job, const std::string& job_id) {
  if (job.state != JobState::kRunning || job.done != static_cast<int>(job.tasks.size())) return;
  job.state = JobState::kDone;
  job_order_.erase(job.order);
  events_.push_back(
      {.kind = SchedulerEvent::Kind::kJobDone, .job_id = job_id, .worker_id = "", .message = ""});
}

std::string Scheduler::describe(const std::string& job_id, int index, const TaskSpec& spec) const {
  return absl::StrCat("task ", index, " of job ", job_id, " (",
                      spec.pass == Pass::kFinal ? "final pass" : "prepass ",
                      spec.pass == Pass::kFinal ? std::string() : absl::StrCat(spec.pass_index),
                      ", tile ", image::to_string(spec.tile), ", samples [", spec.samples.s0, ",",
                      spec.samples.s1, "))");
}

}  // namespace prism::coordinator
