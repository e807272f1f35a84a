// The worker daemon: registers with the coordinator, pulls one task at a time, renders it and
// streams the result back, heartbeating meanwhile. main() builds everything it depends on (the
// Embree device, the TBB arena, the spectrum library, the client, the logger) and passes it in.
//
// Per task: fetch the bundle by hash unless it is cached on disk, load the scene (named spectra
// checked against the library), turn the task's JobSpec into job::RenderOptions (job_spec.h), build
// the RenderScene at the film the task's pass renders (the job's resolution, or the smaller film
// of an image-scaled prepass; the last scene is kept for the next task of the same job and
// film), render the tile and sample range inside the arena, serialise it with the tile codec and
// upload it with the task's event counters. Final-pass tasks (index 0) and prepass tasks
// (index k >= 1: the hero tracer with 4 lanes, early stop when the task asks) are taken; a task
// may carry its tile's per-pixel pdf tables. A scene that cannot be loaded, a spec that does not
// validate and a scene that cannot be built fail the task as SCENE (the coordinator fails the
// job fast); anything else as WORKER (a task this worker cannot run, such as a pdf table that
// does not decode, or a tile outside its film), or INFRASTRUCTURE when the coordinator could not
// be reached for the bundle.
//
// Uploads are pipelined: a finished result goes to a bounded queue that an uploader thread sends
// from, while the next task is acquired and rendered; a full queue holds back the next render
// (WorkerConfig::uploads_in_flight). A result still queued when the process dies is simply lost:
// its lease expires and the task runs again, as for any crash.
//
// Heartbeats run on their own thread every heartbeat_interval_ms (from Register) and carry the
// held lease and those of the results waiting for or in upload (so their deadlines move on).
// Directives: CANCEL_TASK sets the render's cancel flag (it stops between pixels and the task is
// dropped without a result), DRAIN drains, REREGISTER registers again.
//
// Drain (like Seastar's gate): stop acquiring (an AcquireTask in flight is cancelled); a task in
// progress is finished if it completes within drain_timeout from the drain's start while its lease
// lasts (heartbeats go on renewing it; a lease the coordinator stops renewing ends the wait at its
// deadline), or, with no drain_timeout, before the lease deadline known when the drain began (less
// a margin for the upload in both cases); else it is cancelled and returned with
// FailTask(RETURNED); then the worker says Leave (it is listed as `left`, not `lost`) and run()
// returns OK. A drain therefore always ends within the timeout, or within one lease.
#pragma once

#include <spdlog/logger.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "absl/status/status.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "worker/daemon/bundle_cache.h"
#include "worker/daemon/worker_client.h"
#include "worker/embree_device.h"
#include "worker/render_scene.h"
#include "worker/tile_renderer.h"

namespace prism::worker {

struct WorkerConfig {
  std::string host;                       // reported at registration
  std::string version;                    // reported at registration
  int threads = 1;                        // the arena's concurrency, reported at registration
  std::filesystem::path cache_dir;        // bundles live in <cache_dir>/<hash>/
  std::uint32_t acquire_wait_ms = 5'000;  // AcquireTask long poll
  std::uint64_t max_bundle_bytes = std::uint64_t{4} << 30;
  // A draining worker gives up a task that would not finish this long before its deadline.
  std::chrono::milliseconds return_margin{500};
  // The longest a drain waits for the task in progress, its lease renewed meanwhile (0: up to the
  // lease's deadline when the drain began).
  std::chrono::milliseconds drain_timeout{0};
  // Pause after a failed Register or AcquireTask (past the client's own retries) before trying
  // again.
  std::chrono::milliseconds acquire_error_pause{1'000};
  // Finished results waiting for or in upload while the next task renders; 0: each result is
  // uploaded before the next task is acquired.
  int uploads_in_flight = 1;
};

class WorkerDaemon {
 public:
  // Everything passed by reference must outlive the daemon.
  WorkerDaemon(const WorkerConfig& config, WorkerClient& client, EmbreeDevice& device,
               const spectral::SpectrumLibrary& library, tbb::task_arena& arena,
               std::shared_ptr<spdlog::logger> logger);
  ~WorkerDaemon();
  WorkerDaemon(const WorkerDaemon&) = delete;
  WorkerDaemon& operator=(const WorkerDaemon&) = delete;

  // Registers (trying again while the coordinator is unreachable), then takes and renders tasks
  // until drained: OK after a drain. An error when the coordinator refuses the registration
  // (a wrong secret: UNAUTHENTICATED) or the acquisition of tasks.
  absl::Status run();

  // Starts a drain (see above). Thread-safe; not async-signal-safe (main forwards signals from
  // a thread of its own).
  void drain();

  std::string worker_id() const;

 private:
  enum class CancelReason { kNone, kDirective, kReturn };
  struct HeldLease {
    std::string lease_id;
    std::int64_t deadline_unix_ms = 0;
    std::atomic<bool> cancel{false};
    CancelReason reason = CancelReason::kNone;  // guarded by mutex_
    std::atomic<std::uint64_t> progress{0};
  };
  struct TaskFailure;
  struct CachedScene;
  // A rendered result for the uploader.
  struct Upload {
    std::string lease_id;
    std::string context;
    std::string bytes;
    TileStats stats;
  };

  absl::Status register_worker();
  void heartbeat_loop();
  void send_heartbeat();
  void process(const v1::Lease& lease);
  void upload(const Upload& result);
  void upload_loop();
  // Waits until every queued result has been uploaded.
  void flush_uploads();
  // Renders the lease's task into its canonical bytes and statistics; on failure, says how to
  // classify it.
  absl::Status execute(const v1::Lease& lease, HeldLease& held, const std::string& context,
                       std::string* bytes, TileStats* stats, v1::FailureClass* failure_class);
  absl::StatusOr<std::filesystem::path> ensure_bundle(const std::string& hash,
                                                      const std::string& context);
  void fail(const std::string& lease_id, v1::FailureClass failure_class, const std::string& message,
            const std::string& context);
  bool draining() const;

  WorkerConfig config_;
  WorkerClient& client_;
  EmbreeDevice& device_;
  const spectral::SpectrumLibrary& library_;
  tbb::task_arena& arena_;
  std::shared_ptr<spdlog::logger> logger_;
  BundleCache cache_;
  std::unique_ptr<CachedScene> scene_cache_;  // only touched by run()'s thread

  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::string worker_id_;
  std::chrono::milliseconds heartbeat_interval_{1'000};
  bool draining_ = false;
  // The drain's end for the held lease: the drain timeout's, or the lease's at the drain.
  std::optional<std::int64_t> drain_deadline_unix_ms_;
  bool stop_heartbeats_ = false;
  HeldLease* held_ = nullptr;   // the lease being worked on, owned by process()
  std::deque<Upload> uploads_;  // the front is in upload
  bool stop_uploads_ = false;
  std::condition_variable uploads_changed_;
  std::thread heartbeat_thread_;
  std::thread upload_thread_;
};

}  // namespace prism::worker
