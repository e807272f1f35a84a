// FarmCoordinator's restart (farm_coordinator.h): a job the store holds as queued or rendering is
// rebuilt from its spec and replayed from its stored results, in stage order, so that every
// decision taken before the restart (a prepass stopping early, the tiles a target-error round
// went on with) is taken again the same way. The final pass's replayed results also rebuild the
// convergence tracker, so the plot's error goes on from where it was.
#include <algorithm>

#include "absl/strings/str_cat.h"
#include "coordinator/farm_coordinator.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/tile_codec.h"
#include "services/scene/scene_loader.h"

namespace prism::coordinator {

// One job's replay: its stored tasks and the indices found done (handed to the scheduler as
// such).
struct FarmCoordinator::Replay {
  const std::string& job_id;
  ActiveJob& job;
  std::vector<store::TaskRecord> tasks;
  std::vector<int> done;
};

absl::Status FarmCoordinator::resume_locked(const store::JobRecord& record) {
  prism::v1::JobSpec spec;
  if (!spec.ParseFromString(record.spec)) {
    return absl::DataLossError("the stored job spec does not parse");
  }
  // The stored spec is explicit, so the scene's defaults are not needed to decode it; a prepass
  // needs the scene's emitter spectra, and the report its features.
  PRISM_ASSIGN_OR_RETURN(job::JobParameters params,
                         job::job_parameters(spec, scene::SceneDescription{}));
  PRISM_ASSIGN_OR_RETURN(
      scene::LoadedScene loaded,
      bundles_->load_scene(params.allow_unsupported, params.bundle_hash, params.scene_path));
  PRISM_ASSIGN_OR_RETURN(std::unique_ptr<ActiveJob> active,
                         ActiveJob::create(params, spec, loaded.description, library_, cmf_));
  // Admitted before the restart: counted, never refused now.
  const ResourcePlan plan = plan_farm_job(params);
  active->planned_memory = plan.memory_bytes();
  active->planned_disk = plan.disk_bytes();
  const std::vector<TaskSpec> specs = active->task_specs();
  PRISM_ASSIGN_OR_RETURN(std::vector<store::TaskRecord> tasks,
                         stored_tasks_locked(record, *active, specs));
  PRISM_RETURN_IF_ERROR(active->attach_tiles(tiles_dir(record.id)));
  open_convergence_locked(record.id, *active);

  Replay replay{record.id, *active, std::move(tasks), {}};
  PRISM_ASSIGN_OR_RETURN(int stage, replay_prepasses_locked(replay));
  if (stage == active->first_final_stage() && active->target.has_value()) {
    PRISM_ASSIGN_OR_RETURN(stage, replay_rounds_locked(replay));
  }
  active->stage = stage;
  if (stage == active->final_stage() && !active->target.has_value()) {
    PRISM_RETURN_IF_ERROR(restore_final_pass_locked(replay));
    reclaim_locked(record.id, *active);
  }
  active->samples_at_start = record.progress.samples_done;
  active->resumed = true;
  const std::vector<TaskSpec> handed(specs.begin(), specs.begin() + active->stage_first[stage + 1]);
  PRISM_RETURN_IF_ERROR(scheduler_.add_job(record.id, handed, replay.done));
  // QUEUED: stopped while the submission stored the tasks. PREPASS: stopped in the prepass,
  // which the replay may have finished.
  const store::JobState now_state =
      stage < active->first_final_stage() ? store::JobState::kPrepass : store::JobState::kRendering;
  if ((record.state == store::JobState::kQueued || record.state == store::JobState::kPrepass) &&
      record.state != now_state) {
    PRISM_RETURN_IF_ERROR(store_->set_job_state(record.id, now_state, now().count()).status());
  }
  options_.logger->info("[job {}] resumed at stage {} of {}: {} of {} tasks already done",
                        record.id, stage + 1, active->final_stage() + 1, replay.done.size(),
                        specs.size());
  active_[record.id] = std::move(active);
  return absl::OkStatus();
}

absl::StatusOr<std::vector<store::TaskRecord>> FarmCoordinator::stored_tasks_locked(
    const store::JobRecord& record, const ActiveJob& job, const std::vector<TaskSpec>& specs) {
  PRISM_ASSIGN_OR_RETURN(std::vector<store::TaskRecord> tasks, store_->tasks_of(record.id));
  if (record.state == store::JobState::kQueued && tasks.size() < specs.size()) {
    // The coordinator stopped while it stored the job's tasks (in parts): the rest are a pure
    // function of the plan, stored now.
    std::vector<store::TaskRecord> rest;
    for (std::size_t i = tasks.size(); i < specs.size(); ++i) {
      rest.push_back(job.task_record(specs, static_cast<int>(i)));
    }
    PRISM_RETURN_IF_ERROR(store_->add_tasks(record.id, rest));
    options_.logger->info("[job {}] stored the {} tasks its submission had not stored", record.id,
                          rest.size());
    PRISM_ASSIGN_OR_RETURN(tasks, store_->tasks_of(record.id));
  }
  if (tasks.size() != specs.size()) {
    return absl::DataLossError(
        absl::StrCat("the store has ", tasks.size(), " tasks but the plan has ", specs.size()));
  }
  for (const store::TaskRecord& task : tasks) {
    const TaskSpec& planned = specs[static_cast<std::size_t>(task.index)];
    if (!(task.rect == planned.tile) || !(task.samples == planned.samples)) {
      return absl::DataLossError(
          absl::StrCat("stored task ", task.index, " differs from the plan"));
    }
  }
  return tasks;
}

namespace {

// The stored result's SHA-256 (its bytes were read against it), which the live path gives the
// assemblers too.
std::optional<std::array<std::uint8_t, 32>> digest_of(const store::TaskRecord& task) {
  return base::sha256_digest_of_hex(task.result_hash);
}

}  // namespace

absl::StatusOr<std::optional<image::TileResult>> FarmCoordinator::stored_result_locked(
    Replay& replay, int index) {
  const store::TaskRecord& task = replay.tasks[static_cast<std::size_t>(index)];
  if (task.state != store::TaskState::kDone) return std::optional<image::TileResult>();
  // A done task's bytes can be lost to a power cut (its record reached the disk first; it was
  // never acknowledged): the task goes back to pending and runs again.
  absl::StatusOr<std::string> bytes = result_bytes(replay.job, task);
  if (absl::IsDataLoss(bytes.status()) || absl::IsNotFound(bytes.status())) {
    options_.logger->warn("[job {} task {}] {}; rendering it again", replay.job_id, task.index,
                          bytes.status().ToString());
    PRISM_RETURN_IF_ERROR(store_->reopen_task(replay.job_id, task.index));
    return std::optional<image::TileResult>();
  }
  PRISM_RETURN_IF_ERROR(bytes.status());
  PRISM_ASSIGN_OR_RETURN(image::TileResult result, image::parse_tile(*bytes));
  return std::optional<image::TileResult>(std::move(result));
}

absl::Status FarmCoordinator::skip_stages_locked(Replay& replay, int first, int last) {
  const ActiveJob& job = replay.job;
  for (int skipped = first; skipped <= last; ++skipped) {
    for (int i = job.stage_first[skipped]; i < job.stage_first[skipped + 1]; ++i) {
      replay.done.push_back(i);
    }
    PRISM_RETURN_IF_ERROR(
        store_->skip_tasks(replay.job_id, job.stage_first[skipped], job.stage_first[skipped + 1]));
  }
  return absl::OkStatus();
}

absl::StatusOr<int> FarmCoordinator::replay_prepasses_locked(Replay& replay) {
  ActiveJob& job = replay.job;
  const int first_final = job.first_final_stage();
  // Prepasses are replayed in order from their stored results (their reconstruction is a pure
  // function of them) up to the first that is not complete: that stage runs on.
  for (int stage = 0; stage < first_final; ++stage) {
    bool complete = true;
    TileAssembler& assembler = *job.prepass_assemblers[static_cast<std::size_t>(stage)];
    for (int i = job.stage_first[stage]; i < job.stage_first[stage + 1]; ++i) {
      PRISM_ASSIGN_OR_RETURN(std::optional<image::TileResult> result,
                             stored_result_locked(replay, i));
      if (!result.has_value()) {
        complete = false;
        continue;
      }
      PRISM_RETURN_IF_ERROR(assembler.add(job.tile_of(i), *std::move(result),
                                          digest_of(replay.tasks[static_cast<std::size_t>(i)])));
      replay.done.push_back(i);
    }
    if (!complete) return stage;
    PRISM_RETURN_IF_ERROR(job.prepass->finish_pass(stage + 1));
    if (job.prepass->finished() && stage + 1 < first_final) {
      // It stopped early (a pure function of the results, so as before the restart): the later
      // passes are skipped.
      PRISM_RETURN_IF_ERROR(skip_stages_locked(replay, stage + 1, first_final - 1));
      return first_final;
    }
  }
  return first_final;
}

absl::StatusOr<int> FarmCoordinator::replay_rounds_locked(Replay& replay) {
  ActiveJob& job = replay.job;
  const int final_stage = job.final_stage();
  // Rounds are replayed in order from their stored results, as the prepasses: the tracker's
  // decisions are a pure function of them, so the same tiles go on as before the restart. A tile
  // that was done has its round's tasks skipped (again, if the restart came between the decision
  // and the skip).
  TargetErrorTracker& tracker = *job.target;
  for (int stage = job.first_final_stage(); stage <= final_stage; ++stage) {
    const std::size_t round = static_cast<std::size_t>(stage - job.first_final_stage());
    TileAssembler& assembler = *job.round_assemblers[round];
    bool complete = true;
    for (std::size_t t = 0; t < job.plan.tiles.size(); ++t) {
      const int tile = static_cast<int>(t);
      const auto [first, last] = job.tile_tasks(stage, tile);
      if (!tracker.finished() && !tracker.active(tile)) {
        PRISM_RETURN_IF_ERROR(store_->skip_tasks(replay.job_id, first, last));
        PRISM_RETURN_IF_ERROR(assembler.mark_finished(tile));
        for (int i = first; i < last; ++i) replay.done.push_back(i);
        continue;
      }
      for (int i = first; i < last; ++i) {
        PRISM_ASSIGN_OR_RETURN(std::optional<image::TileResult> result,
                               stored_result_locked(replay, i));
        if (!result.has_value()) {
          complete = false;
          continue;
        }
        replay.job.track_convergence(*result, replay.job.convergence_seconds_at_start);
        PRISM_RETURN_IF_ERROR(assembler.add(tile, *std::move(result),
                                            digest_of(replay.tasks[static_cast<std::size_t>(i)])));
        replay.done.push_back(i);
      }
    }
    if (!complete) return stage;
    job.stage = stage;
    PRISM_RETURN_IF_ERROR(job.finish_round());
    if (tracker.finished()) {
      PRISM_RETURN_IF_ERROR(skip_stages_locked(replay, stage + 1, final_stage));
      return final_stage;
    }
  }
  return final_stage;
}

absl::Status FarmCoordinator::restore_final_pass_locked(Replay& replay) {
  ActiveJob& job = replay.job;
  // Tiles finished before the restart come back from the tile pack (their range results are
  // not read); a damaged record falls back to the range results, which are released only once
  // their tile's record is synced, so they are there unless the disk itself failed (then the
  // tasks render again).
  std::vector<bool> restored(job.plan.tiles.size(), false);
  for (std::size_t t = 0; t < restored.size(); ++t) {
    const int tile = static_cast<int>(t);
    if (!job.tiles->has(tile)) continue;
    absl::StatusOr<image::TileResult> merged = job.tiles->get(tile);
    absl::StatusOr<image::SpectralImage> finalised =
        merged.ok() ? job.finalise(*merged) : absl::StatusOr<image::SpectralImage>(merged.status());
    if (!finalised.ok()) {
      options_.logger->warn("[job {}] {}; merging its results again", replay.job_id,
                            finalised.status().ToString());
      continue;
    }
    PRISM_RETURN_IF_ERROR(job.assembler->mark_finished(tile));
    job.track_convergence(*merged, job.convergence_seconds_at_start);
    PRISM_RETURN_IF_ERROR(job.absorb_tile(tile, *merged, *finalised));
    restored[t] = true;
  }
  const int final_stage = job.final_stage();
  for (int i = job.stage_first[final_stage]; i < job.stage_first[final_stage + 1]; ++i) {
    const store::TaskRecord& task = replay.tasks[static_cast<std::size_t>(i)];
    if (task.state != store::TaskState::kDone) continue;
    const int tile = job.tile_of(i);
    const store::ResultLocation location{task.result_offset, task.result_size};
    if (restored[static_cast<std::size_t>(tile)]) {
      // Released before the restart, or not yet: releasing again is harmless. A linked tile's
      // range is the tile.
      if (location.offset >= 0 && !job.tiles->linked(tile)) job.reclaimable.push_back(location);
    } else {
      PRISM_ASSIGN_OR_RETURN(std::optional<image::TileResult> result,
                             stored_result_locked(replay, i));
      if (!result.has_value()) continue;
      const bool exact = !result->round_to_float32();
      job.note_final_result(tile, {location, digest_of(task), exact});
      job.track_convergence(*result, job.convergence_seconds_at_start);
      PRISM_RETURN_IF_ERROR(job.assembler->add(tile, *std::move(result), digest_of(task)));
    }
    replay.done.push_back(i);
  }
  return absl::OkStatus();
}

}  // namespace prism::coordinator
