// Property tests of the Scheduler: random interleavings of workers, faults, expiries and
// cancels keep every task of a surviving job accepted exactly once, deterministically.
#include <gtest/gtest.h>

#include <cstdint>
#include <map>
#include <optional>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "coordinator/scheduler.h"
#include "coordinator/scheduler_test_support.h"

namespace prism::coordinator {
namespace {

using namespace scheduler_testing;

// A simulated farm driven by a seeded random sequence of calls: workers acquire, complete
// (sometimes twice), fail with every class, go silent for a while (their leases expire or they
// are declared lost and re-register under a new id), and a job is sometimes cancelled. Then
// every worker behaves until all jobs end. Whatever the interleaving, every task of a job that
// did not fail or get cancelled is ACCEPTED exactly once, and no task is ever accepted twice.
struct FarmStats {
  int accepted = 0;
  int duplicates = 0;
  int stale = 0;
  int lost = 0;
  int expired_or_lost_attempts = 0;
  int done_jobs = 0;
  int failed_jobs = 0;
  int cancelled_jobs = 0;
  std::string transcript;
};

FarmStats simulate_farm(std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  auto chance = [&](int percent) { return static_cast<int>(rng() % 100) < percent; };
  SchedulerOptions options = test_options();
  options.max_attempts = 5;
  options.retry_preference = Millis{1500};
  Scheduler s(options);
  FarmStats stats;
  auto log = [&](const std::string& line) { stats.transcript += line + "\n"; };

  const std::vector<std::string> jobs = {"a", "b", "c", "d"};
  for (std::size_t j = 0; j < jobs.size(); ++j) {
    const int count = 10 + static_cast<int>(rng() % 21);
    std::vector<int> done;
    if (j == 1) done = {0, 3};
    EXPECT_TRUE(s.add_job(jobs[j], specs(count), done).ok());
  }
  std::map<std::pair<std::string, int>, int> accepted;
  // Fencing seen from outside: only the newest lease handed out for a task may be accepted.
  std::map<std::pair<std::string, int>, std::string> newest_lease;
  std::map<std::string, int> terminal_events;

  struct SimWorker {
    std::string id;
    std::vector<std::string> leases;
    Millis silent_until{0};
    Millis last_beat{0};
  };
  int next_worker = 0;
  std::vector<SimWorker> workers;
  auto add_worker = [&](Millis now) {
    SimWorker w;
    w.id = absl::StrCat("w", next_worker++);
    w.last_beat = now;
    s.register_worker(w.id, 1, now);
    workers.push_back(std::move(w));
  };
  Millis now{0};
  for (int i = 0; i < 4; ++i) add_worker(now);

  auto complete = [&](SimWorker& w, const std::string& lease_id) {
    auto info = s.lease(lease_id);
    const std::string hash = info ? hash_of(info->task) : "unknown";
    CompleteReply reply = s.complete(w.id, lease_id, hash, now);
    log(w.id + " complete " + lease_id + " " + to_string(reply.outcome));
    switch (reply.outcome) {
      case CompleteOutcome::kAccepted:
        ++stats.accepted;
        EXPECT_EQ((newest_lease[{reply.task->job_id, reply.task->index}]), lease_id);
        EXPECT_EQ((++accepted[{reply.task->job_id, reply.task->index}]), 1)
            << "task accepted twice, seed " << seed;
        break;
      case CompleteOutcome::kDuplicate:
        ++stats.duplicates;
        EXPECT_EQ((accepted[{reply.task->job_id, reply.task->index}]), 1);
        break;
      case CompleteOutcome::kStale:
        ++stats.stale;
        EXPECT_FALSE(reply.reason.empty());
        break;
    }
    return reply.outcome;
  };
  auto beat = [&](SimWorker& w) {
    HeartbeatReply reply = s.heartbeat(w.id, w.leases, now);
    w.last_beat = now;
    for (const Directive& d : reply.directives) {
      log(w.id + " directive " + to_string(d.kind) + " " + d.lease_id);
      if (d.kind == DirectiveKind::kCancelTask) std::erase(w.leases, d.lease_id);
      if (d.kind == DirectiveKind::kReregister) {
        w.leases.clear();
        w.id = absl::StrCat("w", next_worker++);
        s.register_worker(w.id, 1, now);
      }
    }
  };
  auto drain_events = [&] {
    for (const SchedulerEvent& e : s.take_events()) {
      log("event " + std::to_string(static_cast<int>(e.kind)) + " " + e.job_id + e.worker_id);
      if (e.kind == Kind::kWorkerLost) ++stats.lost;
      if (e.kind == Kind::kJobDone || e.kind == Kind::kJobFailed) ++terminal_events[e.job_id];
    }
  };

  for (int step = 0; step < 3000; ++step) {
    now += Millis{static_cast<std::int64_t>(rng() % 200)};
    SimWorker& w = workers[rng() % workers.size()];
    const bool silent = now < w.silent_until;
    const int action = static_cast<int>(rng() % 100);
    if (!silent && now - w.last_beat >= Millis{700}) {
      beat(w);
    } else if (action < 30) {
      if (silent) continue;
      if (auto lease = s.acquire(w.id, now)) {
        log(w.id + " acquire " + lease->id + " " + hash_of(lease->task) + " attempt " +
            std::to_string(lease->attempt));
        if (lease->attempt > 1) ++stats.expired_or_lost_attempts;
        newest_lease[{lease->task.job_id, lease->task.index}] = lease->id;
        w.leases.push_back(lease->id);
      }
    } else if (action < 60) {
      // Completing also happens while silent: a late result from a stalled worker.
      if (w.leases.empty()) continue;
      const std::size_t k = rng() % w.leases.size();
      const std::string lease_id = w.leases[k];
      w.leases.erase(w.leases.begin() + static_cast<std::ptrdiff_t>(k));
      complete(w, lease_id);
      if (chance(15)) complete(w, lease_id);  // the upload is retried
    } else if (action < 72) {
      if (silent || w.leases.empty()) continue;
      const std::size_t k = rng() % w.leases.size();
      const std::string lease_id = w.leases[k];
      w.leases.erase(w.leases.begin() + static_cast<std::ptrdiff_t>(k));
      const int pick = static_cast<int>(rng() % 100);
      const FailureClass failure_class = pick == 0   ? FailureClass::kScene
                                         : pick < 50 ? FailureClass::kWorker
                                         : pick < 75 ? FailureClass::kInfrastructure
                                                     : FailureClass::kReturned;
      absl::Status status = s.fail(w.id, lease_id, failure_class, "simulated", now);
      log(w.id + " fail " + lease_id + " " + to_string(failure_class) + " " +
          std::string(status.message()));
    } else if (action < 80) {
      s.tick(now);
    } else if (action < 83) {
      if (!silent) w.silent_until = now + Millis{static_cast<std::int64_t>(1000 + rng() % 5000)};
    } else if (action == 83 && chance(20)) {
      absl::Status status = s.cancel_job(jobs[rng() % jobs.size()]);
      log("cancel " + std::string(status.message()));
    }
    drain_events();
  }

  // Settle: everyone behaves, a fresh worker joins each round (so that a job whose workers are
  // all blocked still ends), until every job has ended.
  auto all_ended = [&] {
    for (const std::string& job : jobs)
      if (s.progress(job)->state == JobState::kRunning) return false;
    return true;
  };
  for (int round = 0; round < 200 && !all_ended(); ++round) {
    now += Millis{500};
    add_worker(now);
    s.tick(now);
    for (SimWorker& w : workers) {
      w.silent_until = Millis{0};
      beat(w);
      while (!w.leases.empty()) {
        const std::string lease_id = w.leases.back();
        w.leases.pop_back();
        complete(w, lease_id);
      }
      while (auto lease = s.acquire(w.id, now)) {
        log(w.id + " acquire " + lease->id);
        newest_lease[{lease->task.job_id, lease->task.index}] = lease->id;
        w.leases.push_back(lease->id);
      }
    }
    drain_events();
  }
  EXPECT_TRUE(all_ended()) << "seed " << seed;

  for (const std::string& job : jobs) {
    const JobProgress progress = *s.progress(job);
    log("job " + job + " " + to_string(progress.state) + " " + progress.message);
    const int resumed = job == "b" ? 2 : 0;
    switch (progress.state) {
      case JobState::kDone: {
        ++stats.done_jobs;
        EXPECT_EQ(progress.done, progress.total);
        EXPECT_EQ(terminal_events[job], 1) << job;
        for (int i = 0; i < progress.total; ++i) {
          const bool was_resumed = job == "b" && (i == 0 || i == 3);
          EXPECT_EQ((accepted[{job, i}]), was_resumed ? 0 : 1)
              << "job " << job << " task " << i << " seed " << seed;
        }
        int accepted_here = 0;
        for (const auto& [key, n] : accepted)
          if (key.first == job) accepted_here += n;
        EXPECT_EQ(accepted_here + resumed, progress.total);
        break;
      }
      case JobState::kFailed:
        ++stats.failed_jobs;
        EXPECT_FALSE(progress.message.empty());
        EXPECT_EQ(terminal_events[job], 1) << job;
        break;
      case JobState::kCancelled:
        ++stats.cancelled_jobs;
        EXPECT_EQ(terminal_events[job], 0) << job;
        break;
      case JobState::kRunning:
        ADD_FAILURE() << "job " << job << " still running, seed " << seed;
        break;
    }
    EXPECT_EQ(progress.leased, 0);
  }
  return stats;
}

TEST(SchedulerPropertyTest, RandomInterleavingsAcceptEveryTaskOfASurvivingJobExactlyOnce) {
  FarmStats total;
  for (std::uint64_t seed = 1; seed <= 40; ++seed) {
    FarmStats stats = simulate_farm(seed);
    total.accepted += stats.accepted;
    total.duplicates += stats.duplicates;
    total.stale += stats.stale;
    total.lost += stats.lost;
    total.expired_or_lost_attempts += stats.expired_or_lost_attempts;
    total.done_jobs += stats.done_jobs;
    total.failed_jobs += stats.failed_jobs;
    total.cancelled_jobs += stats.cancelled_jobs;
  }
  // The runs must exercise the paths the property is about, not only the happy one.
  EXPECT_GT(total.done_jobs, 40);
  EXPECT_GT(total.duplicates, 0);
  EXPECT_GT(total.stale, 0);
  EXPECT_GT(total.lost, 0);
  EXPECT_GT(total.expired_or_lost_attempts, 0);
  EXPECT_GT(total.failed_jobs, 0);
  EXPECT_GT(total.cancelled_jobs, 0);
  RecordProperty("accepted", total.accepted);
  RecordProperty("done_jobs", total.done_jobs);
  RecordProperty("failed_jobs", total.failed_jobs);
  RecordProperty("cancelled_jobs", total.cancelled_jobs);
  RecordProperty("duplicates", total.duplicates);
  RecordProperty("retried_leases", total.expired_or_lost_attempts);
  RecordProperty("stale", total.stale);
  RecordProperty("lost_workers", total.lost);
}

TEST(SchedulerPropertyTest, TheSameCallSequenceGivesTheSameOutcomes) {
  for (std::uint64_t seed : {3u, 17u}) {
    const FarmStats first = simulate_farm(seed);
    const FarmStats second = simulate_farm(seed);
    EXPECT_EQ(first.transcript, second.transcript);
    EXPECT_GT(first.transcript.size(), 1000u);
  }
}

}  // namespace
}  // namespace prism::coordinator
