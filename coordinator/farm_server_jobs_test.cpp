// Jobs through the coordinator's gRPC services: idempotent submission, admission limits and bad
// specs, restarts that resume (and store a large job's remaining tasks), results from an earlier
// version's blob store, cancels, scene faults, and outputs written without the farm's lock.
#include "coordinator/farm_server_fixture.h"
#include "services/job/job_spec.h"

namespace prism::coordinator {
namespace {

using namespace farm_server_testing;  // also fs (std::filesystem) and v1 (prism::v1)

TEST_F(FarmServerTest, SubmitIsIdempotentByClientToken) {
  const v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  const v1::JobInfo a = submit(spec, "token-1");
  const v1::JobInfo b = submit(spec, "token-1");
  const v1::JobInfo c = submit(spec, "token-2");
  EXPECT_EQ(a.job_id(), b.job_id());
  EXPECT_NE(a.job_id(), c.job_id());
  v1::ListJobsRequest request;
  v1::ListJobsResponse response;
  auto context = client();
  ASSERT_TRUE(farm_stub_->ListJobs(context.get(), request, &response).ok());
  EXPECT_EQ(response.jobs_size(), 2);

  // The token with another request is a mistake, not a retry: answering with token-1's job
  // gave a user another scene's image under the name they asked for.
  v1::JobSpec other = spec;
  other.set_spp(spec.spp() + 1);
  v1::JobInfo refused;
  const grpc::Status status = try_submit(other, "token-1", &refused);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::ALREADY_EXISTS) << status.error_message();
  EXPECT_NE(status.error_message().find("client token 'token-1' belongs to job " + a.job_id() +
                                        ", submitted with another request"),
            std::string::npos)
      << status.error_message();
  // After a restart too (the request's hash is stored with the job).
  stop();
  start();
  EXPECT_EQ(try_submit(other, "token-1", &refused).error_code(), grpc::StatusCode::ALREADY_EXISTS);
  EXPECT_EQ(submit(spec, "token-1").job_id(), a.job_id());
}

// `auto` records its pilot's wall time in the spec; a resubmission of the same scene and options
// measured another time and is still the same request (the default token and a given token's
// check both ignore it), so a retry finds its job instead of making a second or being refused.
TEST_F(FarmServerTest, AutosPilotTimeDoesNotMakeAnotherRequest) {
  v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  spec.set_integrator(v1::INTEGRATOR_HERO);
  spec.mutable_auto_choice()->set_choice("hero");
  spec.mutable_auto_choice()->set_reason("test");
  spec.mutable_auto_choice()->set_seconds(0.0022);
  const v1::JobInfo a = submit(spec, "retry-key");
  v1::JobSpec again = spec;
  again.mutable_auto_choice()->set_seconds(0.0101);
  EXPECT_EQ(submit(again, "retry-key").job_id(), a.job_id());
  EXPECT_EQ(job::request_identity(spec), job::request_identity(again));
  // What auto chose is part of the request.
  v1::JobSpec other = again;
  other.mutable_auto_choice()->set_reason("another");
  EXPECT_NE(job::request_identity(other), job::request_identity(spec));
  v1::JobInfo refused;
  EXPECT_EQ(try_submit(other, "retry-key", &refused).error_code(),
            grpc::StatusCode::ALREADY_EXISTS);
}

// A coordinator killed while writing a job's outputs leaves temporaries beside them; the
// finalising runs again after the restart, under new names, and the restart removes the old.
TEST_F(FarmServerTest, ARestartRemovesTheTemporariesOfOutputsBeingWritten) {
  stop();
  const fs::path outputs = root_ / "data" / "outputs" / "j-000001";
  fs::create_directories(outputs);
  std::ofstream(outputs / ".j-000001.exr.tmp.27999.15") << "half";
  std::ofstream(outputs / "j-000001.exr") << "whole";
  start();
  EXPECT_FALSE(fs::exists(outputs / ".j-000001.exr.tmp.27999.15"));
  EXPECT_TRUE(fs::exists(outputs / "j-000001.exr"));
}

TEST_F(FarmServerTest, ARestartResumesWithoutReleasingFinishedTasks) {
  const v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  const std::string job_id = submit(spec).job_id();
  const auto first = run_worker(register_worker(), 7);
  ASSERT_EQ(first.size(), 7u);
  // Tiles 0-2 (tasks 0-5) finished and went to the tile pack; tile 3 has one of its two
  // ranges. The janitor syncs the tile pack and releases the finished tiles' six range results
  // from the result pack, so the restart can only take tiles 0-2 from the tile pack (a missing
  // range result's task would run again).
  const auto released = [&] {
    const absl::StatusOr<std::string> text = farm_->farm().metrics_text();
    EXPECT_TRUE(text.ok()) << text.status();
    const std::string name = "\nprism_results_released_total ";
    const std::size_t at = text.ok() ? text->find(name) : std::string::npos;
    return at == std::string::npos ? -1.0 : std::stod(text->substr(at + name.size()));
  };
  for (int i = 0; i < 500 && released() < 6; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(released(), 6.0);
  stop();

  const fs::path data = root_ / "data";
  ASSERT_GT(fs::file_size(data / "jobs" / job_id / "tiles" / "tiles.pack"), 0u);
  {
    auto store = store::JobStore::open(data / "jobs.sqlite");
    ASSERT_TRUE(store.ok()) << store.status();
    auto tasks = store->tasks_of(job_id);
    ASSERT_TRUE(tasks.ok()) << tasks.status();
    std::ifstream pack(data / "jobs" / job_id / "results.pack", std::ios::binary);
    ASSERT_TRUE(pack.is_open());
    for (const store::TaskRecord& task : *tasks) {
      if (task.state != store::TaskState::kDone) continue;
      ASSERT_GE(task.result_offset, 0) << "task " << task.index;
      std::string bytes(task.result_size, '\0');
      pack.seekg(task.result_offset);
      pack.read(bytes.data(), std::streamsize(bytes.size()));
      ASSERT_TRUE(pack.good()) << "task " << task.index;
      if (task.tile_index < 3) {
        EXPECT_EQ(bytes, std::string(task.result_size, '\0')) << "task " << task.index;
      } else {
        EXPECT_EQ(base::sha256_hex(bytes), task.result_hash) << "task " << task.index;
      }
    }
  }

  start();
  const auto second = run_worker(register_worker());
  EXPECT_EQ(second.size(), 11u);
  std::set<std::pair<int, int>> all(first.begin(), first.end());
  for (const auto& task : second) EXPECT_FALSE(all.contains(task)) << "re-rendered a finished task";
  all.insert(second.begin(), second.end());
  EXPECT_EQ(all.size(), 18u);
  const v1::JobInfo done = wait_done(job_id);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  expect_identical(fetch_spectral_exr(job_id), spec);
  stop();

  // From the store: every task was leased exactly once across both incarnations.
  auto store = store::JobStore::open(root_ / "data" / "jobs.sqlite");
  ASSERT_TRUE(store.ok()) << store.status();
  auto tasks = store->tasks_of(job_id);
  ASSERT_TRUE(tasks.ok());
  for (const store::TaskRecord& task : *tasks) {
    EXPECT_EQ(task.attempts, 1) << "task " << task.index;
    EXPECT_EQ(task.state, store::TaskState::kDone);
  }
  // The finished job keeps its outputs and nothing else.
  EXPECT_EQ(count_files(data / "blobs"), 0u);
  EXPECT_FALSE(fs::exists(data / "jobs" / job_id));
  EXPECT_EQ(count_files(data / "outputs" / job_id), 4u);
}

// By default a task is all of a tile's samples: the finished tile is its one range result,
// already in the result pack, so the tile pack holds a 56-byte link to it instead of a second
// copy, nothing is released, and a restart reads the linked tiles from the result pack.
TEST_F(FarmServerTest, ATileOfOneRangeIsALinkToItsResult) {
  v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  spec.set_samples_per_task(0);  // 9 tiles of 4x4 (the last row 4x2), one task each
  const std::string job_id = submit(spec).job_id();
  const auto first = run_worker(register_worker(), 4);
  ASSERT_EQ(first.size(), 4u);
  stop();

  const fs::path job_dir = root_ / "data" / "jobs" / job_id;
  EXPECT_EQ(fs::file_size(job_dir / "tiles" / "tiles.pack"), 4u * 56u);
  {
    auto store = store::JobStore::open(root_ / "data" / "jobs.sqlite");
    ASSERT_TRUE(store.ok()) << store.status();
    auto tasks = store->tasks_of(job_id);
    ASSERT_TRUE(tasks.ok()) << tasks.status();
    ASSERT_EQ(tasks->size(), 9u);
    std::ifstream pack(job_dir / "results.pack", std::ios::binary);
    int done = 0;
    for (const store::TaskRecord& task : *tasks) {
      if (task.state != store::TaskState::kDone) continue;
      ++done;
      std::string bytes(task.result_size, '\0');
      pack.seekg(task.result_offset);
      pack.read(bytes.data(), std::streamsize(bytes.size()));
      EXPECT_EQ(base::sha256_hex(bytes), task.result_hash) << "task " << task.index;
    }
    EXPECT_EQ(done, 4);
  }

  start();
  const auto second = run_worker(register_worker());
  EXPECT_EQ(second.size(), 5u);
  const v1::JobInfo done = wait_done(job_id);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  expect_identical(fetch_spectral_exr(job_id), spec);
}

// The dashboard's convergence series outlives the coordinator: after a restart it holds the
// points from before, and goes on from the replayed results (the error at the end is the one an
// uninterrupted run of the same job reaches); after the job's end a fresh coordinator still
// serves it, from its file.
TEST_F(FarmServerTest, TheConvergenceSeriesSurvivesARestartAndTheJobsEnd) {
  const v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  const std::string job_id = submit(spec).job_id();
  ASSERT_EQ(run_worker(register_worker(), 7).size(), 7u);
  auto before = farm_->farm().convergence(job_id);
  ASSERT_TRUE(before.ok()) << before.status();
  ASSERT_EQ(before->size(), 7u);
  stop();

  start();
  auto resumed = farm_->farm().convergence(job_id);
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  ASSERT_EQ(resumed->size(), 7u);
  for (std::size_t i = 0; i < 7; ++i) {
    EXPECT_EQ((*resumed)[i].seconds, (*before)[i].seconds);
    EXPECT_EQ((*resumed)[i].samples, (*before)[i].samples);
    EXPECT_EQ((*resumed)[i].relative_error, (*before)[i].relative_error);
  }
  ASSERT_EQ(run_worker(register_worker()).size(), 11u);
  ASSERT_EQ(wait_done(job_id).state(), v1::JOB_STATE_DONE);
  auto series = farm_->farm().convergence(job_id);
  ASSERT_TRUE(series.ok()) << series.status();
  ASSERT_EQ(series->size(), 18u);
  for (std::size_t i = 1; i < series->size(); ++i) {
    EXPECT_GE((*series)[i].seconds, (*series)[i - 1].seconds) << i;
    EXPECT_GT((*series)[i].samples, (*series)[i - 1].samples) << i;
  }
  EXPECT_EQ(series->back().samples, 12u * 10u * 4u);

  // The same job again, uninterrupted.
  const std::string again_id = submit(spec).job_id();
  ASSERT_NE(again_id, job_id);
  run_worker(register_worker());
  ASSERT_EQ(wait_done(again_id).state(), v1::JOB_STATE_DONE);
  auto again = farm_->farm().convergence(again_id);
  ASSERT_TRUE(again.ok() && !again->empty());
  // The resumed job knows its finished tiles as merged float32 sums (tile_merge.h), the
  // uninterrupted one added their ranges: a few float32 roundings apart.
  EXPECT_NEAR(series->back().relative_error, again->back().relative_error,
              1e-6 * again->back().relative_error);
  stop();

  start();
  auto after_end = farm_->farm().convergence(job_id);
  ASSERT_TRUE(after_end.ok()) << after_end.status();
  ASSERT_EQ(after_end->size(), 18u);
  EXPECT_EQ(after_end->back().relative_error, series->back().relative_error);
}

// A data directory from before result packs: a job's results are blobs (result_offset -1) and
// its finished tiles files this version does not read. The restarted coordinator merges the
// blobs again, renders only the rest, gives the embedded render's bytes and deletes the blobs.
TEST_F(FarmServerTest, ResultsStoredAsBlobsByAnEarlierVersionAreResumed) {
  const v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  const std::string job_id = submit(spec).job_id();
  ASSERT_EQ(run_worker(register_worker(), 7).size(), 7u);
  stop();
  const fs::path data = root_ / "data";
  {
    auto store = store::JobStore::open(data / "jobs.sqlite");
    ASSERT_TRUE(store.ok()) << store.status();
    auto blobs = store::BlobStore::open(data / "blobs");
    ASSERT_TRUE(blobs.ok());
    auto tasks = store->tasks_of(job_id);
    ASSERT_TRUE(tasks.ok()) << tasks.status();
    int moved = 0;
    for (const store::TaskRecord& task : *tasks) {
      if (task.state != store::TaskState::kDone) continue;
      // Rendered again (the janitor may have released the pack's copy: the tile is stored).
      v1::Lease lease;
      *lease.mutable_task()->mutable_spec() = spec;
      v1::TileRect& rect = *lease.mutable_task()->mutable_tile();
      rect.set_x0(task.rect.x0);
      rect.set_y0(task.rect.y0);
      rect.set_x1(task.rect.x1);
      rect.set_y1(task.rect.y1);
      lease.mutable_task()->mutable_samples()->set_begin(task.samples.s0);
      lease.mutable_task()->mutable_samples()->set_end(task.samples.s1);
      const std::string bytes = render(lease);
      auto put = blobs->put(bytes);
      ASSERT_TRUE(put.ok()) << put.status();
      ASSERT_EQ(*put, task.result_hash);
      ASSERT_TRUE(store->database()
                      .run("UPDATE tasks SET result_offset = -1, result_size = 0 "
                           "WHERE job_id = ? AND task_index = ?",
                           {job_id, std::int64_t{task.index}})
                      .ok());
      ++moved;
    }
    EXPECT_EQ(moved, 7);
  }
  fs::remove(data / "jobs" / job_id / "results.pack");
  fs::remove(data / "jobs" / job_id / "tiles" / "tiles.pack");
  start();
  EXPECT_EQ(run_worker(register_worker()).size(), 11u);
  const v1::JobInfo done = wait_done(job_id);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  expect_identical(fetch_spectral_exr(job_id), spec);
  EXPECT_EQ(count_files(data / "blobs"), 0u);
}

// Issue 18, case 4: cancelling a job with a few hundred finished tiles took 10-11 s, deleting
// its files under the coordinator's lock. Cancel now only moves them out of the way (renames);
// the job's tiles and results are gone from the store when it returns, and the janitor frees
// the space afterwards, without the lock.
TEST_F(FarmServerTest, CancelMovesAJobsFilesOutAtOnceAndTheJanitorDeletesThem) {
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  ASSERT_EQ(run_worker(register_worker(), 7).size(), 7u);
  const fs::path data = root_ / "data";
  ASSERT_GT(fs::file_size(data / "jobs" / job_id / "tiles" / "tiles.pack"), 0u);
  ASSERT_GT(fs::file_size(data / "jobs" / job_id / "results.pack"), 0u);
  v1::JobInfo info;
  ASSERT_TRUE(cancel_job(job_id, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_FALSE(fs::exists(data / "jobs" / job_id));
  EXPECT_EQ(count_files(data / "blobs"), 0u);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (count_files(data / "trash") > 0 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(count_files(data / "trash"), 0u);
}

TEST_F(FarmServerTest, ASceneFaultFailsTheJobWithTheWorkersMessage) {
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  const std::string worker_id = register_worker();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  ASSERT_TRUE(fail_task(worker_id, lease->lease_id(), v1::FAILURE_CLASS_SCENE,
                        "scene.pbrt:9:3: the sphere is made of cheese")
                  .ok());
  const v1::JobInfo info = wait_done(job_id);
  EXPECT_EQ(info.state(), v1::JOB_STATE_FAILED);
  EXPECT_NE(info.error().find("the sphere is made of cheese"), std::string::npos) << info.error();
  EXPECT_FALSE(acquire(worker_id).has_value());
}

TEST_F(FarmServerTest, SubmissionsBeyondTheQueueLimitAreResourceExhausted) {
  stop();
  configure_ = [](FarmOptions& options) { options.max_queued_jobs = 1; };
  start();
  const v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  submit(spec, "first");
  grpc::Status status = try_submit(spec, "second");
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(status.error_message().find("--max-queued-jobs 1"), std::string::npos)
      << status.error_message();
  // A repeat of the accepted submission is still answered.
  EXPECT_FALSE(submit(spec, "first").job_id().empty());
}

// Issue 18, "found under load" case 1: the farm accepted a 16384x16384 job that would have
// needed ~2 TB of disk and GBs of coordinator memory. Admission control refuses what does not
// fit the budgets, with the numbers, before allocating anything; what fits is accepted, and a
// cancelled job gives its share back.
TEST_F(FarmServerTest, JobsBeyondTheMemoryOrDiskBudgetAreRefusedWithTheNumbers) {
  stop();
  configure_ = [](FarmOptions& options) {
    options.max_memory_bytes = 64 << 20;
    options.max_disk_bytes = std::uint64_t{100} << 30;
  };
  start();
  const std::string hash = upload_scene();
  ASSERT_FALSE(hash.empty());
  auto submit_sized = [&](int side, int bins, const std::string& token, v1::JobInfo* info) {
    v1::JobSpec spec = small_spec(hash);
    spec.set_width(static_cast<std::uint32_t>(side));
    spec.set_height(static_cast<std::uint32_t>(side));
    spec.set_bins(static_cast<std::uint32_t>(bins));
    spec.set_tile_size(64);
    spec.set_samples_per_task(0);
    return try_submit(spec, token, info);
  };
  // 16384² at 32 bins: ~200 GiB of finished tiles and outputs.
  grpc::Status huge = submit_sized(16384, 32, "huge", nullptr);
  EXPECT_EQ(huge.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(huge.error_message().find("a job of 16384x16384 with 32 bins needs about"),
            std::string::npos)
      << huge.error_message();
  // Refused on memory (its RGB image alone is 3 GiB) before disk is looked at.
  EXPECT_NE(huge.error_message().find("of memory (RGB image 3.0 GiB"), std::string::npos)
      << huge.error_message();
  // 1024² at 16 bins with 64-pixel tiles plans 12 MiB of RGB, 8 MiB for a row of tiles (and
  // its finalised copy) and 3 MiB of PNG: two fit in 64 MiB, a third does not.
  v1::JobInfo first;
  ASSERT_TRUE(submit_sized(1024, 16, "a", &first).ok());
  ASSERT_TRUE(submit_sized(1024, 16, "b", nullptr).ok());
  grpc::Status third = submit_sized(1024, 16, "c", nullptr);
  EXPECT_EQ(third.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(third.error_message().find("more than the 64 MiB allowed (--max-memory; the "
                                       "unfinished jobs plan 46 MiB)"),
            std::string::npos)
      << third.error_message();
  // Cancelling gives the first job's share back.
  v1::JobInfo cancelled;
  ASSERT_TRUE(cancel_job(first.job_id(), &cancelled).ok());
  EXPECT_TRUE(submit_sized(1024, 16, "c", nullptr).ok());

  // Disk: within the memory budget but over --max-disk.
  stop();
  configure_ = [](FarmOptions& options) {
    options.max_memory_bytes = std::uint64_t{1} << 40;
    options.max_disk_bytes = 64 << 20;
  };
  start();
  grpc::Status disk = submit_sized(2048, 64, "disk", nullptr);
  EXPECT_EQ(disk.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(disk.error_message().find("of disk (finished tiles"), std::string::npos)
      << disk.error_message();
  // Over --max-disk alone: waiting for the other jobs would not help, and it says so not.
  EXPECT_NE(disk.error_message().find("(--max-disk 64 MiB); use fewer bins or a smaller "
                                      "resolution"),
            std::string::npos)
      << disk.error_message();
  // A small job fits alone, but the two unfinished 1024² jobs resumed with the restart and
  // count too: that refusal says to wait.
  grpc::Status later = submit_sized(64, 16, "later", nullptr);
  EXPECT_EQ(later.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(later.error_message().find("(--max-disk 64 MiB less the unfinished jobs' "),
            std::string::npos)
      << later.error_message();
  EXPECT_NE(later.error_message().find("or wait for the farm's unfinished jobs"), std::string::npos)
      << later.error_message();
}

// The data directory's free space is shared with the unfinished jobs: each new job is checked
// against what is free less what those still plan to write. Checked against the free space
// alone, twelve 10 MiB jobs were let onto a 20 MiB disk, and the last ones failed writing their
// outputs after they had been accepted.
TEST_F(FarmServerTest, TheFreeDiskIsSharedWithTheUnfinishedJobs) {
  stop();
  configure_ = [](FarmOptions& options) {
    options.max_memory_bytes = std::uint64_t{1} << 40;
    options.free_disk = [](const fs::path&) -> absl::StatusOr<std::uint64_t> {
      return std::uint64_t{800} << 20;  // an 800 MiB disk that nothing fills
    };
  };
  start();
  const std::string hash = upload_scene();
  ASSERT_FALSE(hash.empty());
  auto submit_sized = [&](const std::string& token) {
    v1::JobSpec spec = small_spec(hash);
    spec.set_width(1024);
    spec.set_height(1024);
    spec.set_bins(16);
    spec.set_tile_size(64);
    spec.set_samples_per_task(0);
    return try_submit(spec, token, nullptr);
  };
  // Each plans 315 MiB of disk (finished tiles 224 MiB, outputs 91 MiB): two fit in 800 MiB, a
  // third does not while they are unfinished.
  const grpc::Status a = submit_sized("a");
  ASSERT_TRUE(a.ok()) << a.error_message();
  ASSERT_TRUE(submit_sized("b").ok());
  const grpc::Status third = submit_sized("c");
  EXPECT_EQ(third.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << third.error_message();
  EXPECT_NE(third.error_message().find("less what the unfinished jobs still plan to write"),
            std::string::npos)
      << third.error_message();
}

// A cancel the job store cannot record (its disk is full) fails with nothing changed: the job
// renders on. The scheduler used to be told first, so it stopped handing out the job's tasks
// while the store and the job list said it was rendering, until a restart.
TEST_F(FarmServerTest, ACancelTheStoreCannotRecordChangesNothing) {
  std::atomic<bool> full{true};
  stop();
  configure_ = [&full](FarmOptions& options) {
    options.disk_fault = [&full](std::string_view what) -> absl::Status {
      if (full && what == "cancel")
        return absl::InternalError("sqlite: step 'COMMIT': database or disk is full");
      return absl::OkStatus();
    };
  };
  start();
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  v1::JobInfo info;
  const grpc::Status refused = cancel_job(job_id, &info);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::INTERNAL);
  EXPECT_NE(refused.error_message().find("cannot cancel job " + job_id +
                                         ": sqlite: step 'COMMIT': database or disk is full; "
                                         "the job goes on as it was"),
            std::string::npos)
      << refused.error_message();
  const std::string worker_id = register_worker();
  EXPECT_FALSE(run_worker(worker_id).empty());
  ASSERT_TRUE(get_job(job_id, &info).ok());
  EXPECT_EQ(info.progress().tasks_done(), info.progress().tasks_total());
  // With room again a cancel of another job goes through.
  full = false;
  const std::string other = submit_small_job();
  ASSERT_TRUE(cancel_job(other, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_CANCELLED);
}

// The data directory holds back a MiB so that a cancel can be recorded on a full disk (a job
// that filled it could not be cancelled: the store's COMMIT failed, before and after restarts).
TEST_F(FarmServerTest, ACancelOnAFullDiskUsesTheDiskReserve) {
  const fs::path reserve = root_ / "data" / "disk.reserve";
  EXPECT_EQ(fs::file_size(reserve), 1u << 20);
  stop();
  std::atomic<int> attempts{0};
  configure_ = [&](FarmOptions& options) {
    // Full while the reserve takes its space.
    options.disk_fault = [&](std::string_view what) -> absl::Status {
      if (what != "cancel") return absl::OkStatus();
      ++attempts;
      return fs::exists(reserve)
                 ? absl::InternalError("sqlite: step 'COMMIT': database or disk is full")
                 : absl::OkStatus();
    };
  };
  start();
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  v1::JobInfo info;
  ASSERT_TRUE(cancel_job(job_id, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(attempts, 2);
  // The janitor makes the reserve again once there is room (here at once) for the next one.
  for (int i = 0; i < 100 && !fs::exists(reserve); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(fs::file_size(reserve), 1u << 20);
}

// Outputs that meet a full disk are written again once there is room: the job waits in
// FINALISING and says why. It used to fail, and its finished tiles were deleted with it.
TEST_F(FarmServerTest, OutputsThatMeetAFullDiskAreWrittenAgainLater) {
  std::atomic<int> attempts{0};
  stop();
  configure_ = [&attempts](FarmOptions& options) {
    options.finalise_retry_delay = Millis(1000);  // 1 s, then 2 s: past run_worker's idle end
    options.disk_fault = [&attempts](std::string_view what) -> absl::Status {
      if (what == "outputs" && ++attempts <= 2) {
        return absl::InternalError("cannot write j.exr.tmp: No space left on device");
      }
      return absl::OkStatus();
    };
  };
  start();
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  EXPECT_FALSE(run_worker(register_worker()).empty());
  v1::JobInfo info;
  bool said_why = false;
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (std::chrono::steady_clock::now() < end) {
    ASSERT_TRUE(get_job(job_id, &info).ok());
    if (info.state() == v1::JOB_STATE_FINALISING &&
        info.waiting().find("cannot write the outputs (cannot write j.exr.tmp: No space left on "
                            "device): waiting for disk space") != std::string::npos) {
      said_why = true;
    }
    if (info.state() != v1::JOB_STATE_FINALISING && info.state() != v1::JOB_STATE_RENDERING) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_EQ(info.state(), v1::JOB_STATE_DONE) << info.error();
  EXPECT_TRUE(said_why);
  EXPECT_EQ(attempts.load(), 3);
  EXPECT_TRUE(fs::exists(root_ / "data" / "outputs" / job_id / (job_id + ".exr")));
}

TEST_F(FarmServerTest, ABadSpecIsInvalidArgumentNamingTheField) {
  v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  spec.set_bins(1000);
  const grpc::Status status = try_submit(spec);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(status.error_message(), "bins 1000 is out of range: want 4..256");
}

// Issue 18: storing a job of hundreds of thousands of tasks held the coordinator's lock for
// seconds, and every heartbeat, lease and query waited. The tasks are stored in parts with the
// lock released between them (4 tasks a part here, 18 tasks): at each pause the farm answers
// another call and the job reads QUEUED with the tasks stored so far. A coordinator that
// stops in the middle (simulated: the hook ends the submission as a crash would) stores the
// rest when it restarts, and the job renders the embedded render's bytes.
TEST_F(FarmServerTest, ALargeJobsTasksAreStoredInPartsAndARestartStoresTheRest) {
  stop();
  std::vector<std::uint64_t> stored_at_pause;
  bool crash = true;
  auto between_parts = [&](const std::string& job_id) -> absl::Status {
    // Another thread's call is answered while the submission pauses (were the lock held, it
    // would wait for it: the test's 30 s deadline would fail it).
    auto query = std::async(std::launch::async, [&] {
      v1::GetJobRequest request;
      request.set_job_id(job_id);
      v1::JobInfo info;
      auto context = client();
      const grpc::Status status = farm_stub_->GetJob(context.get(), request, &info);
      EXPECT_TRUE(status.ok()) << status.error_message();
      EXPECT_EQ(info.state(), v1::JOB_STATE_QUEUED);
      return info.progress().tasks_total();
    });
    stored_at_pause.push_back(query.get());
    if (crash && stored_at_pause.size() == 2) return absl::UnavailableError("stopped here");
    return absl::OkStatus();
  };
  configure_ = [&](FarmOptions& options) {
    options.tasks_per_store_part = 4;
    options.between_task_parts = between_parts;
  };
  start();
  const std::string hash = upload_scene();
  ASSERT_FALSE(hash.empty());
  const v1::JobSpec spec = small_spec(hash);  // 9 tiles x 2 ranges
  EXPECT_EQ(try_submit(spec).error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_EQ(stored_at_pause, (std::vector<std::uint64_t>{4, 8}));

  stop();
  crash = false;
  start();
  v1::ListJobsRequest list;
  v1::ListJobsResponse jobs;
  {
    auto context = client();
    ASSERT_TRUE(farm_stub_->ListJobs(context.get(), list, &jobs).ok());
  }
  ASSERT_EQ(jobs.jobs_size(), 1);
  const std::string job_id = jobs.jobs(0).job_id();
  EXPECT_EQ(jobs.jobs(0).progress().tasks_total(), 18u);
  EXPECT_EQ(run_worker(register_worker()).size(), 18u);
  const v1::JobInfo done = wait_done(job_id);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  expect_identical(fetch_spectral_exr(job_id), spec);

  // A submission in parts on a running coordinator: the same bytes again.
  stored_at_pause.clear();
  const std::string second = submit(spec, "again").job_id();
  EXPECT_EQ(stored_at_pause, (std::vector<std::uint64_t>{4, 8, 12, 16}));
  EXPECT_EQ(run_worker(register_worker()).size(), 18u);
  ASSERT_EQ(wait_done(second).state(), v1::JOB_STATE_DONE);
  expect_identical(fetch_spectral_exr(second), spec);
}

// Writing a finished job's outputs (tens of seconds for a big one) held the coordinator's lock,
// so every RPC waited. The finaliser thread writes them without it: while it is held up before
// writing, the job reads FINALISING, another job is submitted and its task leased and
// completed; released, the job is DONE with the embedded render's bytes. A job cancelled while
// finalising ends CANCELLED with no outputs. (Were the lock held, these calls would block
// until the test's 30 s deadlines and fail.)
TEST_F(FarmServerTest, OutputsAreWrittenWithoutTheCoordinatorsLock) {
  std::mutex gate_mutex;
  std::condition_variable gate;
  int waiting = 0;
  bool open = false;
  stop();
  configure_ = [&](FarmOptions& options) {
    options.before_write_outputs = [&] {
      std::unique_lock<std::mutex> lock(gate_mutex);
      ++waiting;
      gate.notify_all();
      gate.wait(lock, [&] { return open; });
    };
  };
  start();
  auto wait_for_writer = [&](int n) {
    std::unique_lock<std::mutex> lock(gate_mutex);
    return gate.wait_for(lock, std::chrono::seconds(30), [&] { return waiting >= n; });
  };
  const std::string hash = upload_scene();
  ASSERT_FALSE(hash.empty());
  const v1::JobSpec spec = small_spec(hash);
  const std::string job_id = submit(spec, "first").job_id();
  const std::string worker_id = register_worker();
  EXPECT_EQ(run_worker(worker_id).size(), 18u);
  ASSERT_TRUE(wait_for_writer(1));
  v1::JobInfo info;
  ASSERT_TRUE(get_job(job_id, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_FINALISING);
  v1::JobSpec other = small_spec(hash);
  other.set_seed(9);
  const std::string other_id = submit(other, "second").job_id();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  EXPECT_EQ(lease->task().job_id(), other_id);
  EXPECT_TRUE(complete(worker_id, lease->lease_id(), render(*lease)).ok());
  {
    std::lock_guard<std::mutex> lock(gate_mutex);
    open = true;
  }
  gate.notify_all();
  const v1::JobInfo done = wait_done(job_id);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  expect_identical(fetch_spectral_exr(job_id), spec);

  // Cancelled while finalising: no outputs.
  {
    std::lock_guard<std::mutex> lock(gate_mutex);
    open = false;
  }
  EXPECT_EQ(run_worker(worker_id).size(), 17u);
  ASSERT_TRUE(wait_for_writer(2));
  ASSERT_TRUE(cancel_job(other_id, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_CANCELLED);
  {
    std::lock_guard<std::mutex> lock(gate_mutex);
    open = true;
  }
  gate.notify_all();
  // The finaliser finishes; the job stays cancelled and its outputs are gone.
  for (int i = 0; i < 500 && fs::exists(root_ / "data" / "outputs" / other_id); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_FALSE(fs::exists(root_ / "data" / "outputs" / other_id));
  ASSERT_TRUE(get_job(other_id, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_CANCELLED);
  stop();  // joins the finaliser while the test's gate still exists
}

}  // namespace
}  // namespace prism::coordinator
