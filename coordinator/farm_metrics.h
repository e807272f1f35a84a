// The coordinator's metrics in the Prometheus text exposition format (`GET /metrics` on the HTTP
// listener, coordinator/http/). Built on prometheus-cpp's core (Debian's prometheus-cpp-dev):
// its registry, counters, gauges and histograms, and its text serialiser; the HTTP side is ours.
//
// Two kinds of figures:
//  - events the FarmCoordinator records as they happen (task_completed, result_refused): counters
//    and histograms that only grow;
//  - the farm as it stands, read once per scrape from a FarmSnapshot: jobs, tasks and workers by
//    state, the running jobs' sample rate, the Scheduler's running totals (lease expiries,
//    retries), the data directory's size, and the process's own CPU time and resident memory.
//
// Every metric and label set exists from the start (zeros included), so a query never finds a
// series missing because nothing has happened yet. Names and units follow Prometheus's
// conventions (`_total` for counters, `_seconds`, `_bytes`; the standard `process_*` names).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "coordinator/scheduler.h"
#include "services/store/job_store.h"

namespace prometheus {
class Registry;
class Counter;
class Gauge;
class Histogram;
}  // namespace prometheus

namespace prism::coordinator {

// The farm as it stands (FarmCoordinator::snapshot).
struct FarmSnapshot {
  std::map<store::JobState, std::int64_t> jobs;  // states with no job may be absent
  TaskCounts tasks;                              // of the running jobs
  std::map<std::string, int> workers;            // by WorkerStatus::state
  double samples_per_second = 0;                 // summed over the running jobs
  SchedulerCounters scheduler;
  std::uint64_t store_bytes = 0;  // disk used by everything under the data directory
};

class FarmMetrics {
 public:
  FarmMetrics();
  ~FarmMetrics();
  FarmMetrics(const FarmMetrics&) = delete;
  FarmMetrics& operator=(const FarmMetrics&) = delete;

  // An accepted task result: what the worker says it spent rendering, the time from the lease's
  // grant to acceptance, the coordinator's own time to check, store and merge it, its bytes and
  // its pixel samples. Thread-safe.
  void task_completed(double render_seconds, double lease_seconds, double merge_seconds,
                      std::uint64_t bytes, std::uint64_t samples);
  // A result that was not merged: "duplicate", "stale" or "refused" (bytes that do not parse
  // or do not match the task). Thread-safe.
  void result_not_merged(const std::string& outcome, std::uint64_t bytes);
  // Stored task results whose bytes were released from a result pack: their tile is stored
  // merged (result_pack.h). Thread-safe.
  void results_released(std::uint64_t count, std::uint64_t bytes);

  // The whole exposition, the snapshot's figures and this process's included. Thread-safe.
  std::string text(const FarmSnapshot& snapshot);

 private:
  struct Families;
  std::shared_ptr<prometheus::Registry> registry_;
  std::unique_ptr<Families> f_;
  std::mutex mutex_;  // the snapshot's counters move by differences from the last scrape
  SchedulerCounters last_;
  double last_cpu_seconds_ = 0;
};

// This process's CPU time (user + system) in seconds and resident set in bytes, from /proc/self;
// zeros where /proc cannot be read.
struct ProcessUsage {
  double cpu_seconds = 0;
  std::uint64_t resident_bytes = 0;
  double start_time_seconds = 0;  // since the Unix epoch
};
ProcessUsage process_usage();

}  // namespace prism::coordinator
