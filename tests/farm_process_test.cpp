// The farm as separate processes on loopback: a `prism-coordinator` and `prism-worker`s, driven
// over gRPC by this test, compared byte for byte with `prism render` (the real CLI). Each test
// has its own data directory and kills every child it started in TearDown.
#include <arpa/inet.h>
#include <fcntl.h>
#include <grpcpp/create_channel.h>
#include <grpcpp/security/credentials.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "coordinator/finished_tiles.h"
#include "coordinator/tile_plan.h"
#include "prism/v1/farm.grpc.pb.h"
#include "prism/v1/worker.grpc.pb.h"
#include "services/base/sha256.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile_codec.h"
#include "services/rpc/auth.h"
#include "services/rpc/chunks.h"
#include "services/rpc/result_download.h"
#include "services/rpc/result_upload.h"
#include "services/scene/bundle.h"
#include "services/store/job_store.h"
#include "tests/testing/child_process.h"

namespace prism {
namespace {

namespace fs = std::filesystem;
namespace v1 = prism::v1;
using Clock = std::chrono::steady_clock;

fs::path source_scene() {
  return fs::path(PRISM_SOURCE_DIR) / "worker/testdata/unbiased.pbrt";
}

constexpr int kSpp = 16;

class FarmProcessTest : public ::testing::Test {
 protected:
  void SetUp() override { root_ = testing::fresh_scene_dir(source_scene()); }
  void TearDown() override {
    children_.clear();  // each is killed and reaped; its output printed when the test failed
    fs::remove_all(root_);
  }

  // Starts `argv`; the fixture owns it until the test ends.
  testing::ChildProcess* spawn(std::vector<std::string> argv,
                               const testing::ChildOptions& options = {}) {
    children_.push_back(testing::ChildProcess::start(std::move(argv), options));
    return children_.back().get();
  }

  // `prism` with `args` to the end; fails the test unless it exits with `want`.
  testing::RunResult run_prism(std::vector<std::string> args, int want = 0) {
    args.insert(args.begin(), PRISM_BINARY);
    testing::RunResult r = testing::run(std::move(args));
    EXPECT_EQ(r.exit_code, want) << r.out << r.err;
    return r;
  }

  // Starts the coordinator on `port` (0: any) and connects the stubs to it.
  void start_coordinator(int port = 0, const std::string& data = "data") {
    coordinator_ = spawn(testing::coordinator_command(
        PRISM_COORDINATOR_BINARY, "127.0.0.1:" + std::to_string(port), root_ / data,
        testing::kWorkerSecret, testing::kApiToken,
        {"--heartbeat-ms", std::to_string(testing::kHeartbeatMs), "--lease-ms", "1000"}));
    ASSERT_NE(coordinator_, nullptr);
    const std::optional<std::string> line =
        coordinator_->wait_for_line("listening on port", std::chrono::seconds(20));
    port_ = 0;
    if (line.has_value()) std::sscanf(line->c_str(), "listening on port %d", &port_);
    ASSERT_GT(port_, 0) << "the coordinator did not print its port";
    auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(port_),
                                       grpc::InsecureChannelCredentials());
    stub_ = v1::FarmService::NewStub(channel);
  }

  testing::ChildProcess* start_worker(int i) {
    std::string host = "w";
    host += std::to_string(i);
    return spawn({PRISM_WORKER_BINARY, "--coordinator", "127.0.0.1:" + std::to_string(port_),
                  "--threads", "1", "--secret", testing::kWorkerSecret, "--host", host,
                  "--cache-dir", (root_ / ("cache" + std::to_string(i))).string(), "--log-level",
                  "error"});
  }

  // Whether the worker started as start_worker(i) with host `host` holds a lease within `seconds`.
  bool wait_busy(const std::string& host, double seconds) {
    const auto end = Clock::now() + std::chrono::duration<double>(seconds);
    while (Clock::now() < end) {
      v1::ListWorkersRequest request;
      v1::ListWorkersResponse response;
      auto context = client();
      if (stub_->ListWorkers(context.get(), request, &response).ok()) {
        for (const auto& w : response.workers()) {
          if (w.host() == host && w.state() == "busy") return true;
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return false;
  }

  std::unique_ptr<grpc::ClientContext> client() {
    auto context = std::make_unique<grpc::ClientContext>();
    prism::rpc::add_bearer(*context, testing::kApiToken);
    context->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
    return context;
  }

  // `files`: what the scene references besides itself (SceneDescription::files, as the client
  // passes them).
  std::string upload(const std::vector<std::string>& files = {}) {
    auto bundle = scene::make_bundle(root_ / "scene", "scene.pbrt", files);
    EXPECT_TRUE(bundle.ok()) << bundle.status();
    const std::string bytes = scene::pack(*bundle);
    auto context = client();
    v1::UploadBundleResponse response;
    auto writer = stub_->UploadBundle(context.get(), &response);
    for (std::string_view piece : prism::rpc::split_chunks(bytes, 16 << 10)) {
      v1::BundleChunk chunk;
      chunk.set_total_bytes(bytes.size());
      chunk.set_data(std::string(piece));
      if (!writer->Write(chunk)) break;
    }
    writer->WritesDone();
    const grpc::Status status = writer->Finish();
    EXPECT_TRUE(status.ok()) << status.error_message();
    return response.bundle_hash();
  }

  // 24x24 in 8-pixel tiles: 9 tasks, each one tile's whole sample range (as `prism render`).
  // No prepass unless asked for (the scene would have one by default): these tests count tasks.
  v1::JobSpec spec(const std::string& hash, int spp, int samples_per_task = 0) {
    v1::JobSpec s;
    s.mutable_prepass()->set_enabled(false);
    s.set_samples_per_task(samples_per_task);
    s.set_bundle_hash(hash);
    s.set_scene_path("scene.pbrt");
    s.set_spp(spp);
    s.set_tile_size(8);
    s.set_seed(11);
    return s;
  }

  // The coordinator's answer to SubmitJob; `job_id` is set when it accepts.
  grpc::Status try_submit(const v1::JobSpec& s, std::string* job_id) {
    v1::SubmitJobRequest request;
    *request.mutable_spec() = s;
    v1::SubmitJobResponse response;
    auto context = client();
    const grpc::Status status = stub_->SubmitJob(context.get(), request, &response);
    *job_id = response.job().job_id();
    return status;
  }

  std::string submit(const v1::JobSpec& s) {
    std::string job_id;
    const grpc::Status status = try_submit(s, &job_id);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return job_id;
  }

  v1::JobInfo get_job(const std::string& job_id) {
    v1::GetJobRequest request;
    request.set_job_id(job_id);
    v1::JobInfo info;
    auto context = client();
    stub_->GetJob(context.get(), request, &info);
    return info;
  }

  // Polls until `done(info)` or the timeout.
  template <typename Pred>
  v1::JobInfo wait_for(const std::string& job_id, Pred done, double seconds) {
    const auto end = Clock::now() + std::chrono::duration<double>(seconds);
    v1::JobInfo info;
    while (Clock::now() < end) {
      info = get_job(job_id);
      if (done(info)) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return info;
  }
  static bool terminal(const v1::JobInfo& info) {
    return info.state() == v1::JOB_STATE_DONE || info.state() == v1::JOB_STATE_FAILED ||
           info.state() == v1::JOB_STATE_CANCELLED;
  }

  std::vector<float> fetch_spectral(const std::string& job_id,
                                    v1::OutputKind kind = v1::OUTPUT_KIND_SPECTRAL_EXR) {
    const fs::path file = root_ / "farm.exr";
    std::ofstream(file, std::ios::binary) << fetch_bytes(job_id, kind);
    return read_pixels(file);
  }

  std::string fetch_bytes(const std::string& job_id, v1::OutputKind kind) {
    v1::GetResultRequest request;
    request.set_job_id(job_id);
    request.add_kinds(kind);
    auto context = client();
    auto reader = stub_->GetResult(context.get(), request);
    absl::StatusOr<rpc::ResultFiles> read = rpc::read_result_files(*reader);
    EXPECT_TRUE(reader->Finish().ok());
    EXPECT_TRUE(read.ok() && !read->ended_inside_a_file && read->files.size() == 1)
        << read.status();
    return read.ok() ? read->files[kind] : std::string();
  }

  static std::vector<float> read_pixels(const fs::path& file) {
    auto exr = image::read_spectral_exr(file);
    EXPECT_TRUE(exr.ok()) << exr.status();
    if (!exr.ok()) return {};
    const auto data = exr->spectral.data();
    return {data.begin(), data.end()};
  }

  // `prism render` of the same job; `extra` are more flags (default: no prepass, as spec()).
  std::vector<float> cli_render(int spp, int samples_per_task = 0,
                                std::vector<std::string> extra = {"--no-prepass"},
                                const std::string& read = "cli.exr") {
    const fs::path out = root_ / "cli" / "cli.exr";
    fs::create_directories(out.parent_path());
    std::vector<std::string> args = {PRISM_BINARY,
                                     "render",
                                     (root_ / "scene" / "scene.pbrt").string(),
                                     "-o",
                                     out.string(),
                                     "--spp",
                                     std::to_string(spp),
                                     "--seed",
                                     "11",
                                     "--tile",
                                     "8",
                                     "--threads",
                                     "2"};
    if (samples_per_task > 0) {
      args.push_back("--samples-per-task");
      args.push_back(std::to_string(samples_per_task));
    }
    // The farm's jobs here name no integrator (hero); `prism render` would choose with auto.
    if (std::find(extra.begin(), extra.end(), "--integrator") == extra.end()) {
      args.insert(args.end(), {"--integrator", "hero"});
    }
    args.insert(args.end(), extra.begin(), extra.end());
    const testing::RunResult run = testing::run(args);
    EXPECT_EQ(run.exit_code, 0) << run.out << run.err;
    return read_pixels(out.parent_path() / read);
  }

  // A prepass job of Ñ = `prepass_spp` (9 tiles, 27 tasks: pass 1, pass 2 done or skipped, the
  // final pass) through a coordinator killed (-9) and restarted once `kill_after` tasks are done,
  // compared byte for byte with `prism render` of the same job. Returns that render's JSON report.
  std::string prepass_job_across_a_restart(int prepass_spp, int kill_after) {
    const int port = testing::free_port();
    start_coordinator(port);
    v1::JobSpec s = spec(upload(), kSpp);
    s.mutable_prepass()->set_enabled(true);
    s.mutable_prepass()->set_spp(prepass_spp);
    const std::string job_id = submit(s);
    EXPECT_FALSE(job_id.empty());
    EXPECT_EQ(wait_for(
                  job_id, [](const v1::JobInfo&) { return true; }, 5)
                  .state(),
              v1::JOB_STATE_PREPASS);
    start_worker(0);
    const v1::JobInfo mid = wait_for(
        job_id,
        [&](const v1::JobInfo& i) {
          return i.progress().tasks_done() >= std::uint64_t(kill_after);
        },
        30);
    EXPECT_GE(mid.progress().tasks_done(), std::uint64_t(kill_after));
    // PREPASS until the final pass's 9 tasks begin (a skipped pass 2 counts as done), then
    // RENDERING.
    if (mid.progress().tasks_done() < 18) {
      EXPECT_EQ(mid.state(), v1::JOB_STATE_PREPASS);
    } else if (mid.progress().tasks_done() < 27) {
      EXPECT_EQ(mid.state(), v1::JOB_STATE_RENDERING);
    }
    coordinator_->kill();
    start_coordinator(port);
    start_worker(1);
    const v1::JobInfo done = wait_for(job_id, terminal, 60);
    EXPECT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
    EXPECT_EQ(done.progress().tasks_done(), 27u);
    EXPECT_EQ(done.progress().tasks_total(), 27u);
    const std::string n = std::to_string(prepass_spp);
    expect_identical(fetch_spectral(job_id),
                     cli_render(kSpp, 0, {"--prepass", "--prepass-spp", n}));
    std::ifstream json(root_ / "cli" / "cli.json");
    return std::string((std::istreambuf_iterator<char>(json)), std::istreambuf_iterator<char>());
  }

  void expect_identical(const std::vector<float>& farm, const std::vector<float>& cli) {
    ASSERT_EQ(farm.size(), cli.size());
    ASSERT_GT(farm.size(), 0u);
    EXPECT_EQ(std::memcmp(farm.data(), cli.data(), farm.size() * sizeof(float)), 0);
    double sum = 0;
    for (float v : farm) sum += v;
    EXPECT_GT(sum, 0.0);
  }

  fs::path root_;
  std::vector<std::unique_ptr<testing::ChildProcess>> children_;
  testing::ChildProcess* coordinator_ = nullptr;
  int port_ = 0;
  std::unique_ptr<v1::FarmService::Stub> stub_;
};

// About 0.1-0.2 s per 8x8 task on one thread: the kills land in the middle of the job.
constexpr int kSlowSpp = 1024;

TEST_F(FarmProcessTest, TwoWorkerProcessesMatchPrismRenderByteForByte) {
  start_coordinator();
  const std::string job_id = submit(spec(upload(), kSpp));
  ASSERT_FALSE(job_id.empty());
  start_worker(0);
  start_worker(1);
  const v1::JobInfo done = wait_for(job_id, terminal, 20);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  EXPECT_EQ(done.progress().tasks_done(), 9u);
  expect_identical(fetch_spectral(job_id), cli_render(kSpp));
}

// Spectral gradient sampling through the farm: workers return I and G, the coordinator merges
// them and reconstructs each tile; the reconstruction and the raw I and G are the embedded
// render's bytes, with the L2 and the variance-weighted reconstruction.
TEST_F(FarmProcessTest, AGradientJobMatchesPrismRenderByteForByte) {
  start_coordinator();
  v1::JobSpec s = spec(upload(), kSpp, 6);
  s.set_integrator(v1::INTEGRATOR_GRADIENT);
  s.mutable_gradient()->set_tau(0.01f);
  s.mutable_outputs()->set_primal_and_gradients(true);
  const std::string job_id = submit(s);
  ASSERT_FALSE(job_id.empty());
  start_worker(0);
  start_worker(1);
  const v1::JobInfo done = wait_for(job_id, terminal, 30);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  const std::vector<std::string> flags = {"--no-prepass", "--integrator", "gradient",
                                          "--tau",        "0.01",         "--primal-and-gradients"};
  expect_identical(fetch_spectral(job_id), cli_render(kSpp, 6, flags));
  expect_identical(fetch_spectral(job_id, v1::OUTPUT_KIND_PRIMAL_EXR),
                   cli_render(kSpp, 6, flags, "cli.primal.exr"));
  const std::vector<float> farm_gradient = fetch_spectral(job_id, v1::OUTPUT_KIND_GRADIENT_EXR);
  const std::vector<float> cli_gradient = cli_render(kSpp, 6, flags, "cli.gradient.exr");
  ASSERT_EQ(farm_gradient.size(), cli_gradient.size());
  ASSERT_GT(farm_gradient.size(), 0u);
  EXPECT_EQ(std::memcmp(farm_gradient.data(), cli_gradient.data(), cli_gradient.size() * 4), 0);

  // The variance-weighted reconstruction: the workers add the halves, the coordinator pools
  // variances over each tile; the same bytes as `prism render --poisson weighted`.
  v1::JobSpec weighted = spec(upload(), kSpp, 6);
  weighted.set_integrator(v1::INTEGRATOR_GRADIENT);
  weighted.mutable_gradient()->set_norm(v1::POISSON_NORM_WEIGHTED);
  const std::string weighted_id = submit(weighted);
  ASSERT_FALSE(weighted_id.empty());
  const v1::JobInfo weighted_done = wait_for(weighted_id, terminal, 30);
  ASSERT_EQ(weighted_done.state(), v1::JOB_STATE_DONE) << weighted_done.error();
  const std::vector<float> farm_weighted = fetch_spectral(weighted_id);
  EXPECT_NE(farm_weighted, fetch_spectral(job_id));
  expect_identical(farm_weighted, cli_render(kSpp, 6,
                                             {"--no-prepass", "--integrator", "gradient", "--tau",
                                              "0", "--poisson", "weighted"}));
}

// A scene that reads images (an image texture and an environment map) and uses coated
// materials and a disk: the images travel in the bundle and the workers decode them from it.
TEST_F(FarmProcessTest, AJobWhoseSceneReadsImagesMatchesPrismRenderByteForByte) {
  const fs::path source = fs::path(PRISM_SOURCE_DIR) / "tests/testdata/pipeline";
  fs::copy_file(source / "textured.pbrt", root_ / "scene" / "scene.pbrt",
                fs::copy_options::overwrite_existing);
  fs::create_directories(root_ / "scene" / "textures");
  for (const char* image : {"hues.png", "sky-equalarea.png"}) {
    fs::copy_file(source / "textures" / image, root_ / "scene" / "textures" / image);
  }
  start_coordinator();
  const std::string job_id =
      submit(spec(upload({"textures/hues.png", "textures/sky-equalarea.png"}), kSpp));
  ASSERT_FALSE(job_id.empty());
  start_worker(0);
  start_worker(1);
  const v1::JobInfo done = wait_for(job_id, terminal, 30);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  EXPECT_EQ(done.progress().tasks_done(), 6u);
  expect_identical(fetch_spectral(job_id), cli_render(kSpp));
}

// A scene with features Prism does not support (a hair material, a partial sphere) is refused
// at submit unless the job allows substitutions; then the workers load it with the same
// substitutions as `prism render --allow-unsupported`, and the report lists them.
TEST_F(FarmProcessTest, AJobThatAllowsUnsupportedInputMatchesPrismRenderAndListsSubstitutions) {
  {
    std::ofstream scene(root_ / "scene" / "scene.pbrt");
    scene << R"(LookAt 0 2 -5  0 0.5 0  0 1 0
Camera "perspective" "float fov" 40
Film "spectral" "integer xresolution" 24 "integer yresolution" 24 "integer nbuckets" 16
Sampler "independent" "integer pixelsamples" 16
WorldBegin
LightSource "point" "point3 from" [0 4 -2] "blackbody I" 4000 "float scale" 20
Material "hair" "float eumelanin" 1.3
Shape "trianglemesh" "point3 P" [-4 0 -4  4 0 -4  4 0 4  -4 0 4] "integer indices" [0 1 2 0 2 3]
Material "diffuse" "rgb reflectance" [0.7 0.3 0.2]
Translate 0 0.7 0
Shape "sphere" "float radius" 0.7 "float zmin" 0
)";
  }
  start_coordinator();
  const std::string hash = upload();
  v1::JobSpec strict = spec(hash, kSpp);
  {
    std::string refused_id;
    const grpc::Status status = try_submit(strict, &refused_id);
    EXPECT_TRUE(refused_id.empty());
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(status.error_message().find("scene.pbrt:7:10: unsupported material type \"hair\""),
              std::string::npos)
        << status.error_message();
  }
  v1::JobSpec allowed = strict;
  allowed.set_allow_unsupported(true);
  const std::string job_id = submit(allowed);
  ASSERT_FALSE(job_id.empty());
  start_worker(0);
  start_worker(1);
  const v1::JobInfo done = wait_for(job_id, terminal, 30);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  expect_identical(fetch_spectral(job_id),
                   cli_render(kSpp, 0, {"--no-prepass", "--allow-unsupported"}));
  const std::string report = fetch_bytes(job_id, v1::OUTPUT_KIND_REPORT_JSON);
  EXPECT_NE(report.find("\"feature\": \"Material \\\"hair\\\"\""), std::string::npos) << report;
  EXPECT_NE(report.find("\"substitution\": \"a full sphere\""), std::string::npos) << report;
}

// The multi-pass prepass through the farm: two prepasses of 9 tile tasks each, the coordinator's
// filters and tables between them, then the final pass with each tile's tables. Killing the
// coordinator during the prepass resumes it from the stored prepass results.
TEST_F(FarmProcessTest, APrepassJobMatchesPrismRenderByteForByteAcrossACoordinatorRestart) {
  // Two rooms under a red and a blue LED: the tables pay, so the prepass runs both passes.
  fs::copy_file(fs::path(PRISM_SOURCE_DIR) / "tests/testdata/pipeline/two_leds.pbrt",
                root_ / "scene" / "scene.pbrt", fs::copy_options::overwrite_existing);
  const std::string report = prepass_job_across_a_restart(64, 10);
  // This one goes on after pass 1 (the next test covers the early stop).
  EXPECT_NE(report.find("\"stopped_early\": false"), std::string::npos) << report;
}

// A prepass that stops after its first pass (its tables predict too little: prepass.h
// kMinImageGain): the second pass's 9 tasks are skipped, not rendered, and count as done; the
// final pass samples the default distribution. Killing the coordinator during the final pass
// resumes it with the same decision, taken again from the stored first pass.
TEST_F(FarmProcessTest, APrepassThatStopsAfterItsFirstPassSkipsTheRestAndMatchesPrismRender) {
  // One F11 lamp over grey surfaces: the emitter mixture is already the best distribution.
  {
    std::ofstream scene(root_ / "scene" / "scene.pbrt");
    scene << R"(LookAt 0 3 -6  0 0.6 0  0 1 0
Camera "perspective" "float fov" 40
Film "spectral" "integer xresolution" 24 "integer yresolution" 24 "integer nbuckets" 16
Sampler "independent" "integer pixelsamples" 16
WorldBegin
AttributeBegin
  Material "diffuse" "rgb reflectance" [0.5 0.5 0.5]
  Shape "trianglemesh" "point3 P" [-4 0 -4  4 0 -4  4 0 4  -4 0 4] "integer indices" [0 1 2 0 2 3]
  Translate 0 0.7 0
  Shape "sphere" "float radius" 0.7
AttributeEnd
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" "stdillum-F11" "float scale" 4
  Translate 0 3 0
  Rotate 90 1 0 0
  Shape "bilinearmesh" "point3 P" [-1 -1 0  1 -1 0  -1 1 0  1 1 0]
AttributeEnd
)";
  }
  const std::string report = prepass_job_across_a_restart(128, 20);
  EXPECT_NE(report.find("\"stopped_early\": true"), std::string::npos) << report;
}

// A job to a target error (5 % per pixel, 4 spp doubling to at most 256): the tiles that see
// only black background meet it in round 1 and the others run on, so later rounds skip some
// tiles' tasks. Killing the coordinator mid-job replays the stored rounds and takes the same
// decisions; the bytes and the report's reached errors are those of `prism render` with the
// same flags.
TEST_F(FarmProcessTest, ATargetErrorJobMatchesPrismRenderAcrossACoordinatorRestart) {
  const int port = testing::free_port();
  start_coordinator(port);
  v1::JobSpec s = spec(upload(), 4);
  s.set_target_error(0.05f);
  s.set_max_spp(256);
  const std::string job_id = submit(s);
  ASSERT_FALSE(job_id.empty());
  start_worker(0);
  const v1::JobInfo mid = wait_for(
      job_id, [](const v1::JobInfo& i) { return i.progress().tasks_done() >= 12; }, 30);
  EXPECT_GE(mid.progress().tasks_done(), 12u);
  ASSERT_LT(mid.progress().tasks_done(), 63u) << "the job finished before the kill";
  coordinator_->kill();
  start_coordinator(port);
  start_worker(1);
  const v1::JobInfo done = wait_for(job_id, terminal, 60);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  // 9 tiles x 7 rounds (4, 8, ..., 256), every task done or skipped.
  EXPECT_EQ(done.progress().tasks_total(), 63u);
  EXPECT_EQ(done.progress().tasks_done(), 63u);
  const std::vector<float> farm = fetch_spectral(job_id);
  const std::string farm_report = fetch_bytes(job_id, v1::OUTPUT_KIND_REPORT_JSON);
  coordinator_->kill();
  {
    auto store = store::JobStore::open(root_ / "data" / "jobs.sqlite");
    ASSERT_TRUE(store.ok()) << store.status();
    auto tasks = store->tasks_of(job_id);
    ASSERT_TRUE(tasks.ok()) << tasks.status();
    int skipped = 0;
    for (const store::TaskRecord& t : *tasks) skipped += t.state == store::TaskState::kSkipped;
    EXPECT_GT(skipped, 0) << "no tile met the target before the last round";
    EXPECT_LT(skipped, 54) << "every tile met the target in round 1";
  }
  expect_identical(farm,
                   cli_render(4, 0, {"--no-prepass", "--target-error", "5%", "--max-spp", "256"}));
  std::ifstream json(root_ / "cli" / "cli.json");
  const std::string cli_report((std::istreambuf_iterator<char>(json)),
                               std::istreambuf_iterator<char>());
  auto section = [](const std::string& report) {
    auto j = nlohmann::json::parse(report);
    EXPECT_TRUE(j.contains("target_error")) << report;
    return j.value("target_error", nlohmann::json());
  };
  EXPECT_EQ(section(farm_report), section(cli_report));
  EXPECT_EQ(section(cli_report)["rounds"], 7);
  EXPECT_EQ(section(cli_report)["spp"]["min"], 4);
  EXPECT_EQ(section(cli_report)["spp"]["max"], 256);
}

// The README demo as a user submits it, with auto (the default) choosing in `prism submit` as in
// `prism render`: its clean-caustics choice (hero with light-traced caustics at 1/64 of a light
// path per pixel, tests/render_cli_test.cpp) goes into the job, whose whole-image tasks over two
// worker processes give `prism render`'s bytes and the same auto section in the report.
TEST_F(FarmProcessTest, TheDemoSubmittedWithAutoIsPrismRendersBytes) {
  start_coordinator();
  start_worker(0);
  start_worker(1);
  const std::string scene = (fs::path(PRISM_SOURCE_DIR) / "scenes/prism.pbrt").string();
  const std::vector<std::string> job = {"--resolution", "160x120", "--spp", "64"};
  std::vector<std::string> submit = testing::submit_command(
      PRISM_BINARY, scene, "127.0.0.1:" + std::to_string(port_), testing::kApiToken,
      {"--wait", "-o", (root_ / "farm" / "demo.exr").string()});
  submit.insert(submit.end(), job.begin(), job.end());
  fs::create_directories(root_ / "farm");
  const testing::RunResult submitted = testing::run(submit);
  ASSERT_EQ(submitted.exit_code, 0) << submitted.out << submitted.err;
  std::vector<std::string> render = {"render", scene, "-o", (root_ / "cli" / "demo.exr").string()};
  render.insert(render.end(), job.begin(), job.end());
  fs::create_directories(root_ / "cli");
  run_prism(render);
  expect_identical(read_pixels(root_ / "farm" / "demo.exr"),
                   read_pixels(root_ / "cli" / "demo.exr"));
  auto report = [&](const char* dir) {
    std::ifstream in(root_ / dir / "demo.json");
    return nlohmann::json::parse(
        std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>()),
        nullptr, false);
  };
  const nlohmann::json farm = report("farm"), cli = report("cli");
  ASSERT_FALSE(farm.is_discarded());
  ASSERT_FALSE(cli.is_discarded());
  EXPECT_EQ(cli["auto"]["choice"], "hero+caustics") << cli["auto"].dump();
  EXPECT_EQ(cli["caustic_paths"], 0.015625) << cli.dump();
  EXPECT_EQ(farm["auto"]["choice"], cli["auto"]["choice"]) << farm.dump();
  EXPECT_EQ(farm["auto"]["reason"], cli["auto"]["reason"]);
  EXPECT_EQ(farm["caustic_paths"], cli["caustic_paths"]);
  // The work reported is the same: rays and counters of the final pass, its seconds on the
  // wall clock (the farm's summed over workers apart), and the job was not resumed.
  EXPECT_EQ(farm["rays"], cli["rays"]);
  EXPECT_EQ(farm["counters"], cli["counters"]);
  EXPECT_GT(farm["render_seconds"].get<double>(), 0.0);
  EXPECT_GT(farm["worker_seconds"].get<double>(), 0.0);
  EXPECT_FALSE(farm.contains("resumed"));
  // Who rendered it: the workers' shares add up to the job's samples, and `threads` is theirs
  // together (it was 0, "spread over the farm").
  ASSERT_TRUE(farm["workers"].is_array()) << farm.dump();
  std::uint64_t samples = 0;
  int threads = 0;
  for (const auto& w : farm["workers"]) {
    EXPECT_TRUE(w["host"] == "w0" || w["host"] == "w1") << w.dump();
    EXPECT_EQ(w["threads"], 1) << w.dump();
    EXPECT_GT(w["tasks"].get<int>(), 0) << w.dump();
    samples += w["samples"].get<std::uint64_t>();
    threads += w["threads"].get<int>();
  }
  EXPECT_EQ(samples, cli["samples"].get<std::uint64_t>());
  EXPECT_EQ(farm["threads"], threads);
  EXPECT_FALSE(cli.contains("workers"));
}

// Tasks of tile x sample range: each tile's four ranges ([0,5), [5,10), [10,15), [15,16)) come
// back from either worker in any order and are added in range order.
TEST_F(FarmProcessTest, SampleRangeTasksMatchPrismRenderByteForByte) {
  start_coordinator();
  const std::string job_id = submit(spec(upload(), kSpp, 5));
  ASSERT_FALSE(job_id.empty());
  start_worker(0);
  start_worker(1);
  const v1::JobInfo done = wait_for(job_id, terminal, 20);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  EXPECT_EQ(done.progress().tasks_done(), 9u * 4u);
  expect_identical(fetch_spectral(job_id), cli_render(kSpp, 5));
}

// `prism bench --coordinator`: every render (the reference's two halves included) is a job of
// its own on the farm, and since the farm's bytes are `prism render`'s, the errors are exactly
// those of the same bench run in process, each with a reference cache of its own. A rerun submits
// new jobs (its own client tokens) and takes the reference from the cache the first run filled.
TEST_F(FarmProcessTest, BenchOnTheFarmMeasuresExactlyWhatALocalBenchMeasures) {
  start_coordinator();
  start_worker(0);
  start_worker(1);
  // prism bench refuses a farm with no worker to take its jobs: wait for both to register.
  const auto registered = Clock::now() + std::chrono::seconds(20);
  for (int workers = 0; workers < 2 && Clock::now() < registered;) {
    v1::ListWorkersRequest request;
    v1::ListWorkersResponse response;
    auto context = client();
    workers =
        stub_->ListWorkers(context.get(), request, &response).ok() ? response.workers_size() : 0;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  auto run = [&](const std::string& out, const std::string& cache, bool farm) {
    std::vector<std::string> args = {PRISM_BINARY,
                                     "bench",
                                     (root_ / "scene" / "scene.pbrt").string(),
                                     "--spp",
                                     "4,8",
                                     "--seeds",
                                     "1",
                                     "--methods",
                                     "uniform,hero",
                                     "--reference-spp",
                                     "32",
                                     "--inset",
                                     "4,4,8,8",
                                     "--reference-cache",
                                     (root_ / cache).string(),
                                     "-o",
                                     (root_ / out).string()};
    if (farm) {
      args.insert(args.end(), {"--coordinator", "127.0.0.1:" + std::to_string(port_), "--token",
                               testing::kApiToken});
    }
    const testing::RunResult r = testing::run(args);
    EXPECT_EQ(r.exit_code, 0) << out << ": " << r.err;
  };
  auto jobs = [&] {
    v1::ListJobsRequest request;
    v1::ListJobsResponse response;
    auto context = client();
    EXPECT_TRUE(stub_->ListJobs(context.get(), request, &response).ok());
    int done = 0;
    for (const auto& job : response.jobs()) done += job.state() == v1::JOB_STATE_DONE ? 1 : 0;
    EXPECT_EQ(done, response.jobs_size());
    return response.jobs_size();
  };
  // The CSV without its timing columns (seconds, wall_seconds, cpu_seconds).
  auto measured = [&](const std::string& out) {
    std::ifstream in(root_ / out / "results.csv");
    std::vector<std::string> rows;
    for (std::string line; std::getline(in, line);) {
      std::vector<std::string> fields(1);  // split at commas outside quotes
      bool quoted = false;
      for (char c : line) {
        if (c == '"') quoted = !quoted;
        if (c == ',' && !quoted) {
          fields.emplace_back();
        } else {
          fields.back().push_back(c);
        }
      }
      EXPECT_EQ(fields.size(), 17u) << line;
      if (fields.size() == 17) fields.erase(fields.begin() + 6, fields.begin() + 9);
      std::string kept;
      for (const std::string& f : fields) kept += f + ",";
      rows.push_back(kept);
    }
    return rows;
  };

  run("farm", "farm-cache", true);
  EXPECT_EQ(jobs(), 2 + 2 * 2);  // the reference's halves, then 2 methods x 2 spp
  run("local", "local-cache", false);
  EXPECT_EQ(jobs(), 6);
  const std::vector<std::string> farm = measured("farm"), local = measured("local");
  ASSERT_EQ(farm.size(), 1u + 2 * 2 * 2);  // the header, then two regions per render
  EXPECT_EQ(farm, local);
  EXPECT_NE(farm[1].find(",uniform,4spp,1,image,4,"), std::string::npos) << farm[1];
  EXPECT_TRUE(fs::exists(root_ / "farm" / "scene.png"));
  EXPECT_FALSE(fs::exists(root_ / "farm" / ".farm"));  // the fetched outputs are gone

  run("again", "farm-cache", true);
  EXPECT_EQ(jobs(), 6 + 4);  // new jobs, the cached reference
  EXPECT_EQ(measured("again"), farm);
}

// With no worker to take its jobs, prism bench stops before it renders or submits anything
// (instead of waiting for ever on its first job).
TEST_F(FarmProcessTest, BenchOnAFarmWithoutWorkersStopsBeforeSubmittingAnything) {
  start_coordinator();
  const testing::RunResult r =
      run_prism({"bench", (root_ / "scene" / "scene.pbrt").string(), "--spp", "4", "--seeds", "1",
                 "--reference-spp", "8", "--reference-cache", (root_ / "cache").string(), "-o",
                 (root_ / "out").string(), "--coordinator", "127.0.0.1:" + std::to_string(port_),
                 "--token", testing::kApiToken},
                1);
  const std::string& message = r.err;
  EXPECT_NE(message.find("has no idle or busy worker"), std::string::npos) << message;
  EXPECT_FALSE(fs::exists(root_ / "out" / "results.csv"));
  EXPECT_FALSE(fs::exists(root_ / "cache"));
  v1::ListJobsRequest request;
  v1::ListJobsResponse response;
  auto context = client();
  ASSERT_TRUE(stub_->ListJobs(context.get(), request, &response).ok());
  EXPECT_EQ(response.jobs_size(), 0);
}

TEST_F(FarmProcessTest, AWorkerKilledMidJobLeavesTheBytesUnchanged) {
  start_coordinator();
  const std::string job_id = submit(spec(upload(), kSlowSpp));
  testing::ChildProcess* doomed = start_worker(0);
  start_worker(1);
  // Kill worker 0 while it holds a lease, after at least one task is done.
  wait_for(
      job_id, [](const v1::JobInfo& i) { return i.progress().tasks_done() >= 1; }, 20);
  ASSERT_TRUE(wait_busy("w0", 10));
  ASSERT_LT(get_job(job_id).progress().tasks_done(), 9u) << "the job finished before the kill";
  doomed->kill();
  const v1::JobInfo done = wait_for(job_id, terminal, 30);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  expect_identical(fetch_spectral(job_id), cli_render(kSlowSpp));
}

// `prism submit --wait` (the command the Slurm and Kubernetes docs give) through a coordinator
// killed and started again mid-job: it exited with "Socket closed" though the job resumed and
// finished. It waits for the coordinator, follows the job to the end, and fetches prism render's
// bytes.
TEST_F(FarmProcessTest, SubmitWaitFollowsItsJobThroughACoordinatorRestart) {
  const int port = testing::free_port();
  start_coordinator(port);
  start_worker(0);
  fs::create_directories(root_ / "farm");
  std::vector<std::string> submit = testing::submit_command(
      PRISM_BINARY, root_ / "scene" / "scene.pbrt", "127.0.0.1:" + std::to_string(port),
      testing::kApiToken, {"--wait", "-o", (root_ / "farm" / "farm.exr").string()});
  submit.push_back("--spp");
  submit.push_back(std::to_string(kSlowSpp));
  for (const char* f : {"--seed", "11", "--tile", "8", "--integrator", "hero", "--no-prepass"}) {
    submit.push_back(f);
  }
  testing::ChildProcess* submitted = spawn(submit);
  ASSERT_NE(submitted, nullptr);
  // Its job, once it has finished a few tasks.
  std::string job_id;
  const auto listed_by = Clock::now() + std::chrono::seconds(20);
  while (Clock::now() < listed_by && job_id.empty()) {
    v1::ListJobsRequest request;
    v1::ListJobsResponse response;
    auto context = client();
    if (stub_->ListJobs(context.get(), request, &response).ok() && response.jobs_size() > 0) {
      job_id = response.jobs(0).job_id();
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_FALSE(job_id.empty()) << submitted->out() << submitted->err();
  const v1::JobInfo mid = wait_for(
      job_id, [](const v1::JobInfo& i) { return i.progress().tasks_done() >= 2; }, 20);
  ASSERT_LT(mid.progress().tasks_done(), 9u) << "the job finished before the kill";
  coordinator_->kill();
  std::this_thread::sleep_for(std::chrono::seconds(1));
  start_coordinator(port);
  const std::optional<int> exit_code = submitted->wait(std::chrono::minutes(2));
  ASSERT_TRUE(exit_code.has_value()) << "prism submit --wait did not end";
  ASSERT_EQ(*exit_code, 0) << submitted->out() << submitted->err();
  EXPECT_NE((submitted->out() + submitted->err()).find("is unreachable"), std::string::npos)
      << submitted->out() << submitted->err();
  // The last progress line says the job is done, with no rate or time left ("0 samples/s").
  {
    const std::string progress = submitted->out() + submitted->err();
    const std::size_t done = progress.find(" done 100.0%");
    ASSERT_NE(done, std::string::npos) << progress;
    const std::string line = progress.substr(done, progress.find('\n', done) - done);
    EXPECT_EQ(line.find("samples/s"), std::string::npos) << line;
  }
  // Its report says the counters cover the work since the restart (they summed that alone).
  {
    std::ifstream in(root_ / "farm" / "farm.json");
    const nlohmann::json report = nlohmann::json::parse(in, nullptr, false);
    ASSERT_FALSE(report.is_discarded());
    EXPECT_EQ(report["resumed"], true) << report.dump();
    // The rates divide what was rendered since then (the workers' samples), not the whole job's
    // samples: those gave twice the real rate for a job resumed halfway.
    ASSERT_TRUE(report.contains("workers") && report.contains("worker_seconds")) << report.dump();
    double since = 0;
    for (const auto& w : report["workers"]) since += w["samples"].get<double>();
    EXPECT_GT(since, 0.0);
    EXPECT_LT(since, report["samples"].get<double>());
    if (report["render_seconds"].get<double>() > 0) {
      EXPECT_NEAR(report["samples_per_second"].get<double>(),
                  since / report["render_seconds"].get<double>(),
                  1e-6 * report["samples_per_second"].get<double>());
    }
  }
  expect_identical(read_pixels(root_ / "farm" / "farm.exr"), cli_render(kSlowSpp));
}

// Gathering filters the whole image at the end: on the coordinator's threads for the farm, on
// the render's own for `prism render`. Their denormal values differed, since Embree leaves
// flush-to-zero on in the threads that build its BVH (services/base/float_mode.h).
TEST_F(FarmProcessTest, AGatheringJobsFilteredImageIsPrismRendersBytes) {
  start_coordinator();
  start_worker(0);
  const fs::path scene = fs::path(PRISM_SOURCE_DIR) / "scenes" / "glass-enclosed.pbrt";
  const std::vector<std::string> flags = {
      "--resolution", "64x48", "--spp", "16", "--integrator", "hero", "--gather", "--seed", "12"};
  fs::create_directories(root_ / "farm");
  std::vector<std::string> submit = testing::submit_command(
      PRISM_BINARY, scene, "127.0.0.1:" + std::to_string(port_), testing::kApiToken,
      {"--wait", "-o", (root_ / "farm" / "g.exr").string()});
  submit.insert(submit.end(), flags.begin(), flags.end());
  const testing::RunResult farm = testing::run(submit);
  ASSERT_EQ(farm.exit_code, 0) << farm.out << farm.err;
  std::vector<std::string> render = {"render", scene.string(), "--threads",
                                     "2",      "-o",           (root_ / "cli.exr").string()};
  render.insert(render.end(), flags.begin(), flags.end());
  run_prism(render);
  expect_identical(read_pixels(root_ / "farm" / "g.exr"), read_pixels(root_ / "cli.exr"));
  expect_identical(read_pixels(root_ / "farm" / "g.filtered.exr"),
                   read_pixels(root_ / "cli.filtered.exr"));
}

// The coordinator comes back at the same address on another data directory, where another
// job has the same id: `prism submit --wait` wrote that job's outputs under its own name. It
// must notice the job is not its own and write nothing.
TEST_F(FarmProcessTest, SubmitWaitDoesNotFollowItsJobIdIntoAnotherFarm) {
  const int port = testing::free_port();
  start_coordinator(port);
  fs::create_directories(root_ / "farm");
  std::vector<std::string> submit = testing::submit_command(
      PRISM_BINARY, root_ / "scene" / "scene.pbrt", "127.0.0.1:" + std::to_string(port),
      testing::kApiToken, {"--wait", "-o", (root_ / "farm" / "mine.exr").string()});
  for (const char* f : {"--spp", "64", "--seed", "11", "--integrator", "hero", "--no-prepass"}) {
    submit.push_back(f);
  }
  // No worker yet: it waits. Killed once it has its job's id (printed when SubmitJob answered;
  // killed before, it submits again, and rightly renders its job on the other farm).
  testing::ChildOptions merged;
  merged.merge_stderr = true;
  testing::ChildProcess* submitted = spawn(submit, merged);
  ASSERT_TRUE(submitted->wait_for_line("j-000001", std::chrono::seconds(20)).has_value());
  coordinator_->kill();
  // Another user's job on the other data directory, also j-000001, stored before that
  // coordinator takes over the address (submitted after, it raced the client's reconnection).
  start_coordinator(0, "other-data");
  std::vector<std::string> theirs =
      testing::submit_command(PRISM_BINARY, root_ / "scene" / "scene.pbrt",
                              "127.0.0.1:" + std::to_string(port_), testing::kApiToken, {});
  for (const char* f : {"--spp", "2", "--seed", "3", "--integrator", "hero", "--no-prepass"}) {
    theirs.push_back(f);
  }
  const testing::RunResult other = testing::run(theirs);
  ASSERT_EQ(other.exit_code, 0) << other.out << other.err;
  coordinator_->kill();
  start_coordinator(port, "other-data");
  start_worker(0);
  const std::optional<int> exit_code = submitted->wait(std::chrono::minutes(2));
  ASSERT_TRUE(exit_code.has_value()) << "prism submit --wait did not end";
  EXPECT_NE(*exit_code, 0) << submitted->out() << submitted->err();
  EXPECT_NE((submitted->out() + submitted->err()).find("came back with another job j-000001"),
            std::string::npos)
      << submitted->out() << submitted->err();
  EXPECT_FALSE(fs::exists(root_ / "farm" / "mine.exr"));
}

TEST_F(FarmProcessTest, ACoordinatorKilledMidJobResumesWithoutRerenderingFinishedTasks) {
  const int port = testing::free_port();
  start_coordinator(port);
  const std::string job_id = submit(spec(upload(), kSlowSpp));
  start_worker(0);
  start_worker(1);
  const v1::JobInfo mid = wait_for(
      job_id, [](const v1::JobInfo& i) { return i.progress().tasks_done() >= 3; }, 20);
  ASSERT_LT(mid.progress().tasks_done(), 9u) << "the job finished before the kill";
  coordinator_->kill();
  std::map<int, store::TaskRecord> before;
  {
    auto store = store::JobStore::open(root_ / "data" / "jobs.sqlite");
    ASSERT_TRUE(store.ok()) << store.status();
    auto tasks = store->tasks_of(job_id);
    ASSERT_TRUE(tasks.ok()) << tasks.status();
    for (const store::TaskRecord& t : *tasks) {
      if (t.state == store::TaskState::kDone) before[t.index] = t;
    }
  }
  ASSERT_GE(before.size(), 3u);
  ASSERT_LT(before.size(), 9u);
  start_coordinator(port);
  const v1::JobInfo done = wait_for(job_id, terminal, 30);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  const std::vector<float> farm = fetch_spectral(job_id);
  coordinator_->kill();
  {
    auto store = store::JobStore::open(root_ / "data" / "jobs.sqlite");
    ASSERT_TRUE(store.ok()) << store.status();
    auto tasks = store->tasks_of(job_id);
    ASSERT_TRUE(tasks.ok()) << tasks.status();
    ASSERT_EQ(tasks->size(), 9u);
    for (const store::TaskRecord& t : *tasks) {
      EXPECT_EQ(t.state, store::TaskState::kDone);
      auto it = before.find(t.index);
      if (it == before.end()) continue;
      EXPECT_EQ(t.attempts, 1) << "task " << t.index << " was leased again after the restart";
      EXPECT_EQ(t.result_hash, it->second.result_hash) << "task " << t.index;
    }
  }
  expect_identical(farm, cli_render(kSlowSpp));
}

// Synthetic workers for the burst test below: they register, lease and answer each task at
// once with a result whose value depends on its sample range (1 + the range's first sample),
// so a range merged twice, or lost, changes its tile's mean. Each acknowledged result is
// listed with its SHA-256; a worker stops at its first error (the coordinator was killed).
struct Acknowledged {
  image::TileRect rect;
  image::SampleRange samples;
  std::string sha256;
};

struct SyntheticWorkers {
  int port = 0;
  int bins = 0;
  std::atomic<bool> stop{false};
  std::mutex mutex;
  std::vector<Acknowledged> acknowledged;
  std::vector<std::thread> threads;

  void start(int count) {
    for (int i = 0; i < count; ++i) threads.emplace_back([this, i] { run(i); });
  }
  void join() {
    stop = true;
    for (std::thread& t : threads) t.join();
    threads.clear();
  }
  std::size_t count() {
    std::lock_guard<std::mutex> lock(mutex);
    return acknowledged.size();
  }

  static std::unique_ptr<grpc::ClientContext> call() {
    auto context = std::make_unique<grpc::ClientContext>();
    prism::rpc::add_bearer(*context, testing::kWorkerSecret);
    context->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    return context;
  }

  std::string result(const image::TileRect& rect, const image::SampleRange& samples) const {
    image::TileBuffers buffers;
    buffers.rgb = true;
    image::TileResult r = image::TileResult::create(rect, samples, bins, buffers).value();
    const double n = double(samples.count());
    const double v = 1.0 + double(samples.s0);
    for (double& x : r.mutable_sums()) x = v * n;
    for (double& x : r.mutable_sum_squares()) x = v * v * n;
    for (double& x : r.mutable_rgb_sums()) x = v * n;
    for (double& x : r.mutable_rgb_squares()) x = v * v * n;
    for (std::uint64_t& c : r.mutable_counts()) c = samples.count();
    return image::serialise_tile(r);
  }

  void run(int index) {
    auto stub = v1::WorkerService::NewStub(grpc::CreateChannel("127.0.0.1:" + std::to_string(port),
                                                               grpc::InsecureChannelCredentials()));
    v1::RegisterRequest hello;
    hello.set_host("synthetic-" + std::to_string(index));
    hello.set_threads(1);
    v1::RegisterResponse registered;
    if (!stub->Register(call().get(), hello, &registered).ok()) return;
    Clock::time_point beat = Clock::now();
    while (!stop) {
      if (Clock::now() - beat > std::chrono::milliseconds(testing::kHeartbeatMs / 2)) {
        v1::HeartbeatRequest request;
        request.set_worker_id(registered.worker_id());
        v1::HeartbeatResponse reply;
        if (!stub->Heartbeat(call().get(), request, &reply).ok()) return;
        beat = Clock::now();
      }
      v1::AcquireTaskRequest request;
      request.set_worker_id(registered.worker_id());
      request.set_wait_ms(50);
      v1::AcquireTaskResponse response;
      if (!stub->AcquireTask(call().get(), request, &response).ok()) return;
      if (!response.has_lease()) continue;
      const v1::Task& task = response.lease().task();
      const image::TileRect rect{task.tile().x0(), task.tile().y0(), task.tile().x1(),
                                 task.tile().y1()};
      const image::SampleRange samples{task.samples().begin(), task.samples().end()};
      const std::string bytes = result(rect, samples);
      prism::rpc::ResultUploadHeader header;
      header.worker_id = registered.worker_id();
      header.lease_id = response.lease().lease_id();
      header.sha256 = base::sha256_hex(bytes);
      auto context = call();
      v1::CompleteTaskResponse done;
      auto writer = stub->CompleteTask(context.get(), &done);
      if (!prism::rpc::upload_result(*writer, header, bytes).ok()) return;
      if (!done.accepted()) return;
      std::lock_guard<std::mutex> lock(mutex);
      acknowledged.push_back({rect, samples, header.sha256});
    }
  }
};

// Issue 18: results are made durable in groups (one sync of the result pack and the store for
// every result acknowledged meanwhile). A coordinator killed (-9) in the middle of a burst of
// completions from eight workers has every acknowledged result in its store, whole; once
// restarted it finishes the job with every task counted once, and the image is exactly that of
// the same job run without a kill (a range merged twice or lost would change a tile's mean).
TEST_F(FarmProcessTest, AKillDuringABurstOfResultsLosesNothingAcknowledgedAndMergesNothingTwice) {
  const int port = testing::free_port();
  start_coordinator(port);
  const std::string hash = upload();
  v1::JobSpec s = spec(hash, 4, 1);  // four one-sample ranges per tile
  s.set_width(64);
  s.set_height(64);  // 64 tiles of 8x8: 256 tasks
  s.set_bins(8);
  const std::string job_id = submit(s);
  ASSERT_FALSE(job_id.empty());

  SyntheticWorkers workers;
  workers.port = port;
  workers.bins = 8;
  workers.start(8);
  const auto until = Clock::now() + std::chrono::seconds(30);
  while (workers.count() < 80 && Clock::now() < until) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  coordinator_->kill();
  workers.join();
  const std::vector<Acknowledged> acknowledged = workers.acknowledged;
  ASSERT_GE(acknowledged.size(), 80u);
  ASSERT_LT(acknowledged.size(), 256u) << "the job finished before the kill";

  // Every acknowledged result is DONE in the store with its hash, and its bytes are whole: in
  // the result pack, or, once released from it, merged in its tile's synced record.
  {
    coordinator::TilePlanOptions options;
    options.width = options.height = 64;
    options.tile_size = int(s.tile_size());
    options.spp = s.spp();
    options.samples_per_task = s.samples_per_task();
    auto plan = coordinator::plan_tiles(options);
    ASSERT_TRUE(plan.ok()) << plan.status();
    auto tiles =
        coordinator::FinishedTiles::open(root_ / "data" / "jobs" / job_id / "tiles", *plan, 64, 8);
    ASSERT_TRUE(tiles.ok()) << tiles.status();
    auto store = store::JobStore::open(root_ / "data" / "jobs.sqlite");
    ASSERT_TRUE(store.ok()) << store.status();
    auto tasks = store->tasks_of(job_id);
    ASSERT_TRUE(tasks.ok()) << tasks.status();
    ASSERT_EQ(tasks->size(), 256u);
    const int fd = ::open((root_ / "data" / "jobs" / job_id / "results.pack").c_str(), O_RDONLY);
    ASSERT_GE(fd, 0);
    int found = 0, released = 0;
    for (const Acknowledged& a : acknowledged) {
      for (const store::TaskRecord& t : *tasks) {
        if (!(t.rect == a.rect) || !(t.samples == a.samples)) continue;
        ++found;
        EXPECT_EQ(t.state, store::TaskState::kDone) << "task " << t.index;
        EXPECT_EQ(t.result_hash, a.sha256) << "task " << t.index;
        std::string bytes(t.result_size, '\0');
        EXPECT_EQ(::pread(fd, bytes.data(), bytes.size(), t.result_offset), ssize_t(bytes.size()));
        if (base::sha256_hex(bytes) == a.sha256) continue;
        ++released;
        EXPECT_EQ(bytes, std::string(bytes.size(), '\0')) << "task " << t.index;
        auto merged = tiles->get(t.tile_index);
        ASSERT_TRUE(merged.ok()) << "task " << t.index << ": " << merged.status();
        EXPECT_EQ(merged->samples(), (image::SampleRange{0, s.spp()}));
      }
    }
    ::close(fd);
    EXPECT_EQ(found, int(acknowledged.size()));
    std::printf("%d of %zu acknowledged results released, their tiles stored\n", released,
                acknowledged.size());
  }

  start_coordinator(port);
  workers.stop = false;
  workers.start(8);
  const v1::JobInfo done = wait_for(job_id, terminal, 60);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  EXPECT_EQ(done.progress().tasks_done(), 256u);
  EXPECT_EQ(done.progress().samples_done(), done.progress().samples_total());
  EXPECT_EQ(done.progress().samples_total(), 64u * 64u * 4u);
  const std::string killed = fetch_bytes(job_id, v1::OUTPUT_KIND_SPECTRAL_EXR);

  // The same job on the same coordinator without a kill.
  const std::string again = submit(s);
  ASSERT_FALSE(again.empty());
  const v1::JobInfo done_again = wait_for(again, terminal, 60);
  workers.join();
  ASSERT_EQ(done_again.state(), v1::JOB_STATE_DONE) << done_again.error();
  const std::string clean = fetch_bytes(again, v1::OUTPUT_KIND_SPECTRAL_EXR);
  ASSERT_FALSE(clean.empty());
  EXPECT_TRUE(killed == clean) << "the job across the kill differs from the same job without";
  // Each pixel is the mean of its four ranges' values, 1..4: a range counted twice or lost
  // would move it.
  const fs::path file = root_ / "killed.exr";
  std::ofstream(file, std::ios::binary) << killed;
  const std::vector<float> pixels = read_pixels(file);
  ASSERT_EQ(pixels.size(), 64u * 64u * 8u);
  for (std::size_t i = 0; i < pixels.size(); ++i) ASSERT_EQ(pixels[i], pixels[i % 8]) << i;
}

TEST_F(FarmProcessTest, ACancelledJobFreesItsWorkerWithinAHeartbeat) {
  start_coordinator();
  const std::string hash = upload();
  // One 24x24 tile at a sample count that takes far longer than the test waits.
  v1::JobSpec long_spec = spec(hash, 1 << 16);
  long_spec.set_tile_size(32);
  const std::string long_job = submit(long_spec);
  start_worker(0);
  // Wait until the worker holds the long task's lease.
  ASSERT_TRUE(wait_busy("w0", 10));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // well into the render
  {
    v1::CancelJobRequest request;
    request.set_job_id(long_job);
    v1::JobInfo info;
    auto context = client();
    ASSERT_TRUE(stub_->CancelJob(context.get(), request, &info).ok());
  }
  const auto cancelled_at = Clock::now();
  const v1::JobInfo cancelled = wait_for(
      long_job, [](const v1::JobInfo& i) { return i.state() == v1::JOB_STATE_CANCELLED; }, 5);
  EXPECT_EQ(cancelled.state(), v1::JOB_STATE_CANCELLED);
  // A tiny job: one 4x4 tile at 1 spp, rendered as soon as the worker drops the cancelled task.
  v1::JobSpec tiny = spec(hash, 1);
  tiny.set_width(4);
  tiny.set_height(4);
  tiny.set_tile_size(4);
  const std::string tiny_job = submit(tiny);
  const v1::JobInfo done = wait_for(tiny_job, terminal, 10);
  const double seconds = std::chrono::duration<double>(Clock::now() - cancelled_at).count();
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE) << done.error();
  // Two heartbeats for the directive to reach the worker, plus the tiny render and finalise.
  EXPECT_LT(seconds, 2 * testing::kHeartbeatMs / 1000.0 + 0.8);
}

}  // namespace
}  // namespace prism
