#include "coordinator/farm_metrics.h"

#include <prometheus/counter.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>
#include <unistd.h>

#include <fstream>
#include <sstream>
#include <vector>

namespace prism::coordinator {
namespace {

using prometheus::Counter;
using prometheus::Gauge;
using prometheus::Histogram;

// Seconds, from 1 ms to 10 min: tasks run from milliseconds (small tiles) to minutes.
const Histogram::BucketBoundaries& seconds_buckets() {
  static const Histogram::BucketBoundaries buckets = {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05,
                                                      0.1,   0.25,   0.5,   1,    2.5,   5,
                                                      10,    30,     60,    120,  300,   600};
  return buckets;
}

const char* state_label(store::JobState state) {
  switch (state) {
    case store::JobState::kQueued:
      return "queued";
    case store::JobState::kPrepass:
      return "prepass";
    case store::JobState::kRendering:
      return "rendering";
    case store::JobState::kFinalising:
      return "finalising";
    case store::JobState::kDone:
      return "done";
    case store::JobState::kFailed:
      return "failed";
    case store::JobState::kCancelled:
      return "cancelled";
  }
  return "unknown";
}

constexpr store::JobState kJobStates[] = {store::JobState::kQueued,    store::JobState::kPrepass,
                                          store::JobState::kRendering, store::JobState::kFinalising,
                                          store::JobState::kDone,      store::JobState::kFailed,
                                          store::JobState::kCancelled};
constexpr const char* kWorkerStates[] = {"idle", "busy", "lost", "left"};
constexpr const char* kResultOutcomes[] = {"accepted", "duplicate", "stale", "refused", "unstored"};

void add_difference(Counter& counter, std::uint64_t now, std::uint64_t before) {
  if (now > before) counter.Increment(double(now - before));
}

}  // namespace

struct FarmMetrics::Families {
  std::map<store::JobState, Gauge*> jobs;
  Gauge* tasks_pending = nullptr;
  Gauge* tasks_leased = nullptr;
  Gauge* tasks_done = nullptr;
  std::map<std::string, Gauge*> workers;
  Gauge* samples_per_second = nullptr;
  Counter* samples = nullptr;
  Histogram* render_seconds = nullptr;
  Histogram* lease_seconds = nullptr;
  Histogram* merge_seconds = nullptr;
  Counter* result_bytes = nullptr;
  std::map<std::string, Counter*> results;
  Counter* leases_granted = nullptr;
  Counter* lease_expiries = nullptr;
  Counter* workers_lost = nullptr;
  Counter* retries_worker = nullptr;
  Counter* retries_infrastructure = nullptr;
  Counter* retries_returned = nullptr;
  Counter* released_results = nullptr;
  Counter* released_bytes = nullptr;
  Gauge* store_bytes = nullptr;
  Counter* cpu_seconds = nullptr;  // moved by the CPU time /proc reports since the last scrape
  Gauge* resident_bytes = nullptr;
  Gauge* start_time = nullptr;
};

FarmMetrics::FarmMetrics()
    : registry_(std::make_shared<prometheus::Registry>()), f_(std::make_unique<Families>()) {
  prometheus::Registry& r = *registry_;
  auto& jobs = prometheus::BuildGauge()
                   .Name("prism_jobs")
                   .Help("Jobs in the coordinator's store, by state")
                   .Register(r);
  for (store::JobState s : kJobStates) f_->jobs[s] = &jobs.Add({{"state", state_label(s)}});
  auto& tasks = prometheus::BuildGauge()
                    .Name("prism_tasks")
                    .Help("Tasks of the running jobs, by state (queued, leased, done)")
                    .Register(r);
  f_->tasks_pending = &tasks.Add({{"state", "queued"}});
  f_->tasks_leased = &tasks.Add({{"state", "leased"}});
  f_->tasks_done = &tasks.Add({{"state", "done"}});
  auto& workers = prometheus::BuildGauge()
                      .Name("prism_workers")
                      .Help("Registered workers, by state (idle, busy, lost, left)")
                      .Register(r);
  for (const char* s : kWorkerStates) f_->workers[s] = &workers.Add({{"state", s}});
  f_->samples_per_second = &prometheus::BuildGauge()
                                .Name("prism_samples_per_second")
                                .Help("Pixel samples per second, summed over the running jobs")
                                .Register(r)
                                .Add({});
  f_->samples = &prometheus::BuildCounter()
                     .Name("prism_samples_total")
                     .Help("Pixel samples in accepted task results")
                     .Register(r)
                     .Add({});
  f_->render_seconds = &prometheus::BuildHistogram()
                            .Name("prism_task_render_seconds")
                            .Help("Time a worker reports it spent rendering an accepted task")
                            .Register(r)
                            .Add({}, seconds_buckets());
  f_->lease_seconds = &prometheus::BuildHistogram()
                           .Name("prism_task_latency_seconds")
                           .Help("Time from a lease's grant to its result's acceptance")
                           .Register(r)
                           .Add({}, seconds_buckets());
  f_->merge_seconds =
      &prometheus::BuildHistogram()
           .Name("prism_result_merge_seconds")
           .Help("Coordinator time to check, store and merge an accepted task result")
           .Register(r)
           .Add({}, seconds_buckets());
  f_->result_bytes = &prometheus::BuildCounter()
                          .Name("prism_result_bytes_total")
                          .Help("Bytes of task results received from workers")
                          .Register(r)
                          .Add({});
  f_->released_results =
      &prometheus::BuildCounter()
           .Name("prism_results_released_total")
           .Help("Stored task results whose bytes were freed because their tile is stored merged")
           .Register(r)
           .Add({});
  f_->released_bytes = &prometheus::BuildCounter()
                            .Name("prism_result_bytes_released_total")
                            .Help("Bytes of stored task results freed: their tile is stored merged")
                            .Register(r)
                            .Add({});
  auto& results = prometheus::BuildCounter()
                      .Name("prism_results_total")
                      .Help("Task results received, by outcome")
                      .Register(r);
  for (const char* o : kResultOutcomes) f_->results[o] = &results.Add({{"outcome", o}});
  f_->leases_granted = &prometheus::BuildCounter()
                            .Name("prism_leases_granted_total")
                            .Help("Leases handed to workers")
                            .Register(r)
                            .Add({});
  f_->lease_expiries = &prometheus::BuildCounter()
                            .Name("prism_lease_expiries_total")
                            .Help("Leases that ran past their deadline")
                            .Register(r)
                            .Add({});
  f_->workers_lost = &prometheus::BuildCounter()
                          .Name("prism_workers_lost_total")
                          .Help("Workers declared lost after missed heartbeats")
                          .Register(r)
                          .Add({});
  auto& retries =
      prometheus::BuildCounter()
          .Name("prism_task_retries_total")
          .Help(
              "Tasks queued again after their lease ended, by reason (worker, infrastructure, "
              "returned)")
          .Register(r);
  f_->retries_worker = &retries.Add({{"reason", "worker"}});
  f_->retries_infrastructure = &retries.Add({{"reason", "infrastructure"}});
  f_->retries_returned = &retries.Add({{"reason", "returned"}});
  f_->store_bytes = &prometheus::BuildGauge()
                         .Name("prism_store_bytes")
                         .Help(
                             "Disk used under the coordinator's data directory (allocated blocks, "
                             "counted every 10 s)")
                         .Register(r)
                         .Add({});
  f_->cpu_seconds = &prometheus::BuildCounter()
                         .Name("process_cpu_seconds_total")
                         .Help("Total user and system CPU time spent in seconds")
                         .Register(r)
                         .Add({});
  f_->resident_bytes = &prometheus::BuildGauge()
                            .Name("process_resident_memory_bytes")
                            .Help("Resident memory size in bytes")
                            .Register(r)
                            .Add({});
  f_->start_time = &prometheus::BuildGauge()
                        .Name("process_start_time_seconds")
                        .Help("Start time of the process since unix epoch in seconds")
                        .Register(r)
                        .Add({});
}

FarmMetrics::~FarmMetrics() = default;

void FarmMetrics::task_completed(double render_seconds, double lease_seconds, double merge_seconds,
                                 std::uint64_t bytes, std::uint64_t samples) {
  f_->render_seconds->Observe(render_seconds);
  f_->lease_seconds->Observe(lease_seconds);
  f_->merge_seconds->Observe(merge_seconds);
  f_->result_bytes->Increment(double(bytes));
  f_->samples->Increment(double(samples));
  f_->results.at("accepted")->Increment();
}

void FarmMetrics::results_released(std::uint64_t count, std::uint64_t bytes) {
  f_->released_results->Increment(double(count));
  f_->released_bytes->Increment(double(bytes));
}

void FarmMetrics::result_not_merged(const std::string& outcome, std::uint64_t bytes) {
  f_->result_bytes->Increment(double(bytes));
  auto it = f_->results.find(outcome);
  if (it != f_->results.end()) it->second->Increment();
}

std::string FarmMetrics::text(const FarmSnapshot& snapshot) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto& [state, gauge] : f_->jobs) {
    auto it = snapshot.jobs.find(state);
    gauge->Set(it == snapshot.jobs.end() ? 0.0 : double(it->second));
  }
  f_->tasks_pending->Set(double(snapshot.tasks.pending));
  f_->tasks_leased->Set(double(snapshot.tasks.leased));
  f_->tasks_done->Set(double(snapshot.tasks.done));
  for (auto& [state, gauge] : f_->workers) {
    auto it = snapshot.workers.find(state);
    gauge->Set(it == snapshot.workers.end() ? 0.0 : double(it->second));
  }
  f_->samples_per_second->Set(snapshot.samples_per_second);
  const SchedulerCounters& c = snapshot.scheduler;
  add_difference(*f_->leases_granted, c.leases_granted, last_.leases_granted);
  add_difference(*f_->lease_expiries, c.lease_expiries, last_.lease_expiries);
  add_difference(*f_->workers_lost, c.workers_lost, last_.workers_lost);
  add_difference(*f_->retries_worker, c.retries_worker, last_.retries_worker);
  add_difference(*f_->retries_infrastructure, c.retries_infrastructure,
                 last_.retries_infrastructure);
  add_difference(*f_->retries_returned, c.retries_returned, last_.retries_returned);
  last_ = c;
  f_->store_bytes->Set(double(snapshot.store_bytes));
  const ProcessUsage usage = process_usage();
  if (usage.cpu_seconds > last_cpu_seconds_) {
    f_->cpu_seconds->Increment(usage.cpu_seconds - last_cpu_seconds_);
    last_cpu_seconds_ = usage.cpu_seconds;
  }
  f_->resident_bytes->Set(double(usage.resident_bytes));
  f_->start_time->Set(usage.start_time_seconds);
  return prometheus::TextSerializer().Serialize(registry_->Collect());
}

ProcessUsage process_usage() {
  ProcessUsage usage;
  const double ticks = double(::sysconf(_SC_CLK_TCK));
  const double page = double(::sysconf(_SC_PAGESIZE));
  // /proc/self/stat: the command name (field 2) is in parentheses and may hold spaces; the
  // fields after its closing parenthesis start at field 3 (state).
  std::ifstream stat("/proc/self/stat");
  std::string line;
  if (ticks > 0 && std::getline(stat, line)) {
    const std::size_t close = line.rfind(')');
    if (close != std::string::npos) {
      std::istringstream fields(line.substr(close + 1));
      std::vector<std::string> f;
      for (std::string field; fields >> field;) f.push_back(field);
      // Fields 14 and 15 (utime, stime) and 22 (starttime) are f[11], f[12] and f[19].
      if (f.size() > 19) {
        usage.cpu_seconds = (std::stod(f[11]) + std::stod(f[12])) / ticks;
        double boot = 0;
        std::ifstream proc_stat("/proc/stat");
        for (std::string l; std::getline(proc_stat, l);) {
          if (l.rfind("btime ", 0) == 0) boot = std::stod(l.substr(6));
        }
        usage.start_time_seconds = boot + std::stod(f[19]) / ticks;
      }
    }
  }
  std::ifstream statm("/proc/self/statm");
  std::uint64_t size = 0, resident = 0;
  if (page > 0 && statm >> size >> resident) usage.resident_bytes = std::uint64_t(resident * page);
  return usage;
}

}  // namespace prism::coordinator
