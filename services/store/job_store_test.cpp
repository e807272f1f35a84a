#include "services/store/job_store.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <fstream>
#include <map>

#include "services/base/check.h"

namespace prism::store {
namespace {

namespace fs = std::filesystem;

constexpr std::array<JobState, 7> kAllStates = {
    JobState::kQueued, JobState::kPrepass, JobState::kRendering, JobState::kFinalising,
    JobState::kDone,   JobState::kFailed,  JobState::kCancelled};

// Tasks of a job: task i covers the 8x4 tile at x = 8i with samples [0,16), 512 pixel samples.
std::vector<TaskRecord> make_tasks(int n) {
  std::vector<TaskRecord> tasks;
  for (int i = 0; i < n; ++i) {
    TaskRecord t;
    t.index = i;
    t.pass = TaskPass::kFinal;
    t.tile_index = i;
    t.rect = {i * 8, 0, i * 8 + 8, 4};
    t.samples = {0, 16};
    tasks.push_back(t);
  }
  return tasks;
}

JobRecord make_job(std::string token = "", std::string spec = "spec-bytes") {
  JobRecord job;
  job.client_token = std::move(token);
  job.spec = std::move(spec);
  job.bundle_hash = std::string(64, 'a');
  job.submitted_ms = 1000;
  return job;
}

std::int64_t count_rows(Database& db, const std::string& table) {
  auto rows = db.query("SELECT count(*) FROM " + table);
  EXPECT_TRUE(rows.ok()) << rows.status();
  return rows.ok() ? (*rows)[0].integer(0) : -1;
}

class JobStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("prism_job_store_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    file_ = dir_ / "jobs.db";
  }
  void TearDown() override { fs::remove_all(dir_); }

  JobStore open_store() {
    auto store = JobStore::open(file_);
    PRISM_CHECK(store.ok());
    return std::move(*store);
  }

  std::string create(JobStore& store, int tasks = 2, std::string token = "") {
    auto created = store.create_job(make_job(std::move(token)), make_tasks(tasks));
    EXPECT_TRUE(created.ok()) << created.status();
    return created.ok() ? created->job.id : std::string();
  }

  fs::path dir_;
  fs::path file_;
};

TEST_F(JobStoreTest, IdempotentSubmitSurvivesReopen) {
  std::string id;
  {
    JobStore store = open_store();
    auto first = store.create_job(make_job("token-1", "spec A"), make_tasks(4));
    ASSERT_TRUE(first.ok()) << first.status();
    EXPECT_FALSE(first->existed);
    EXPECT_EQ(first->job.id, "j-000001");
    EXPECT_EQ(first->job.state, JobState::kQueued);
    EXPECT_EQ(first->job.progress, (JobProgress{4, 0, 4 * 512, 0}));
    id = first->job.id;

    auto again = store.create_job(make_job("token-1", "spec B"), make_tasks(7));
    ASSERT_TRUE(again.ok()) << again.status();
    EXPECT_TRUE(again->existed);
    EXPECT_EQ(again->job.id, id);
    EXPECT_EQ(again->job.spec, "spec A");
    EXPECT_EQ(count_rows(store.database(), "tasks"), 4);
  }
  JobStore store = open_store();
  auto after = store.create_job(make_job("token-1", "spec C"), make_tasks(2));
  ASSERT_TRUE(after.ok()) << after.status();
  EXPECT_TRUE(after->existed);
  EXPECT_EQ(after->job.id, id);
  EXPECT_EQ(after->job.spec, "spec A");
  EXPECT_EQ(count_rows(store.database(), "jobs"), 1);
  EXPECT_EQ(count_rows(store.database(), "tasks"), 4);
  auto by_token = store.find_by_client_token("token-1");
  ASSERT_TRUE(by_token.ok());
  EXPECT_EQ(by_token->id, id);

  // Without a token every submit is a new job; another token is another job.
  auto untokened_a = store.create_job(make_job(), make_tasks(1));
  auto untokened_b = store.create_job(make_job(), make_tasks(1));
  auto other = store.create_job(make_job("token-2"), make_tasks(1));
  ASSERT_TRUE(untokened_a.ok() && untokened_b.ok() && other.ok());
  EXPECT_FALSE(untokened_a->existed || untokened_b->existed || other->existed);
  EXPECT_NE(untokened_a->job.id, untokened_b->job.id);
  EXPECT_EQ(count_rows(store.database(), "jobs"), 4);
}

// A cancelled or failed job gives its token up: the same submission again is a new job, which
// its retries then find; a live or done job keeps its token (one render, not two).
TEST_F(JobStoreTest, CancelledAndFailedJobsGiveTheirTokenToTheNextSubmission) {
  JobStore store = open_store();
  auto first = store.create_job(make_job("token-1", "spec A"), make_tasks(2));
  ASSERT_TRUE(first.ok()) << first.status();
  ASSERT_TRUE(store.set_job_state(first->job.id, JobState::kCancelled, 10).ok());
  auto second = store.create_job(make_job("token-1", "spec A"), make_tasks(2));
  ASSERT_TRUE(second.ok()) << second.status();
  EXPECT_FALSE(second->existed);
  EXPECT_NE(second->job.id, first->job.id);
  EXPECT_EQ(second->job.state, JobState::kQueued);
  auto retry = store.create_job(make_job("token-1", "spec A"), make_tasks(2));
  ASSERT_TRUE(retry.ok());
  EXPECT_TRUE(retry->existed);
  EXPECT_EQ(retry->job.id, second->job.id);
  EXPECT_EQ(store.find_by_client_token("token-1")->id, second->job.id);
  // The cancelled job is still there, without its token.
  auto old = store.get_job(first->job.id);
  ASSERT_TRUE(old.ok());
  EXPECT_EQ(old->state, JobState::kCancelled);
  EXPECT_TRUE(old->client_token.empty());

  ASSERT_TRUE(store.set_job_state(second->job.id, JobState::kFailed, 20).ok());
  auto third = store.create_job(make_job("token-1", "spec A"), make_tasks(2));
  ASSERT_TRUE(third.ok());
  EXPECT_FALSE(third->existed);

  // A live job keeps it (so does a DONE one: only FAILED and CANCELLED give it up).
  EXPECT_FALSE(gives_up_client_token(JobState::kDone));
  ASSERT_TRUE(store.set_job_state(third->job.id, JobState::kRendering, 30).ok());
  auto fourth = store.create_job(make_job("token-1", "spec A"), make_tasks(2));
  ASSERT_TRUE(fourth.ok());
  EXPECT_TRUE(fourth->existed);
  EXPECT_EQ(fourth->job.id, third->job.id);
  EXPECT_EQ(count_rows(store.database(), "jobs"), 3);
}

TEST_F(JobStoreTest, MigratesEmptyFileAndRefusesNewerSchema) {
  { std::ofstream(file_).flush(); }
  ASSERT_EQ(fs::file_size(file_), 0u);
  {
    JobStore store = open_store();
    auto version = store.database().query("PRAGMA user_version");
    ASSERT_TRUE(version.ok());
    EXPECT_EQ((*version)[0].integer(0), JobStore::kSchemaVersion);
    auto tables =
        store.database().query("SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name");
    ASSERT_TRUE(tables.ok());
    std::vector<std::string> names;
    for (const auto& row : *tables) names.push_back(row.text(0));
    EXPECT_EQ(names, (std::vector<std::string>{"counters", "jobs", "tasks", "worker_failures",
                                               "workers"}));
    create(store);
  }
  {
    // Reopening an up-to-date store migrates nothing and keeps the data.
    JobStore store = open_store();
    EXPECT_EQ(count_rows(store.database(), "jobs"), 1);
    ASSERT_TRUE(store.database()
                    .exec("PRAGMA user_version = " + std::to_string(JobStore::kSchemaVersion + 1))
                    .ok());
  }
  auto refused = JobStore::open(file_);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(refused.status().message().find("schema version " +
                                            std::to_string(JobStore::kSchemaVersion + 1)),
            std::string::npos)
      << refused.status();
  auto db = Database::open(file_);
  ASSERT_TRUE(db.ok());
  EXPECT_EQ((*db->query("PRAGMA user_version"))[0].integer(0), JobStore::kSchemaVersion + 1);
  EXPECT_EQ(count_rows(*db, "jobs"), 1);

  auto garbage = dir_ / "garbage.db";
  { std::ofstream(garbage) << std::string(4096, 'x'); }
  EXPECT_EQ(JobStore::open(garbage).status().code(), absl::StatusCode::kFailedPrecondition);
}

TEST_F(JobStoreTest, CountsJobsByState) {
  JobStore store = open_store();
  EXPECT_TRUE(store.count_jobs_by_state()->empty());
  const std::string a = create(store), b = create(store), c = create(store);
  create(store);
  ASSERT_TRUE(store.set_job_state(a, JobState::kRendering, 10).ok());
  ASSERT_TRUE(store.set_job_state(b, JobState::kRendering, 10).ok());
  ASSERT_TRUE(store.set_job_state(c, JobState::kCancelled, 10, "by hand").ok());
  auto counts = store.count_jobs_by_state();
  ASSERT_TRUE(counts.ok()) << counts.status();
  EXPECT_EQ(*counts,
            (std::map<JobState, std::int64_t>{
                {JobState::kQueued, 1}, {JobState::kRendering, 2}, {JobState::kCancelled, 1}}));
}

TEST_F(JobStoreTest, CountsTheTilesWhoseFinalTasksAreAllDone) {
  JobStore store = open_store();
  // Tiles 0 and 1 have two final-pass tasks each, tile 2 one; one prepass task on tile 0.
  std::vector<TaskRecord> tasks = make_tasks(6);
  const int tile_of[] = {0, 0, 1, 1, 2, 0};
  for (int i = 0; i < 6; ++i) tasks[i].tile_index = tile_of[i];
  tasks[5].pass = TaskPass::kPrepass;
  tasks[5].pass_index = 1;
  auto created = store.create_job(make_job(), tasks);
  ASSERT_TRUE(created.ok()) << created.status();
  const std::string id = created->job.id;
  EXPECT_EQ(*store.final_tile_counts(id), (JobStore::TileCounts{0, 3}));
  ASSERT_TRUE(store.mark_task_done(id, 0, "a").ok());  // half of tile 0
  ASSERT_TRUE(store.mark_task_done(id, 4, "b").ok());  // all of tile 2
  EXPECT_EQ(*store.final_tile_counts(id), (JobStore::TileCounts{1, 3}));
  ASSERT_TRUE(store.mark_task_done(id, 1, "c").ok());  // tile 0 done; its prepass task is not
  EXPECT_EQ(*store.final_tile_counts(id), (JobStore::TileCounts{2, 3}));
  EXPECT_EQ(*store.done_final_tiles(id), (std::vector<int>{0, 2}));
  EXPECT_EQ(*store.final_tile_counts("j-nope"), (JobStore::TileCounts{0, 0}));
}

TEST_F(JobStoreTest, StateTransitionTable) {
  // Rows: from, columns: to, both in kAllStates order (Q P R F D X C).
  constexpr bool kAllowed[7][7] = {
      {false, true, true, false, false, true, true},      // QUEUED
      {false, false, true, false, false, true, true},     // PREPASS
      {false, false, false, true, false, true, true},     // RENDERING
      {false, false, false, false, true, true, true},     // FINALISING
      {false, false, false, false, false, false, false},  // DONE
      {false, false, false, false, false, false, false},  // FAILED
      {false, false, false, false, false, false, false},  // CANCELLED
  };
  // A valid path from QUEUED to each state.
  const std::vector<std::vector<JobState>> paths = {
      {},
      {JobState::kPrepass},
      {JobState::kRendering},
      {JobState::kRendering, JobState::kFinalising},
      {JobState::kRendering, JobState::kFinalising, JobState::kDone},
      {JobState::kFailed},
      {JobState::kCancelled},
  };
  JobStore store = open_store();
  for (int f = 0; f < 7; ++f) {
    for (int t = 0; t < 7; ++t) {
      JobState from = kAllStates[f], to = kAllStates[t];
      EXPECT_EQ(is_valid_transition(from, to), kAllowed[f][t])
          << to_string(from) << " -> " << to_string(to);
      std::string id = create(store, 1);
      ASSERT_TRUE(store.mark_task_done(id, 0, "hash").ok());
      std::int64_t now = 100;
      for (JobState step : paths[f]) ASSERT_TRUE(store.set_job_state(id, step, ++now).ok());
      auto moved = store.set_job_state(id, to, 500, "why");
      if (from == to) {
        ASSERT_TRUE(moved.ok()) << moved.status();
        EXPECT_EQ(moved->state, to);
        EXPECT_NE(moved->finished_ms, 500);  // a repeated state changes nothing
      } else if (kAllowed[f][t]) {
        ASSERT_TRUE(moved.ok()) << to_string(from) << " -> " << to_string(to) << ": "
                                << moved.status();
        EXPECT_EQ(store.get_job(id)->state, to);
        EXPECT_EQ(moved->finished_ms, is_terminal(to) ? 500 : 0);
        EXPECT_EQ(moved->error, "why");
      } else {
        EXPECT_EQ(moved.status().code(), absl::StatusCode::kFailedPrecondition)
            << to_string(from) << " -> " << to_string(to);
        EXPECT_EQ(store.get_job(id)->state, from);
      }
    }
  }

  std::string id = create(store, 2);
  auto started = store.set_job_state(id, JobState::kRendering, 2000);
  ASSERT_TRUE(started.ok());
  EXPECT_EQ(started->started_ms, 2000);
  EXPECT_EQ(started->finished_ms, 0);
  ASSERT_TRUE(store.set_job_state(id, JobState::kFinalising, 2100).ok());
  auto early = store.set_job_state(id, JobState::kDone, 2200);
  EXPECT_EQ(early.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(early.status().message().find("2 of 2 tasks pending"), std::string::npos)
      << early.status();
  auto failed = store.set_job_state(id, JobState::kFailed, 2300, "scene.pbrt:3:1: bad material");
  ASSERT_TRUE(failed.ok());
  EXPECT_EQ(failed->started_ms, 2000);
  EXPECT_EQ(failed->finished_ms, 2300);
  auto back = store.set_job_state(id, JobState::kRendering, 2400);
  EXPECT_EQ(back.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(back.status().message().find("FAILED to RENDERING"), std::string::npos);
  EXPECT_EQ(store.get_job(id)->error, "scene.pbrt:3:1: bad material");

  auto missing = store.set_job_state("j-999999", JobState::kRendering, 1);
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
  auto missing_get = store.get_job("j-424242");
  EXPECT_EQ(missing_get.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(missing_get.status().message().find("j-424242"), std::string::npos);
}

// Results in a job's result pack: the record names the range, survives a reopen, and a result
// lost to a power loss (reopen_task) sends the task back to pending with its progress undone.
// Blob-store cleanup ignores pack results (they go with the job's directory).
TEST_F(JobStoreTest, PackLocationsAreKeptAndAReopenedTaskIsPendingAgain) {
  std::string id;
  {
    JobStore store = open_store();
    id = create(store, 3);
    ASSERT_TRUE(store.mark_task_done(id, 0, "aaaa", ResultLocation{4096, 777}).ok());
    ASSERT_TRUE(store.mark_task_done(id, 1, "bbbb").ok());  // a blob-store result
    ASSERT_TRUE(store.sync().ok());
  }
  JobStore store = open_store();
  auto tasks = store.tasks_of(id);
  ASSERT_TRUE(tasks.ok()) << tasks.status();
  EXPECT_EQ((*tasks)[0].result_offset, 4096);
  EXPECT_EQ((*tasks)[0].result_size, 777u);
  EXPECT_EQ((*tasks)[1].result_offset, -1);
  EXPECT_EQ((*tasks)[2].result_offset, -1);
  EXPECT_EQ(*store.unshared_results(id), std::vector<std::string>{"bbbb"});
  EXPECT_EQ(*store.progress(id), (JobProgress{3, 2, 3 * 512, 2 * 512}));

  ASSERT_TRUE(store.reopen_task(id, 0).ok());
  EXPECT_EQ(*store.progress(id), (JobProgress{3, 1, 3 * 512, 512}));
  tasks = store.tasks_of(id);
  ASSERT_TRUE(tasks.ok());
  EXPECT_EQ((*tasks)[0].state, TaskState::kPending);
  EXPECT_EQ((*tasks)[0].result_hash, "");
  EXPECT_EQ((*tasks)[0].result_offset, -1);
  // Pending already: nothing changes; unknown ones are named.
  ASSERT_TRUE(store.reopen_task(id, 0).ok());
  ASSERT_TRUE(store.reopen_task(id, 2).ok());
  EXPECT_EQ(*store.progress(id), (JobProgress{3, 1, 3 * 512, 512}));
  EXPECT_EQ(store.reopen_task(id, 9).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store.reopen_task("j-000777", 0).code(), absl::StatusCode::kNotFound);
  // Done again, with another range.
  ASSERT_TRUE(store.mark_task_done(id, 0, "cccc", ResultLocation{0, 10}).ok());
  EXPECT_EQ(*store.progress(id), (JobProgress{3, 2, 3 * 512, 2 * 512}));
}

// The parts of a large job's tasks added as deferred commits, after the job's first part.
TEST_F(JobStoreTest, TasksAddedInDeferredPartsContinueTheJob) {
  JobStore store = open_store();
  std::vector<TaskRecord> all = make_tasks(10);
  auto created = store.create_job(make_job(), std::span(all).first(4));
  ASSERT_TRUE(created.ok()) << created.status();
  const std::string id = created->job.id;
  ASSERT_TRUE(store.add_tasks(id, std::span(all).subspan(4, 4), Database::Commit::kDeferred).ok());
  ASSERT_TRUE(store.add_tasks(id, std::span(all).subspan(8), Database::Commit::kDeferred).ok());
  EXPECT_EQ(*store.progress(id), (JobProgress{10, 0, 10 * 512, 0}));
  auto tasks = store.tasks_of(id);
  ASSERT_TRUE(tasks.ok());
  ASSERT_EQ(tasks->size(), 10u);
  for (int i = 0; i < 10; ++i) EXPECT_EQ((*tasks)[std::size_t(i)].rect, all[std::size_t(i)].rect);
  // A part out of order is refused.
  EXPECT_FALSE(store.add_tasks(id, std::span(all).first(1), Database::Commit::kDeferred).ok());
  ASSERT_TRUE(store.set_job_state(id, JobState::kCancelled, 2000).ok());
  EXPECT_EQ(store.add_tasks(id, std::span(all).first(1)).code(),
            absl::StatusCode::kFailedPrecondition);
}

TEST_F(JobStoreTest, TaskDoneIsIdempotentAndConflictingHashRefused) {
  JobStore store = open_store();
  std::string id = create(store, 3);
  auto first = store.mark_task_done(id, 1, "aaaa");
  ASSERT_TRUE(first.ok()) << first.status();
  EXPECT_TRUE(*first);
  auto duplicate = store.mark_task_done(id, 1, "aaaa");
  ASSERT_TRUE(duplicate.ok()) << duplicate.status();
  EXPECT_FALSE(*duplicate);
  EXPECT_EQ(*store.progress(id), (JobProgress{3, 1, 3 * 512, 512}));

  auto conflict = store.mark_task_done(id, 1, "bbbb");
  EXPECT_EQ(conflict.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(conflict.status().message().find("aaaa"), std::string::npos);
  auto tasks = store.tasks_of(id);
  ASSERT_TRUE(tasks.ok());
  ASSERT_EQ(tasks->size(), 3u);
  EXPECT_EQ((*tasks)[1].state, TaskState::kDone);
  EXPECT_EQ((*tasks)[1].result_hash, "aaaa");
  EXPECT_EQ((*tasks)[0].state, TaskState::kPending);
  EXPECT_EQ(*store.progress(id), (JobProgress{3, 1, 3 * 512, 512}));

  EXPECT_EQ(store.mark_task_done(id, 3, "cccc").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store.mark_task_done(id, 0, "").status().code(), absl::StatusCode::kInvalidArgument);
  auto unknown = store.mark_task_done("j-000777", 0, "cccc");
  EXPECT_EQ(unknown.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(unknown.status().message().find("j-000777"), std::string::npos);

  EXPECT_EQ(*store.record_attempt(id, 2), 1);
  EXPECT_EQ(*store.record_attempt(id, 2), 2);
  EXPECT_EQ(store.record_attempt(id, 9).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(*store.record_worker_failure(id, "w-000001"), 1);
  EXPECT_EQ(*store.record_worker_failure(id, "w-000001"), 2);
  EXPECT_EQ(*store.record_worker_failure(id, "w-000002"), 1);
  EXPECT_EQ(*store.record_worker_failure(id, "w-000001"), 3);
  EXPECT_EQ(*store.worker_failures(id),
            (std::map<std::string, int>{{"w-000001", 3}, {"w-000002", 1}}));
  EXPECT_EQ(store.record_worker_failure("j-000777", "w-000001").status().code(),
            absl::StatusCode::kNotFound);

  // A cancelled job takes no new results; a duplicate of an accepted one is still harmless.
  ASSERT_TRUE(store.set_job_state(id, JobState::kCancelled, 5).ok());
  EXPECT_EQ(store.mark_task_done(id, 0, "dddd").status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_FALSE(*store.mark_task_done(id, 1, "aaaa"));
  EXPECT_EQ(store.add_tasks(id, make_tasks(1)).code(), absl::StatusCode::kFailedPrecondition);
}

// Tasks of a prepass the coordinator decided not to render are skipped: they count as finished,
// leave the pending list, carry no result, and the job can be DONE; skipping again changes
// nothing, a done task cannot be skipped, and the range must lie inside the job.
TEST_F(JobStoreTest, SkippedTasksCountAsFinishedWithoutAResult) {
  JobStore store = open_store();
  std::string id = create(store, 5);
  ASSERT_TRUE(store.set_job_state(id, JobState::kRendering, 2).ok());
  ASSERT_TRUE(store.mark_task_done(id, 0, "aaaa").ok());
  ASSERT_TRUE(store.skip_tasks(id, 1, 3).ok());
  EXPECT_EQ(*store.progress(id), (JobProgress{5, 3, 5 * 512, 3 * 512}));
  ASSERT_TRUE(store.skip_tasks(id, 1, 3).ok());  // a restarted coordinator repeats it
  EXPECT_EQ(*store.progress(id), (JobProgress{5, 3, 5 * 512, 3 * 512}));
  auto tasks = store.tasks_of(id);
  ASSERT_TRUE(tasks.ok());
  EXPECT_EQ((*tasks)[1].state, TaskState::kSkipped);
  EXPECT_EQ((*tasks)[2].state, TaskState::kSkipped);
  EXPECT_TRUE((*tasks)[1].result_hash.empty());
  auto pending = store.pending_tasks(id);
  ASSERT_TRUE(pending.ok());
  ASSERT_EQ(pending->size(), 2u);
  EXPECT_EQ((*pending)[0].index, 3);
  EXPECT_EQ(*store.unshared_results(id), std::vector<std::string>{"aaaa"});
  EXPECT_EQ(store.skip_tasks(id, 0, 2).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store.skip_tasks(id, 4, 6).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store.skip_tasks(id, 3, 2).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store.skip_tasks("j-000777", 0, 1).code(), absl::StatusCode::kNotFound);
  ASSERT_TRUE(store.mark_task_done(id, 3, "bbbb").ok());
  ASSERT_TRUE(store.set_job_state(id, JobState::kFinalising, 3).ok());
  EXPECT_FALSE(store.set_job_state(id, JobState::kDone, 3).ok());  // task 4 is pending
  ASSERT_TRUE(store.skip_tasks(id, 4, 5).ok());
  auto done = store.set_job_state(id, JobState::kDone, 4);
  EXPECT_TRUE(done.ok()) << done.status();
  // The state survives a reopen.
  JobStore again = open_store();
  EXPECT_EQ((*again.tasks_of(id))[2].state, TaskState::kSkipped);
}

TEST_F(JobStoreTest, UnsharedResultsLeaveOutThoseAnotherUnfinishedJobHolds) {
  JobStore store = open_store();
  const std::string a = create(store, 3);
  const std::string b = create(store, 2);
  ASSERT_TRUE(store.mark_task_done(a, 0, "1111").ok());
  ASSERT_TRUE(store.mark_task_done(a, 1, "2222").ok());
  ASSERT_TRUE(store.mark_task_done(a, 2, "2222").ok());  // identical results share one blob
  ASSERT_TRUE(store.mark_task_done(b, 0, "1111").ok());  // the same job submitted twice
  EXPECT_EQ(*store.unshared_results(a), (std::vector<std::string>{"2222"}));
  EXPECT_EQ(*store.unshared_results(b), (std::vector<std::string>{}));
  // Once b is over, its results hold nothing back.
  ASSERT_TRUE(store.set_job_state(b, JobState::kCancelled, 5).ok());
  EXPECT_EQ(*store.unshared_results(a), (std::vector<std::string>{"1111", "2222"}));
  EXPECT_EQ(store.unshared_results("j-000777").status().code(), absl::StatusCode::kNotFound);
}

TEST_F(JobStoreTest, RejectsMalformedTasks) {
  JobStore store = open_store();
  auto gap = make_tasks(3);
  gap[2].index = 3;
  EXPECT_EQ(store.create_job(make_job(), gap).status().code(), absl::StatusCode::kInvalidArgument);
  auto empty_rect = make_tasks(2);
  empty_rect[1].rect = {4, 4, 4, 8};
  EXPECT_EQ(store.create_job(make_job(), empty_rect).status().code(),
            absl::StatusCode::kInvalidArgument);
  auto empty_range = make_tasks(2);
  empty_range[0].samples = {5, 5};
  EXPECT_EQ(store.create_job(make_job(), empty_range).status().code(),
            absl::StatusCode::kInvalidArgument);
  auto done = make_tasks(1);
  done[0].state = TaskState::kDone;
  EXPECT_EQ(store.create_job(make_job(), done).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(count_rows(store.database(), "jobs"), 0);

  // A later pass continues the numbering.
  std::string id = create(store, 2);
  auto next = make_tasks(3);
  EXPECT_EQ(store.add_tasks(id, next).code(), absl::StatusCode::kInvalidArgument);
  for (int i = 0; i < 3; ++i) next[i].index = 2 + i;
  next[2].samples = {16, 48};
  ASSERT_TRUE(store.add_tasks(id, next).ok());
  EXPECT_EQ(*store.progress(id), (JobProgress{5, 0, 4 * 512 + 1024, 0}));
  EXPECT_EQ(store.tasks_of(id)->back().samples, (image::SampleRange{16, 48}));
}

TEST_F(JobStoreTest, ResumeAfterReopenListsNonTerminalJobsAndPendingTasks) {
  std::string rendering, queued, prepass;
  {
    JobStore store = open_store();
    rendering = create(store, 4);
    queued = create(store, 2);
    std::string done = create(store, 1);
    std::string cancelled = create(store, 2);
    std::string failed = create(store, 2);
    prepass = create(store, 3);
    ASSERT_TRUE(store.set_job_state(rendering, JobState::kRendering, 10).ok());
    ASSERT_TRUE(store.mark_task_done(rendering, 0, "h0").ok());
    ASSERT_TRUE(store.mark_task_done(rendering, 2, "h2").ok());
    ASSERT_TRUE(store.record_attempt(rendering, 1).ok());
    ASSERT_TRUE(store.record_worker_failure(rendering, "w-000003").ok());
    ASSERT_TRUE(store.set_job_state(done, JobState::kRendering, 10).ok());
    ASSERT_TRUE(store.mark_task_done(done, 0, "h").ok());
    ASSERT_TRUE(store.set_job_state(done, JobState::kFinalising, 11).ok());
    ASSERT_TRUE(store.set_report(done, R"({"spp":16})").ok());
    ASSERT_TRUE(store.set_job_state(done, JobState::kDone, 12).ok());
    ASSERT_TRUE(store.set_job_state(cancelled, JobState::kCancelled, 10).ok());
    ASSERT_TRUE(store.set_job_state(failed, JobState::kFailed, 10, "worker crashed").ok());
    ASSERT_TRUE(store.set_job_state(prepass, JobState::kPrepass, 10).ok());
    EXPECT_EQ(store.get_job(done)->report_json, R"({"spp":16})");
  }
  JobStore store = open_store();
  auto resume = store.jobs_to_resume();
  ASSERT_TRUE(resume.ok()) << resume.status();
  ASSERT_EQ(resume->size(), 3u);
  EXPECT_EQ((*resume)[0].id, rendering);
  EXPECT_EQ((*resume)[0].state, JobState::kRendering);
  EXPECT_EQ((*resume)[1].id, queued);
  EXPECT_EQ((*resume)[2].id, prepass);

  auto pending = store.pending_tasks(rendering);
  ASSERT_TRUE(pending.ok());
  ASSERT_EQ(pending->size(), 2u);
  EXPECT_EQ((*pending)[0].index, 1);
  EXPECT_EQ((*pending)[0].attempts, 1);
  EXPECT_EQ((*pending)[0].rect, (image::TileRect{8, 0, 16, 4}));
  EXPECT_EQ((*pending)[1].index, 3);
  EXPECT_EQ((*resume)[0].progress, (JobProgress{4, 2, 4 * 512, 2 * 512}));
  EXPECT_EQ(store.pending_tasks(queued)->size(), 2u);
  EXPECT_EQ(store.tasks_of(rendering)->size(), 4u);
  EXPECT_EQ(*store.worker_failures(rendering), (std::map<std::string, int>{{"w-000003", 1}}));
  EXPECT_EQ(store.pending_tasks("j-000999").status().code(), absl::StatusCode::kNotFound);

  // Finishing the resumed job after the restart.
  ASSERT_TRUE(store.mark_task_done(rendering, 1, "h1").ok());
  ASSERT_TRUE(store.mark_task_done(rendering, 3, "h3").ok());
  EXPECT_TRUE(store.pending_tasks(rendering)->empty());
  ASSERT_TRUE(store.set_job_state(rendering, JobState::kFinalising, 20).ok());
  ASSERT_TRUE(store.set_job_state(rendering, JobState::kDone, 21).ok());
  EXPECT_EQ(store.jobs_to_resume()->size(), 2u);
}

TEST_F(JobStoreTest, ListJobsNewestFirstWithStateFilter) {
  JobStore store = open_store();
  std::vector<std::string> ids;
  for (int i = 0; i < 5; ++i) ids.push_back(create(store, 1));
  ASSERT_TRUE(store.set_job_state(ids[1], JobState::kRendering, 1).ok());
  ASSERT_TRUE(store.set_job_state(ids[3], JobState::kCancelled, 1).ok());
  auto all = store.list_jobs(0);
  ASSERT_TRUE(all.ok());
  ASSERT_EQ(all->size(), 5u);
  for (int i = 0; i < 5; ++i) EXPECT_EQ((*all)[i].id, ids[4 - i]);
  auto two = store.list_jobs(2);
  ASSERT_EQ(two->size(), 2u);
  EXPECT_EQ((*two)[0].id, ids[4]);
  EXPECT_EQ((*two)[1].id, ids[3]);
  const JobState active[] = {JobState::kRendering, JobState::kCancelled};
  auto filtered = store.list_jobs(0, active);
  ASSERT_EQ(filtered->size(), 2u);
  EXPECT_EQ((*filtered)[0].id, ids[3]);
  EXPECT_EQ((*filtered)[1].id, ids[1]);
}

TEST_F(JobStoreTest, ConcurrentReaderSeesCommittedDataOnly) {
  JobStore store = open_store();
  std::string first = create(store);
  auto reader = Database::open(file_);
  ASSERT_TRUE(reader.ok()) << reader.status();
  auto rows = reader->query("SELECT id, state FROM jobs");
  ASSERT_TRUE(rows.ok()) << rows.status();
  ASSERT_EQ(rows->size(), 1u);
  EXPECT_EQ((*rows)[0].text(0), first);
  // Stored as TEXT, so ad-hoc queries with literals work.
  EXPECT_EQ(reader->query("SELECT id FROM jobs WHERE id = 'j-000001'")->size(), 1u);

  // A reader's snapshot does not block the writer, and does not see its later commits.
  ASSERT_TRUE(reader->exec("BEGIN").ok());
  EXPECT_EQ(count_rows(*reader, "jobs"), 1);
  create(store);
  EXPECT_EQ(count_rows(*reader, "jobs"), 1);
  ASSERT_TRUE(reader->exec("COMMIT").ok());
  EXPECT_EQ(count_rows(*reader, "jobs"), 2);
  EXPECT_EQ(count_rows(*reader, "tasks"), 4);

  // Uncommitted writes are invisible to the reader, which does not block on them.
  auto status = store.database().transaction([&]() -> absl::Status {
    auto s = store.database().run("UPDATE jobs SET state = 3 WHERE id = 'j-000001'");
    if (!s.ok()) return s;
    auto state = reader->query("SELECT state FROM jobs WHERE id = 'j-000001'");
    if (!state.ok()) return state.status();
    EXPECT_EQ((*state)[0].integer(0), static_cast<int>(JobState::kQueued));
    return absl::OkStatus();
  });
  ASSERT_TRUE(status.ok()) << status;
  EXPECT_EQ((*reader->query("SELECT state FROM jobs WHERE id = 'j-000001'"))[0].integer(0),
            static_cast<int>(JobState::kRendering));
}

TEST_F(JobStoreTest, FailedTransactionLeavesNoPartialRows) {
  {
    JobStore store = open_store();
    // Make the sixth task insert fail after the job row and five tasks are written.
    ASSERT_TRUE(store.database()
                    .exec("CREATE TRIGGER fail_task BEFORE INSERT ON tasks WHEN NEW.task_index = 5 "
                          "BEGIN SELECT RAISE(ABORT, 'injected failure'); END")
                    .ok());
    auto failed = store.create_job(make_job("tok"), make_tasks(10));
    ASSERT_FALSE(failed.ok());
    EXPECT_NE(failed.status().message().find("injected failure"), std::string::npos);
    EXPECT_EQ(count_rows(store.database(), "jobs"), 0);
    EXPECT_EQ(count_rows(store.database(), "tasks"), 0);
    ASSERT_TRUE(store.database().exec("DROP TRIGGER fail_task").ok());

    // The failed create consumed neither the id nor the token.
    auto created = store.create_job(make_job("tok"), make_tasks(10));
    ASSERT_TRUE(created.ok()) << created.status();
    EXPECT_FALSE(created->existed);
    EXPECT_EQ(created->job.id, "j-000001");

    // A failing counter update undoes the task's done mark.
    ASSERT_TRUE(store.database()
                    .exec("CREATE TRIGGER fail_progress BEFORE UPDATE OF tasks_done ON jobs "
                          "BEGIN SELECT RAISE(ABORT, 'injected failure'); END")
                    .ok());
    EXPECT_FALSE(store.mark_task_done("j-000001", 0, "h").ok());
    EXPECT_EQ(store.tasks_of("j-000001")->front().state, TaskState::kPending);
    ASSERT_TRUE(store.database().exec("DROP TRIGGER fail_progress").ok());
  }

  // A process killed in the middle of a transaction leaves nothing of it behind.
  pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    auto store = JobStore::open(file_);
    if (!store.ok()) ::_exit(2);
    (void)store->database().transaction([&]() -> absl::Status {
      (void)store->database().run(
          "INSERT INTO jobs (id, spec, bundle_hash, state, submitted_ms) "
          "VALUES ('j-000002', x'00', 'h', 1, 0)");
      (void)store->database().run(
          "INSERT INTO tasks (job_id, task_index, pass, pass_index, tile_index, x0, y0, x1, y1, "
          "s0, s1, state) VALUES ('j-000002', 0, 2, 0, 0, 0, 0, 8, 8, 0, 4, 0)");
      ::_exit(count_rows(store->database(), "jobs") == 2 ? 0 : 3);
      return absl::OkStatus();
    });
    ::_exit(4);
  }
  int wstatus = 0;
  ASSERT_EQ(::waitpid(child, &wstatus, 0), child);
  ASSERT_TRUE(WIFEXITED(wstatus));
  ASSERT_EQ(WEXITSTATUS(wstatus), 0);

  JobStore store = open_store();
  EXPECT_EQ(count_rows(store.database(), "jobs"), 1);
  EXPECT_EQ(count_rows(store.database(), "tasks"), 10);
  EXPECT_EQ((*store.database().query("PRAGMA integrity_check"))[0].text(0), "ok");
  EXPECT_EQ(store.get_job("j-000001")->progress, (JobProgress{10, 0, 10 * 512, 0}));
  EXPECT_EQ(create(store), "j-000002");
}

TEST_F(JobStoreTest, IdsAreMonotonicAcrossReopen) {
  {
    JobStore store = open_store();
    EXPECT_EQ(create(store), "j-000001");
    EXPECT_EQ(create(store), "j-000002");
    EXPECT_EQ(create(store), "j-000003");
    EXPECT_EQ(store.register_worker({})->id, "w-000001");
  }
  {
    JobStore store = open_store();
    EXPECT_EQ(create(store), "j-000004");
    EXPECT_EQ(store.register_worker({})->id, "w-000002");
  }
  JobStore store = open_store();
  EXPECT_EQ(create(store), "j-000005");
}

TEST_F(JobStoreTest, WorkersRegisterReattachAndTouch) {
  WorkerRecord registered;
  {
    JobStore store = open_store();
    WorkerRecord w;
    w.host = "render-01";
    w.version = "0.1.0";
    w.threads = 8;
    w.capabilities = {"integrator:hero", "prepass"};
    w.last_seen_ms = 100;
    auto stored = store.register_worker(w);
    ASSERT_TRUE(stored.ok()) << stored.status();
    registered = *stored;
    EXPECT_EQ(registered.id, "w-000001");
    WorkerRecord bad = w;
    bad.capabilities = {"a\nb"};
    EXPECT_EQ(store.register_worker(bad).status().code(), absl::StatusCode::kInvalidArgument);
  }
  JobStore store = open_store();
  EXPECT_EQ(*store.get_worker("w-000001"), registered);
  WorkerRecord reattach = registered;
  reattach.threads = 16;
  reattach.capabilities.clear();
  ASSERT_TRUE(store.register_worker(reattach).ok());
  ASSERT_TRUE(store.touch_worker("w-000001", 900).ok());
  auto workers = store.list_workers();
  ASSERT_TRUE(workers.ok());
  ASSERT_EQ(workers->size(), 1u);
  EXPECT_EQ((*workers)[0].threads, 16);
  EXPECT_TRUE((*workers)[0].capabilities.empty());
  EXPECT_EQ((*workers)[0].last_seen_ms, 900);
  EXPECT_EQ(store.touch_worker("w-000042", 1).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store.get_worker("w-000042").status().code(), absl::StatusCode::kNotFound);
}

// A clean leave is kept (a restarted coordinator lists the worker as left), registering again
// clears it, and records of workers long gone are forgotten, except the live ones.
TEST_F(JobStoreTest, WorkersLeaveAndAreForgotten) {
  JobStore store = open_store();
  std::vector<std::string> ids;
  for (int i = 0; i < 3; ++i) {
    WorkerRecord w;
    w.host = "pod-" + std::to_string(i);
    w.last_seen_ms = 100 * (i + 1);
    auto stored = store.register_worker(w);
    ASSERT_TRUE(stored.ok()) << stored.status();
    ids.push_back(stored->id);
  }
  ASSERT_TRUE(store.mark_worker_left(ids[0], 150).ok());
  EXPECT_EQ(store.mark_worker_left("w-000042", 1).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store.get_worker(ids[0])->left_ms, 150);
  EXPECT_EQ(store.get_worker(ids[0])->last_seen_ms, 150);
  WorkerRecord back = *store.get_worker(ids[1]);
  back.left_ms = 0;
  ASSERT_TRUE(store.mark_worker_left(ids[1], 250).ok());
  ASSERT_TRUE(store.register_worker(back).ok());
  EXPECT_EQ(store.get_worker(ids[1])->left_ms, 0) << "registering again clears the leave";
  // Seen before 260: ids[0] (150) and ids[1] (200); ids[1] is live and kept.
  auto forgotten = store.forget_workers(260, {ids[1]});
  ASSERT_TRUE(forgotten.ok()) << forgotten.status();
  EXPECT_EQ(*forgotten, 1);
  EXPECT_EQ(store.get_worker(ids[0]).status().code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(store.get_worker(ids[1]).ok());
  EXPECT_TRUE(store.get_worker(ids[2]).ok());
}

}  // namespace
}  // namespace prism::store
