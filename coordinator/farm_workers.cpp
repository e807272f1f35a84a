// FarmCoordinator's workers and leases (farm_coordinator.h): registration, lease grants with
// what a task needs, heartbeats, results checked and merged, failures.
#include "absl/strings/str_cat.h"
#include "coordinator/farm_coordinator.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/tile_codec.h"

namespace prism::coordinator {

namespace fs = std::filesystem;
using SteadyClock = std::chrono::steady_clock;

absl::StatusOr<store::WorkerRecord> FarmCoordinator::register_worker(
    store::WorkerRecord record, const std::string& previous_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  record.id.clear();
  if (!previous_id.empty() && store_->get_worker(previous_id).ok()) record.id = previous_id;
  record.last_seen_ms = now().count();
  PRISM_ASSIGN_OR_RETURN(store::WorkerRecord stored, store_->register_worker(std::move(record)));
  scheduler_.register_worker(stored.id, stored.threads, now());
  left_.erase(stored.id);
  options_.logger->info("[worker {}] registered: host {}, version {}, {} threads", stored.id,
                        stored.host, stored.version, stored.threads);
  changed_locked();
  return stored;
}

absl::StatusOr<std::optional<LeaseGrant>> FarmCoordinator::acquire(const std::string& worker_id,
                                                                   Millis wait) {
  const SteadyClock::time_point deadline = SteadyClock::now() + wait;
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_ && scheduler_.knows_worker(worker_id)) {
    std::optional<Lease> lease = scheduler_.acquire(worker_id, now());
    if (lease.has_value()) {
      auto it = active_.find(lease->task.job_id);
      if (it == active_.end()) {
        // Cannot happen: the Scheduler only serves running jobs, which are all active.
        (void)scheduler_.fail(worker_id, lease->id, FailureClass::kInfrastructure,
                              "the job is not active on the coordinator", now());
        continue;
      }
      absl::StatusOr<int> attempt = store_->record_attempt(lease->task.job_id, lease->task.index);
      if (!attempt.ok()) {
        options_.logger->warn("[job {}] cannot record an attempt: {}", lease->task.job_id,
                              attempt.status().ToString());
      }
      options_.logger->debug("[job {} task {}] leased to {} as {}", lease->task.job_id,
                             lease->task.index, worker_id, lease->id);
      ActiveJob& job = *it->second;
      LeaseGrant grant;
      grant.lease = *lease;
      grant.spec = job.spec;
      grant.bundle_hash = job.params.bundle_hash;
      if (job.prepass.has_value()) {
        const TaskSpec& spec = lease->task.spec;
        absl::StatusOr<std::optional<std::string>> tables = std::optional<std::string>();
        if (spec.pass == Pass::kPrepass) {
          const PrepassPass& pass = job.prepass->pass(spec.pass_index);
          tables = job.prepass->tables_for_pass(spec.pass_index, spec.tile);
          grant.want_guides = true;
          grant.early_stop = true;
          if (pass.width != job.params.width || pass.height != job.params.height) {
            grant.film_width = pass.width;
            grant.film_height = pass.height;
          }
        } else if (job.prepass->final_pass_has_tables()) {
          absl::StatusOr<std::string> final_tables = job.prepass->final_tables(spec.tile);
          if (final_tables.ok()) {
            tables = std::optional<std::string>(*std::move(final_tables));
          } else {
            tables = final_tables.status();
          }
        }
        if (!tables.ok()) {
          // Cannot happen: a stage's tasks are handed out only once its tables exist.
          (void)scheduler_.fail(worker_id, lease->id, FailureClass::kInfrastructure,
                                std::string(tables.status().message()), now());
          continue;
        }
        grant.pdf_table = *std::move(tables);
        grant.table_cells = job.prepass->table_cells();
      }
      changed_locked();
      return std::optional<LeaseGrant>(std::move(grant));
    }
    const SteadyClock::time_point current = SteadyClock::now();
    if (current >= deadline) break;
    // Woken by any change; the short cap also covers leases requeued by tick().
    changed_.wait_until(lock, std::min(deadline, current + Millis(100)));
  }
  return std::optional<LeaseGrant>();
}

HeartbeatReply FarmCoordinator::heartbeat(const std::string& worker_id,
                                          const std::vector<std::string>& lease_ids) {
  std::lock_guard<std::mutex> lock(mutex_);
  HeartbeatReply reply = scheduler_.heartbeat(worker_id, lease_ids, now());
  if (scheduler_.knows_worker(worker_id)) (void)store_->touch_worker(worker_id, now().count());
  process_events_locked();
  return reply;
}

absl::StatusOr<CompleteResult> FarmCoordinator::complete(
    const std::string& worker_id, const std::string& lease_id, std::string bytes,
    const std::string& sha256, double render_seconds, std::uint64_t rays,
    const std::vector<std::pair<std::string, std::uint64_t>>& counters) {
  const SteadyClock::time_point started = SteadyClock::now();
  const std::uint64_t received = bytes.size();
  // Parsing is the expensive part and needs no state.
  absl::StatusOr<image::TileResult> parsed = image::parse_tile(bytes);
  std::unique_lock<std::mutex> lock(mutex_);
  const std::optional<Lease> lease = scheduler_.lease(lease_id);
  if (lease.has_value() && lease->worker_id == worker_id) {
    auto it = active_.find(lease->task.job_id);
    std::string problem;
    if (!parsed.ok()) {
      problem = std::string(parsed.status().message());
    } else if (!(parsed->rect() == lease->task.spec.tile) ||
               !(parsed->samples() == lease->task.spec.samples)) {
      problem = "the result's tile or sample range is not the task's";
    } else if (it != active_.end() && parsed->bins() != it->second->params.render.bins) {
      problem = absl::StrCat("the result has ", parsed->bins(), " bins, the job ",
                             it->second->params.render.bins);
    } else if (it != active_.end()) {
      // The buffers the task's stage merges: a prepass needs guides, a gradient job's final
      // pass its gradients. Refused here as the worker's fault, before they could fail the job.
      const bool prepass = lease->task.spec.pass == Pass::kPrepass;
      const bool gradient = it->second->params.render.integrator == job::IntegratorKind::kGradient;
      if (prepass && !parsed->has_guides()) {
        problem = "a prepass result without guide buffers";
      } else if (!prepass && !parsed->has_rgb()) {
        problem = "a final-pass result without RGB buffers (the RGB outputs need them)";
      } else if (!prepass && gradient && !parsed->has_gradients()) {
        problem = "a gradient job's result without gradients";
      } else if (!prepass && gradient &&
                 it->second->params.render.gradient_variances != parsed->has_halves()) {
        problem = parsed->has_halves()
                      ? "a gradient job's result with halves its reconstruction does not use"
                      : "a variance-weighted gradient job's result without halves";
      } else if (!prepass &&
                 it->second->params.render.splats_differentials() != parsed->has_filtered()) {
        problem = parsed->has_filtered()
                      ? "a result with filtered sums its job did not ask for"
                      : "a differential-splatting job's result without its filtered sums";
      } else if (!prepass && it->second->params.render.gathers() &&
                 !(parsed->has_offsets() && parsed->has_guides())) {
        problem = "a gathering job's result without its offsets and guides";
      }
    }
    if (!problem.empty()) {
      metrics_.result_not_merged("refused", received);
      const std::string message = absl::StrCat("result for lease ", lease_id, ": ", problem);
      PRISM_RETURN_IF_ERROR(
          scheduler_.fail(worker_id, lease_id, FailureClass::kWorker, message, now()));
      process_events_locked();
      return absl::InvalidArgumentError(message);
    }
  }
  // Stale leases are refused by the Scheduler before anything is stored.
  std::optional<CompleteReply> reply;
  store::ResultLocation location;
  if (!lease.has_value() || lease->worker_id != worker_id) {
    reply = scheduler_.complete(worker_id, lease_id, sha256, now());
  } else {
    // Write the bytes first, without the lock: into a range of the job's result pack (made
    // durable with the record, by the group commit below), or, for a job no longer active, the
    // blob store (synced at once). A lease that goes stale meanwhile leaves only unreferenced
    // bytes.
    auto it = active_.find(lease->task.job_id);
    std::shared_ptr<ResultPack> pack =
        it != active_.end() ? it->second->results : std::shared_ptr<ResultPack>();
    if (pack != nullptr) {
      location = {static_cast<std::int64_t>(pack->reserve(bytes.size())), bytes.size()};
    }
    lock.unlock();
    absl::Status stored = options_.disk_fault ? options_.disk_fault("result") : absl::OkStatus();
    if (stored.ok()) {
      stored = pack != nullptr ? pack->write(std::uint64_t(location.offset), bytes)
                               : blobs_->put_hashed(sha256, bytes);
    }
    if (pack != nullptr && stored.ok()) dirty_packs_.add(pack);
    lock.lock();
    if (!stored.ok()) {
      // The coordinator's fault (a full disk), not the worker's: the task goes back to the
      // queue at once as an infrastructure failure. Left to expire, the lease counted against
      // the worker, which was then blocked from the job after a few such results.
      metrics_.result_not_merged("unstored", received);
      // Whatever part of it reached the pack is freed (the range is never handed out again).
      if (pack != nullptr) (void)pack->release(std::uint64_t(location.offset), bytes.size());
      const std::string message =
          absl::StrCat("the coordinator could not store the result for lease ", lease_id, ": ",
                       stored.message(), "; the task goes back to the queue");
      options_.logger->error("[worker {}] {}", worker_id, message);
      last_unstored_ = std::string(stored.message());
      if (absl::Status failed = scheduler_.hold_back(worker_id, lease_id, now()); !failed.ok()) {
        options_.logger->warn("[worker {}] {}", worker_id, failed.ToString());
      }
      process_events_locked();
      changed_locked();
      return absl::UnavailableError(message);
    }
    reply = scheduler_.complete(worker_id, lease_id, sha256, now());
  }
  switch (reply->outcome) {
    case CompleteOutcome::kStale:
      metrics_.result_not_merged("stale", received);
      return absl::FailedPreconditionError(reply->reason);
    case CompleteOutcome::kDuplicate: {
      metrics_.result_not_merged("duplicate", received);
      // The first copy's record may not be durable yet (its own call is still waiting).
      const std::uint64_t ticket = commit_->last_ticket();
      lock.unlock();
      PRISM_RETURN_IF_ERROR(make_durable(ticket));
      return CompleteResult::kDuplicate;
    }
    case CompleteOutcome::kAccepted:
      break;
  }
  PRISM_CHECK(reply->task.has_value());
  const Task& task = *reply->task;
  ++tasks_completed_[worker_id];
  samples_completed_[worker_id] += std::uint64_t(task.spec.tile.area()) * task.spec.samples.count();
  absl::StatusOr<bool> marked = store_->mark_task_done(task.job_id, task.index, sha256, location);
  if (!marked.ok()) {
    fail_job_locked(task.job_id, absl::StrCat("cannot record task ", task.index, ": ",
                                              marked.status().message()));
    return marked.status();
  }
  auto it = active_.find(task.job_id);
  if (it != active_.end()) {
    ActiveJob& job = *it->second;
    const int stage = job.stage_of(task.index);
    const int tile = job.tile_of(task.index);
    const bool final_stage = stage >= job.first_final_stage();
    if (final_stage) {
      // The final pass's, as `prism render` reports them (the prepass has its own seconds).
      job.render_seconds += render_seconds;
      job.rays += rays;
      ActiveJob::WorkerShare& share = job.worker_shares[worker_id];
      ++share.tasks;
      share.samples += std::uint64_t(task.spec.tile.area()) * task.spec.samples.count();
      share.seconds += render_seconds;
      const SteadyClock::time_point now_steady = SteadyClock::now();
      const SteadyClock::time_point began =
          now_steady - std::chrono::duration_cast<SteadyClock::duration>(
                           std::chrono::duration<double>(std::max(0.0, render_seconds)));
      if (!job.final_begin.has_value() || began < *job.final_begin) job.final_begin = began;
      job.final_end = now_steady;
      for (const auto& [name, value] : counters) job.counters[name] += value;
      record_convergence_locked(
          task.job_id, job,
          job.track_convergence(
              *parsed,
              job.convergence_seconds_at_start +
                  std::chrono::duration<double>(SteadyClock::now() - job.started).count()));
    }
    // The upload checked the bytes against it: the assembler need not hash the result again.
    const std::optional<std::array<std::uint8_t, 32>> digest = base::sha256_digest_of_hex(sha256);
    const bool exact = !parsed->round_to_float32();  // what the assembler would do
    if (final_stage) job.note_final_result(tile, {location, digest, exact});
    TileAssembler& assembler =
        !final_stage ? *job.prepass_assemblers[static_cast<std::size_t>(stage)]
        : job.target.has_value()
            ? *job.round_assemblers[static_cast<std::size_t>(stage - job.first_final_stage())]
            : *job.assembler;
    absl::Status added = assembler.add(tile, *std::move(parsed), digest);
    if (!added.ok()) {
      fail_job_locked(task.job_id,
                      absl::StrCat("merging task ", task.index, ": ", added.message()));
      return added;
    }
    options_.logger->debug("[job {} task {}] accepted from {}", task.job_id, task.index, worker_id);
    reclaim_locked(task.job_id, job);
  }
  process_events_locked();
  changed_locked();
  const Millis granted = lease.has_value() ? lease->granted : now();
  const double lease_seconds = std::max(0.0, double((now() - granted).count()) / 1000.0);
  const std::uint64_t pixel_samples =
      std::uint64_t(task.spec.tile.area()) * task.spec.samples.count();
  // Group commit: the task's record was committed without a sync; the worker hears "accepted"
  // only once it is durable, and one sync serves every result acknowledged meanwhile.
  const std::uint64_t ticket = commit_->note_write();
  lock.unlock();
  PRISM_RETURN_IF_ERROR(make_durable(ticket));
  metrics_.task_completed(render_seconds, lease_seconds,
                          std::chrono::duration<double>(SteadyClock::now() - started).count(),
                          received, pixel_samples);
  return CompleteResult::kAccepted;
}

absl::Status FarmCoordinator::fail(const std::string& worker_id, const std::string& lease_id,
                                   FailureClass failure_class, const std::string& message) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_RETURN_IF_ERROR(scheduler_.fail(worker_id, lease_id, failure_class, message, now()));
  options_.logger->info("[worker {}] lease {} failed ({}): {}", worker_id, lease_id,
                        to_string(failure_class), message);
  process_events_locked();
  changed_locked();
  return absl::OkStatus();
}

absl::Status FarmCoordinator::leave(const std::string& worker_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_RETURN_IF_ERROR(store_->get_worker(worker_id).status());
  const int returned = scheduler_.remove_worker(worker_id, now());
  left_[worker_id] = now().count();
  // Kept in the store too, so that a restarted coordinator lists it as left, not lost.
  if (absl::Status kept = store_->mark_worker_left(worker_id, now().count()); !kept.ok()) {
    options_.logger->warn("[worker {}] {}", worker_id, kept.ToString());
  }
  options_.logger->info("[worker {}] left ({} {} returned)", worker_id, returned,
                        returned == 1 ? "lease" : "leases");
  process_events_locked();
  changed_locked();
  return absl::OkStatus();
}

absl::StatusOr<std::vector<WorkerStatus>> FarmCoordinator::workers() {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(std::vector<store::WorkerRecord> records, store_->list_workers());
  std::map<std::string, WorkerInfo> live;
  for (const WorkerInfo& info : scheduler_.workers()) live[info.id] = info;
  std::vector<WorkerStatus> out;
  for (const store::WorkerRecord& record : records) {
    WorkerStatus status;
    status.record = record;
    status.last_seen_ms = record.last_seen_ms;
    auto it = live.find(record.id);
    if (it == live.end()) {
      auto left = left_.find(record.id);
      if (left != left_.end()) {
        status.state = "left";
        status.last_seen_ms = left->second;
      } else if (record.left_ms > 0) {  // left before this coordinator started
        status.state = "left";
        status.last_seen_ms = record.left_ms;
      } else {
        status.state = "lost";
      }
    } else {
      status.leases = it->second.leases;
      status.current = it->second.current;
      status.state = it->second.leases > 0 ? "busy" : "idle";
      status.last_seen_ms = it->second.last_seen.count();
    }
    auto done = tasks_completed_.find(record.id);
    if (done != tasks_completed_.end()) status.tasks_completed = done->second;
    auto samples = samples_completed_.find(record.id);
    if (samples != samples_completed_.end()) status.samples_completed = samples->second;
    out.push_back(std::move(status));
  }
  return out;
}

void FarmCoordinator::forget_old_workers_locked() {
  const std::int64_t before =
      now().count() - std::chrono::duration_cast<Millis>(kForgetWorkersAfter).count();
  std::vector<std::string> live;
  for (const WorkerInfo& info : scheduler_.workers()) live.push_back(info.id);
  absl::StatusOr<int> forgotten = store_->forget_workers(before, live);
  if (!forgotten.ok()) {
    options_.logger->warn("forgetting old workers: {}", forgotten.status().ToString());
  } else if (*forgotten > 0) {
    options_.logger->info(
        "forgot {} worker(s) not seen for {} h", *forgotten,
        std::chrono::duration_cast<std::chrono::hours>(kForgetWorkersAfter).count());
  }
}

}  // namespace prism::coordinator
