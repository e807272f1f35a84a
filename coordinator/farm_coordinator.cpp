#include "coordinator/farm_coordinator.h"

#include <fcntl.h>
#include <spdlog/sinks/null_sink.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/check.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/tile_codec.h"
#include "services/job/job_spec.h"
#include "services/scene/scene_loader.h"

namespace prism::coordinator {
namespace {

namespace fs = std::filesystem;
using SteadyClock = std::chrono::steady_clock;

// The data directory's disk reserve (FarmCoordinator::keep_disk_reserve): room for the job
// store's journal to record a cancel on a full disk.
constexpr const char* kDiskReserveFile = "disk.reserve";
constexpr std::uintmax_t kDiskReserveBytes = std::uintmax_t{1} << 20;

Millis unix_now() {
  return std::chrono::duration_cast<Millis>(std::chrono::system_clock::now().time_since_epoch());
}

}  // namespace

FarmCoordinator::FarmCoordinator(FarmOptions options)
    : options_(std::move(options)),
      cmf_(spectral::ColorMatching::cie1931()),
      scheduler_(options_.scheduler) {}

absl::StatusOr<std::unique_ptr<FarmCoordinator>> FarmCoordinator::open(FarmOptions options) {
  if (options.data_dir.empty()) return absl::InvalidArgumentError("--data-dir is empty");
  if (!options.clock) options.clock = unix_now;
  if (options.logger == nullptr) {
    options.logger = std::make_shared<spdlog::logger>(
        "coordinator", std::make_shared<spdlog::sinks::null_sink_mt>());
  }
  if (options.tick_interval.count() <= 0) {
    return absl::InvalidArgumentError("the tick interval must be positive");
  }
  // A fresh lease prefix per incarnation: a worker reattaching with an old lease id can never
  // match a lease of this process.
  options.scheduler.lease_prefix = absl::StrCat("l", options.clock().count(), "-");
  std::unique_ptr<FarmCoordinator> farm(new FarmCoordinator(std::move(options)));
  PRISM_RETURN_IF_ERROR(farm->start());
  return farm;
}

absl::Status FarmCoordinator::start() {
  const fs::path& dir = options_.data_dir;
  for (const char* sub :
       {"blobs", "bundles", "convergence", "jobs", "scenes", "outputs", "tmp", "trash"}) {
    PRISM_RETURN_IF_ERROR(base::make_directories(dir / sub));
  }
  PRISM_ASSIGN_OR_RETURN(
      data_dir_lock_, base::FileLock::acquire(dir / "coordinator.lock",
                                              absl::StrCat("the data directory ", dir.string())));
  // Leftovers of an interrupted upload are never referenced.
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir / "tmp", ec))
    fs::remove_all(entry.path(), ec);
  // So are the temporaries of outputs being written when the process died (a kill during
  // finalising): the finalising runs again, under new names.
  for (const auto& job : fs::directory_iterator(dir / "outputs", ec)) {
    if (job.is_directory(ec)) base::remove_temporaries(job.path());
  }

  keep_disk_reserve();

  PRISM_ASSIGN_OR_RETURN(library_, spectral::SpectrumLibrary::load_builtin());
  memory_budget_ = options_.max_memory_bytes > 0
                       ? MemoryBudget{options_.max_memory_bytes, "--max-memory", false}
                       : machine_memory_budget();
  // A machine-derived budget is for the whole process; --max-memory is for the jobs alone.
  baseline_memory_ =
      options_.max_memory_bytes > 0 ? 0 : memory_in_use(memory_budget_.address_space);
  bundles_.emplace(dir, options_.max_bundle_bytes, library_, options_.logger);
  PRISM_ASSIGN_OR_RETURN(store::JobStore job_store, store::JobStore::open(dir / "jobs.sqlite"));
  store_.emplace(std::move(job_store));
  PRISM_ASSIGN_OR_RETURN(store::BlobStore blob_store, store::BlobStore::open(dir / "blobs"));
  blobs_.emplace(std::move(blob_store));
  // Result bytes first: a record made durable before its bytes would name a lost result.
  commit_ = std::make_unique<store::GroupCommit>([this]() -> absl::Status {
    PRISM_RETURN_IF_ERROR(dirty_packs_.sync());
    return store_->sync();
  });

  {
    std::lock_guard<std::mutex> lock(mutex_);
    PRISM_ASSIGN_OR_RETURN(std::vector<store::JobRecord> resume, store_->jobs_to_resume());
    for (const store::JobRecord& record : resume) {
      absl::Status resumed = resume_locked(record);
      if (!resumed.ok()) {
        options_.logger->error("[job {}] cannot resume: {}", record.id, resumed.ToString());
        fail_job_locked(record.id,
                        absl::StrCat("cannot resume after a restart: ", resumed.message()));
      }
    }
    if (!resume.empty()) options_.logger->info("resumed {} unfinished jobs", resume.size());
    // A job that ended just before a crash may have left its tiles and results behind.
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir / "jobs", ec)) {
      const std::string id = entry.path().filename().string();
      absl::StatusOr<store::JobRecord> record = store_->get_job(id);
      if (record.ok() && store::is_terminal(record->state)) clean_up_locked(id);
    }
    process_events_locked();
  }
  janitor_ = std::thread([this] { janitor_loop(); });
  finaliser_ = std::thread([this] { finaliser_loop(); });
  ticker_ = std::thread([this] { tick_loop(); });
  return absl::OkStatus();
}

FarmCoordinator::~FarmCoordinator() {
  shutdown();
}

void FarmCoordinator::shutdown() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
    changed_locked();
  }
  tick_wake_.notify_all();
  finaliser_wake_.notify_all();
  if (ticker_.joinable()) ticker_.join();
  if (finaliser_.joinable()) finaliser_.join();
  {
    std::lock_guard<std::mutex> lock(janitor_mutex_);
    janitor_stopping_ = true;
  }
  janitor_wake_.notify_all();
  if (janitor_.joinable()) janitor_.join();
}

void FarmCoordinator::tick_loop() {
  using Steady = std::chrono::steady_clock;
  std::unique_lock<std::mutex> lock(mutex_);
  Steady::time_point previous = Steady::now();
  Steady::time_point forgot;  // the last forget_old_workers_locked (none yet)
  while (!stopping_) {
    tick_wake_.wait_for(lock, options_.tick_interval, [&] { return stopping_; });
    if (stopping_) break;
    // Ticks come at most tick_interval apart unless the lock was held (by another call, or by
    // the last tick's own events, such as finalising a job) or the process was stopped for
    // longer: heartbeats queued behind it all that time, which must not count as silence.
    const Steady::time_point started = Steady::now();
    const Millis unheard =
        std::chrono::duration_cast<Millis>(started - previous) - options_.tick_interval;
    previous = started;
    if (unheard > options_.scheduler.heartbeat_interval) {
      options_.logger->warn(
          "the coordinator could not listen for {} ms; leases and workers' "
          "silence are not counted for that time",
          unheard.count());
      scheduler_.forgive(unheard);
    }
    scheduler_.tick(now());
    process_events_locked();
    requeue_due_finalises_locked();
    if (forgot == Steady::time_point() || started - forgot >= std::chrono::hours(1)) {
      forgot = started;
      forget_old_workers_locked();
    }
  }
}

void FarmCoordinator::changed_locked() {
  ++change_counter_;
  changed_.notify_all();
}

absl::Status FarmCoordinator::make_durable(std::uint64_t ticket) {
  absl::Status durable = commit_->wait(ticket);
  if (durable.ok()) return durable;
  options_.logger->error(
      "the job store cannot be synced; results are refused until the "
      "coordinator is restarted: {}",
      durable.ToString());
  return absl::UnavailableError(
      absl::StrCat("the coordinator cannot make results durable: ", durable.message()));
}

absl::StatusOr<std::string> FarmCoordinator::result_bytes(const ActiveJob& job,
                                                          const store::TaskRecord& task) {
  if (task.result_offset < 0) return blobs_->get(task.result_hash);
  PRISM_CHECK(job.results != nullptr);
  return job.results->read(std::uint64_t(task.result_offset), task.result_size, task.result_hash);
}

std::uint64_t FarmCoordinator::change_counter() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return change_counter_;
}

std::uint64_t FarmCoordinator::wait_for_change(std::uint64_t seen, Millis timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait_for(lock, timeout, [&] { return stopping_ || change_counter_ != seen; });
  return change_counter_;
}

fs::path FarmCoordinator::tiles_dir(const std::string& job_id) const {
  return options_.data_dir / "jobs" / job_id / "tiles";
}
// ---- bundles ----

absl::StatusOr<std::string> FarmCoordinator::upload_bundle(const std::string& claimed_hash,
                                                           std::string_view bytes) {
  return bundles_->upload(claimed_hash, bytes);
}

bool FarmCoordinator::has_bundle(const std::string& hash) const {
  return bundles_->has(hash);
}

absl::StatusOr<std::string> FarmCoordinator::bundle_bytes(const std::string& hash) const {
  return bundles_->bytes(hash);
}

// ---- jobs ----

absl::StatusOr<JobStatus> FarmCoordinator::submit(const prism::v1::JobSpec& spec,
                                                  const std::string& client_token) {
  std::unique_lock<std::mutex> lock(mutex_);
  // A client token names one request: sent again with it, the submission is a retry and finds
  // its job; with another request, it is a mistake that must not be answered with that job.
  const std::string request_hash = base::sha256_hex(job::request_identity(spec));
  auto same_request = [&](const store::JobRecord& job) -> absl::Status {
    if (job.request_hash.empty() || job.request_hash == request_hash) return absl::OkStatus();
    return absl::AlreadyExistsError(absl::StrCat(
        "client token '", client_token, "' belongs to job ", job.id,
        ", submitted with another request (scene, bundle or options differ); send that request "
        "again to find the job, or use a new token for a new job"));
  };
  if (!client_token.empty()) {
    // A failed or cancelled job gives its token up to this submission (JobStore::create_job).
    absl::StatusOr<store::JobRecord> known = store_->find_by_client_token(client_token);
    if (known.ok() && !store::gives_up_client_token(known->state)) {
      PRISM_RETURN_IF_ERROR(same_request(*known));
      return status_locked(*known);
    }
    if (!known.ok() && known.status().code() != absl::StatusCode::kNotFound) {
      return known.status();
    }
  }
  // Checked again after planning, which runs unlocked.
  auto check_queue = [this]() -> absl::Status {
    if (active_.size() < options_.max_queued_jobs) return absl::OkStatus();
    return absl::ResourceExhaustedError(absl::StrCat(
        "the coordinator already has ", active_.size(), " unfinished jobs (--max-queued-jobs ",
        options_.max_queued_jobs, "): try again later"));
  };
  PRISM_RETURN_IF_ERROR(check_queue());
  // Loading the scene and planning touch no shared state (the library is read-only once
  // started): other calls go on meanwhile.
  lock.unlock();
  if (!base::is_sha256_hex(spec.bundle_hash())) {
    return absl::InvalidArgumentError(absl::StrCat("bundle_hash '", spec.bundle_hash(),
                                                   "': want 64 lower case hex digits (SHA-256)"));
  }
  if (!has_bundle(spec.bundle_hash())) {
    return absl::FailedPreconditionError(
        absl::StrCat("bundle ", spec.bundle_hash(), " is not on the coordinator: upload it first"));
  }
  PRISM_ASSIGN_OR_RETURN(std::string bundle_scene, bundles_->scene_path(spec.bundle_hash()));
  if (spec.scene_path() != bundle_scene) {
    return absl::InvalidArgumentError(absl::StrCat(
        "scene_path '", spec.scene_path(), "' is not the bundle's scene '", bundle_scene, "'"));
  }
  PRISM_ASSIGN_OR_RETURN(
      scene::LoadedScene loaded,
      bundles_->load_scene(spec.allow_unsupported(), spec.bundle_hash(), bundle_scene));
  PRISM_ASSIGN_OR_RETURN(job::JobParameters params, job::job_parameters(spec, loaded.description));
  const prism::v1::JobSpec explicit_spec = to_proto(params);
  // Admission before the job's buffers exist: the plan's bytes stay reserved until the job is
  // active (then they are its own) or the submission fails.
  std::uint64_t memory = 0, disk = 0;
  lock.lock();
  PRISM_RETURN_IF_ERROR(admit_locked(params, &memory, &disk));
  lock.unlock();
  struct Reservation {
    FarmCoordinator* farm;
    std::unique_lock<std::mutex>* lock;
    std::uint64_t memory, disk;
    ~Reservation() {
      if (!lock->owns_lock()) lock->lock();
      farm->release_locked(memory, disk);
    }
  } reservation{this, &lock, memory, disk};
  PRISM_ASSIGN_OR_RETURN(
      std::unique_ptr<ActiveJob> active,
      ActiveJob::create(params, explicit_spec, loaded.description, library_, cmf_));
  active->planned_memory = memory;
  active->planned_disk = disk;

  store::JobRecord record;
  record.client_token = client_token;
  record.request_hash = request_hash;
  record.spec = explicit_spec.SerializeAsString();
  record.bundle_hash = params.bundle_hash;
  record.submitted_ms = now().count();
  const std::vector<TaskSpec> specs = active->task_specs();
  std::vector<store::TaskRecord> tasks(specs.size());
  for (std::size_t i = 0; i < specs.size(); ++i) {
    tasks[i] = active->task_record(specs, static_cast<int>(i));
  }
  lock.lock();
  PRISM_RETURN_IF_ERROR(check_queue());
  if (options_.before_store_job) options_.before_store_job();
  // The tasks go to the store in parts, the lock released between them: storing a job of
  // hundreds of thousands of tasks holds up heartbeats and leases for one part at a time. Until
  // the last part the job is QUEUED and unknown to the scheduler; a restart before then stores
  // the rest (resume_locked), a cancel meanwhile ends the submission.
  const std::span<const store::TaskRecord> all(tasks);
  const std::size_t part = std::max<std::size_t>(1, options_.tasks_per_store_part);
  const std::size_t first_part = std::min(all.size(), part);
  PRISM_ASSIGN_OR_RETURN(store::CreateJobResult created,
                         store_->create_job(record, all.first(first_part)));
  if (created.existed) {
    PRISM_RETURN_IF_ERROR(same_request(created.job));
    return status_locked(created.job);
  }
  const std::string id = created.job.id;
  SteadyClock::duration part_time{};
  for (std::size_t at = first_part; at < all.size(); at += part) {
    lock.unlock();
    if (options_.between_task_parts) PRISM_RETURN_IF_ERROR(options_.between_task_parts(id));
    // A mutex is no queue: relocked at once, it would go to this thread again while the calls
    // waiting for it stay asleep (measured: ListJobs waited 5 s for a 262,144-task job). A pause
    // of a quarter of a part's time (at least 1 ms) lets them in.
    std::this_thread::sleep_for(
        std::max<SteadyClock::duration>(std::chrono::milliseconds(1), part_time / 4));
    lock.lock();
    const SteadyClock::time_point part_start = SteadyClock::now();
    absl::Status added = store_->add_tasks(id, all.subspan(at, std::min(part, all.size() - at)),
                                           store::Database::Commit::kDeferred);
    if (!added.ok()) {
      absl::StatusOr<store::JobRecord> now_record = store_->get_job(id);
      if (now_record.ok() && !store::is_terminal(now_record->state)) {
        fail_job_locked(id, absl::StrCat("cannot store its tasks: ", added.message()));
      }
      return added;
    }
    part_time = SteadyClock::now() - part_start;
  }
  if (absl::Status attached = active->attach_tiles(tiles_dir(id)); !attached.ok()) {
    (void)store_->set_job_state(id, store::JobState::kFailed, now().count(),
                                absl::StrCat("cannot store its tiles: ", attached.message()));
    return attached;
  }
  open_convergence_locked(id, *active);
  // The first stage only: later stages need the tables their predecessor learns.
  PRISM_RETURN_IF_ERROR(scheduler_.add_job(id, active->stage_specs(0)));
  // A job with a prepass says so until its final pass begins (farm_stages.cpp).
  PRISM_ASSIGN_OR_RETURN(
      store::JobRecord rendering,
      store_->set_job_state(
          id,
          active->first_final_stage() > 0 ? store::JobState::kPrepass : store::JobState::kRendering,
          now().count()));
  active_[id] = std::move(active);
  options_.logger->info("[job {}] submitted: {}x{}, {} spp, {} bins, {}, {} tasks{}, bundle {}", id,
                        params.width, params.height, params.spp, params.render.bins,
                        job::name(params.render.integrator), specs.size(),
                        params.prepass.has_value() ? " (with a prepass)" : "", params.bundle_hash);
  process_events_locked();
  changed_locked();
  PRISM_ASSIGN_OR_RETURN(store::JobRecord now_record, store_->get_job(id));
  return status_locked(now_record);
}

absl::Status FarmCoordinator::admit_locked(const job::JobParameters& params, std::uint64_t* memory,
                                           std::uint64_t* disk) {
  const ResourcePlan plan = plan_farm_job(params);
  std::uint64_t planned_memory = reserved_memory_, planned_disk = reserved_disk_;
  for (const auto& [id, job] : active_) {
    planned_memory += job->planned_memory;
    planned_disk += job->planned_disk;
  }
  const std::string job = absl::StrCat("a job of ", params.width, "x", params.height, " with ",
                                       params.render.bins, " bins");
  const std::string advice =
      "use fewer bins or a smaller resolution, or wait for the farm's unfinished jobs";
  const std::uint64_t budget = memory_budget_.bytes;
  // Over what the coordinator holds with nothing else to do: waiting will not help.
  {
    const std::string alone = "use fewer bins or a smaller resolution";
    absl::Status never =
        check_memory(job, plan, baseline_memory_, budget, memory_budget_.source, alone);
    if (never.ok() && options_.max_disk_bytes > 0) {
      never = check_disk(job, plan, options_.max_disk_bytes,
                         absl::StrCat("--max-disk ", format_bytes(options_.max_disk_bytes)), alone);
    }
    if (!never.ok()) return permanent_refusal(never);
  }
  PRISM_RETURN_IF_ERROR(
      check_memory(job, plan, baseline_memory_ + planned_memory, budget,
                   absl::StrCat(memory_budget_.source, "; the unfinished jobs plan ",
                                format_bytes(planned_memory)),
                   advice));
  PRISM_ASSIGN_OR_RETURN(std::uint64_t free, options_.free_disk
                                                 ? options_.free_disk(options_.data_dir)
                                                 : free_disk_bytes(options_.data_dir));
  // The free space is shared with the unfinished jobs: what each still has to write (its plan
  // less what its directories hold now) is promised already. Checking each job against the free
  // space alone let twelve 10 MiB jobs onto a 20 MiB disk, and the last ones failed writing.
  std::uint64_t promised = reserved_disk_;
  for (const auto& [id, active] : active_) {
    const std::uint64_t written = directory_bytes(options_.data_dir / "jobs" / id) +
                                  directory_bytes(options_.data_dir / "outputs" / id);
    promised += active->planned_disk > written ? active->planned_disk - written : 0;
  }
  PRISM_RETURN_IF_ERROR(
      check_disk(job, plan, free > promised ? free - promised : 0,
                 absl::StrCat("free in ", options_.data_dir.string(), " (", format_bytes(free),
                              ") less what the unfinished jobs still plan to write (",
                              format_bytes(promised), ")"),
                 advice));
  if (options_.max_disk_bytes > 0) {
    const std::uint64_t left =
        options_.max_disk_bytes > planned_disk ? options_.max_disk_bytes - planned_disk : 0;
    PRISM_RETURN_IF_ERROR(
        check_disk(job, plan, left,
                   absl::StrCat("--max-disk ", format_bytes(options_.max_disk_bytes),
                                " less the unfinished jobs' ", format_bytes(planned_disk)),
                   advice));
  }
  *memory = plan.memory_bytes();
  *disk = plan.disk_bytes();
  reserved_memory_ += *memory;
  reserved_disk_ += *disk;
  return absl::OkStatus();
}

void FarmCoordinator::release_locked(std::uint64_t memory, std::uint64_t disk) {
  reserved_memory_ -= std::min(reserved_memory_, memory);
  reserved_disk_ -= std::min(reserved_disk_, disk);
}

JobStatus FarmCoordinator::status_locked(const store::JobRecord& record) {
  JobStatus status;
  status.record = record;
  auto it = active_.find(record.id);
  if (it != active_.end()) {
    const ActiveJob& job = *it->second;
    status.tiles_finalised = job.tiles_finalised;
    status.tiles_total = static_cast<int>(job.plan.tiles.size());
    const double seconds = std::chrono::duration<double>(SteadyClock::now() - job.started).count();
    const std::uint64_t fresh = record.progress.samples_done >= job.samples_at_start
                                    ? record.progress.samples_done - job.samples_at_start
                                    : 0;
    const std::optional<JobProgress> p = scheduler_.progress(record.id);
    const bool running = p.has_value() && p->state == JobState::kRunning;
    if (running && p->pending > 0 && p->leased == 0) {
      const std::vector<WorkerInfo> workers = scheduler_.workers();
      const bool all_blocked =
          !workers.empty() && std::all_of(workers.begin(), workers.end(), [&](const WorkerInfo& w) {
            return std::binary_search(p->blocked_workers.begin(), p->blocked_workers.end(), w.id);
          });
      if (workers.empty()) {
        status.waiting = "no worker is connected (start prism-worker --coordinator ADDRESS)";
      } else if (all_blocked) {
        status.waiting = absl::StrCat(
            "every connected worker (", workers.size(),
            ") is blocked from this job after repeated failures of its tasks; the last: ",
            p->last_fault);
      }
    }
    // Results the coordinator could not store, held back: the job is not moving, whether all of
    // its pending tasks wait so or a worker is still busy on one that will be refused too.
    if (status.waiting.empty() && running && p->held_back > 0) {
      status.waiting = absl::StrCat("the coordinator could not store ", p->held_back,
                                    " of its tasks' results (", last_unstored_,
                                    "); they go out again, further apart up to 30 s, until it can");
    }
    if (auto retry = finalise_retries_.find(record.id); retry != finalise_retries_.end()) {
      status.waiting = absl::StrCat("cannot write the outputs (", retry->second.problem,
                                    "): waiting for disk space, trying again every ",
                                    retry->second.delay.count() / 1000, " s");
    }
    // A job waiting (for a worker, for disk space) has no rate or time left to show: the mean
    // since it started said it would end soon while nothing moved.
    if (seconds > 0 && fresh > 0 && status.waiting.empty()) {
      status.samples_per_second = double(fresh) / seconds;
      status.eta_seconds = double(record.progress.samples_total - record.progress.samples_done) /
                           status.samples_per_second;
    }
  } else if (record.state == store::JobState::kCancelled ||
             record.state == store::JobState::kFailed) {
    // What it finished before it ended (its tasks stay in the store).
    absl::StatusOr<store::JobStore::TileCounts> tiles = store_->final_tile_counts(record.id);
    if (tiles.ok()) {
      status.tiles_finalised = static_cast<int>(tiles->done);
      status.tiles_total = static_cast<int>(tiles->total);
    }
  } else if (record.state == store::JobState::kDone) {
    // The stored spec is explicit (every field set), so its own numbers give the tile count.
    prism::v1::JobSpec spec;
    if (spec.ParseFromString(record.spec) && spec.tile_size() > 0) {
      const std::int64_t tile = spec.tile_size();
      status.tiles_total = static_cast<int>(((std::int64_t(spec.width()) + tile - 1) / tile) *
                                            ((std::int64_t(spec.height()) + tile - 1) / tile));
      status.tiles_finalised = status.tiles_total;
    }
    status.eta_seconds = 0;
  }
  return status;
}

absl::StatusOr<JobStatus> FarmCoordinator::job(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
  return status_locked(record);
}

absl::StatusOr<prism::v1::JobSpec> FarmCoordinator::job_spec(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
  prism::v1::JobSpec spec;
  if (!spec.ParseFromString(record.spec)) {
    return absl::DataLossError(absl::StrCat("job ", job_id, ": the stored spec does not parse"));
  }
  return spec;
}

absl::StatusOr<std::vector<JobStatus>> FarmCoordinator::jobs(
    std::size_t limit, const std::vector<store::JobState>& states) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(std::vector<store::JobRecord> records, store_->list_jobs(limit, states));
  std::vector<JobStatus> out;
  out.reserve(records.size());
  for (const store::JobRecord& record : records) out.push_back(status_locked(record));
  return out;
}

absl::StatusOr<FarmSnapshot> FarmCoordinator::snapshot() {
  FarmSnapshot snapshot;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    PRISM_ASSIGN_OR_RETURN(snapshot.jobs, store_->count_jobs_by_state());
    snapshot.tasks = scheduler_.task_counts();
    snapshot.scheduler = scheduler_.counters();
    // The running jobs' progress in one query, not one per job under the lock.
    const store::JobState running[] = {store::JobState::kQueued, store::JobState::kPrepass,
                                       store::JobState::kRendering, store::JobState::kFinalising};
    PRISM_ASSIGN_OR_RETURN(std::vector<store::JobRecord> records, store_->list_jobs(0, running));
    for (const store::JobRecord& record : records) {
      if (active_.contains(record.id)) {
        snapshot.samples_per_second += status_locked(record).samples_per_second;
      }
    }
  }
  PRISM_ASSIGN_OR_RETURN(std::vector<WorkerStatus> workers, this->workers());
  for (const WorkerStatus& w : workers) ++snapshot.workers[w.state];
  snapshot.store_bytes = data_dir_bytes_.load(std::memory_order_relaxed);
  return snapshot;
}

absl::StatusOr<std::string> FarmCoordinator::metrics_text() {
  PRISM_ASSIGN_OR_RETURN(FarmSnapshot snapshot, this->snapshot());
  return metrics_.text(snapshot);
}

absl::StatusOr<JobStatus> FarmCoordinator::cancel(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  PRISM_ASSIGN_OR_RETURN(store::JobRecord record, store_->get_job(job_id));
  if (record.state == store::JobState::kCancelled) return status_locked(record);
  if (store::is_terminal(record.state)) {
    return absl::FailedPreconditionError(
        absl::StrCat("job ", job_id, " is already ", store::to_string(record.state)));
  }
  // The store first: when it cannot be written (a full disk) the cancel fails with nothing
  // changed. The scheduler cancelled first had stopped handing out the job's tasks while the
  // store and the job list still said it was rendering, until a restart.
  auto record_cancel = [&]() -> absl::StatusOr<store::JobRecord> {
    const absl::Status fault =
        options_.disk_fault ? options_.disk_fault("cancel") : absl::OkStatus();
    if (!fault.ok()) return fault;
    return store_->set_job_state(job_id, store::JobState::kCancelled, now().count(),
                                 "cancelled by a client");
  };
  absl::StatusOr<store::JobRecord> stored = record_cancel();
  bool released = false;
  if (!stored.ok() && release_disk_reserve()) {
    // A full disk: the reserve makes room for the store's write, and the cancel's clean-up
    // gives the space back.
    released = true;
    options_.logger->warn("[job {}] cancel: {}; released the disk reserve to record it", job_id,
                          stored.status().ToString());
    stored = record_cancel();
  }
  if (!stored.ok()) {
    return absl::Status(stored.status().code(),
                        absl::StrCat("cannot cancel job ", job_id, ": ", stored.status().message(),
                                     "; the job goes on as it was"));
  }
  const store::JobState before = record.state;
  record = *std::move(stored);
  if (before == store::JobState::kFinalising) {
    // Every task is done and the finaliser is writing the outputs: they are dropped when it
    // finishes (finish_finalise_locked).
    (void)scheduler_.remove_job(job_id);
  } else if (absl::Status cancelled = scheduler_.cancel_job(job_id);
             !cancelled.ok() && cancelled.code() != absl::StatusCode::kNotFound) {
    options_.logger->warn("[job {}] {}", job_id, cancelled.ToString());
  }
  // The Scheduler keeps the cancelled job so that heartbeats listing its leases get CANCEL_TASK.
  active_.erase(job_id);
  clean_up_locked(job_id);
  options_.logger->info("[job {}] cancelled", job_id);
  changed_locked();
  return status_locked(record);
}

void FarmCoordinator::keep_disk_reserve() const {
  const fs::path path = options_.data_dir / kDiskReserveFile;
  std::error_code ec;
  if (fs::file_size(path, ec) == kDiskReserveBytes) return;
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC, 0600);
  if (fd < 0) return;
  // Blocks really allocated (not a sparse file), or none: a reserve that a full disk cut short
  // is removed and made again later.
  const int error = ::posix_fallocate(fd, 0, off_t(kDiskReserveBytes));
  ::close(fd);
  if (error != 0) {
    fs::remove(path, ec);
    // Once per stretch without it: the janitor tries again at every round.
    if (!disk_reserve_missing_.exchange(true)) {
      options_.logger->warn("cannot keep a disk reserve of {} in {}: {}",
                            format_bytes(kDiskReserveBytes), options_.data_dir.string(),
                            std::strerror(error));
    }
    return;
  }
  disk_reserve_missing_ = false;
}

bool FarmCoordinator::release_disk_reserve() const {
  std::error_code ec;
  return fs::remove(options_.data_dir / kDiskReserveFile, ec);
}

}  // namespace prism::coordinator
