#include "coordinator/scheduler.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <map>
#include <optional>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "coordinator/scheduler_test_support.h"

namespace prism::coordinator {
namespace {

using namespace scheduler_testing;

TEST(SchedulerTest, LeasesCarryUniqueIdsAttemptDeadlineAndTask) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(3)).ok());
  s.register_worker("w", 4, at(0));
  std::vector<std::string> ids;
  for (int i = 0; i < 3; ++i) {
    auto lease = s.acquire("w", at(100 * i));
    ASSERT_TRUE(lease.has_value());
    EXPECT_EQ(lease->attempt, 1);
    EXPECT_EQ(lease->deadline, at(100 * i) + kLease);
    EXPECT_EQ(lease->worker_id, "w");
    EXPECT_EQ(lease->task, (Task{.job_id = "j", .index = i, .spec = spec(i)}));
    ids.push_back(lease->id);
  }
  EXPECT_EQ(ids, (std::vector<std::string>{"l-1", "l-2", "l-3"}));
  EXPECT_FALSE(s.acquire("w", at(400)).has_value());
  auto progress = s.progress("j");
  ASSERT_TRUE(progress.has_value());
  EXPECT_EQ(progress->leased, 3);
  EXPECT_EQ(progress->pending, 0);
  // Ids are never reused, also after a lease ended and its task was leased again.
  ASSERT_TRUE(s.fail("w", "l-2", FailureClass::kInfrastructure, "disk full", at(500)).ok());
  auto again = s.acquire("w", at(600));
  ASSERT_TRUE(again.has_value());
  EXPECT_EQ(again->id, "l-4");
  EXPECT_EQ(again->task.index, 1);
}

TEST(SchedulerTest, ServesJobsInSubmissionOrderAndRequeuedTasksFirst) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("b-first", specs(2)).ok());
  ASSERT_TRUE(s.add_job("a-second", specs(2)).ok());
  s.register_worker("w", 1, at(0));
  std::vector<std::pair<std::string, int>> order;
  std::vector<std::string> leases;
  for (int i = 0; i < 3; ++i) {
    auto lease = s.acquire("w", at(0));
    ASSERT_TRUE(lease.has_value());
    order.emplace_back(lease->task.job_id, lease->task.index);
    leases.push_back(lease->id);
  }
  EXPECT_EQ(order, (std::vector<std::pair<std::string, int>>{
                       {"b-first", 0}, {"b-first", 1}, {"a-second", 0}}));
  // A requeued task of the older job goes before the younger job's pending task.
  ASSERT_TRUE(s.fail("w", leases[0], FailureClass::kInfrastructure, "network", at(10)).ok());
  auto lease = s.acquire("w", at(20));
  ASSERT_TRUE(lease.has_value());
  EXPECT_EQ(lease->task.job_id, "b-first");
  EXPECT_EQ(lease->task.index, 0);
  EXPECT_EQ(lease->attempt, 1) << "an infrastructure failure is a free retry";
  lease = s.acquire("w", at(30));
  ASSERT_TRUE(lease.has_value());
  EXPECT_EQ(lease->task.job_id, "a-second");
  EXPECT_EQ(lease->task.index, 1);
}

TEST(SchedulerTest, HeartbeatsExtendLeasesPastTheirFirstDeadline) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  s.register_worker("w", 1, at(0));
  auto lease = s.acquire("w", at(0));
  ASSERT_TRUE(lease.has_value());
  for (std::int64_t t = 1000; t <= 10000; t += 1000) {
    HeartbeatReply reply = s.heartbeat("w", {lease->id}, at(t));
    EXPECT_TRUE(reply.directives.empty());
    ASSERT_TRUE(reply.lease_deadline.has_value());
    EXPECT_EQ(*reply.lease_deadline, at(t) + kLease);
    s.tick(at(t + 500));
  }
  EXPECT_EQ(s.lease(lease->id)->deadline, at(13000));
  EXPECT_EQ(s.complete("w", lease->id, "h", at(10500)).outcome, CompleteOutcome::kAccepted);
  EXPECT_EQ(s.take_events(), job_done("j"));
}

TEST(SchedulerTest, ExpiredLeaseIsRequeuedItsLateResultStaleAndTheNewOneAccepted) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  s.register_worker("w2", 1, at(0));
  auto first = s.acquire("w1", at(0));
  ASSERT_TRUE(first.has_value());
  // w1 keeps heartbeating but stops listing its lease (a hung render thread).
  s.heartbeat("w1", {}, at(2000));
  s.heartbeat("w2", {}, at(2000));
  s.tick(at(3000));
  EXPECT_TRUE(s.lease(first->id).has_value());
  EXPECT_EQ(s.progress("j")->leased, 1) << "a lease is current up to its deadline";
  s.tick(at(3001));
  EXPECT_EQ(s.progress("j")->leased, 0);
  EXPECT_EQ(s.progress("j")->pending, 1);
  EXPECT_TRUE(s.take_events().empty()) << "an expiry is not a worker loss";
  EXPECT_EQ(s.counters().lease_expiries, 1u);
  EXPECT_EQ(s.counters().retries_worker, 1u);
  EXPECT_EQ(s.counters().workers_lost, 0u);

  auto second = s.acquire("w2", at(3100));
  ASSERT_TRUE(second.has_value());
  EXPECT_EQ(second->granted, at(3100));
  EXPECT_EQ(s.counters().leases_granted, 2u);
  EXPECT_NE(second->id, first->id);
  EXPECT_EQ(second->attempt, 2) << "an expired lease is a counted worker fault";

  CompleteReply late = s.complete("w1", first->id, hash_of(first->task), at(3200));
  EXPECT_EQ(late.outcome, CompleteOutcome::kStale);
  EXPECT_NE(late.reason.find("expired at 3000 ms"), std::string::npos) << late.reason;
  EXPECT_EQ(s.heartbeat("w1", {first->id}, at(3300)).directives,
            (std::vector<Directive>{{DirectiveKind::kCancelTask, first->id}}));

  CompleteReply fresh = s.complete("w2", second->id, hash_of(second->task), at(3400));
  EXPECT_EQ(fresh.outcome, CompleteOutcome::kAccepted);
  ASSERT_TRUE(fresh.task.has_value());
  EXPECT_EQ(*fresh.task, second->task);
  EXPECT_EQ(s.progress("j")->state, JobState::kDone);
  // The late result arriving once the task is done with identical bytes is harmless.
  EXPECT_EQ(s.complete("w1", first->id, hash_of(first->task), at(3500)).outcome,
            CompleteOutcome::kDuplicate);
  // Different bytes from the expired lease are stale for that reason, not "non-deterministic".
  CompleteReply other = s.complete("w1", first->id, "other-hash", at(3600));
  EXPECT_EQ(other.outcome, CompleteOutcome::kStale);
  EXPECT_NE(other.reason.find("expired at 3000 ms"), std::string::npos) << other.reason;
}

TEST(SchedulerTest, DuplicateCompletionIsHarmlessAndADifferentHashIsRefused) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(2)).ok());
  s.register_worker("w", 1, at(0));
  auto lease = s.acquire("w", at(0));
  ASSERT_TRUE(lease.has_value());
  EXPECT_EQ(s.complete("w", lease->id, "abc", at(10)).outcome, CompleteOutcome::kAccepted);
  CompleteReply again = s.complete("w", lease->id, "abc", at(20));
  EXPECT_EQ(again.outcome, CompleteOutcome::kDuplicate);
  EXPECT_TRUE(again.reason.empty());
  CompleteReply other = s.complete("w", lease->id, "xyz", at(30));
  EXPECT_EQ(other.outcome, CompleteOutcome::kStale);
  EXPECT_NE(other.reason.find("already accepted with result hash abc"), std::string::npos)
      << other.reason;
  EXPECT_NE(other.reason.find("not deterministic"), std::string::npos);
  auto progress = s.progress("j");
  EXPECT_EQ(progress->done, 1);
  EXPECT_EQ(progress->state, JobState::kRunning);
  EXPECT_TRUE(s.take_events().empty());
  // The done task is never leased again.
  auto next = s.acquire("w", at(40));
  ASSERT_TRUE(next.has_value());
  EXPECT_EQ(next->task.index, 1);
  EXPECT_FALSE(s.acquire("w", at(50)).has_value());
}

TEST(SchedulerTest, OnlyTheHoldingWorkerCanCompleteOrFailALease) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  s.register_worker("w2", 1, at(0));
  auto lease = s.acquire("w1", at(0));
  ASSERT_TRUE(lease.has_value());
  CompleteReply wrong = s.complete("w2", lease->id, "h", at(10));
  EXPECT_EQ(wrong.outcome, CompleteOutcome::kStale);
  EXPECT_EQ(wrong.reason, "lease l-1 belongs to worker w1, not w2");
  CompleteReply unknown = s.complete("w1", "l-99", "h", at(10));
  EXPECT_EQ(unknown.outcome, CompleteOutcome::kStale);
  EXPECT_EQ(unknown.reason, "unknown lease l-99");
  EXPECT_FALSE(unknown.task.has_value());
  absl::Status fail = s.fail("w2", lease->id, FailureClass::kWorker, "boom", at(10));
  EXPECT_EQ(fail.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(s.heartbeat("w2", {lease->id}, at(20)).directives,
            (std::vector<Directive>{{DirectiveKind::kCancelTask, lease->id}}));
  EXPECT_EQ(s.progress("j")->leased, 1) << "nothing changed";
  EXPECT_EQ(s.complete("w1", lease->id, "h", at(30)).outcome, CompleteOutcome::kAccepted);
}

TEST(SchedulerTest, WorkerIsLostAfterThreeMissedHeartbeatsAndItsTaskGoesToAnother) {
  SchedulerOptions options = test_options();
  options.lease_duration = Millis{60000};  // the loss, not an expiry, must requeue the task
  Scheduler s(options);
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  s.register_worker("w2", 1, at(0));
  auto lease = s.acquire("w1", at(0));
  ASSERT_TRUE(lease.has_value());
  s.heartbeat("w1", {lease->id}, at(1000));  // then w1 is killed
  for (std::int64_t t = 1000; t <= 4000; t += 1000) {
    s.heartbeat("w2", {}, at(t));
    s.tick(at(t));
  }
  EXPECT_TRUE(s.knows_worker("w1")) << "exactly 3 intervals of silence is not yet lost";
  EXPECT_FALSE(s.acquire("w2", at(4000)).has_value());
  s.tick(at(4001));
  EXPECT_FALSE(s.knows_worker("w1"));
  auto events = s.take_events();
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, Kind::kWorkerLost);
  EXPECT_EQ(events[0].worker_id, "w1");
  EXPECT_NE(events[0].message.find("requeued 1 lease"), std::string::npos) << events[0].message;

  auto retry = s.acquire("w2", at(4100));
  ASSERT_TRUE(retry.has_value());
  EXPECT_EQ(retry->task.index, 0);
  EXPECT_EQ(retry->attempt, 2);
  // The lost worker comes back: told to re-register, its old result is stale.
  EXPECT_EQ(s.heartbeat("w1", {lease->id}, at(4200)).directives,
            (std::vector<Directive>{{DirectiveKind::kReregister, ""}}));
  EXPECT_FALSE(s.acquire("w1", at(4200)).has_value());
  CompleteReply late = s.complete("w1", lease->id, "h", at(4300));
  EXPECT_EQ(late.outcome, CompleteOutcome::kStale);
  EXPECT_NE(late.reason.find("declared lost"), std::string::npos) << late.reason;
  EXPECT_EQ(s.complete("w2", retry->id, "h", at(4400)).outcome, CompleteOutcome::kAccepted);
}

// Issue 18, case 2: a coordinator that could not listen for 10 s (planning a huge job under its
// lock) declared its healthy workers lost and dropped their finished tiles. Forgiven time is
// not silence; silence after it still is.
TEST(SchedulerTest, TimeTheCoordinatorCouldNotListenIsNotSilence) {
  SchedulerOptions options = test_options();
  options.lease_duration = Millis{2500};
  Scheduler s(options);
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  auto lease = s.acquire("w1", at(0));
  ASSERT_TRUE(lease.has_value());
  s.heartbeat("w1", {lease->id}, at(1000));
  // The coordinator stalls from 1000 to 11000 ms; its next tick forgives the 10 s first.
  s.forgive(Millis{10000});
  s.tick(at(11000));
  EXPECT_TRUE(s.knows_worker("w1"));
  EXPECT_TRUE(s.take_events().empty());
  EXPECT_EQ(s.counters().lease_expiries, 0u);
  // The queued heartbeat arrives; the lease is still current and completes.
  EXPECT_TRUE(s.heartbeat("w1", {lease->id}, at(11001)).directives.empty());
  EXPECT_EQ(s.complete("w1", lease->id, "h", at(11002)).outcome, CompleteOutcome::kAccepted);
  // Silence after the stall counts as before: 3 intervals and a bit more is lost.
  s.tick(at(14002));
  EXPECT_TRUE(s.knows_worker("w1"));
  s.tick(at(14003));
  EXPECT_FALSE(s.knows_worker("w1"));
}

TEST(SchedulerTest, RetryPrefersAnotherWorkerButDoesNotStarve) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  s.register_worker("w2", 1, at(0));
  auto lease = s.acquire("w1", at(0));
  ASSERT_TRUE(lease.has_value());
  ASSERT_TRUE(s.fail("w1", lease->id, FailureClass::kWorker, "segfault", at(100)).ok());
  EXPECT_FALSE(s.acquire("w1", at(200)).has_value()) << "w2 could take it";
  auto retry = s.acquire("w2", at(300));
  ASSERT_TRUE(retry.has_value());
  EXPECT_EQ(retry->attempt, 2);

  // If the other worker does not ask, the faulty one gets it back after the preferred wait.
  ASSERT_TRUE(s.fail("w2", retry->id, FailureClass::kWorker, "segfault", at(400)).ok());
  EXPECT_FALSE(s.acquire("w2", at(400) + kPreference - Millis{1}).has_value());
  auto third = s.acquire("w2", at(400) + kPreference);
  ASSERT_TRUE(third.has_value());
  EXPECT_EQ(third->attempt, 3);
}

TEST(SchedulerTest, RetryGoesBackAtOnceWhenNoOtherWorkerCouldTakeIt) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  auto lease = s.acquire("w1", at(0));
  ASSERT_TRUE(lease.has_value());
  ASSERT_TRUE(s.fail("w1", lease->id, FailureClass::kWorker, "segfault", at(100)).ok());
  auto retry = s.acquire("w1", at(100));
  ASSERT_TRUE(retry.has_value());
  EXPECT_EQ(retry->attempt, 2);
}

TEST(SchedulerTest, RetriedTaskWaitsWhileTheFaultyWorkerTakesOtherWork) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(2)).ok());
  s.register_worker("w1", 1, at(0));
  s.register_worker("w2", 1, at(0));
  auto lease = s.acquire("w1", at(0));
  ASSERT_TRUE(lease.has_value());
  ASSERT_TRUE(s.fail("w1", lease->id, FailureClass::kWorker, "segfault", at(10)).ok());
  auto next = s.acquire("w1", at(20));
  ASSERT_TRUE(next.has_value());
  EXPECT_EQ(next->task.index, 1) << "task 0 is kept for w2";
  auto retry = s.acquire("w2", at(30));
  ASSERT_TRUE(retry.has_value());
  EXPECT_EQ(retry->task.index, 0);
}

TEST(SchedulerTest, ThreeWorkerFaultsOnAJobBlockTheWorkerFromItOnly) {
  SchedulerOptions options = test_options();
  options.max_attempts = 10;
  Scheduler s(options);
  ASSERT_TRUE(s.add_job("a", specs(4)).ok());
  ASSERT_TRUE(s.add_job("b", specs(2)).ok());
  s.register_worker("w1", 1, at(0));
  for (int fault = 0; fault < 3; ++fault) {
    auto lease = s.acquire("w1", at(10 * fault));
    ASSERT_TRUE(lease.has_value());
    ASSERT_EQ(lease->task.job_id, "a");
    EXPECT_TRUE(s.progress("a")->blocked_workers.empty());
    ASSERT_TRUE(s.fail("w1", lease->id, FailureClass::kWorker, "oom", at(10 * fault + 5)).ok());
  }
  EXPECT_EQ(s.progress("a")->blocked_workers, std::vector<std::string>{"w1"});
  auto b0 = s.acquire("w1", at(100));
  auto b1 = s.acquire("w1", at(100));
  ASSERT_TRUE(b0.has_value() && b1.has_value());
  EXPECT_EQ(b0->task.job_id, "b");
  EXPECT_EQ(b1->task.job_id, "b");
  EXPECT_FALSE(s.acquire("w1", at(100)).has_value()) << "job a still has 4 pending tasks";
  EXPECT_EQ(s.progress("a")->pending, 4);
  EXPECT_EQ(s.progress("a")->state, JobState::kRunning);
  // Another worker takes job a's tasks, the faulted one first (it prefers a fresh worker).
  s.register_worker("w2", 1, at(200));
  auto a = s.acquire("w2", at(200));
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(a->task.job_id, "a");
  EXPECT_EQ(a->task.index, 0);
  EXPECT_EQ(a->attempt, 4);
}

TEST(SchedulerTest, AttemptCapFailsTheJobNamingTheTaskAndTheLastFault) {
  SchedulerOptions options = test_options();
  options.max_attempts = 3;
  options.block_after_faults = 10;
  options.retry_preference = Millis{0};  // w1 may retry at once although w2 exists
  Scheduler s(options);
  ASSERT_TRUE(s.add_job("j", specs(2)).ok());
  ASSERT_TRUE(s.add_job("k", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  s.register_worker("w2", 1, at(0));
  auto other = s.acquire("w2", at(0));  // task 0 of j, held by w2 throughout
  ASSERT_TRUE(other.has_value());
  // Task 1 of j fails twice on w1 (worker faults) and then its lease expires: 3 counted.
  for (int attempt = 1; attempt <= 2; ++attempt) {
    auto lease = s.acquire("w1", at(attempt * 10));
    ASSERT_TRUE(lease.has_value());
    ASSERT_EQ(lease->task.index, 1);
    EXPECT_EQ(lease->attempt, attempt);
    ASSERT_TRUE(
        s.fail("w1", lease->id, FailureClass::kWorker, "out of memory", at(attempt * 10 + 1)).ok());
    EXPECT_EQ(s.progress("j")->state, JobState::kRunning);
  }
  auto last = s.acquire("w1", at(30));
  ASSERT_TRUE(last.has_value());
  EXPECT_EQ(last->attempt, 3);
  s.heartbeat("w1", {}, at(2000));
  s.heartbeat("w2", {other->id}, at(2000));
  s.tick(at(3031));
  auto events = s.take_events();
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, Kind::kJobFailed);
  EXPECT_EQ(events[0].job_id, "j");
  EXPECT_EQ(events[0].message,
            "task 1 of job j (final pass, tile [8,16)x[0,8), samples [0,16)) failed 3 times (the "
            "cap is 3); last: lease l-4 of worker w1 expired at 3030 ms");
  auto progress = s.progress("j");
  EXPECT_EQ(progress->state, JobState::kFailed);
  EXPECT_EQ(progress->message, events[0].message);
  EXPECT_EQ(progress->leased, 0);
  EXPECT_EQ(progress->pending, 0);
  // The failed job's other lease is cancelled; job k still runs.
  EXPECT_EQ(s.heartbeat("w2", {other->id}, at(3100)).directives,
            (std::vector<Directive>{{DirectiveKind::kCancelTask, other->id}}));
  auto k = s.acquire("w2", at(3200));
  ASSERT_TRUE(k.has_value());
  EXPECT_EQ(k->task.job_id, "k");
}

TEST(SchedulerTest, SceneFaultFailsTheJobAtOnceAndCancelsItsOtherLeases) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(4)).ok());
  ASSERT_TRUE(s.add_job("k", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  s.register_worker("w2", 1, at(0));
  auto l1 = s.acquire("w1", at(0));
  auto l2 = s.acquire("w2", at(0));
  ASSERT_TRUE(l1.has_value() && l2.has_value());
  const std::string why = "scene.pbrt:12:3: unknown material \"gold\"";
  ASSERT_TRUE(s.fail("w1", l1->id, FailureClass::kScene, why, at(100)).ok());
  auto events = s.take_events();
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, Kind::kJobFailed);
  EXPECT_EQ(events[0].message,
            "scene fault in task 0 of job j (final pass, tile [0,8)x[0,8), samples [0,16)) on "
            "worker w1: " +
                why);
  EXPECT_EQ(s.progress("j")->state, JobState::kFailed);
  EXPECT_EQ(s.progress("j")->pending, 0);
  HeartbeatReply reply = s.heartbeat("w2", {l2->id}, at(1000));
  EXPECT_EQ(reply.directives, (std::vector<Directive>{{DirectiveKind::kCancelTask, l2->id}}));
  EXPECT_FALSE(reply.lease_deadline.has_value());
  CompleteReply late = s.complete("w2", l2->id, "h", at(1100));
  EXPECT_EQ(late.outcome, CompleteOutcome::kStale);
  EXPECT_NE(late.reason.find("job j failed"), std::string::npos) << late.reason;
  auto next = s.acquire("w1", at(1200));
  ASSERT_TRUE(next.has_value());
  EXPECT_EQ(next->task.job_id, "k");
  EXPECT_FALSE(s.acquire("w2", at(1200)).has_value());
  EXPECT_EQ(s.cancel_job("j").code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(s.add_tasks("j", specs(1)).status().code(), absl::StatusCode::kFailedPrecondition);
}

TEST(SchedulerTest, CancelStopsTheJobsTasksWithinOneHeartbeat) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(3)).ok());
  ASSERT_TRUE(s.add_job("k", specs(1)).ok());
  s.register_worker("w1", 1, at(0));
  s.register_worker("w2", 1, at(0));
  auto l1 = s.acquire("w1", at(0));
  auto l2 = s.acquire("w2", at(0));
  ASSERT_TRUE(l1.has_value() && l2.has_value());
  EXPECT_TRUE(s.heartbeat("w1", {l1->id}, at(1000)).directives.empty());
  ASSERT_TRUE(s.cancel_job("j").ok());
  // The very next heartbeat of each holder carries the cancel.
  EXPECT_EQ(s.heartbeat("w1", {l1->id}, at(1500)).directives,
            (std::vector<Directive>{{DirectiveKind::kCancelTask, l1->id}}));
  EXPECT_EQ(s.heartbeat("w2", {l2->id}, at(1600)).directives,
            (std::vector<Directive>{{DirectiveKind::kCancelTask, l2->id}}));
  auto progress = s.progress("j");
  EXPECT_EQ(progress->state, JobState::kCancelled);
  EXPECT_EQ(progress->leased, 0);
  EXPECT_EQ(progress->pending, 0);
  EXPECT_TRUE(s.take_events().empty());
  EXPECT_EQ(s.complete("w1", l1->id, "h", at(1700)).outcome, CompleteOutcome::kStale);
  auto next = s.acquire("w1", at(1800));
  ASSERT_TRUE(next.has_value());
  EXPECT_EQ(next->task.job_id, "k");
  EXPECT_FALSE(s.acquire("w2", at(1800)).has_value());
  EXPECT_TRUE(s.cancel_job("j").ok()) << "idempotent";
  EXPECT_EQ(s.cancel_job("nope").code(), absl::StatusCode::kNotFound);
  ASSERT_EQ(s.complete("w1", next->id, "h", at(1900)).outcome, CompleteOutcome::kAccepted);
  EXPECT_EQ(s.cancel_job("k").code(), absl::StatusCode::kFailedPrecondition);
  // Finished jobs can be forgotten; running ones cannot.
  ASSERT_TRUE(s.add_job("m", specs(1)).ok());
  EXPECT_EQ(s.remove_job("m").code(), absl::StatusCode::kFailedPrecondition);
  ASSERT_TRUE(s.remove_job("j").ok());
  EXPECT_FALSE(s.progress("j").has_value());
  EXPECT_EQ(s.complete("w1", l1->id, "h", at(2000)).reason, "unknown lease l-1");
}

TEST(SchedulerTest, DrainingHandsOutNothingAndReturnedLeasesAreNotCounted) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(2)).ok());
  s.register_worker("w", 1, at(0));
  auto lease = s.acquire("w", at(0));
  ASSERT_TRUE(lease.has_value());
  s.set_draining(true);
  HeartbeatReply reply = s.heartbeat("w", {lease->id}, at(1000));
  EXPECT_EQ(reply.directives, (std::vector<Directive>{{DirectiveKind::kDrain, ""}}));
  EXPECT_EQ(reply.lease_deadline, at(1000) + kLease) << "held leases may still finish";
  EXPECT_FALSE(s.acquire("w", at(1100)).has_value());
  EXPECT_EQ(s.task_counts().leased, 1u);
  ASSERT_TRUE(s.fail("w", lease->id, FailureClass::kReturned, "SIGTERM", at(1200)).ok());
  EXPECT_EQ(s.progress("j")->pending, 2);
  EXPECT_EQ(s.task_counts().pending, 2u);
  EXPECT_EQ(s.task_counts().leased, 0u);
  EXPECT_EQ(s.counters().retries_returned, 1u);
  EXPECT_EQ(s.counters().retries_worker, 0u);
  s.set_draining(false);
  EXPECT_TRUE(s.heartbeat("w", {}, at(2000)).directives.empty());
  auto again = s.acquire("w", at(2100));
  ASSERT_TRUE(again.has_value());
  EXPECT_EQ(again->task.index, 0);
  EXPECT_EQ(again->attempt, 1);
}

TEST(SchedulerTest, UnknownWorkersAreToldToReregister) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  EXPECT_EQ(s.heartbeat("ghost", {"l-1"}, at(0)).directives,
            (std::vector<Directive>{{DirectiveKind::kReregister, ""}}));
  EXPECT_FALSE(s.acquire("ghost", at(0)).has_value());
  s.register_worker("ghost", 2, at(10));
  EXPECT_EQ(s.heartbeat("ghost", {"l-7"}, at(20)).directives,
            (std::vector<Directive>{{DirectiveKind::kCancelTask, "l-7"}}));
  ASSERT_EQ(s.workers().size(), 1u);
  EXPECT_EQ(s.workers()[0].threads, 2);
  EXPECT_EQ(s.workers()[0].last_seen, at(20));
}

TEST(SchedulerTest, WorkersListTheLeasesTheyHoldOldestFirst) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(3)).ok());
  s.register_worker("w", 2, at(0));
  auto first = s.acquire("w", at(1));
  auto second = s.acquire("w", at(2));
  ASSERT_TRUE(first.has_value() && second.has_value());
  ASSERT_EQ(s.workers().size(), 1u);
  EXPECT_EQ(s.workers()[0].leases, 2);
  EXPECT_EQ(s.workers()[0].current, (std::vector<Lease>{*first, *second}));
  ASSERT_EQ(s.complete("w", first->id, "h0", at(3)).outcome, CompleteOutcome::kAccepted);
  EXPECT_EQ(s.workers()[0].current, (std::vector<Lease>{*second}));
}

TEST(SchedulerTest, ResumedJobNeverLeasesItsDoneTasks) {
  Scheduler s(test_options());
  ASSERT_TRUE(s.add_job("j", specs(5), {0, 2, 4, 2}).ok());
  auto progress = s.progress("j");
  EXPECT_EQ(progress->done, 3);
  EXPECT_EQ(progress->total, 5);
  EXPECT_EQ(progress->pending, 2);
  s.register_worker("w", 1, at(0));
  std::vector<int> leased;
  while (auto lease = s.acquire("w", at(0))) {
    leased.push_back(lease->task.index);
    ASSERT_EQ(s.complete("w", lease->id, hash_of(lease->task), at(0)).outcome,
              CompleteOutcome::kAccepted);
  }
  EXPECT_EQ(leased, (std::vector<int>{1, 3}));
  EXPECT_EQ(s.take_events(), job_done("j"));

  // Everything done already: the job completes on the spot.
  ASSERT_TRUE(s.add_job("all", specs(3), {2, 1, 0}).ok());
  EXPECT_EQ(s.progress("all")->state, JobState::kDone);
  EXPECT_EQ(s.take_events(), job_done("all"));
  EXPECT_FALSE(s.acquire("w", at(10)).has_value());

  // A later pass reopens a done job; its new tasks are numbered after the old ones.
  auto first = s.add_tasks("all", {spec(9)});
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(*first, 3);
  EXPECT_EQ(s.progress("all")->state, JobState::kRunning);
  auto lease = s.acquire("w", at(20));
  ASSERT_TRUE(lease.has_value());
  EXPECT_EQ(lease->task.index, 3);
  EXPECT_EQ(lease->task.spec, spec(9));
  ASSERT_EQ(s.complete("w", lease->id, hash_of(lease->task), at(20)).outcome,
            CompleteOutcome::kAccepted);
  (void)s.take_events();

  // Skipped tasks (a prepass that stopped early) keep the numbering, are never leased, count as
  // done, and the tasks after them are leased as usual.
  auto skipped = s.add_tasks("all", specs(2), true);
  ASSERT_TRUE(skipped.ok());
  EXPECT_EQ(*skipped, 4);
  auto next = s.add_tasks("all", {spec(7)});
  ASSERT_TRUE(next.ok());
  EXPECT_EQ(*next, 6);
  lease = s.acquire("w", at(30));
  ASSERT_TRUE(lease.has_value());
  EXPECT_EQ(lease->task.index, 6);
  EXPECT_FALSE(s.acquire("w", at(30)).has_value());
  EXPECT_EQ(s.progress("all")->done, 6);
  ASSERT_EQ(s.complete("w", lease->id, hash_of(lease->task), at(31)).outcome,
            CompleteOutcome::kAccepted);
  EXPECT_EQ(s.progress("all")->state, JobState::kDone);
}

TEST(SchedulerTest, RefusesBadJobs) {
  Scheduler s(test_options());
  EXPECT_EQ(s.add_job("j", specs(2), {2}).message(), "done task index 2 of job j is outside 0..1");
  EXPECT_FALSE(s.progress("j").has_value()) << "nothing added on error";
  EXPECT_EQ(s.add_job("", specs(1)).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(s.add_job("j", {TaskSpec{.tile = {4, 0, 0, 4}, .samples = {0, 1}}}).message(),
            "task 0 of job j has an empty or reversed tile [4,0)x[0,4)");
  EXPECT_EQ(s.add_job("j", {TaskSpec{.tile = {0, 0, 4, 4}, .samples = {3, 3}}}).message(),
            "task 0 of job j has an empty sample range [3,3)");
  ASSERT_TRUE(s.add_job("j", specs(1)).ok());
  EXPECT_EQ(s.add_job("j", specs(1)).code(), absl::StatusCode::kAlreadyExists);
  EXPECT_EQ(s.add_tasks("x", specs(1)).status().code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace prism::coordinator
