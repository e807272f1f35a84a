// The coordinator's gRPC server in process on 127.0.0.1 port 0, driven by a test client and a
// fake worker that renders its leases with worker::TileRenderer in this process.
#include <grpcpp/create_channel.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/security/credentials.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <future>
#include <set>

#include "absl/strings/str_cat.h"
#include "coordinator/farm_coordinator.h"
#include "coordinator/local_render.h"
#include "coordinator/rpc/coordinator_server.h"
#include "coordinator/testing/in_process_farm.h"
#include "prism/v1/farm.grpc.pb.h"
#include "prism/v1/worker.grpc.pb.h"
#include "services/base/check.h"
#include "services/base/sha256.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile_codec.h"
#include "services/job/job_spec.h"
#include "services/rpc/auth.h"
#include "services/rpc/chunks.h"
#include "services/rpc/result_upload.h"
#include "services/scene/bundle.h"
#include "services/scene/scene_loader.h"
#include "services/store/blob_store.h"
#include "services/store/job_store.h"
#include "tests/testing/child_process.h"
#include "worker/render_scene.h"
#include "worker/tile_renderer.h"

namespace prism::coordinator {
namespace {

namespace fs = std::filesystem;
namespace v1 = prism::v1;

// Regular files anywhere under `dir` (0 when it does not exist).
std::size_t count_files(const fs::path& dir) {
  std::size_t n = 0;
  std::error_code ec;
  for (const auto& entry : fs::recursive_directory_iterator(dir, ec)) {
    if (entry.is_regular_file()) ++n;
  }
  return n;
}

using testing::fresh_dir;

void write(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

using testing::packed_bundle;
constexpr const char* kToken = testing::kApiToken;
constexpr const char* kSecret = testing::kWorkerSecret;
constexpr const char* kScene = testing::kSmallScene;

class FarmServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fresh_dir(::testing::UnitTest::GetInstance()->current_test_info()->name());
    library_ = *spectral::SpectrumLibrary::load_builtin();
    start();
  }
  void TearDown() override { stop(); }

  void start() {
    farm_ = testing::InProcessFarm::start(root_ / "data", [this](FarmOptions& options) {
      options.max_bundle_bytes = 64 << 10;
      options.max_queued_jobs = max_queued_jobs_;
      options.scheduler.lease_duration = Millis(5000);
    });
    ASSERT_NE(farm_, nullptr);
    auto channel = grpc::CreateChannel(farm_->address(), grpc::InsecureChannelCredentials());
    farm_stub_ = v1::FarmService::NewStub(channel);
    worker_stub_ = v1::WorkerService::NewStub(channel);
  }
  void stop() { farm_.reset(); }

  std::unique_ptr<grpc::ClientContext> client(const std::string& token = kToken) {
    auto context = std::make_unique<grpc::ClientContext>();
    prism::rpc::add_bearer(*context, token);
    context->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    return context;
  }
  std::unique_ptr<grpc::ClientContext> worker_call() { return client(kSecret); }

  grpc::Status upload(const std::string& bytes, std::string* hash, std::uint64_t declared = 0) {
    auto context = client();
    v1::UploadBundleResponse response;
    auto writer = farm_stub_->UploadBundle(context.get(), &response);
    bool first = true;
    for (std::string_view piece : prism::rpc::split_chunks(bytes, 1000)) {
      v1::BundleChunk chunk;
      if (first) chunk.set_total_bytes(declared != 0 ? declared : bytes.size());
      chunk.set_total_bytes(declared != 0 ? declared : bytes.size());
      chunk.set_data(std::string(piece));
      first = false;
      if (!writer->Write(chunk)) break;
    }
    writer->WritesDone();
    grpc::Status status = writer->Finish();
    if (hash != nullptr) *hash = response.bundle_hash();
    return status;
  }

  v1::JobSpec small_spec(const std::string& hash) {
    v1::JobSpec spec;
    spec.set_bundle_hash(hash);
    spec.set_scene_path("scene.pbrt");
    spec.set_width(12);
    spec.set_height(10);
    spec.set_tile_size(4);
    spec.set_spp(4);
    spec.set_samples_per_task(2);
    spec.set_seed(7);
    return spec;
  }

  v1::JobInfo submit(const v1::JobSpec& spec, const std::string& token = "") {
    v1::SubmitJobRequest request;
    *request.mutable_spec() = spec;
    request.set_client_token(token);
    v1::SubmitJobResponse response;
    auto context = client();
    grpc::Status status = farm_stub_->SubmitJob(context.get(), request, &response);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return response.job();
  }

  std::string register_worker() {
    v1::RegisterRequest request;
    request.set_host("test");
    request.set_threads(1);
    v1::RegisterResponse response;
    auto context = worker_call();
    EXPECT_TRUE(worker_stub_->Register(context.get(), request, &response).ok());
    return response.worker_id();
  }

  std::optional<v1::Lease> acquire(const std::string& worker_id) {
    v1::AcquireTaskRequest request;
    request.set_worker_id(worker_id);
    request.set_wait_ms(500);
    v1::AcquireTaskResponse response;
    auto context = worker_call();
    grpc::Status status = worker_stub_->AcquireTask(context.get(), request, &response);
    EXPECT_TRUE(status.ok()) << status.error_message();
    if (!response.has_lease()) return std::nullopt;
    return response.lease();
  }

  // The fake worker's render of a lease, in the canonical tile bytes.
  std::string render(const v1::Lease& lease) {
    auto loaded = scene::load_scene(scene_root_ / "scene.pbrt", {});
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    auto params = job::job_parameters(lease.task().spec(), loaded->description);
    EXPECT_TRUE(params.ok()) << params.status();
    auto scene = worker::RenderScene::build(device_, loaded->description, library_, params->render,
                                            params->width, params->height);
    EXPECT_TRUE(scene.ok()) << scene.status();
    worker::TileRenderer renderer(**scene);
    worker::RenderTask task;
    const auto& t = lease.task().tile();
    task.tile = {t.x0(), t.y0(), t.x1(), t.y1()};
    task.samples = {lease.task().samples().begin(), lease.task().samples().end()};
    worker::TileStats stats;
    auto result = renderer.render(task, &stats, nullptr, nullptr);
    EXPECT_TRUE(result.ok()) << result.status();
    return image::serialise_tile(*result);
  }

  grpc::Status complete(const std::string& worker_id, const std::string& lease_id,
                        const std::string& bytes, bool* accepted = nullptr) {
    auto context = worker_call();
    v1::CompleteTaskResponse response;
    auto writer = worker_stub_->CompleteTask(context.get(), &response);
    prism::rpc::ResultUploadHeader header;
    header.worker_id = worker_id;
    header.lease_id = lease_id;
    grpc::Status status = prism::rpc::upload_result(*writer, header, bytes, 4096);
    if (accepted != nullptr) *accepted = response.accepted();
    return status;
  }

  // Renders leases until none is left or `limit` were completed; returns the task indices
  // (tile-major) it rendered.
  std::vector<std::pair<int, int>> run_worker(const std::string& worker_id, int limit = 1 << 30) {
    std::vector<std::pair<int, int>> rendered;
    int idle = 0;
    while (static_cast<int>(rendered.size()) < limit && idle < 3) {
      std::optional<v1::Lease> lease = acquire(worker_id);
      if (!lease) {
        ++idle;
        continue;
      }
      idle = 0;
      EXPECT_TRUE(complete(worker_id, lease->lease_id(), render(*lease)).ok());
      rendered.emplace_back(lease->task().tile().x0() * 10000 + lease->task().tile().y0(),
                            static_cast<int>(lease->task().samples().begin()));
    }
    return rendered;
  }

  v1::JobInfo wait_done(const std::string& job_id, int polls = 200) {
    v1::JobInfo info;
    for (int i = 0; i < polls; ++i) {
      v1::GetJobRequest request;
      request.set_job_id(job_id);
      auto context = client();
      EXPECT_TRUE(farm_stub_->GetJob(context.get(), request, &info).ok());
      if (info.state() == v1::JOB_STATE_DONE || info.state() == v1::JOB_STATE_FAILED) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return info;
  }

  // The embedded render of the same job, through the same output writer.
  image::SpectralExr oracle(const v1::JobSpec& spec) {
    auto loaded = scene::load_scene(scene_root_ / "scene.pbrt", {});
    auto params = job::job_parameters(spec, loaded->description);
    EXPECT_TRUE(params.ok()) << params.status();
    LocalRenderOptions options;
    options.render = params->render;
    options.width = params->width;
    options.height = params->height;
    options.spp = params->spp;
    options.tile_size = params->tile_size;
    options.samples_per_task = params->samples_per_task;
    options.threads = 2;
    auto local = LocalRender::create(device_, loaded->description, library_, options);
    EXPECT_TRUE(local.ok()) << local.status();
    auto result = (*local)->render();
    EXPECT_TRUE(result.ok()) << result.status();
    const fs::path dir = root_ / "oracle";
    fs::create_directories(dir);
    OutputPaths paths{dir / "o.exr", dir / "o.rgb.exr", dir / "o.png", dir / "o.json"};
    RenderReport report;
    EXPECT_TRUE(write_outputs(result->image, result->rgb, report, paths, {}).ok());
    auto exr = image::read_spectral_exr(paths.spectral_exr);
    EXPECT_TRUE(exr.ok()) << exr.status();
    return *std::move(exr);
  }

  std::string fetch_spectral_exr(const std::string& job_id) {
    v1::GetResultRequest request;
    request.set_job_id(job_id);
    request.add_kinds(v1::OUTPUT_KIND_SPECTRAL_EXR);
    auto context = client();
    auto reader = farm_stub_->GetResult(context.get(), request);
    std::string bytes, sha;
    v1::ResultChunk chunk;
    while (reader->Read(&chunk)) {
      EXPECT_EQ(chunk.offset(), bytes.size());
      bytes += chunk.data();
      if (chunk.last()) sha = chunk.sha256();
    }
    EXPECT_TRUE(reader->Finish().ok());
    EXPECT_EQ(sha, base::sha256_hex(bytes));
    return bytes;
  }

  void expect_identical(const std::string& exr_bytes, const v1::JobSpec& spec) {
    const fs::path fetched = root_ / "fetched.exr";
    write(fetched, exr_bytes);
    auto farm_exr = image::read_spectral_exr(fetched);
    ASSERT_TRUE(farm_exr.ok()) << farm_exr.status();
    const image::SpectralExr local = oracle(spec);
    const auto a = farm_exr->spectral.data();
    const auto b = local.spectral.data();
    ASSERT_EQ(a.size(), b.size());
    ASSERT_GT(a.size(), 0u);
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(float)), 0);
    double sum = 0;
    for (float v : a) sum += v;
    EXPECT_GT(sum, 0.0);  // not a black image
  }

  std::size_t max_queued_jobs_ = 1000;
  fs::path root_;
  fs::path scene_root_;
  spectral::SpectrumLibrary library_;
  worker::EmbreeDevice device_;
  std::unique_ptr<testing::InProcessFarm> farm_;
  std::unique_ptr<v1::FarmService::Stub> farm_stub_;
  std::unique_ptr<v1::WorkerService::Stub> worker_stub_;
};

TEST_F(FarmServerTest, AFakeWorkerRendersAJobBitIdenticalToTheEmbeddedRender) {
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  {
    v1::HasBundleRequest request;
    request.set_bundle_hash(hash);
    v1::HasBundleResponse response;
    auto context = client();
    ASSERT_TRUE(farm_stub_->HasBundle(context.get(), request, &response).ok());
    EXPECT_TRUE(response.present());
  }
  const v1::JobSpec spec = small_spec(hash);
  const v1::JobInfo job = submit(spec);
  ASSERT_FALSE(job.job_id().empty());
  EXPECT_EQ(job.progress().tasks_total(), 3u * 3u * 2u);

  // A watcher sees the job through to DONE.
  std::vector<v1::JobInfo> updates;
  std::thread watcher([&] {
    v1::WatchJobRequest request;
    request.set_job_id(job.job_id());
    auto context = client();
    auto reader = farm_stub_->WatchJob(context.get(), request);
    v1::JobInfo info;
    while (reader->Read(&info)) updates.push_back(info);
    EXPECT_TRUE(reader->Finish().ok());
  });

  const std::string worker_id = register_worker();
  const auto rendered = run_worker(worker_id);
  EXPECT_EQ(rendered.size(), 18u);
  const v1::JobInfo done = wait_done(job.job_id());
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  EXPECT_EQ(done.progress().tasks_done(), 18u);
  EXPECT_EQ(done.progress().tiles_finalised(), 9u);
  EXPECT_FALSE(done.report_json().empty());
  watcher.join();
  ASSERT_FALSE(updates.empty());
  EXPECT_EQ(updates.back().state(), v1::JOB_STATE_DONE);

  expect_identical(fetch_spectral_exr(job.job_id()), spec);

  v1::GetPreviewRequest preview_request;
  preview_request.set_job_id(job.job_id());
  v1::Preview preview;
  auto context = client();
  ASSERT_TRUE(farm_stub_->GetPreview(context.get(), preview_request, &preview).ok());
  EXPECT_EQ(preview.png().substr(0, 4), "\x89PNG");
  // Tiles and range results are deleted once the job is done.
  EXPECT_EQ(count_files(root_ / "data" / "blobs"), 0u);
  EXPECT_EQ(count_files(root_ / "data" / "jobs"), 0u);
}

TEST_F(FarmServerTest, WrongTokensAreUnauthenticated) {
  v1::GetJobRequest request;
  request.set_job_id("j-1");
  v1::JobInfo info;
  auto context = client("wrong");
  EXPECT_EQ(farm_stub_->GetJob(context.get(), request, &info).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  // The client token is not the worker secret.
  v1::RegisterRequest reg;
  v1::RegisterResponse reg_response;
  auto worker_context = client(kToken);
  EXPECT_EQ(worker_stub_->Register(worker_context.get(), reg, &reg_response).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
}

TEST_F(FarmServerTest, OversizedUploadIsResourceExhausted) {
  const std::string junk(100 << 10, 'x');
  grpc::Status status = upload(junk, nullptr);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
}

TEST_F(FarmServerTest, BadBundlesAreInvalidArgumentWithTheLoadersMessage) {
  const std::string escaping = std::string(kScene) + "Include \"../x.pbrt\"\n";
  scene_root_ = root_ / "escape";
  write(root_ / "x.pbrt", "# outside the scene's directory\n");
  grpc::Status status = upload(packed_bundle(scene_root_, escaping), nullptr);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("scene.pbrt:"), std::string::npos)
      << status.error_message();
  EXPECT_NE(status.error_message().find("../x.pbrt"), std::string::npos) << status.error_message();
  EXPECT_TRUE(fs::is_empty(root_ / "data" / "scenes"));

  status = upload("not a bundle at all", nullptr);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
}

TEST_F(FarmServerTest, UnknownJobIsNotFound) {
  v1::GetJobRequest request;
  request.set_job_id("j-999999");
  v1::JobInfo info;
  auto context = client();
  grpc::Status status = farm_stub_->GetJob(context.get(), request, &info);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_NE(status.error_message().find("j-999999"), std::string::npos);
}

TEST_F(FarmServerTest, StaleLeasesAreRefusedAndDuplicatesAreHarmless) {
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  submit(small_spec(hash));
  const std::string worker_id = register_worker();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  const std::string bytes = render(*lease);
  // The worker hands the lease back, then sends a result for it anyway.
  {
    v1::FailTaskRequest request;
    request.set_worker_id(worker_id);
    request.set_lease_id(lease->lease_id());
    request.set_failure_class(v1::FAILURE_CLASS_RETURNED);
    v1::FailTaskResponse response;
    auto context = worker_call();
    ASSERT_TRUE(worker_stub_->FailTask(context.get(), request, &response).ok());
  }
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
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  v1::JobSpec spec = small_spec(hash);
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
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  v1::JobSpec spec = small_spec(hash);
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
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  const std::string job_id = submit(small_spec(hash)).job_id();
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

TEST_F(FarmServerTest, SubmitIsIdempotentByClientToken) {
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  const v1::JobInfo a = submit(small_spec(hash), "token-1");
  const v1::JobInfo b = submit(small_spec(hash), "token-1");
  const v1::JobInfo c = submit(small_spec(hash), "token-2");
  EXPECT_EQ(a.job_id(), b.job_id());
  EXPECT_NE(a.job_id(), c.job_id());
  v1::ListJobsRequest request;
  v1::ListJobsResponse response;
  auto context = client();
  ASSERT_TRUE(farm_stub_->ListJobs(context.get(), request, &response).ok());
  EXPECT_EQ(response.jobs_size(), 2);
}

TEST_F(FarmServerTest, ARestartResumesWithoutReleasingFinishedTasks) {
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  const v1::JobSpec spec = small_spec(hash);
  const std::string job_id = submit(spec).job_id();
  const auto first = run_worker(register_worker(), 7);
  ASSERT_EQ(first.size(), 7u);
  stop();

  // Tiles 0-2 (tasks 0-5) finished and went to disk; tile 3 has one of its two ranges. Their
  // range results are deleted here, so the restart can only take tiles 0-2 from their files.
  const fs::path data = root_ / "data";
  EXPECT_EQ(count_files(data / "jobs" / job_id / "tiles"), 3u);
  {
    auto store = store::JobStore::open(data / "jobs.sqlite");
    ASSERT_TRUE(store.ok()) << store.status();
    auto blobs = store::BlobStore::open(data / "blobs");
    ASSERT_TRUE(blobs.ok());
    auto tasks = store->tasks_of(job_id);
    ASSERT_TRUE(tasks.ok()) << tasks.status();
    for (const store::TaskRecord& task : *tasks) {
      if (task.tile_index >= 3) continue;
      ASSERT_EQ(task.state, store::TaskState::kDone) << "task " << task.index;
      ASSERT_TRUE(blobs->remove(task.result_hash).ok()) << task.result_hash;
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
    v1::CancelJobRequest request;
    request.set_job_id(job_id);
    v1::JobInfo info;
    auto context = client();
    ASSERT_TRUE(farm_stub_->CancelJob(context.get(), request, &info).ok());
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

TEST_F(FarmServerTest, ASceneFaultFailsTheJobWithTheWorkersMessage) {
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  const std::string job_id = submit(small_spec(hash)).job_id();
  const std::string worker_id = register_worker();
  std::optional<v1::Lease> lease = acquire(worker_id);
  ASSERT_TRUE(lease.has_value());
  v1::FailTaskRequest request;
  request.set_worker_id(worker_id);
  request.set_lease_id(lease->lease_id());
  request.set_failure_class(v1::FAILURE_CLASS_SCENE);
  request.set_message("scene.pbrt:9:3: the sphere is made of cheese");
  v1::FailTaskResponse response;
  auto context = worker_call();
  ASSERT_TRUE(worker_stub_->FailTask(context.get(), request, &response).ok());
  const v1::JobInfo info = wait_done(job_id);
  EXPECT_EQ(info.state(), v1::JOB_STATE_FAILED);
  EXPECT_NE(info.error().find("the sphere is made of cheese"), std::string::npos) << info.error();
  EXPECT_FALSE(acquire(worker_id).has_value());
}

TEST_F(FarmServerTest, ALostWorkersLeaseGoesToAnotherWorker) {
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  submit(small_spec(hash));
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
  EXPECT_EQ(complete(silent, lease->lease_id(), render(*lease)).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
}

TEST_F(FarmServerTest, SubmissionsBeyondTheQueueLimitAreResourceExhausted) {
  stop();
  max_queued_jobs_ = 1;
  start();
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  submit(small_spec(hash), "first");
  v1::SubmitJobRequest request;
  *request.mutable_spec() = small_spec(hash);
  request.set_client_token("second");
  v1::SubmitJobResponse response;
  auto context = client();
  grpc::Status status = farm_stub_->SubmitJob(context.get(), request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(status.error_message().find("--max-queued-jobs 1"), std::string::npos)
      << status.error_message();
  // A repeat of the accepted submission is still answered.
  EXPECT_FALSE(submit(small_spec(hash), "first").job_id().empty());
}

TEST_F(FarmServerTest, ABadSpecIsInvalidArgumentNamingTheField) {
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  v1::SubmitJobRequest request;
  *request.mutable_spec() = small_spec(hash);
  request.mutable_spec()->set_bins(1000);
  v1::SubmitJobResponse response;
  auto context = client();
  grpc::Status status = farm_stub_->SubmitJob(context.get(), request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(status.error_message(), "bins 1000 is out of range: want 4..256");
}

// Two real prism-worker processes (the build's, or PRISM_WORKER_BIN) render a job through the
// in-process coordinator, bit-identical to the embedded render.
TEST_F(FarmServerTest, RealWorkerProcessesRenderTheSameBytes) {
  const char* binary = std::getenv("PRISM_WORKER_BIN");
  if (binary == nullptr || *binary == '\0') binary = PRISM_WORKER_BINARY;
  scene_root_ = root_ / "scene";
  std::string hash;
  ASSERT_TRUE(upload(packed_bundle(scene_root_, kScene), &hash).ok());
  const v1::JobSpec spec = small_spec(hash);
  const std::string job_id = submit(spec).job_id();
  std::vector<std::unique_ptr<prism::testing::ChildProcess>> workers;
  for (int i = 0; i < 2; ++i) {
    const std::string cache = (root_ / ("cache" + std::to_string(i))).string();
    workers.push_back(prism::testing::ChildProcess::start(
        {binary, "--coordinator", farm_->address(), "--threads", "1", "--secret", kSecret,
         "--cache-dir", cache, "--log-level", "warn"}));
    ASSERT_NE(workers.back(), nullptr);
  }
  const v1::JobInfo done = wait_done(job_id, 1500);
  for (auto& worker : workers) {
    worker->signal(SIGTERM);
    worker->wait();
  }
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  expect_identical(fetch_spectral_exr(job_id), spec);
  v1::ListWorkersRequest request;
  v1::ListWorkersResponse response;
  auto context = client();
  ASSERT_TRUE(farm_stub_->ListWorkers(context.get(), request, &response).ok());
  EXPECT_EQ(response.workers_size(), 2);
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

}  // namespace
}  // namespace prism::coordinator
