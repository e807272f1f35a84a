// What the monitoring side reads of the farm: the HTTP/JSON API's GET routes, /metrics, the
// dashboard's event stream and previews. One read-only interface, so a reader depends on what it
// may see and not on how the farm runs its jobs; FarmCoordinator implements it (each call takes
// the farm's lock briefly and returns copies). The status types here are the clients' view of
// jobs, workers and outputs.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "coordinator/convergence.h"
#include "coordinator/farm_metrics.h"
#include "coordinator/scheduler.h"
#include "services/store/job_store.h"

namespace prism::coordinator {

// A job as the clients see it.
struct JobStatus {
  store::JobRecord record;
  int tiles_finalised = 0;
  int tiles_total = 0;
  double samples_per_second = 0;
  double eta_seconds = -1;
  // Why a running job has tasks to render and no worker rendering them, when it is not a moment's
  // wait: no worker is connected, or every connected one is blocked from the job after repeated
  // failures of its tasks (with the last). Empty otherwise.
  std::string waiting;
};

struct WorkerStatus {
  store::WorkerRecord record;
  std::string state;  // idle, busy, lost, left
  int leases = 0;
  std::vector<Lease> current;  // the leases it holds now, oldest first
  std::uint64_t tasks_completed = 0;
  std::uint64_t samples_completed = 0;  // pixel samples of its accepted results
  std::int64_t last_seen_ms = 0;
};

enum class OutputKind {
  kSpectralExr = 1,
  kRgbExr = 2,
  kPng = 3,
  kReportJson = 4,
  kPrimalExr = 5,    // gradient jobs with primal_and_gradients
  kGradientExr = 6,  // likewise
  kFilteredExr = 7,  // jobs with differential splatting
  kFilteredPng = 8,  // likewise
};

struct OutputFile {
  OutputKind kind;
  std::filesystem::path path;
  std::string file_name;
};

// The final pass's tiles: queued, leased, done or failed (prism::v1::TileMap's characters).
struct TileMapStatus {
  int width = 0, height = 0, tile_size = 0, tiles_x = 0, tiles_y = 0;
  std::string states;  // one of q, l, d, f per tile in raster order
};

class FarmView {
 public:
  virtual ~FarmView() = default;

  // NOT_FOUND for an unknown job.
  virtual absl::StatusOr<JobStatus> job(const std::string& job_id) = 0;
  // The newest `limit` jobs (0: all) in the given states (empty: any).
  virtual absl::StatusOr<std::vector<JobStatus>> jobs(
      std::size_t limit, const std::vector<store::JobState>& states) = 0;
  // The output files of a DONE job (all kinds when `kinds` is empty). FAILED_PRECONDITION
  // naming the state otherwise.
  virtual absl::StatusOr<std::vector<OutputFile>> result_files(
      const std::string& job_id, const std::vector<OutputKind>& kinds) = 0;
  virtual absl::StatusOr<TileMapStatus> tile_map(const std::string& job_id) = 0;
  // The job's error estimate against time (convergence.h), one point per accepted final-pass
  // result; kept for the 256 newest jobs (empty for older ones and before the first result).
  virtual absl::StatusOr<std::vector<ConvergencePoint>> convergence(const std::string& job_id) = 0;
  // An 8-bit PNG of the image as far as it is finalised. FAILED_PRECONDITION before any tile.
  virtual absl::StatusOr<std::string> preview_png(const std::string& job_id,
                                                  float exposure_stops) = 0;
  virtual absl::StatusOr<std::vector<WorkerStatus>> workers() = 0;
  virtual bool has_bundle(const std::string& hash) const = 0;

  // The farm as it stands (jobs, tasks and workers by state, the Scheduler's totals, the data
  // directory's size), and the Prometheus exposition of it and of the events recorded so far
  // (farm_metrics.h).
  virtual absl::StatusOr<FarmSnapshot> snapshot() = 0;
  virtual absl::StatusOr<std::string> metrics_text() = 0;

  // A counter that moves on every change of any job's state or progress, and a wait for it to
  // move past `seen` (returns the new value; `seen` on timeout).
  virtual std::uint64_t change_counter() const = 0;
  virtual std::uint64_t wait_for_change(std::uint64_t seen, std::chrono::milliseconds timeout) = 0;
};

}  // namespace prism::coordinator
