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

namespace prism::coordinator {
namespace {

using Kind = SchedulerEvent::Kind;

constexpr Millis kInterval{1000};
constexpr Millis kLease{3000};
constexpr Millis kPreference{2000};

SchedulerOptions test_options() {
  SchedulerOptions options;
  options.heartbeat_interval = kInterval;
  options.lost_after_missed = 3;
  options.lease_duration = kLease;
  options.max_attempts = 4;
  options.block_after_faults = 3;
  options.retry_preference = kPreference;
  return options;
}

TaskSpec spec(int i) {
  return TaskSpec{.tile = {i * 8, 0, i * 8 + 8, 8}, .samples = {0, 16}};
}

std::vector<TaskSpec> specs(int n) {
  std::vector<TaskSpec> out;
  for (int i = 0; i < n; ++i) out.push_back(spec(i));
  return out;
}

Millis at(std::int64_t ms) {
  return Millis{ms};
}

std::string hash_of(const Task& task) {
  return task.job_id + "#" + std::to_string(task.index);
}

std::vector<SchedulerEvent> job_done(const std::string& job_id) {
  SchedulerEvent event;
  event.kind = Kind::kJobDone;
  event.job_id = job_id;
  return {event};
}

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

  auto second = s.acquire("w2", at(3100));
  ASSERT_TRUE(second.has_value());
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
  ASSERT_TRUE(s.fail("w", lease->id, FailureClass::kReturned, "SIGTERM", at(1200)).ok());
  EXPECT_EQ(s.progress("j")->pending, 2);
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
