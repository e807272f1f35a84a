#include "worker/daemon/worker_daemon.h"

#include <algorithm>
#include <optional>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "services/image/tile_codec.h"
#include "services/job/job_spec.h"
#include "services/scene/path_guard.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/pixel_tables.h"
#include "worker/tile_renderer.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

// "[lease L job J tile x0,y0-x1,y1 samples s0-s1]": the prefix of every log line about a task.
std::string lease_context(const v1::Lease& lease) {
  const v1::Task& t = lease.task();
  return absl::StrCat("[lease ", lease.lease_id(), " job ", t.job_id(), " tile ", t.tile().x0(),
                      ",", t.tile().y0(), "-", t.tile().x1(), ",", t.tile().y1(), " samples ",
                      t.samples().begin(), "-", t.samples().end(), "]");
}

// What a RenderScene is built from besides its RenderOptions (compared whole, every field): the
// bundle and scene, and the film, which is the task's (an image-scaled prepass renders the job's
// camera on a smaller one). The key once listed the options by hand and missed light-traced
// caustics, their share, splatting and gathering: a worker reused the previous job's scene and
// returned wrong bytes, or results its job could not take.
std::string scene_key(const std::string& hash, const job::JobParameters& p, int film_width,
                      int film_height) {
  return absl::StrCat(hash, "|", p.scene_path, "|", film_width, "x", film_height);
}

// A task as TileRenderer takes it, validated against its job: the pass, the film the pass
// renders, the tile and samples inside them, and the tile's decoded pdf tables.
struct TaskSetup {
  RenderTask render_task;  // tables unset: point them at `tables` where the setup stays put
  std::optional<spectral::PixelTables> tables;
  int film_width = 0;
  int film_height = 0;
};

// INVALID_ARGUMENT, saying what is wrong with the task, when it is not one this worker can run.
absl::StatusOr<TaskSetup> task_setup(const v1::Task& task, const job::JobParameters& p) {
  TaskSetup setup;
  RenderTask& rt = setup.render_task;
  if (task.pass() == v1::PASS_FINAL && task.pass_index() == 0) {
    rt.pass = 0;
  } else if (task.pass() == v1::PASS_PREPASS && task.pass_index() >= 1) {
    rt.pass = task.pass_index();
    rt.prepass = true;
    // Only a prepass may stop paths early (a final pass would be biased).
    rt.early_stop = task.early_stop_prepass();
  } else {
    return absl::InvalidArgumentError(
        absl::StrCat("a ", v1::Pass_Name(task.pass()), " task with pass index ", task.pass_index(),
                     ": want PASS_FINAL with index 0 or PASS_PREPASS with index >= 1"));
  }
  rt.want_guides = task.want_guides();

  // 0 x 0: the job's film; an image-scaled prepass names its own.
  const std::uint32_t fw = task.film_width(), fh = task.film_height();
  if ((fw == 0) != (fh == 0) || fw > std::uint32_t(image::kMaxImageSide) ||
      fh > std::uint32_t(image::kMaxImageSide)) {
    return absl::InvalidArgumentError(absl::StrCat("film ", fw, "x", fh, ": want both sides in 1..",
                                                   image::kMaxImageSide,
                                                   ", or both 0 for the job's resolution"));
  }
  setup.film_width = fw == 0 ? p.width : int(fw);
  setup.film_height = fh == 0 ? p.height : int(fh);

  const v1::TileRect& r = task.tile();
  if (r.x0() < 0 || r.y0() < 0 || r.x0() >= r.x1() || r.y0() >= r.y1() ||
      r.x1() > setup.film_width || r.y1() > setup.film_height) {
    return absl::InvalidArgumentError(absl::StrCat(
        "tile ", r.x0(), ",", r.y0(), "-", r.x1(), ",", r.y1(), " is empty or outside the ",
        setup.film_width, "x", setup.film_height, " film"));
  }
  rt.tile = {r.x0(), r.y0(), r.x1(), r.y1()};

  // A prepass has its own sample count: at most Ñ, the last prepass's (a job without prepass
  // parameters sending one is held to the job limit only).
  const std::uint64_t max_spp = !rt.prepass ? (p.target_error ? p.target_error->max_spp : p.spp)
                                            : (p.prepass ? p.prepass->spp : job::kMaxJobSpp);
  if (task.samples().begin() >= task.samples().end() || task.samples().end() > max_spp) {
    return absl::InvalidArgumentError(absl::StrCat("sample range ", task.samples().begin(), "-",
                                                   task.samples().end(), " is empty or beyond ",
                                                   max_spp, " spp"));
  }
  rt.samples = {task.samples().begin(), task.samples().end()};

  if (task.has_pdf_table()) {
    // One mass per bin of the job (pixel_tables.h).
    const v1::PdfTable& table = task.pdf_table();
    if (table.cells() != std::uint32_t(p.render.bins)) {
      return absl::InvalidArgumentError(
          absl::StrCat("the pdf table of tile ", r.x0(), ",", r.y0(), "-", r.x1(), ",", r.y1(),
                       " has ", table.cells(), " cells but the job has ", p.render.bins, " bins"));
    }
    const int cells = int(std::min<std::uint32_t>(
        table.cells(), std::uint32_t(spectral::WavelengthDistribution::kMaxCells) + 1));
    absl::StatusOr<spectral::PixelTables> decoded = spectral::PixelTables::decode(
        rt.tile.width(), rt.tile.height(), cells, table.quantised_cdf());
    if (!decoded.ok()) {
      return absl::InvalidArgumentError(absl::StrCat(
          "the pdf table of tile ", r.x0(), ",", r.y0(), "-", r.x1(), ",", r.y1(), " (",
          table.cells(), " cells) does not decode: ", decoded.status().message()));
    }
    setup.tables.emplace(std::move(*decoded));
  }
  return setup;
}

}  // namespace

struct WorkerDaemon::CachedScene {
  std::string description_key;  // bundle hash | scene path
  scene::LoadedScene loaded;
  std::string render_key;             // scene_key() of `render`
  job::RenderOptions render_options;  // what `render` was built with
  std::unique_ptr<RenderScene> render;
  // The description's geometry, from its first build: it depends on the shapes alone, so another
  // job, seed or pass on the same scene builds its RenderScene without building the BVH again.
  std::shared_ptr<const Geometry> geometry;
};

WorkerDaemon::WorkerDaemon(const WorkerConfig& config, WorkerClient& client, EmbreeDevice& device,
                           const spectral::SpectrumLibrary& library, tbb::task_arena& arena,
                           std::shared_ptr<spdlog::logger> logger)
    : config_(config),
      client_(client),
      device_(device),
      library_(library),
      arena_(arena),
      logger_(std::move(logger)),
      cache_(config.cache_dir, scene::BundleLimits{}),
      scene_cache_(std::make_unique<CachedScene>()) {}

WorkerDaemon::~WorkerDaemon() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_heartbeats_ = true;
    stop_uploads_ = true;
  }
  wake_.notify_all();
  uploads_changed_.notify_all();
  if (upload_thread_.joinable()) upload_thread_.join();
  if (heartbeat_thread_.joinable()) heartbeat_thread_.join();
}

std::string WorkerDaemon::worker_id() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return worker_id_;
}

bool WorkerDaemon::draining() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return draining_;
}

void WorkerDaemon::drain() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (draining_) return;
    draining_ = true;
    // With a drain timeout, the task has until then, as long as heartbeats keep its lease
    // (heartbeat_loop); without one, until the lease's deadline as it stands now. A lease
    // without a deadline (0) and no timeout is simply finished.
    if (held_ != nullptr && config_.drain_timeout.count() > 0) {
      drain_deadline_unix_ms_ =
          std::chrono::duration_cast<std::chrono::milliseconds>(
              std::chrono::system_clock::now().time_since_epoch() + config_.drain_timeout)
              .count();
    } else if (held_ != nullptr && held_->deadline_unix_ms > 0) {
      drain_deadline_unix_ms_ = held_->deadline_unix_ms;
    }
  }
  logger_->info("draining: no new tasks; finishing or returning the held lease");
  client_.cancel_acquire();
  wake_.notify_all();
}

absl::Status WorkerDaemon::register_worker() {
  v1::RegisterRequest request;
  request.set_host(config_.host);
  request.set_version(config_.version);
  request.set_threads(static_cast<std::uint32_t>(config_.threads));
  request.add_capabilities("integrator:uniform");
  request.add_capabilities("integrator:hero");
  request.add_capabilities("prepass");
  request.set_previous_worker_id(worker_id());
  PRISM_ASSIGN_OR_RETURN(v1::RegisterResponse response, client_.register_worker(request));
  std::lock_guard<std::mutex> lock(mutex_);
  worker_id_ = response.worker_id();
  // 0 means the coordinator has no preference; below 10 ms heartbeats would be all we do.
  const std::uint32_t interval_ms = response.heartbeat_interval_ms();
  heartbeat_interval_ = std::chrono::milliseconds(
      interval_ms == 0 ? 1'000 : std::max<std::uint32_t>(interval_ms, 10));
  logger_->info("registered as worker {} ({} threads, heartbeat every {} ms)", worker_id_,
                config_.threads, heartbeat_interval_.count());
  return absl::OkStatus();
}

absl::Status WorkerDaemon::run() {
  // A worker may start before its coordinator (or while it restarts, or while its disk is full
  // and it cannot record workers): keep trying while the coordinator is unreachable or fails on
  // its side, give up on what retrying cannot mend (a refused secret above all).
  for (;;) {
    absl::Status registered = register_worker();
    if (registered.ok()) break;
    const absl::StatusCode code = registered.code();
    if (code != absl::StatusCode::kUnavailable && code != absl::StatusCode::kDeadlineExceeded &&
        code != absl::StatusCode::kInternal && code != absl::StatusCode::kResourceExhausted &&
        code != absl::StatusCode::kAborted) {
      return registered;
    }
    logger_->warn("{}; trying again", std::string(registered.message()));
    std::unique_lock<std::mutex> lock(mutex_);
    if (wake_.wait_for(lock, config_.acquire_error_pause, [&] { return draining_; })) {
      logger_->info("drained before registering");
      return absl::OkStatus();
    }
  }
  heartbeat_thread_ = std::thread([this] { heartbeat_loop(); });
  if (config_.uploads_in_flight > 0) upload_thread_ = std::thread([this] { upload_loop(); });

  absl::Status result;
  while (!draining()) {
    v1::AcquireTaskRequest request;
    request.set_worker_id(worker_id());
    request.set_wait_ms(config_.acquire_wait_ms);
    absl::StatusOr<v1::AcquireTaskResponse> response = client_.acquire(request);
    if (!response.ok()) {
      if (draining()) break;
      const absl::StatusCode code = response.status().code();
      if (code == absl::StatusCode::kUnauthenticated ||
          code == absl::StatusCode::kPermissionDenied) {
        result = response.status();
        break;
      }
      logger_->warn("{}", std::string(response.status().message()));
      if (code == absl::StatusCode::kNotFound) {
        // The coordinator does not know this worker (it restarted): attach again.
        absl::Status registered = register_worker();
        if (!registered.ok()) logger_->warn("{}", std::string(registered.message()));
      }
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait_for(lock, config_.acquire_error_pause, [&] { return draining_; });
      continue;
    }
    if (!response->has_lease()) continue;
    process(response->lease());
  }

  // Reverse order of startup: the last results are sent, then heartbeats stop after the last
  // lease is settled.
  flush_uploads();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_uploads_ = true;
  }
  uploads_changed_.notify_all();
  if (upload_thread_.joinable()) upload_thread_.join();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_heartbeats_ = true;
  }
  wake_.notify_all();
  if (heartbeat_thread_.joinable()) heartbeat_thread_.join();
  if (result.ok()) {
    // Said once: a coordinator that cannot be reached lists the worker as lost instead.
    absl::Status left = client_.leave(worker_id());
    if (!left.ok()) logger_->warn("{}", std::string(left.message()));
    logger_->info("drained; worker {} stops", worker_id());
  }
  return result;
}

void WorkerDaemon::heartbeat_loop() {
  using Clock = std::chrono::system_clock;
  std::unique_lock<std::mutex> lock(mutex_);
  Clock::time_point next_beat = Clock::now() + heartbeat_interval_;
  while (!stop_heartbeats_) {
    Clock::time_point wake_at = next_beat;
    if (draining_ && held_ != nullptr && drain_deadline_unix_ms_.has_value()) {
      // The lease as heartbeats have renewed it also bounds a timed drain: past it the
      // coordinator gives the task to another worker anyway.
      std::int64_t deadline = *drain_deadline_unix_ms_;
      if (config_.drain_timeout.count() > 0 && held_->deadline_unix_ms > 0) {
        deadline = std::min(deadline, held_->deadline_unix_ms);
      }
      const Clock::time_point give_up =
          Clock::time_point(std::chrono::milliseconds(deadline)) - config_.return_margin;
      if (Clock::now() >= give_up) {
        if (held_->reason == CancelReason::kNone) {
          held_->reason = CancelReason::kReturn;
          held_->cancel.store(true);
          logger_->info("[lease {}] will not finish within its lease: returning it",
                        held_->lease_id);
        }
      } else {
        wake_at = std::min(wake_at, give_up);
      }
    }
    wake_.wait_until(lock, wake_at);
    if (stop_heartbeats_) break;
    if (Clock::now() < next_beat) continue;
    lock.unlock();
    send_heartbeat();
    lock.lock();
    next_beat = Clock::now() + heartbeat_interval_;
  }
}

void WorkerDaemon::send_heartbeat() {
  v1::HeartbeatRequest request;
  std::chrono::milliseconds interval;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    request.set_worker_id(worker_id_);
    if (held_ != nullptr) {
      request.add_lease_ids(held_->lease_id);
      request.set_samples_done(held_->progress.load());
    }
    for (const Upload& waiting : uploads_) request.add_lease_ids(waiting.lease_id);
    interval = heartbeat_interval_;
  }
  absl::StatusOr<v1::HeartbeatResponse> response =
      client_.heartbeat(request, std::max(interval, std::chrono::milliseconds(1'000)));
  if (!response.ok()) {
    logger_->warn("{}", std::string(response.status().message()));
    return;
  }
  bool reregister = false;
  bool drain_now = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (held_ != nullptr && response->lease_deadline_unix_ms() > 0) {
      held_->deadline_unix_ms = response->lease_deadline_unix_ms();
    }
    for (const v1::Directive& directive : response->directives()) {
      switch (directive.kind()) {
        case v1::Directive::KIND_CANCEL_TASK:
          if (held_ != nullptr && held_->lease_id == directive.lease_id()) {
            if (held_->reason == CancelReason::kNone) held_->reason = CancelReason::kDirective;
            held_->cancel.store(true);
            logger_->info("[lease {}] cancelled by the coordinator", directive.lease_id());
          }
          break;
        case v1::Directive::KIND_DRAIN:
          drain_now = true;
          break;
        case v1::Directive::KIND_REREGISTER:
          reregister = true;
          break;
        default:
          logger_->warn("ignoring unknown heartbeat directive {}",
                        static_cast<int>(directive.kind()));
      }
    }
  }
  if (drain_now) drain();
  if (reregister) {
    logger_->info("the coordinator asks this worker to register again");
    absl::Status status = register_worker();
    if (!status.ok()) logger_->warn("{}", std::string(status.message()));
  }
}

void WorkerDaemon::fail(const std::string& lease_id, v1::FailureClass failure_class,
                        const std::string& message, const std::string& context) {
  v1::FailTaskRequest request;
  request.set_worker_id(worker_id());
  request.set_lease_id(lease_id);
  request.set_failure_class(failure_class);
  request.set_message(message);
  logger_->info("{} failed ({}): {}", context, v1::FailureClass_Name(failure_class), message);
  absl::Status status = client_.fail_task(request);
  if (!status.ok()) logger_->warn("{} {}", context, std::string(status.message()));
}

void WorkerDaemon::process(const v1::Lease& lease) {
  const std::string context = lease_context(lease);
  HeldLease held;
  held.lease_id = lease.lease_id();
  held.deadline_unix_ms = lease.deadline_unix_ms();
  bool returned = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    held_ = &held;
    // A lease that arrived as the drain began goes straight back.
    returned = draining_;
  }
  logger_->debug("{} acquired (attempt {})", context, lease.attempt());

  std::string bytes;
  TileStats stats;
  v1::FailureClass failure_class = v1::FAILURE_CLASS_WORKER;
  absl::Status status = returned ? absl::CancelledError("draining")
                                 : execute(lease, held, context, &bytes, &stats, &failure_class);
  CancelReason reason;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    held_ = nullptr;
    reason = returned ? CancelReason::kReturn : held.reason;
    drain_deadline_unix_ms_.reset();
  }
  wake_.notify_all();

  if (status.ok()) {
    Upload result{lease.lease_id(), context, std::move(bytes), stats};
    if (config_.uploads_in_flight <= 0) {
      upload(result);
      return;
    }
    // The next task renders while this one uploads; a full queue waits for room first.
    std::unique_lock<std::mutex> lock(mutex_);
    uploads_changed_.wait(lock, [&] {
      return uploads_.size() < std::size_t(config_.uploads_in_flight) || stop_uploads_;
    });
    uploads_.push_back(std::move(result));
    uploads_changed_.notify_all();
    return;
  }
  if (status.code() == absl::StatusCode::kCancelled && reason != CancelReason::kNone) {
    if (reason == CancelReason::kReturn) {
      fail(lease.lease_id(), v1::FAILURE_CLASS_RETURNED, "the worker is draining", context);
    } else {
      logger_->info("{} dropped after a cancel directive", context);
    }
    return;
  }
  fail(lease.lease_id(), failure_class, std::string(status.message()), context);
}

void WorkerDaemon::upload(const Upload& result) {
  absl::StatusOr<v1::CompleteTaskResponse> response =
      client_.complete_task(worker_id(), result.lease_id, result.bytes, result.stats.seconds,
                            result.stats.counters.rays, counter_list(result.stats.counters));
  if (!response.ok()) {
    logger_->warn("{} {}", result.context, std::string(response.status().message()));
  } else {
    logger_->debug("{} completed: {} bytes in {:.3f} s{}", result.context, result.bytes.size(),
                   result.stats.seconds, response->accepted() ? "" : " (a duplicate)");
  }
}

void WorkerDaemon::upload_loop() {
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    uploads_changed_.wait(lock, [&] { return !uploads_.empty() || stop_uploads_; });
    if (uploads_.empty()) return;
    // The front stays queued while it uploads: heartbeats keep its lease alive.
    const Upload& front = uploads_.front();
    lock.unlock();
    upload(front);
    lock.lock();
    uploads_.pop_front();
    uploads_changed_.notify_all();
  }
}

void WorkerDaemon::flush_uploads() {
  std::unique_lock<std::mutex> lock(mutex_);
  uploads_changed_.wait(lock, [&] { return uploads_.empty() || !upload_thread_.joinable(); });
}

absl::StatusOr<fs::path> WorkerDaemon::ensure_bundle(const std::string& hash,
                                                     const std::string& context) {
  PRISM_ASSIGN_OR_RETURN(std::optional<fs::path> cached, cache_.find(hash));
  if (cached.has_value()) return *cached;
  logger_->info("{} fetching bundle {}", context, hash);
  PRISM_ASSIGN_OR_RETURN(std::string blob, client_.fetch_bundle(hash, config_.max_bundle_bytes));
  return cache_.install(hash, blob);
}

absl::Status WorkerDaemon::execute(const v1::Lease& lease, HeldLease& held,
                                   const std::string& context, std::string* bytes, TileStats* stats,
                                   v1::FailureClass* failure_class) {
  const v1::Task& task = lease.task();
  const std::string hash =
      lease.bundle_hash().empty() ? task.spec().bundle_hash() : lease.bundle_hash();
  if (!task.spec().bundle_hash().empty() && task.spec().bundle_hash() != hash) {
    *failure_class = v1::FAILURE_CLASS_WORKER;
    return absl::InvalidArgumentError(absl::StrCat(
        "the lease names bundle ", hash, " but its job spec names ", task.spec().bundle_hash()));
  }

  absl::StatusOr<fs::path> dir = ensure_bundle(hash, context);
  if (!dir.ok()) {
    const absl::StatusCode code = dir.status().code();
    *failure_class =
        code == absl::StatusCode::kUnavailable || code == absl::StatusCode::kDeadlineExceeded
            ? v1::FAILURE_CLASS_INFRASTRUCTURE
            : v1::FAILURE_CLASS_WORKER;
    return dir.status();
  }

  // Everything from here to a built RenderScene is the scene's (or the spec's) fault.
  *failure_class = v1::FAILURE_CLASS_SCENE;
  CachedScene& cached = *scene_cache_;
  const std::string description_key =
      absl::StrCat(hash, "|", task.spec().scene_path(), "|", task.spec().allow_unsupported());
  if (cached.description_key != description_key) {
    cached = CachedScene{};
    PRISM_ASSIGN_OR_RETURN(scene::PathGuard guard, scene::PathGuard::create(*dir));
    PRISM_ASSIGN_OR_RETURN(fs::path scene_file, guard.resolve(task.spec().scene_path()));
    scene::LoadOptions load = scene::with_library_names(library_);
    load.allow_unsupported = task.spec().allow_unsupported();
    PRISM_ASSIGN_OR_RETURN(cached.loaded, scene::load_scene(scene_file, load));
    cached.description_key = description_key;
  }
  PRISM_ASSIGN_OR_RETURN(job::JobParameters params,
                         job::job_parameters(task.spec(), cached.loaded.description));

  // The task itself comes from the coordinator: a task this worker cannot run is its own
  // failure, not the scene's.
  *failure_class = v1::FAILURE_CLASS_WORKER;
  PRISM_ASSIGN_OR_RETURN(TaskSetup setup, task_setup(task, params));

  *failure_class = v1::FAILURE_CLASS_SCENE;
  const std::string render_key = scene_key(hash, params, setup.film_width, setup.film_height);
  if (cached.render_key != render_key || !(cached.render_options == params.render) ||
      cached.render == nullptr) {
    cached.render.reset();
    cached.render_key.clear();
    PRISM_ASSIGN_OR_RETURN(
        cached.render,
        RenderScene::build(device_, cached.loaded.description, library_, params.render,
                           setup.film_width, setup.film_height, cached.geometry));
    cached.geometry = cached.render->shared_geometry();
    cached.render_key = render_key;
    cached.render_options = params.render;
    logger_->debug("{} built the render scene ({}x{}, {} bins)", context, setup.film_width,
                   setup.film_height, params.render.bins);
  }

  *failure_class = v1::FAILURE_CLASS_WORKER;
  if (setup.tables) setup.render_task.tables = &*setup.tables;
  const TileRenderer renderer(*cached.render);
  absl::StatusOr<image::TileResult> result = absl::UnknownError("not rendered");
  arena_.execute(
      [&] { result = renderer.render(setup.render_task, stats, &held.cancel, &held.progress); });
  PRISM_RETURN_IF_ERROR(result.status());
  *bytes = image::serialise_task_result(*std::move(result));
  return absl::OkStatus();
}

}  // namespace prism::worker
