// The coordinator's WorkerService and its leases through gRPC: stale leases and duplicates,
// malformed results, busy, lost, stalled and leaving workers, cancels reaching workers, real
// worker processes, health.
#include <set>
#include <tuple>

#include "coordinator/farm_server_fixture.h"

namespace prism::coordinator {
namespace {

using namespace farm_server_testing;  // also fs (std::filesystem) and v1 (prism::v1)

// A worker that fails every task it takes (a broken cache directory, say) is blocked from the
// job after three faults; with no other worker the job waits, and its status says why instead of
// sitting at 0 % with the worker listed as idle.
TEST_F(FarmServerTest, AJobEveryWorkerIsBlockedFromSaysWhyItWaits) {
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  v1::JobInfo info;
  ASSERT_TRUE(get_job(job_id, &info).ok());
  EXPECT_EQ(info.waiting(), "no worker is connected (start prism-worker --coordinator ADDRESS)");
  const std::string worker_id = register_worker();
  for (int fault = 0; fault < 3; ++fault) {
    ASSERT_TRUE(get_job(job_id, &info).ok());
    EXPECT_EQ(info.waiting(), "") << fault;
    std::optional<v1::Lease> lease = acquire(worker_id);
    ASSERT_TRUE(lease.has_value());
    ASSERT_TRUE(fail_task(worker_id, lease->lease_id(), v1::FAILURE_CLASS_WORKER,
                          "cannot create the bundle cache afile: Not a directory")
                    .ok());
  }
  ASSERT_TRUE(get_job(job_id, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_RENDERING);
  EXPECT_NE(info.waiting().find("every connected worker (1) is blocked from this job after "
                                "repeated failures of its tasks; the last: "),
            std::string::npos)
      << info.waiting();
  EXPECT_NE(info.waiting().find("cannot create the bundle cache afile"), std::string::npos)
      << info.waiting();
}

// A result the coordinator cannot store (its disk is full) is its own fault: the task goes back
// to the queue at once, the worker hears UNAVAILABLE and is not blocked however often it
// happens. Left to expire, each lease counted against the worker, blocked after three, and the
// job waited for a worker that had done nothing wrong.
TEST_F(FarmServerTest, AResultTheCoordinatorCannotStoreIsNotTheWorkersFault) {
  std::atomic<bool> full{true};
  stop();
  configure_ = [&full](FarmOptions& options) {
    // Fewer infrastructure retries than the test makes: an unstored result counts against no
    // cap (a long full disk failed the job after 100 of them, losing it).
    options.scheduler.max_free_retries = 3;
    options.scheduler.unstored_retry_delay = Millis(5000);  // past the time to try every task
    options.disk_fault = [&full](std::string_view what) -> absl::Status {
      if (full && what == "result")
        return absl::InternalError("results.pack write failed: No space left on device");
      return absl::OkStatus();
    };
  };
  start();
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  const std::string worker_id = register_worker();
  v1::JobInfo info;
  ASSERT_TRUE(get_job(job_id, &info).ok());
  const int tasks = static_cast<int>(info.progress().tasks_total());
  ASSERT_GT(tasks, 3);
  std::set<std::tuple<int, int, std::uint64_t>> unstored;  // tile corner and first sample
  for (int attempt = 0; attempt < tasks; ++attempt) {
    std::optional<v1::Lease> lease = acquire(worker_id);
    ASSERT_TRUE(lease.has_value()) << attempt;
    // A task whose result was not kept is held back (not rendered again at once) while other
    // tasks are waiting: every attempt here gets a task not tried yet.
    EXPECT_TRUE(unstored
                    .insert({lease->task().tile().x0(), lease->task().tile().y0(),
                             lease->task().samples().begin()})
                    .second)
        << attempt;
    const grpc::Status status = complete(worker_id, lease->lease_id(), render(*lease));
    EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
    EXPECT_NE(status.error_message().find("the coordinator could not store the result"),
              std::string::npos)
        << status.error_message();
    EXPECT_NE(status.error_message().find("No space left on device"), std::string::npos);
    if (attempt == 0) {
      // Held back while the rest still go out: the job already says it is not moving (it
      // showed a rate and a time left while a worker re-rendered refused results).
      ASSERT_TRUE(get_job(job_id, &info).ok());
      EXPECT_NE(info.waiting().find("the coordinator could not store 1 of its tasks' results "
                                    "(results.pack write failed: No space left on device)"),
                std::string::npos)
          << info.waiting();
      EXPECT_LT(info.progress().eta_seconds(), 0.0);
    }
  }
  // Every task is held back now: the job says why it waits (it said nothing, workers idle).
  ASSERT_TRUE(get_job(job_id, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_RENDERING);
  EXPECT_NE(info.waiting().find("the coordinator could not store " + std::to_string(tasks) +
                                " of its tasks' results "
                                "(results.pack write failed: No space left on device)"),
            std::string::npos)
      << info.waiting();
  // Space again: the same worker finishes the job, once the tasks' hold is over.
  full = false;
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (std::chrono::steady_clock::now() < end) {
    run_worker(worker_id);
    ASSERT_TRUE(get_job(job_id, &info).ok());
    if (info.progress().tasks_done() == info.progress().tasks_total()) break;
  }
  EXPECT_EQ(info.progress().tasks_done(), info.progress().tasks_total());
  const absl::StatusOr<std::string> metrics = farm_->farm().metrics_text();
  ASSERT_TRUE(metrics.ok());
  const std::string count = std::to_string(tasks) + "\n";
  EXPECT_NE(metrics->find("prism_task_retries_total{reason=\"infrastructure\"} " + count),
            std::string::npos)
      << *metrics;
  EXPECT_NE(metrics->find("prism_results_total{outcome=\"unstored\"} " + count), std::string::npos);
}

TEST_F(FarmServerTest, StaleLeasesAreRefusedAndDuplicatesAreHarmless) {
  ASSERT_FALSE(submit_small_job().empty());
  const std::string worker_id = register_worker();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  const std::string bytes = render(*lease);
  // The worker hands the lease back, then sends a result for it anyway.
  ASSERT_TRUE(fail_task(worker_id, lease->lease_id(), v1::FAILURE_CLASS_RETURNED).ok());
  grpc::Status stale = complete(worker_id, lease->lease_id(), bytes);
  EXPECT_EQ(stale.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_FALSE(stale.error_message().empty());
  EXPECT_NE(stale.error_message().find(lease->lease_id()), std::string::npos)
      << stale.error_message();

  // The requeued task under a fresh lease: accepted once, then a harmless duplicate.
  std::optional<v1::Lease> again = acquire(worker_id);
  ASSERT_TRUE(again.has_value());
  EXPECT_EQ(again->task().tile().x0(), lease->task().tile().x0());
  bool accepted = false;
  ASSERT_TRUE(complete(worker_id, again->lease_id(), bytes, &accepted).ok());
  EXPECT_TRUE(accepted);
  grpc::Status duplicate = complete(worker_id, again->lease_id(), bytes, &accepted);
  EXPECT_TRUE(duplicate.ok()) << duplicate.error_message();
  EXPECT_FALSE(accepted);
}

// A gradient job's result must carry gradients: one without is the worker's fault (refused,
// the task requeued), not a reason to fail the job.
TEST_F(FarmServerTest, AGradientResultWithoutGradientsIsTheWorkersFault) {
  v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  spec.set_integrator(v1::INTEGRATOR_GRADIENT);
  spec.set_bins(16);
  const v1::JobInfo job = submit(spec);
  ASSERT_FALSE(job.job_id().empty());
  const std::string worker_id = register_worker();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  const auto& t = lease->task().tile();
  image::TileBuffers buffers;
  buffers.rgb = true;  // what a final-pass result has, all but the gradients
  auto plain = image::TileResult::create(
      {t.x0(), t.y0(), t.x1(), t.y1()},
      {lease->task().samples().begin(), lease->task().samples().end()}, 16, buffers);
  ASSERT_TRUE(plain.ok()) << plain.status();
  const grpc::Status refused =
      complete(worker_id, lease->lease_id(), image::serialise_tile(*plain));
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(refused.error_message().find("without gradients"), std::string::npos)
      << refused.error_message();
  v1::GetJobRequest request;
  request.set_job_id(job.job_id());
  v1::JobInfo info;
  auto context = client();
  ASSERT_TRUE(farm_stub_->GetJob(context.get(), request, &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_RENDERING);
  // The real render of the same task is accepted.
  std::optional<v1::Lease> again = acquire(worker_id);
  ASSERT_TRUE(again.has_value());
  EXPECT_TRUE(complete(worker_id, again->lease_id(), render(*again)).ok());
}

// A variance-weighted gradient job needs the halves (squares of G, the even samples' sums) in
// every result; a result with gradients only is the worker's fault too, and the real render of
// the task, which carries them, is accepted.
TEST_F(FarmServerTest, AWeightedGradientResultWithoutHalvesIsTheWorkersFault) {
  v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  spec.set_integrator(v1::INTEGRATOR_GRADIENT);
  spec.set_bins(16);
  spec.mutable_gradient()->set_norm(v1::POISSON_NORM_WEIGHTED);
  ASSERT_FALSE(submit(spec).job_id().empty());
  const std::string worker_id = register_worker();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  // A final-pass result needs each sample's RGB (the RGB outputs), and this job the halves.
  auto empty_result = [](const v1::Lease& l, bool xyz) {
    const auto& t = l.task().tile();
    image::TileBuffers buffers;
    buffers.gradients = true;
    buffers.rgb = xyz;
    auto r = image::TileResult::create({t.x0(), t.y0(), t.x1(), t.y1()},
                                       {l.task().samples().begin(), l.task().samples().end()}, 16,
                                       buffers);
    PRISM_CHECK(r.ok());
    return image::serialise_tile(*r);
  };
  const grpc::Status refused_xyz =
      complete(worker_id, lease->lease_id(), empty_result(*lease, false));
  EXPECT_EQ(refused_xyz.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(refused_xyz.error_message().find("without RGB buffers"), std::string::npos)
      << refused_xyz.error_message();
  lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  const grpc::Status refused = complete(worker_id, lease->lease_id(), empty_result(*lease, true));
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(refused.error_message().find("without halves"), std::string::npos)
      << refused.error_message();
  std::optional<v1::Lease> again = acquire(worker_id);
  ASSERT_TRUE(again.has_value());
  const std::string bytes = render(*again);
  auto parsed = image::parse_tile(bytes);
  ASSERT_TRUE(parsed.ok()) << parsed.status();
  EXPECT_TRUE(parsed->has_halves());
  EXPECT_TRUE(complete(worker_id, again->lease_id(), bytes).ok());
}

TEST_F(FarmServerTest, ListWorkersShowsWhatABusyWorkerRenders) {
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  const std::string worker_id = register_worker();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  v1::ListWorkersRequest request;
  v1::ListWorkersResponse response;
  auto context = client();
  ASSERT_TRUE(farm_stub_->ListWorkers(context.get(), request, &response).ok());
  ASSERT_EQ(response.workers_size(), 1);
  const v1::WorkerInfo& info = response.workers(0);
  EXPECT_EQ(info.state(), "busy");
  EXPECT_EQ(info.leases(), 1u);
  EXPECT_EQ(info.current_lease(), lease->lease_id());
  const auto& t = lease->task();
  EXPECT_EQ(info.current_task(),
            absl::StrCat("job ", job_id, " final tile (", t.tile().x0(), ",", t.tile().y0(), ")-(",
                         t.tile().x1(), ",", t.tile().y1(), ") samples [", t.samples().begin(), ",",
                         t.samples().end(), ")"));
}

TEST_F(FarmServerTest, CancelReachesTheWorkerAtItsNextHeartbeat) {
  scene_root_ = root_ / "scene";
  const std::string packed = packed_bundle(scene_root_, kScene);
  std::string hash;
  ASSERT_TRUE(upload(packed, &hash).ok());
  const std::string job_id = submit(small_spec(hash)).job_id();
  const std::string worker_id = register_worker();

  // The worker fetches the bundle by hash: the same bytes as uploaded.
  {
    v1::FetchBundleRequest request;
    request.set_bundle_hash(hash);
    auto context = worker_call();
    auto reader = worker_stub_->FetchBundle(context.get(), request);
    std::string bytes;
    v1::BundleData data;
    while (reader->Read(&data)) {
      EXPECT_EQ(data.offset(), bytes.size());
      EXPECT_EQ(data.total_bytes(), packed.size());
      bytes += data.data();
    }
    ASSERT_TRUE(reader->Finish().ok());
    EXPECT_EQ(bytes, packed);
  }

  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  EXPECT_EQ(lease->bundle_hash(), hash);
  EXPECT_EQ(lease->attempt(), 1u);
  {
    v1::JobInfo info;
    ASSERT_TRUE(cancel_job(job_id, &info).ok());
    EXPECT_EQ(info.state(), v1::JOB_STATE_CANCELLED);
  }
  v1::HeartbeatRequest beat;
  beat.set_worker_id(worker_id);
  beat.add_lease_ids(lease->lease_id());
  v1::HeartbeatResponse reply;
  auto context = worker_call();
  ASSERT_TRUE(worker_stub_->Heartbeat(context.get(), beat, &reply).ok());
  ASSERT_EQ(reply.directives_size(), 1);
  EXPECT_EQ(reply.directives(0).kind(), v1::Directive::KIND_CANCEL_TASK);
  EXPECT_EQ(reply.directives(0).lease_id(), lease->lease_id());
  EXPECT_FALSE(acquire(worker_id).has_value());
  EXPECT_EQ(complete(worker_id, lease->lease_id(), render(*lease)).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);

  // No outputs for a cancelled job.
  v1::GetResultRequest request;
  request.set_job_id(job_id);
  auto result_context = client();
  auto reader = farm_stub_->GetResult(result_context.get(), request);
  v1::ResultChunk chunk;
  EXPECT_FALSE(reader->Read(&chunk));
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::FAILED_PRECONDITION);
}

TEST_F(FarmServerTest, ALostWorkersLeaseGoesToAnotherWorker) {
  const std::string job_id = submit_small_job();
  ASSERT_FALSE(job_id.empty());
  const std::string silent = register_worker();
  std::optional<v1::Lease> lease = acquire(silent);
  ASSERT_TRUE(lease.has_value());
  // The silent worker never calls again: after 3 missed 200 ms beats it is lost and its task
  // is requeued (the fresh worker keeps calling, so it stays alive).
  const std::string live = register_worker();
  bool requeued = false;
  for (int i = 0; i < 40 && !requeued; ++i) {
    std::optional<v1::Lease> next = acquire(live);
    if (!next.has_value()) continue;  // every other task is done; the lease is not yet requeued
    if (next->task().tile().x0() == lease->task().tile().x0() &&
        next->task().tile().y0() == lease->task().tile().y0() &&
        next->task().samples().begin() == lease->task().samples().begin()) {
      requeued = true;
      EXPECT_EQ(next->attempt(), 2u);
    }
    ASSERT_TRUE(complete(live, next->lease_id(), render(*next)).ok());
  }
  EXPECT_TRUE(requeued);
  // Once the job is over, the lost worker's late result is refused. (While its outputs are
  // written, a result equal to the accepted one is a harmless duplicate.)
  EXPECT_EQ(wait_done(job_id).state(), v1::JOB_STATE_DONE);
  EXPECT_EQ(complete(silent, lease->lease_id(), render(*lease)).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
}

// A worker that drained says Leave: the lease it still held goes straight to another worker as
// a first attempt (no fault counted), and the worker is listed as `left`, never `lost`.
TEST_F(FarmServerTest, ALeavingWorkersLeaseGoesBackUncountedAndItIsListedAsLeft) {
  const std::string hash = upload_scene();
  ASSERT_FALSE(hash.empty());
  submit(small_spec(hash));
  const std::string leaving = register_worker();
  std::optional<v1::Lease> lease = acquire(leaving);
  ASSERT_TRUE(lease.has_value());
  {
    v1::LeaveRequest request;
    request.set_worker_id(leaving);
    v1::LeaveResponse response;
    auto context = worker_call();
    ASSERT_TRUE(worker_stub_->Leave(context.get(), request, &response).ok());
  }
  const std::string other = register_worker();
  std::optional<v1::Lease> next = acquire(other);
  ASSERT_TRUE(next.has_value());
  EXPECT_EQ(next->task().tile().x0(), lease->task().tile().x0());
  EXPECT_EQ(next->task().tile().y0(), lease->task().tile().y0());
  EXPECT_EQ(next->task().samples().begin(), lease->task().samples().begin());
  EXPECT_EQ(next->attempt(), 1u) << "leaving is not a fault";
  EXPECT_EQ(complete(leaving, lease->lease_id(), render(*lease)).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
  // Long after the lost-worker interval (3 x 200 ms) it is still `left`.
  std::this_thread::sleep_for(std::chrono::milliseconds(900));
  v1::ListWorkersRequest request;
  v1::ListWorkersResponse response;
  auto context = client();
  ASSERT_TRUE(farm_stub_->ListWorkers(context.get(), request, &response).ok());
  std::map<std::string, std::string> states;
  for (const v1::WorkerInfo& w : response.workers()) states[w.worker_id()] = w.state();
  EXPECT_EQ(states[leaving], "left");
  // And after a restart of the coordinator (it was listed as lost: the record of leaving was
  // only in memory).
  stop();
  start();
  {
    v1::ListWorkersResponse again;
    auto call = client();
    ASSERT_TRUE(farm_stub_->ListWorkers(call.get(), request, &again).ok());
    std::map<std::string, std::string> after;
    for (const v1::WorkerInfo& w : again.workers()) after[w.worker_id()] = w.state();
    EXPECT_EQ(after[leaving], "left");
    EXPECT_EQ(after[other], "lost") << "the other never reconnected";
  }
  // Leaving is refused for a worker the coordinator never registered.
  v1::LeaveRequest unknown;
  unknown.set_worker_id("w-999999");
  v1::LeaveResponse ignored;
  auto call = worker_call();
  EXPECT_EQ(worker_stub_->Leave(call.get(), unknown, &ignored).error_code(),
            grpc::StatusCode::NOT_FOUND);
}

// Issue 18, case 2: a coordinator that stalled for 18-43 s storing a huge job declared its
// healthy workers lost and rejected their finished tiles. A 10 s stall is injected where a job
// is stored (the in-process farm's heartbeats are 200 ms apart, lost after 3 missed: 50
// intervals). The worker's next heartbeat is sent only after the ticker has run several times
// past the stall (the order that lost workers before): it is still the same worker, its lease
// still current, and its result is accepted.
TEST_F(FarmServerTest, ATenSecondStallDoesNotMakeAHealthyWorkerLost) {
  std::atomic<int> stores{0};
  stop();
  configure_ = [&stores](FarmOptions& options) {
    options.before_store_job = [&stores] {
      if (stores.fetch_add(1) == 1) std::this_thread::sleep_for(std::chrono::seconds(10));
    };
  };
  start();
  const std::string hash = upload_scene();
  ASSERT_FALSE(hash.empty());
  submit(small_spec(hash), "first");
  const std::string worker_id = register_worker();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  auto beat = [&] {
    v1::HeartbeatRequest request;
    request.set_worker_id(worker_id);
    request.add_lease_ids(lease->lease_id());
    v1::HeartbeatResponse reply;
    auto context = worker_call();
    EXPECT_TRUE(worker_stub_->Heartbeat(context.get(), request, &reply).ok());
    return reply;
  };
  EXPECT_EQ(beat().directives_size(), 0);
  v1::JobSpec second = small_spec(hash);
  second.set_seed(8);
  submit(second, "second");  // holds the coordinator's lock for 10 s
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // 5 ticks, no heartbeat
  EXPECT_EQ(beat().directives_size(), 0) << "told to re-register or to cancel its task";
  EXPECT_TRUE(complete(worker_id, lease->lease_id(), render(*lease)).ok());
  v1::ListWorkersRequest request;
  v1::ListWorkersResponse response;
  auto context = client();
  ASSERT_TRUE(farm_stub_->ListWorkers(context.get(), request, &response).ok());
  ASSERT_EQ(response.workers_size(), 1);
  EXPECT_NE(response.workers(0).state(), "lost");
  EXPECT_EQ(farm_->farm().snapshot()->scheduler.workers_lost, 0u);
  EXPECT_EQ(farm_->farm().snapshot()->scheduler.lease_expiries, 0u);
}

// Two real prism-worker processes (the build's, or PRISM_WORKER_BIN) render a job through the
// in-process coordinator, bit-identical to the embedded render.
TEST_F(FarmServerTest, RealWorkerProcessesRenderTheSameBytes) {
  render_with_real_workers(small_spec(""));
}

// A light-tracing job: one whole-image task per range of light-path batches, split over the two
// workers, merged in range order.
TEST_F(FarmServerTest, RealWorkerProcessesRenderALightTracingJobTheSameBytes) {
  v1::JobSpec spec = small_spec("");
  spec.set_integrator(v1::INTEGRATOR_LIGHT);
  spec.set_spp(8);
  render_with_real_workers(spec);
}

// Hero with light-traced caustics: whole-image tasks that trace both kinds of path.
TEST_F(FarmServerTest, RealWorkerProcessesRenderALightCausticsJobTheSameBytes) {
  v1::JobSpec spec = small_spec("");
  spec.set_integrator(v1::INTEGRATOR_HERO);
  spec.set_light_caustics(true);
  render_with_real_workers(spec);
}

// A glass sphere's caustic under a small lamp, over a floor: the farm tests of the filtered image.
constexpr char kCausticScene[] = R"(LookAt 0 4 -3  0 0 0  0 1 0
Camera "perspective" "float fov" 45
Film "spectral" "integer xresolution" 16 "integer yresolution" 16 "integer nbuckets" 8
WorldBegin
LightSource "infinite" "spectrum L" [360 0.1 830 0.1]
Material "diffuse" "rgb reflectance" [0.7 0.7 0.7]
Shape "trianglemesh" "point3 P" [-5 0 -5  5 0 -5  5 0 5  -5 0 5] "integer indices" [0 1 2 0 2 3]
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" "stdillum-D65" "float scale" 4
  Translate 0 2.5 0
  Shape "trianglemesh" "point3 P" [-0.5 0 -0.5  0.5 0 -0.5  0.5 0 0.5  -0.5 0 0.5]
    "integer indices" [0 1 2 0 2 3]
AttributeEnd
AttributeBegin
  Material "dielectric" "spectrum eta" "glass-SF11"
  Translate 0 1 0
  Shape "sphere" "float radius" 0.5
AttributeEnd
)";

// Differential splatting on the farm: light-traced caustics through a dispersive glass sphere,
// drawn as lines into the filtered image, which must come back as the embedded render's bytes.
TEST_F(FarmServerTest, RealWorkerProcessesRenderASplattingJobTheSameBytes) {
  v1::JobSpec spec = small_spec("");
  spec.set_integrator(v1::INTEGRATOR_HERO);
  spec.set_light_caustics(true);
  spec.set_splat_width(60.0f);
  spec.set_spp(8);
  spec.set_samples_per_task(3);
  render_with_real_workers(spec, kCausticScene);
}

// Gathering on the farm: eye paths' offsets and guides come back with every tile, and the
// coordinator's filter over the whole image gives the embedded render's bytes.
TEST_F(FarmServerTest, RealWorkerProcessesRenderAGatheringJobTheSameBytes) {
  v1::JobSpec spec = small_spec("");
  spec.set_integrator(v1::INTEGRATOR_HERO);
  spec.set_gather_width(60.0f);
  spec.set_spp(16);
  spec.set_tile_size(8);
  render_with_real_workers(spec, kCausticScene);
}

TEST_F(FarmServerTest, TheStandardHealthServiceReportsServing) {
  auto channel = grpc::CreateChannel(farm_->address(), grpc::InsecureChannelCredentials());
  grpc::GenericStub stub(channel);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  grpc::Slice empty("");
  grpc::ByteBuffer request(&empty, 1);  // HealthCheckRequest{service: ""}
  grpc::ByteBuffer response;
  std::promise<grpc::Status> done;
  stub.UnaryCall(&context, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&](grpc::Status status) { done.set_value(status); });
  const grpc::Status status = done.get_future().get();
  ASSERT_TRUE(status.ok()) << status.error_message();
  std::vector<grpc::Slice> slices;
  ASSERT_TRUE(response.Dump(&slices).ok());
  std::string bytes;
  for (const grpc::Slice& slice : slices) {
    bytes.append(reinterpret_cast<const char*>(slice.begin()), slice.size());
  }
  EXPECT_EQ(bytes, std::string("\x08\x01", 2));  // HealthCheckResponse{status: SERVING}
}

TEST_F(FarmServerTest, AnUnknownWorkerIsToldToRegisterAgain) {
  v1::HeartbeatRequest beat;
  beat.set_worker_id("w-424242");
  v1::HeartbeatResponse reply;
  auto context = worker_call();
  ASSERT_TRUE(worker_stub_->Heartbeat(context.get(), beat, &reply).ok());
  ASSERT_EQ(reply.directives_size(), 1);
  EXPECT_EQ(reply.directives(0).kind(), v1::Directive::KIND_REREGISTER);
}

// A job with a prepass is PREPASS until its final pass begins (the state the API, /metrics and
// the dashboard show; it had read RENDERING all through), after a restart too. The move to
// RENDERING is checked with real workers (tests/farm_process_test.cpp).
TEST_F(FarmServerTest, AJobWithAPrepassSaysSo) {
  v1::JobSpec spec = uploaded_small_spec();
  ASSERT_FALSE(spec.bundle_hash().empty());
  spec.set_integrator(v1::INTEGRATOR_HERO);
  spec.mutable_prepass()->set_enabled(true);
  spec.mutable_prepass()->set_passes(2);
  spec.mutable_prepass()->set_spp(4);
  const v1::JobInfo submitted = submit(spec);
  ASSERT_FALSE(submitted.job_id().empty());
  EXPECT_EQ(submitted.state(), v1::JOB_STATE_PREPASS);
  stop();
  start();
  v1::JobInfo info;
  ASSERT_TRUE(get_job(submitted.job_id(), &info).ok());
  EXPECT_EQ(info.state(), v1::JOB_STATE_PREPASS);
  // Without a prepass: RENDERING at once.
  spec.mutable_prepass()->Clear();
  spec.mutable_prepass()->set_enabled(false);
  EXPECT_EQ(submit(spec).state(), v1::JOB_STATE_RENDERING);
}

}  // namespace
}  // namespace prism::coordinator
