// Helpers the Scheduler's tests share (scheduler_test.cpp, scheduler_property_test.cpp): the
// options, tasks and clock the tests use.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "coordinator/scheduler.h"

namespace prism::coordinator::scheduler_testing {

using Kind = SchedulerEvent::Kind;

inline constexpr Millis kInterval{1000};
inline constexpr Millis kLease{3000};
inline constexpr Millis kPreference{2000};

inline SchedulerOptions test_options() {
  SchedulerOptions options;
  options.heartbeat_interval = kInterval;
  options.lost_after_missed = 3;
  options.lease_duration = kLease;
  options.max_attempts = 4;
  options.block_after_faults = 3;
  options.retry_preference = kPreference;
  return options;
}

inline TaskSpec spec(int i) {
  return TaskSpec{.tile = {i * 8, 0, i * 8 + 8, 8}, .samples = {0, 16}};
}

inline std::vector<TaskSpec> specs(int n) {
  std::vector<TaskSpec> out;
  for (int i = 0; i < n; ++i) out.push_back(spec(i));
  return out;
}

inline Millis at(std::int64_t ms) {
  return Millis{ms};
}

inline std::string hash_of(const Task& task) {
  return task.job_id + "#" + std::to_string(task.index);
}

inline std::vector<SchedulerEvent> job_done(const std::string& job_id) {
  SchedulerEvent event;
  event.kind = Kind::kJobDone;
  event.job_id = job_id;
  return {event};
}

}  // namespace prism::coordinator::scheduler_testing
