// The fixture the FarmService and WorkerService tests share (farm_server_test.cpp: jobs, bundles,
// authentication; farm_server_workers_test.cpp: leases, workers, restarts): an in-process
// coordinator with its gRPC server on loopback, stubs for both services, and a fake worker that
// renders tasks with the real tile renderer.
#pragma once

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
#include "services/rpc/result_download.h"
#include "services/rpc/result_upload.h"
#include "services/scene/bundle.h"
#include "services/scene/scene_loader.h"
#include "services/store/blob_store.h"
#include "services/store/job_store.h"
#include "tests/testing/child_process.h"
#include "worker/render_scene.h"
#include "worker/tile_renderer.h"

namespace prism::coordinator::farm_server_testing {

namespace fs = std::filesystem;
namespace v1 = prism::v1;

// Regular files anywhere under `dir` (0 when it does not exist).
inline std::size_t count_files(const fs::path& dir) {
  std::size_t n = 0;
  std::error_code ec;
  for (const auto& entry : fs::recursive_directory_iterator(dir, ec)) {
    if (entry.is_regular_file()) ++n;
  }
  return n;
}

using prism::testing::fresh_dir;

inline void write(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

using testing::packed_bundle;
inline constexpr const char* kToken = testing::kApiToken;
inline constexpr const char* kSecret = testing::kWorkerSecret;
inline constexpr const char* kScene = testing::kSmallScene;

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
      options.max_queued_jobs = 1000;
      options.max_memory_bytes = 0;
      options.max_disk_bytes = 0;
      options.scheduler.lease_duration = Millis(5000);
      if (configure_) configure_(options);
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

  // Writes `text` (kScene by default) under root_/scene, uploads its bundle and returns the hash
  // (empty, with the failure recorded, when the upload fails).
  std::string upload_scene(const std::string& text = kScene) {
    scene_root_ = root_ / "scene";
    std::string hash;
    const grpc::Status status = upload(packed_bundle(scene_root_, text), &hash);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return status.ok() ? hash : std::string();
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

  // small_spec of the uploaded scene (no bundle hash, with the test failed, when the upload
  // failed).
  v1::JobSpec uploaded_small_spec() {
    const std::string hash = upload_scene();
    return hash.empty() ? v1::JobSpec() : small_spec(hash);
  }

  // Uploads the scene and submits small_spec of it: the job's id ("" when either failed).
  std::string submit_small_job() {
    const v1::JobSpec spec = uploaded_small_spec();
    return spec.bundle_hash().empty() ? std::string() : submit(spec).job_id();
  }

  // SubmitJob's status (and the job in `info`, when given and submitted).
  grpc::Status try_submit(const v1::JobSpec& spec, const std::string& token = "",
                          v1::JobInfo* info = nullptr) {
    v1::SubmitJobRequest request;
    *request.mutable_spec() = spec;
    request.set_client_token(token);
    v1::SubmitJobResponse response;
    auto context = client();
    grpc::Status status = farm_stub_->SubmitJob(context.get(), request, &response);
    if (info != nullptr) *info = response.job();
    return status;
  }

  v1::JobInfo submit(const v1::JobSpec& spec, const std::string& token = "") {
    v1::JobInfo info;
    const grpc::Status status = try_submit(spec, token, &info);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return info;
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
    return image::serialise_task_result(*std::move(result));
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

  // The worker's FailTask for `lease`.
  grpc::Status fail_task(const std::string& worker_id, const std::string& lease_id,
                         v1::FailureClass failure_class, const std::string& message = "") {
    v1::FailTaskRequest request;
    request.set_worker_id(worker_id);
    request.set_lease_id(lease_id);
    request.set_failure_class(failure_class);
    request.set_message(message);
    v1::FailTaskResponse response;
    auto context = worker_call();
    return worker_stub_->FailTask(context.get(), request, &response);
  }

  grpc::Status get_job(const std::string& job_id, v1::JobInfo* info) {
    v1::GetJobRequest request;
    request.set_job_id(job_id);
    auto context = client();
    return farm_stub_->GetJob(context.get(), request, info);
  }
  grpc::Status cancel_job(const std::string& job_id, v1::JobInfo* info) {
    v1::CancelJobRequest request;
    request.set_job_id(job_id);
    auto context = client();
    return farm_stub_->CancelJob(context.get(), request, info);
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

  // The embedded render of the same job, through the same output writer (its filtered image when
  // `filtered`).
  image::SpectralExr oracle(const v1::JobSpec& spec, bool filtered = false) {
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
    OutputPaths paths{dir / "o.exr",          dir / "o.rgb.exr",     dir / "o.png",
                      dir / "o.json",         dir / "o.primal.exr",  dir / "o.gradient.exr",
                      dir / "o.filtered.exr", dir / "o.filtered.png"};
    RenderReport report;
    if (filtered) {
      EXPECT_TRUE(result->filtered.has_value() && result->filtered_rgb.has_value());
      EXPECT_TRUE(write_filtered(*result->filtered, *result->filtered_rgb, report, paths, {}).ok());
      auto exr = image::read_spectral_exr(paths.filtered_exr);
      EXPECT_TRUE(exr.ok()) << exr.status();
      return *std::move(exr);
    }
    EXPECT_TRUE(write_outputs(result->image, result->rgb, report, paths, {}).ok());
    auto exr = image::read_spectral_exr(paths.spectral_exr);
    EXPECT_TRUE(exr.ok()) << exr.status();
    return *std::move(exr);
  }

  std::string fetch_spectral_exr(const std::string& job_id,
                                 v1::OutputKind kind = v1::OUTPUT_KIND_SPECTRAL_EXR) {
    v1::GetResultRequest request;
    request.set_job_id(job_id);
    request.add_kinds(kind);
    auto context = client();
    auto reader = farm_stub_->GetResult(context.get(), request);
    absl::StatusOr<prism::rpc::ResultFiles> read = prism::rpc::read_result_files(*reader);
    EXPECT_TRUE(reader->Finish().ok());
    EXPECT_TRUE(read.ok() && !read->ended_inside_a_file && read->files.size() == 1)
        << read.status();
    return read.ok() ? read->files[kind] : std::string();
  }

  // `filtered`: the job's filtered image (differential splatting) instead of the main one.
  void expect_identical(const std::string& exr_bytes, const v1::JobSpec& spec,
                        bool filtered = false) {
    const fs::path fetched = root_ / "fetched.exr";
    write(fetched, exr_bytes);
    auto farm_exr = image::read_spectral_exr(fetched);
    ASSERT_TRUE(farm_exr.ok()) << farm_exr.status();
    const image::SpectralExr local = oracle(spec, filtered);
    const auto a = farm_exr->spectral.data();
    const auto b = local.spectral.data();
    ASSERT_EQ(a.size(), b.size());
    ASSERT_GT(a.size(), 0u);
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(float)), 0);
    double sum = 0;
    for (float v : a) sum += v;
    EXPECT_GT(sum, 0.0);  // not a black image
  }

#ifdef PRISM_WORKER_BINARY
  // Two real prism-worker processes render `spec` (its bundle_hash is set here from `scene`); the
  // fetched spectral EXR must be the embedded render's bytes, and so must the filtered one when
  // the job splats.
  void render_with_real_workers(v1::JobSpec spec, const std::string& scene = kScene) {
    const char* binary = std::getenv("PRISM_WORKER_BIN");
    if (binary == nullptr || *binary == '\0') binary = PRISM_WORKER_BINARY;
    const std::string hash = upload_scene(scene);
    ASSERT_FALSE(hash.empty());
    spec.set_bundle_hash(hash);
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
    if (spec.splat_width() > 0 || spec.gather_width() > 0) {
      expect_identical(fetch_spectral_exr(job_id, v1::OUTPUT_KIND_FILTERED_EXR), spec, true);
    }
    v1::ListWorkersRequest request;
    v1::ListWorkersResponse response;
    auto context = client();
    ASSERT_TRUE(farm_stub_->ListWorkers(context.get(), request, &response).ok());
    EXPECT_EQ(response.workers_size(), 2);
  }
#endif

  // A test's own farm options (limits, hooks), applied by the next start().
  std::function<void(FarmOptions&)> configure_;
  fs::path root_;
  fs::path scene_root_;
  spectral::SpectrumLibrary library_;
  worker::EmbreeDevice device_;
  std::unique_ptr<testing::InProcessFarm> farm_;
  std::unique_ptr<v1::FarmService::Stub> farm_stub_;
  std::unique_ptr<v1::WorkerService::Stub> worker_stub_;
};

}  // namespace prism::coordinator::farm_server_testing
