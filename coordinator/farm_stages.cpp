// FarmCoordinator's job stages (farm_coordinator.h): the Scheduler's events applied to the jobs,
// a finished stage handed on to the next (a prepass reconstructed, a target-error round ended),
// and a job failed. Every function here runs under the farm's mutex.
#include "absl/strings/str_cat.h"
#include "coordinator/farm_coordinator.h"
#include "services/base/status.h"

namespace prism::coordinator {

namespace fs = std::filesystem;
using SteadyClock = std::chrono::steady_clock;

absl::Status FarmCoordinator::advance_locked(const std::string& job_id) {
  auto it = active_.find(job_id);
  if (it == active_.end()) {
    return absl::InternalError(absl::StrCat("job ", job_id, " finished but is not active"));
  }
  ActiveJob& job = *it->second;
  auto finalise = [&]() -> absl::Status {
    absl::Status finalised = finalise_locked(job_id);
    if (finalised.ok()) return finalised;
    return absl::Status(finalised.code(),
                        absl::StrCat("cannot write the outputs: ", finalised.message()));
  };
  if (job.target.has_value() && job.stage >= job.first_final_stage()) {
    if (!job.target->finished()) PRISM_RETURN_IF_ERROR(job.finish_round());
    if (!job.target->finished()) {
      ++job.stage;
      return hand_round_locked(job, job_id);
    }
    // Done before its last planned round: the rounds left keep their task numbers, skipped.
    for (; job.stage < job.final_stage(); ++job.stage) {
      const std::size_t next = static_cast<std::size_t>(job.stage + 1);
      PRISM_ASSIGN_OR_RETURN(int first,
                             scheduler_.add_tasks(job_id, job.stage_specs(job.stage + 1), true));
      if (first != job.stage_first[next]) {
        return absl::InternalError(absl::StrCat("job ", job_id, ": skipped round starts at task ",
                                                first, ", the plan says ", job.stage_first[next]));
      }
      PRISM_RETURN_IF_ERROR(
          store_->skip_tasks(job_id, job.stage_first[next], job.stage_first[next + 1]));
    }
    return finalise();
  }
  if (job.stage == job.final_stage()) return finalise();
  const int k = job.stage + 1;
  PRISM_RETURN_IF_ERROR(job.prepass_assemblers[static_cast<std::size_t>(k - 1)]->check_complete());
  PRISM_RETURN_IF_ERROR(job.prepass->finish_pass(k));
  ++job.stage;
  // A prepass that stopped early leaves its later passes unrendered: they keep their task
  // numbers, skipped, so the final pass's tasks are numbered as planned.
  for (; job.prepass->finished() && job.stage < job.first_final_stage(); ++job.stage) {
    const std::size_t s = static_cast<std::size_t>(job.stage);
    PRISM_ASSIGN_OR_RETURN(int first,
                           scheduler_.add_tasks(job_id, job.stage_specs(job.stage), true));
    if (first != job.stage_first[s]) {
      return absl::InternalError(absl::StrCat("job ", job_id, ": skipped stage ", job.stage,
                                              " starts at task ", first, ", the plan says ",
                                              job.stage_first[s]));
    }
    PRISM_RETURN_IF_ERROR(store_->skip_tasks(job_id, job.stage_first[s], job.stage_first[s + 1]));
  }
  if (job.stage == job.first_final_stage()) {
    PRISM_RETURN_IF_ERROR(
        store_->set_job_state(job_id, store::JobState::kRendering, now().count()).status());
    job.prepass_seconds = std::chrono::duration<double>(SteadyClock::now() - job.started).count();
    const PrepassOutcome o = job.prepass->outcome();
    options_.logger->info(
        "[job {}] prepass done after {} of {} passes{}: predicted gain {:.1f} %, {:.1f} % of "
        "pixels on the default distribution",
        job_id, o.passes_run, job.prepass->passes(), o.stopped_early ? " (stopped early)" : "",
        100.0 * (o.stopped_early ? o.first_pass_gain : o.predicted_gain),
        100.0 * o.fallback_fraction);
  }
  PRISM_ASSIGN_OR_RETURN(int first, scheduler_.add_tasks(job_id, job.stage_specs(job.stage)));
  if (first != job.stage_first[static_cast<std::size_t>(job.stage)]) {
    return absl::InternalError(absl::StrCat("job ", job_id, ": stage ", job.stage,
                                            " starts at task ", first, ", the plan says ",
                                            job.stage_first[static_cast<std::size_t>(job.stage)]));
  }
  return absl::OkStatus();
}

absl::Status FarmCoordinator::hand_round_locked(ActiveJob& job, const std::string& job_id) {
  const int stage = job.stage;
  const std::size_t round = static_cast<std::size_t>(stage - job.first_final_stage());
  const std::vector<TaskSpec> specs = job.stage_specs(stage);
  const int per_tile = static_cast<int>(job.round_plans[round].ranges.size());
  for (std::size_t t = 0; t < job.round_plans[round].tiles.size(); ++t) {
    const int tile = static_cast<int>(t);
    const bool skipped = !job.target->active(tile);
    const auto [first, last] = job.tile_tasks(stage, tile);
    const std::vector<TaskSpec> part(specs.begin() + tile * per_tile,
                                     specs.begin() + (tile + 1) * per_tile);
    PRISM_ASSIGN_OR_RETURN(int added, scheduler_.add_tasks(job_id, part, skipped));
    if (added != first) {
      return absl::InternalError(absl::StrCat("job ", job_id, ": round ", round + 1, " tile ", tile,
                                              " starts at task ", added, ", the plan says ",
                                              first));
    }
    if (skipped) {
      PRISM_RETURN_IF_ERROR(store_->skip_tasks(job_id, first, last));
      PRISM_RETURN_IF_ERROR(job.round_assemblers[round]->mark_finished(tile));
    }
  }
  return absl::OkStatus();
}

void FarmCoordinator::process_events_locked() {
  for (const SchedulerEvent& event : scheduler_.take_events()) {
    switch (event.kind) {
      case SchedulerEvent::Kind::kJobDone: {
        absl::Status advanced = advance_locked(event.job_id);
        if (!advanced.ok()) {
          options_.logger->error("[job {}] cannot go on: {}", event.job_id, advanced.ToString());
          fail_job_locked(event.job_id, std::string(advanced.message()));
        }
        break;
      }
      case SchedulerEvent::Kind::kJobFailed:
        options_.logger->warn("[job {}] failed: {}", event.job_id, event.message);
        fail_job_locked(event.job_id, event.message);
        break;
      case SchedulerEvent::Kind::kWorkerLost:
        options_.logger->warn("[worker {}] lost: {}", event.worker_id, event.message);
        break;
    }
    changed_locked();
  }
}

void FarmCoordinator::fail_job_locked(const std::string& job_id, const std::string& message) {
  absl::StatusOr<store::JobRecord> failed =
      store_->set_job_state(job_id, store::JobState::kFailed, now().count(), message);
  if (!failed.ok()) {
    options_.logger->error("[job {}] cannot record the failure: {}", job_id,
                           failed.status().ToString());
  }
  active_.erase(job_id);
  (void)scheduler_.cancel_job(job_id);
  clean_up_locked(job_id);
  changed_locked();
}

}  // namespace prism::coordinator
