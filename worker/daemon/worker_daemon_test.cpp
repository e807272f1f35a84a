// The worker daemon against a fake coordinator: a WorkerService written here (not the real
// coordinator) on 127.0.0.1 with port 0, handing out one lease for the furnace scene.
#include "worker/daemon/worker_daemon.h"

#include <grpcpp/server.h>
#include <grpcpp/server_builder.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <sys/wait.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

#include "absl/strings/str_cat.h"
#include "services/base/sha256.h"
#include "services/image/tile_codec.h"
#include "services/job/job_spec.h"
#include "services/rpc/auth.h"
#include "services/rpc/status_mapping.h"
#include "services/scene/bundle.h"
#include "services/scene/scene_loader.h"
#include "tests/testing/child_process.h"
#include "worker/testing/skewed_tables.h"
#include "worker/tile_renderer.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

std::int64_t unix_ms_from_now(std::chrono::milliseconds delta) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             (std::chrono::system_clock::now() + delta).time_since_epoch())
      .count();
}

struct Upload {
  std::vector<std::size_t> chunk_sizes;
  std::string bytes;
  std::string sha256;
  std::uint64_t total_bytes = 0;
  std::string worker_id, lease_id;
  std::uint64_t rays = 0;
  std::map<std::string, std::uint64_t> counters;  // of the last chunk
};

class FakeCoordinator final : public v1::WorkerService::Service {
 public:
  // Configuration, set before the worker starts.
  std::string blob;  // what FetchBundle streams
  v1::Lease lease;   // handed out by the first AcquireTask
  std::uint32_t heartbeat_interval_ms = 100;
  bool cancel_when_rendering = false;          // CANCEL_TASK once a heartbeat reports progress
  bool drain_when_holding = false;             // DRAIN once a heartbeat carries the lease
  std::chrono::milliseconds extend_leases{0};  // renew the held lease by this much (0: never)
  bool reregister_once = false;                // REREGISTER on the first heartbeat
  int unavailable_registers = 0;               // answer this many Register calls with UNAVAILABLE
  int full_disk_registers = 0;  // then this many with the INTERNAL a full disk gives
  std::string secret;                          // the worker secret every call must carry
  std::vector<v1::Lease> later_leases;         // handed out by the AcquireTasks after the first
  bool hold_uploads = false;                   // CompleteTask answers only once this is false

  grpc::Status Register(grpc::ServerContext* context, const v1::RegisterRequest* request,
                        v1::RegisterResponse* response) override {
    std::lock_guard<std::mutex> lock(mutex);
    const absl::Status auth = rpc::check_bearer(*context, secret);
    if (!auth.ok()) {
      refused_secrets++;
      return rpc::to_grpc(auth);
    }
    if (unavailable_registers > 0) {
      --unavailable_registers;
      return grpc::Status(grpc::StatusCode::UNAVAILABLE, "the coordinator is starting");
    }
    if (full_disk_registers > 0) {
      --full_disk_registers;
      return grpc::Status(grpc::StatusCode::INTERNAL,
                          "sqlite: step 'COMMIT': database or disk is full");
    }
    registrations.push_back(*request);
    response->set_worker_id("w-1");
    response->set_heartbeat_interval_ms(heartbeat_interval_ms);
    return grpc::Status::OK;
  }

  grpc::Status AcquireTask(grpc::ServerContext* context, const v1::AcquireTaskRequest* request,
                           v1::AcquireTaskResponse* response) override {
    std::unique_lock<std::mutex> lock(mutex);
    if (!handed_out) {
      handed_out = true;
      *response->mutable_lease() = lease;
      return grpc::Status::OK;
    }
    if (later_handed < later_leases.size()) {
      *response->mutable_lease() = later_leases[later_handed++];
      changed.notify_all();
      return grpc::Status::OK;
    }
    acquires_after_lease.push_back(Clock::now());
    changed.notify_all();
    // A long poll with nothing to hand out; gives up early when the worker cancels.
    const auto until = Clock::now() + std::chrono::milliseconds(request->wait_ms());
    while (Clock::now() < until && !context->IsCancelled()) changed.wait_for(lock, 20ms);
    return grpc::Status::OK;
  }

  grpc::Status Heartbeat(grpc::ServerContext*, const v1::HeartbeatRequest* request,
                         v1::HeartbeatResponse* response) override {
    std::lock_guard<std::mutex> lock(mutex);
    heartbeats.push_back(*request);
    const bool holding =
        request->lease_ids_size() == 1 && request->lease_ids(0) == lease.lease_id();
    if (reregister_once && heartbeats.size() == 1) {
      response->add_directives()->set_kind(v1::Directive::KIND_REREGISTER);
    }
    if (cancel_when_rendering && holding && request->samples_done() > 0 && !cancel_sent) {
      cancel_sent = Clock::now();
      samples_at_cancel = request->samples_done();
      v1::Directive* directive = response->add_directives();
      directive->set_kind(v1::Directive::KIND_CANCEL_TASK);
      directive->set_lease_id(lease.lease_id());
    }
    if (extend_leases.count() > 0 && holding) {
      response->set_lease_deadline_unix_ms(
          std::chrono::duration_cast<std::chrono::milliseconds>(
              (std::chrono::system_clock::now() + extend_leases).time_since_epoch())
              .count());
    }
    if (drain_when_holding && holding && !drain_sent) {
      drain_sent = true;
      response->add_directives()->set_kind(v1::Directive::KIND_DRAIN);
    }
    changed.notify_all();
    return grpc::Status::OK;
  }

  grpc::Status CompleteTask(grpc::ServerContext*, grpc::ServerReader<v1::ResultUpload>* reader,
                            v1::CompleteTaskResponse* response) override {
    Upload upload;
    v1::ResultUpload chunk;
    bool first = true;
    while (reader->Read(&chunk)) {
      if (first) {
        upload.worker_id = chunk.worker_id();
        upload.lease_id = chunk.lease_id();
        first = false;
      }
      if (chunk.offset() != upload.bytes.size()) {
        return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "chunk out of order");
      }
      upload.chunk_sizes.push_back(chunk.data().size());
      upload.bytes += chunk.data();
      upload.total_bytes = chunk.total_bytes();
      if (chunk.last()) {
        upload.sha256 = chunk.sha256();
        upload.rays = chunk.rays();
        upload.counters.insert(chunk.counters().begin(), chunk.counters().end());
      }
    }
    std::unique_lock<std::mutex> lock(mutex);
    uploads_started.push_back(upload.lease_id);
    changed.notify_all();
    changed.wait(lock, [&] { return !hold_uploads; });
    uploads.push_back(std::move(upload));
    response->set_accepted(true);
    changed.notify_all();
    return grpc::Status::OK;
  }

  grpc::Status FailTask(grpc::ServerContext*, const v1::FailTaskRequest* request,
                        v1::FailTaskResponse*) override {
    std::lock_guard<std::mutex> lock(mutex);
    failures.push_back(*request);
    changed.notify_all();
    return grpc::Status::OK;
  }

  grpc::Status Leave(grpc::ServerContext*, const v1::LeaveRequest* request,
                     v1::LeaveResponse*) override {
    std::lock_guard<std::mutex> lock(mutex);
    left.push_back(request->worker_id());
    changed.notify_all();
    return grpc::Status::OK;
  }

  grpc::Status FetchBundle(grpc::ServerContext*, const v1::FetchBundleRequest* request,
                           grpc::ServerWriter<v1::BundleData>* writer) override {
    {
      std::lock_guard<std::mutex> lock(mutex);
      fetched.push_back(request->bundle_hash());
    }
    // Small chunks, so the worker's assembly of several messages is exercised.
    constexpr std::size_t kChunk = 512;
    for (std::size_t offset = 0; offset < blob.size(); offset += kChunk) {
      v1::BundleData data;
      data.set_offset(offset);
      data.set_data(blob.substr(offset, kChunk));
      data.set_total_bytes(blob.size());
      if (!writer->Write(data)) break;
    }
    return grpc::Status::OK;
  }

  // Waits until `done()` holds (under the mutex) or the timeout passes.
  template <typename Pred>
  bool wait(Pred done, std::chrono::milliseconds timeout = 20s) {
    std::unique_lock<std::mutex> lock(mutex);
    return changed.wait_for(lock, timeout, done);
  }

  std::mutex mutex;
  std::condition_variable changed;
  bool handed_out = false;
  std::size_t later_handed = 0;              // of later_leases
  std::vector<std::string> uploads_started;  // lease ids, as each upload arrived whole
  std::vector<v1::RegisterRequest> registrations;
  int refused_secrets = 0;
  std::vector<v1::HeartbeatRequest> heartbeats;
  std::vector<Clock::time_point> acquires_after_lease;
  std::optional<Clock::time_point> cancel_sent;
  std::uint64_t samples_at_cancel = 0;
  bool drain_sent = false;
  std::vector<Upload> uploads;
  std::vector<v1::FailTaskRequest> failures;
  std::vector<std::string> fetched;
  std::vector<std::string> left;  // worker ids that said Leave
};

class WorkerDaemonTest : public ::testing::Test {
 protected:
  void SetUp() override {
    library_ =
        std::make_unique<spectral::SpectrumLibrary>(*spectral::SpectrumLibrary::load_builtin());
    auto bundle =
        scene::make_bundle(fs::path(PRISM_SOURCE_DIR) / "worker/testdata", "furnace.pbrt", {});
    ASSERT_TRUE(bundle.ok()) << bundle.status();
    bundle_ = *bundle;
    fake_.blob = scene::pack(bundle_);
    cache_dir_ = prism::testing::fresh_dir();
    logger_ = spdlog::get("worker");
    if (!logger_) logger_ = spdlog::stderr_color_mt("worker");
    logger_->set_level(spdlog::level::debug);
  }

  void TearDown() override {
    if (worker_thread_.joinable()) {
      daemon_->drain();
      worker_thread_.join();
    }
    daemon_.reset();
    client_.reset();
    if (server_) server_->Shutdown(std::chrono::system_clock::now() + 1s);
  }

  // A lease for `tile` x `samples` of the furnace at 16x16, 8 bins.
  v1::Lease make_lease(v1::TileRect tile, std::uint32_t s0, std::uint32_t s1,
                       std::uint32_t max_depth, std::chrono::milliseconds lease_time = 60s) {
    v1::Lease lease;
    lease.set_lease_id("lease-1");
    lease.set_attempt(1);
    lease.set_deadline_unix_ms(unix_ms_from_now(lease_time));
    lease.set_bundle_hash(bundle_.content_hash);
    v1::Task& task = *lease.mutable_task();
    task.set_job_id("job-1");
    task.set_pass(v1::PASS_FINAL);
    *task.mutable_tile() = tile;
    task.mutable_samples()->set_begin(s0);
    task.mutable_samples()->set_end(s1);
    v1::JobSpec& spec = *task.mutable_spec();
    spec.set_bundle_hash(bundle_.content_hash);
    spec.set_scene_path("furnace.pbrt");
    spec.set_integrator(v1::INTEGRATOR_HERO);
    spec.set_spp(s1);
    spec.set_width(16);
    spec.set_height(16);
    spec.set_bins(8);
    spec.set_tile_size(8);
    spec.set_seed(7);
    spec.set_max_depth(max_depth);
    return lease;
  }

  static v1::TileRect rect(int x0, int y0, int x1, int y1) {
    v1::TileRect r;
    r.set_x0(x0);
    r.set_y0(y0);
    r.set_x1(x1);
    r.set_y1(y1);
    return r;
  }

  // The fake on 127.0.0.1 with a port the kernel picks; its address.
  std::string start_server() {
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
    builder.RegisterService(&fake_);
    server_ = builder.BuildAndStart();
    EXPECT_NE(server_, nullptr);
    EXPECT_GT(port, 0);
    return "127.0.0.1:" + std::to_string(port);
  }

  void start_worker(std::chrono::milliseconds return_margin = 100ms, const std::string& secret = "",
                    std::chrono::milliseconds drain_timeout = 0ms) {
    ClientConfig client_config;
    client_config.address = start_server();
    client_config.secret = secret;
    client_config.call_timeout = 5s;
    client_ = std::make_unique<WorkerClient>(client_config, logger_);
    WorkerConfig config;
    config.host = "test-host";
    config.version = "test";
    config.threads = 2;
    config.cache_dir = cache_dir_;
    config.acquire_wait_ms = 200;
    config.return_margin = return_margin;
    config.drain_timeout = drain_timeout;
    config.acquire_error_pause = 100ms;
    daemon_ = std::make_unique<WorkerDaemon>(config, *client_, device_, *library_, arena_, logger_);
    worker_thread_ = std::thread([this] {
      run_status_ = daemon_->run();
      run_returned_.store(true);
    });
  }

  // Drains and waits for run() to return; false if it did not within the timeout.
  bool stop_worker(std::chrono::milliseconds timeout = 10s) {
    daemon_->drain();
    return join_worker(timeout);
  }

  bool join_worker(std::chrono::milliseconds timeout = 10s) {
    const auto until = Clock::now() + timeout;
    while (!run_returned_.load() && Clock::now() < until) std::this_thread::sleep_for(10ms);
    if (!run_returned_.load()) return false;
    worker_thread_.join();
    return true;
  }

  // The same task rendered here with TileRenderer: the bytes the worker must upload.
  std::string render_in_process(const v1::Lease& lease) {
    scene::LoadOptions load = scene::with_library_names(*library_);
    auto loaded =
        scene::load_scene(fs::path(PRISM_SOURCE_DIR) / "worker/testdata/furnace.pbrt", load);
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    auto params = job::job_parameters(lease.task().spec(), loaded->description);
    EXPECT_TRUE(params.ok()) << params.status();
    const v1::Task& t = lease.task();
    const int film_width = t.film_width() != 0 ? int(t.film_width()) : params->width;
    const int film_height = t.film_height() != 0 ? int(t.film_height()) : params->height;
    auto scene = RenderScene::build(device_, loaded->description, *library_, params->render,
                                    film_width, film_height);
    EXPECT_TRUE(scene.ok()) << scene.status();
    RenderTask task;
    task.tile = {t.tile().x0(), t.tile().y0(), t.tile().x1(), t.tile().y1()};
    task.samples = {t.samples().begin(), t.samples().end()};
    task.pass = t.pass_index();
    task.want_guides = t.want_guides();
    task.prepass = t.pass() == v1::PASS_PREPASS;
    task.early_stop = task.prepass && t.early_stop_prepass();
    std::optional<spectral::PixelTables> tables;
    if (t.has_pdf_table()) {
      auto decoded =
          spectral::PixelTables::decode(task.tile.width(), task.tile.height(),
                                        int(t.pdf_table().cells()), t.pdf_table().quantised_cdf());
      EXPECT_TRUE(decoded.ok()) << decoded.status();
      tables.emplace(std::move(*decoded));
      task.tables = &*tables;
    }
    auto result = TileRenderer(**scene).render(task, nullptr);
    EXPECT_TRUE(result.ok()) << result.status();
    return image::serialise_task_result(*std::move(result));
  }

  // A prepass-1 lease for `tile` of an 8x8 film (the job's is 16x16) with per-pixel tables over
  // One mass per bin (the job has 8), guides and early stop.
  v1::Lease make_prepass_lease(v1::TileRect tile) {
    v1::Lease lease = make_lease(tile, 0, 6, 8);
    v1::Task& task = *lease.mutable_task();
    task.set_pass(v1::PASS_PREPASS);
    task.set_pass_index(1);
    task.set_film_width(8);
    task.set_film_height(8);
    task.set_want_guides(true);
    task.set_early_stop_prepass(true);
    const int width = tile.x1() - tile.x0(), height = tile.y1() - tile.y0();
    task.mutable_pdf_table()->set_cells(8);
    task.mutable_pdf_table()->set_quantised_cdf(
        testing::skewed_table_bytes(width, height, 8, [](int x, int y) { return x == y; }));
    return lease;
  }

  // Waits for the worker's first heartbeat with samples done, drains it and waits for it to stop
  // cleanly: how long the drain took (a day, with the test failed, when it never rendered or did
  // not stop).
  Clock::duration drain_once_rendering() {
    if (!fake_.wait([&] {
          return !fake_.heartbeats.empty() && fake_.heartbeats.back().samples_done() > 0;
        })) {
      ADD_FAILURE() << "the worker reported no progress";
      return 24h;
    }
    const Clock::time_point drained = Clock::now();
    daemon_->drain();
    if (!join_worker(10s)) {
      ADD_FAILURE() << "the drained worker did not stop";
      return 24h;
    }
    EXPECT_TRUE(run_status_.ok()) << run_status_;
    return Clock::now() - drained;
  }

  // Runs the worker on fake_.lease, which must succeed; its one upload (nothing, with the test
  // failed, otherwise).
  std::optional<Upload> expect_upload() {
    start_worker();
    EXPECT_TRUE(fake_.wait([&] { return !fake_.uploads.empty() || !fake_.failures.empty(); }));
    EXPECT_TRUE(stop_worker());
    std::lock_guard<std::mutex> lock(fake_.mutex);
    EXPECT_TRUE(fake_.failures.empty()) << fake_.failures[0].message();
    EXPECT_EQ(fake_.uploads.size(), 1u);
    if (!fake_.failures.empty() || fake_.uploads.size() != 1) return std::nullopt;
    return fake_.uploads[0];
  }

  // Runs the worker on fake_.lease, which must fail; the failure.
  v1::FailTaskRequest expect_failure() {
    start_worker();
    EXPECT_TRUE(fake_.wait([&] { return !fake_.failures.empty() || !fake_.uploads.empty(); }));
    EXPECT_TRUE(stop_worker());
    std::lock_guard<std::mutex> lock(fake_.mutex);
    EXPECT_TRUE(fake_.uploads.empty());
    EXPECT_EQ(fake_.failures.size(), 1u);
    return fake_.failures.empty() ? v1::FailTaskRequest() : fake_.failures[0];
  }

  FakeCoordinator fake_;
  scene::Bundle bundle_;
  fs::path cache_dir_;
  EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  tbb::task_arena arena_{2};
  std::shared_ptr<spdlog::logger> logger_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<WorkerClient> client_;
  std::unique_ptr<WorkerDaemon> daemon_;
  std::thread worker_thread_;
  std::atomic<bool> run_returned_{false};
  absl::Status run_status_ = absl::UnknownError("run() has not returned");
};

TEST_F(WorkerDaemonTest, FetchesRendersAndUploadsTheSameBytesAsAnInProcessRender) {
  fake_.lease = make_lease(rect(4, 2, 12, 10), 3, 19, 5);
  fake_.reregister_once = true;
  start_worker();
  ASSERT_TRUE(fake_.wait([&] { return !fake_.uploads.empty() || !fake_.failures.empty(); }));
  // The REREGISTER directive of the first heartbeat has been acted on by now or soon.
  ASSERT_TRUE(fake_.wait([&] { return fake_.registrations.size() >= 2; }));
  ASSERT_TRUE(stop_worker());
  EXPECT_TRUE(run_status_.ok()) << run_status_;

  std::lock_guard<std::mutex> lock(fake_.mutex);
  ASSERT_TRUE(fake_.failures.empty()) << fake_.failures[0].message();
  ASSERT_EQ(fake_.uploads.size(), 1u);
  ASSERT_EQ(fake_.fetched, std::vector<std::string>{bundle_.content_hash});
  EXPECT_EQ(fake_.registrations[0].host(), "test-host");
  EXPECT_EQ(fake_.registrations[0].threads(), 2u);
  EXPECT_EQ(fake_.registrations[1].previous_worker_id(), "w-1");

  const Upload& upload = fake_.uploads[0];
  EXPECT_EQ(upload.worker_id, "w-1");
  EXPECT_EQ(upload.lease_id, "lease-1");
  EXPECT_EQ(upload.total_bytes, upload.bytes.size());
  EXPECT_EQ(upload.sha256, base::sha256_hex(upload.bytes));
  auto tile = image::parse_tile(upload.bytes);
  ASSERT_TRUE(tile.ok()) << tile.status();
  EXPECT_EQ(tile->rect().x0, 4);
  EXPECT_EQ(tile->rect().y0, 2);
  EXPECT_EQ(tile->rect().x1, 12);
  EXPECT_EQ(tile->rect().y1, 10);
  EXPECT_EQ(tile->samples(), (image::SampleRange{3, 19}));
  EXPECT_EQ(tile->bins(), 8);
  for (int y = 2; y < 10; ++y)
    for (int x = 4; x < 12; ++x) ASSERT_EQ(tile->count(x, y), 16u);

  // Determinism: byte for byte what TileRenderer gives in this process.
  EXPECT_TRUE(upload.bytes == render_in_process(fake_.lease));
  // The bundle stays cached under its hash.
  EXPECT_TRUE(fs::is_regular_file(cache_dir_ / bundle_.content_hash / "furnace.pbrt"));
}

// Issue 18: a worker renders task N+1 while task N uploads, with at most one result waiting
// (WorkerConfig::uploads_in_flight = 1), and keeps the uploading lease alive by heartbeat.
TEST_F(WorkerDaemonTest, RendersTheNextTaskWhileAResultUploadsWithABoundedQueue) {
  fake_.lease = make_lease(rect(0, 0, 16, 16), 0, 8, 5);
  for (const char* id : {"lease-2", "lease-3"}) {
    v1::Lease next = fake_.lease;
    next.set_lease_id(id);
    fake_.later_leases.push_back(next);
  }
  fake_.hold_uploads = true;
  start_worker();
  // lease-1's upload is held; lease-2 is handed out and rendered meanwhile, and its result
  // queued behind lease-1's, so the worker asks for nothing more.
  ASSERT_TRUE(
      fake_.wait([&] { return fake_.uploads_started.size() == 1 && fake_.later_handed >= 1; }));
  ASSERT_TRUE(fake_.wait([&] {
    for (const v1::HeartbeatRequest& beat : fake_.heartbeats) {
      for (const std::string& id : beat.lease_ids()) {
        if (id == "lease-1") return true;
      }
    }
    return false;
  })) << "the uploading lease is not kept alive";
  std::this_thread::sleep_for(500ms);
  {
    std::lock_guard<std::mutex> lock(fake_.mutex);
    EXPECT_EQ(fake_.later_handed, 1u) << "a third task was taken while two results were held";
    EXPECT_EQ(fake_.uploads_started, std::vector<std::string>{"lease-1"});
    fake_.hold_uploads = false;
  }
  fake_.changed.notify_all();
  ASSERT_TRUE(fake_.wait([&] { return fake_.uploads.size() == 3; }));
  ASSERT_TRUE(stop_worker());
  EXPECT_TRUE(run_status_.ok()) << run_status_;
  std::lock_guard<std::mutex> lock(fake_.mutex);
  EXPECT_TRUE(fake_.failures.empty());
  ASSERT_EQ(fake_.uploads.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(fake_.uploads[i].lease_id, absl::StrCat("lease-", i + 1));
    EXPECT_TRUE(fake_.uploads[i].bytes == fake_.uploads[0].bytes);
  }
}

// Tasks of other jobs on the same scene (another seed, another integrator, the first job's
// options with gathering on) rebuild the render scene around the geometry the first one built;
// each result is still byte for byte the in-process render of its own task. (The scene's key
// once missed gathering, splatting and light-traced caustics: the gathering job reused the first
// job's scene and returned a result without the offsets its job needs.)
TEST_F(WorkerDaemonTest, TasksOfOtherJobsOnTheSameSceneRenderTheirOwnBytes) {
  fake_.lease = make_lease(rect(0, 0, 8, 8), 0, 8, 5);
  v1::Lease other_seed = fake_.lease;
  other_seed.set_lease_id("lease-2");
  other_seed.mutable_task()->set_job_id("job-2");
  other_seed.mutable_task()->mutable_spec()->set_seed(8);
  v1::Lease other_integrator = other_seed;
  other_integrator.set_lease_id("lease-3");
  other_integrator.mutable_task()->set_job_id("job-3");
  other_integrator.mutable_task()->mutable_spec()->set_integrator(v1::INTEGRATOR_UNIFORM);
  v1::Lease gathering = fake_.lease;
  gathering.set_lease_id("lease-4");
  gathering.mutable_task()->set_job_id("job-4");
  gathering.mutable_task()->mutable_spec()->set_gather_width(100);
  fake_.later_leases = {other_seed, other_integrator, gathering};
  start_worker();
  ASSERT_TRUE(fake_.wait([&] { return fake_.uploads.size() == 4 || !fake_.failures.empty(); }));
  ASSERT_TRUE(stop_worker());
  EXPECT_TRUE(run_status_.ok()) << run_status_;
  std::lock_guard<std::mutex> lock(fake_.mutex);
  ASSERT_TRUE(fake_.failures.empty()) << fake_.failures[0].message();
  ASSERT_EQ(fake_.uploads.size(), 4u);
  const v1::Lease* leases[] = {&fake_.lease, &other_seed, &other_integrator, &gathering};
  EXPECT_FALSE(render_in_process(gathering) == render_in_process(fake_.lease));
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(fake_.uploads[i].lease_id, leases[i]->lease_id());
    EXPECT_TRUE(fake_.uploads[i].bytes == render_in_process(*leases[i])) << i;
  }
  EXPECT_FALSE(fake_.uploads[0].bytes == fake_.uploads[1].bytes);  // the seed reached the tracer
}

TEST_F(WorkerDaemonTest, ACancelDirectiveStopsALongTaskWithinOneHeartbeat) {
  // Full 16x16 tile, paths up to depth 100 in a lossless furnace, 32768 samples per pixel:
  // seconds of work (each pixel ~15 ms), so the directive arrives mid-task.
  constexpr std::uint32_t kSpp = 1 << 15;
  fake_.lease = make_lease(rect(0, 0, 16, 16), 0, kSpp, 100);
  fake_.heartbeat_interval_ms = 200;
  fake_.cancel_when_rendering = true;
  start_worker();
  ASSERT_TRUE(fake_.wait([&] { return fake_.cancel_sent.has_value(); }));
  // Dropping the task sends the worker back to AcquireTask.
  ASSERT_TRUE(fake_.wait([&] { return !fake_.acquires_after_lease.empty(); }, 10s));
  Clock::time_point cancelled, back;
  {
    std::lock_guard<std::mutex> lock(fake_.mutex);
    cancelled = *fake_.cancel_sent;
    back = fake_.acquires_after_lease.front();
  }
  const auto stop_ms = std::chrono::duration_cast<std::chrono::milliseconds>(back - cancelled);
  EXPECT_LT(stop_ms.count(), fake_.heartbeat_interval_ms)
      << "the task stopped after " << stop_ms.count() << " ms";
  // The next heartbeat no longer carries the lease.
  ASSERT_TRUE(fake_.wait(
      [&] {
        return Clock::now() > cancelled && !fake_.heartbeats.empty() &&
               fake_.heartbeats.back().lease_ids_size() == 0;
      },
      5s));
  ASSERT_TRUE(stop_worker());
  EXPECT_TRUE(run_status_.ok()) << run_status_;

  std::lock_guard<std::mutex> lock(fake_.mutex);
  EXPECT_TRUE(fake_.uploads.empty());
  EXPECT_TRUE(fake_.failures.empty());
  std::cout << "samples done before the cancel directive: " << fake_.samples_at_cancel << "\n";
  EXPECT_LT(fake_.samples_at_cancel, std::uint64_t{256} * kSpp);
}

TEST_F(WorkerDaemonTest, RefusesABundleWhoseHashDoesNotMatchAndCachesNothing) {
  fake_.lease = make_lease(rect(0, 0, 8, 8), 0, 4, 5);
  // The coordinator sends another bundle's bytes (a valid bundle, another hash).
  auto other =
      scene::make_bundle(fs::path(PRISM_SOURCE_DIR) / "worker/testdata", "unbiased.pbrt", {});
  ASSERT_TRUE(other.ok()) << other.status();
  ASSERT_NE(other->content_hash, bundle_.content_hash);
  fake_.blob = scene::pack(*other);
  const v1::FailTaskRequest failure = expect_failure();
  EXPECT_EQ(failure.lease_id(), "lease-1");
  EXPECT_EQ(failure.failure_class(), v1::FAILURE_CLASS_WORKER);
  EXPECT_NE(failure.message().find(other->content_hash), std::string::npos) << failure.message();
  EXPECT_FALSE(fs::exists(cache_dir_ / bundle_.content_hash));
  EXPECT_FALSE(fs::exists(cache_dir_ / other->content_hash));
  const int left = fs::exists(cache_dir_)
                       ? static_cast<int>(std::distance(fs::directory_iterator(cache_dir_),
                                                        fs::directory_iterator()))
                       : 0;
  EXPECT_EQ(left, 0);
}

TEST_F(WorkerDaemonTest, DrainReturnsALeaseThatWouldNotFinishInTime) {
  // Minutes of work and a lease that ends in 1.5 s (heartbeats do not extend it here).
  fake_.lease = make_lease(rect(0, 0, 16, 16), 0, 1 << 16, 100, 1500ms);
  fake_.heartbeat_interval_ms = 100;
  start_worker(/*return_margin=*/300ms);
  const Clock::duration took = drain_once_rendering();
  EXPECT_LT(took, 3s);

  std::lock_guard<std::mutex> lock(fake_.mutex);
  EXPECT_TRUE(fake_.uploads.empty());
  ASSERT_EQ(fake_.failures.size(), 1u);
  EXPECT_EQ(fake_.failures[0].lease_id(), "lease-1");
  EXPECT_EQ(fake_.failures[0].failure_class(), v1::FAILURE_CLASS_RETURNED);
  // It stopped acquiring: no AcquireTask after the lease.
  EXPECT_TRUE(fake_.acquires_after_lease.empty());
  // And said it left, so it is listed as left, not lost.
  EXPECT_EQ(fake_.left.size(), 1u);
}

TEST_F(WorkerDaemonTest, ADrainTimeoutReturnsALongTaskLongBeforeItsLeaseEnds) {
  // Minutes of work on a one-minute lease; the drain may wait 800 ms (less the 300 ms margin).
  fake_.lease = make_lease(rect(0, 0, 16, 16), 0, 1 << 16, 100, 60s);
  fake_.heartbeat_interval_ms = 100;
  start_worker(/*return_margin=*/300ms, "", /*drain_timeout=*/800ms);
  const Clock::duration took = drain_once_rendering();
  EXPECT_GE(took, 400ms) << "it gave the task its time first";
  EXPECT_LT(took, 3s) << "the drain timeout, not the one-minute lease, bounds the drain";
  std::lock_guard<std::mutex> lock(fake_.mutex);
  EXPECT_TRUE(fake_.uploads.empty());
  ASSERT_EQ(fake_.failures.size(), 1u);
  EXPECT_EQ(fake_.failures[0].failure_class(), v1::FAILURE_CLASS_RETURNED);
  ASSERT_EQ(fake_.left.size(), 1u);
  EXPECT_FALSE(fake_.left[0].empty());
}

// A drain timeout longer than the lease, with heartbeats renewing the lease: the task gets the
// drain timeout (it was cut to the lease's deadline at the drain, 30 s by default, whatever
// --drain-timeout said, and its work thrown away).
TEST_F(WorkerDaemonTest, ADrainTimeoutOutlastsARenewedLease) {
  // Minutes of work on a one-second lease that every heartbeat renews for another second.
  fake_.lease = make_lease(rect(0, 0, 16, 16), 0, 1 << 16, 100, 1s);
  fake_.heartbeat_interval_ms = 100;
  fake_.extend_leases = 1s;
  start_worker(/*return_margin=*/300ms, "", /*drain_timeout=*/2500ms);
  const Clock::duration took = drain_once_rendering();
  EXPECT_GE(took, 1800ms) << "the drain timeout, not the lease at the drain, bounds the wait";
  EXPECT_LT(took, 5s);
  std::lock_guard<std::mutex> lock(fake_.mutex);
  ASSERT_EQ(fake_.failures.size(), 1u);
  EXPECT_EQ(fake_.failures[0].failure_class(), v1::FAILURE_CLASS_RETURNED);
}

TEST_F(WorkerDaemonTest, ADrainDirectiveLetsATaskThatFitsItsLeaseComplete) {
  // A few hundred milliseconds of work, heartbeats every 20 ms: the directive comes mid-task.
  fake_.lease = make_lease(rect(0, 0, 16, 16), 0, 4096, 100);
  fake_.heartbeat_interval_ms = 20;
  fake_.drain_when_holding = true;
  start_worker();
  // The worker drains by itself after the DRAIN directive: run() returns without drain().
  ASSERT_TRUE(join_worker(20s));
  EXPECT_TRUE(run_status_.ok()) << run_status_;

  std::lock_guard<std::mutex> lock(fake_.mutex);
  EXPECT_TRUE(fake_.drain_sent);
  EXPECT_TRUE(fake_.failures.empty());
  ASSERT_EQ(fake_.uploads.size(), 1u);
  EXPECT_TRUE(image::parse_tile(fake_.uploads[0].bytes).ok());
  EXPECT_TRUE(fake_.acquires_after_lease.empty());
}

TEST_F(WorkerDaemonTest, RetriesRegisterWhileTheCoordinatorIsUnavailableAndSendsItsSecret) {
  fake_.lease = make_lease(rect(0, 0, 4, 4), 0, 2, 5);
  // More refusals than the client's 5 attempts: the daemon keeps trying; and through a
  // coordinator whose disk is full (it exited then, and the farm lost it for good).
  fake_.unavailable_registers = 7;
  fake_.full_disk_registers = 2;
  fake_.secret = "worker-secret";
  start_worker(100ms, "worker-secret");
  ASSERT_TRUE(fake_.wait([&] { return !fake_.uploads.empty(); }));
  ASSERT_TRUE(stop_worker());
  EXPECT_TRUE(run_status_.ok()) << run_status_;
  std::lock_guard<std::mutex> lock(fake_.mutex);
  EXPECT_EQ(fake_.unavailable_registers, 0);
  EXPECT_EQ(fake_.full_disk_registers, 0);
  EXPECT_TRUE(fake_.failures.empty());
  EXPECT_EQ(fake_.refused_secrets, 0);
  EXPECT_EQ(fake_.registrations.size(), 1u);
}

TEST_F(WorkerDaemonTest, AWrongSecretEndsRunWithUnauthenticated) {
  fake_.secret = "worker-secret";
  start_worker(100ms, "not-the-secret");
  ASSERT_TRUE(join_worker(10s));
  EXPECT_EQ(run_status_.code(), absl::StatusCode::kUnauthenticated) << run_status_;
  std::lock_guard<std::mutex> lock(fake_.mutex);
  // Not retried: UNAUTHENTICATED is not transient.
  EXPECT_EQ(fake_.refused_secrets, 1);
}

TEST_F(WorkerDaemonTest, ASceneThatDoesNotLoadFailsTheTaskAsASceneFault) {
  auto bad = scene::make_bundle(fs::path(PRISM_SOURCE_DIR) / "services/scene/testdata/parser/bad",
                                "unknown_shape.pbrt", {});
  ASSERT_TRUE(bad.ok()) << bad.status();
  bundle_ = *bad;
  fake_.blob = scene::pack(bundle_);
  fake_.lease = make_lease(rect(0, 0, 4, 4), 0, 2, 5);
  fake_.lease.mutable_task()->mutable_spec()->set_scene_path("unknown_shape.pbrt");
  const v1::FailTaskRequest failure = expect_failure();
  EXPECT_EQ(failure.failure_class(), v1::FAILURE_CLASS_SCENE);
  // The loader's message, with the position in the scene file.
  EXPECT_NE(failure.message().find("unknown_shape.pbrt:2:"), std::string::npos)
      << failure.message();
}

TEST_F(WorkerDaemonTest, AResultLargerThanAChunkIsStreamedInMebibyteChunks) {
  // 64x64 pixels x 128 bins: float32 sums and squared sums alone are 4 MiB.
  fake_.lease = make_lease(rect(0, 0, 64, 64), 0, 1, 1);
  v1::JobSpec& spec = *fake_.lease.mutable_task()->mutable_spec();
  spec.set_width(64);
  spec.set_height(64);
  spec.set_bins(128);
  const std::optional<Upload> uploaded = expect_upload();
  ASSERT_TRUE(uploaded.has_value());
  const Upload& upload = *uploaded;
  EXPECT_GT(upload.bytes.size(), std::size_t{4} << 20);
  EXPECT_EQ(upload.chunk_sizes.size(), (upload.bytes.size() + (1u << 20) - 1) >> 20);
  for (std::size_t size : upload.chunk_sizes) EXPECT_LE(size, std::size_t{1} << 20);
  EXPECT_EQ(upload.total_bytes, upload.bytes.size());
  EXPECT_EQ(upload.sha256, base::sha256_hex(upload.bytes));
  EXPECT_TRUE(image::parse_tile(upload.bytes).ok());
  EXPECT_TRUE(upload.bytes == render_in_process(fake_.lease));
}

// A prepass task: pass 1 on its own 8x8 film (not the job's 16x16), sampled from the tile's
// pdf tables (8 bins), with guides and early stop; the upload is byte for byte the
// in-process render of the same task, and carries the task's counters.
TEST_F(WorkerDaemonTest, RendersAPrepassTaskWithPdfTablesOnItsFilm) {
  fake_.lease = make_prepass_lease(rect(2, 1, 8, 8));
  const std::optional<Upload> uploaded = expect_upload();
  ASSERT_TRUE(uploaded.has_value());
  const Upload& upload = *uploaded;
  auto tile = image::parse_tile(upload.bytes);
  ASSERT_TRUE(tile.ok()) << tile.status();
  EXPECT_EQ(tile->rect(), (image::TileRect{2, 1, 8, 8}));
  EXPECT_TRUE(tile->has_guides());
  EXPECT_FALSE(tile->has_gradients());
  EXPECT_TRUE(upload.bytes == render_in_process(fake_.lease));

  // The pixels whose rows are all zero fell back earlier: the prepass skips them.
  std::uint64_t samples = 0;
  int skipped = 0;
  for (std::uint64_t n : tile->counts()) {
    samples += n;
    if (n == 0) ++skipped;
  }
  EXPECT_GT(skipped, 0);
  EXPECT_EQ(samples, (6u * 7u - skipped) * 6u);
  EXPECT_EQ(upload.counters.at("camera_rays"), samples);
  EXPECT_EQ(upload.counters.at("rays"), upload.rays);
  EXPECT_GT(upload.rays, samples);
  for (const auto& [name, value] : upload.counters) EXPECT_GT(value, 0u) << name;
  EXPECT_EQ(upload.counters.count("gradient_events"), 0u);  // zero counters are left out
  // The worker says it takes prepass tasks.
  const auto& capabilities = fake_.registrations.at(0).capabilities();
  EXPECT_NE(std::find(capabilities.begin(), capabilities.end(), "prepass"), capabilities.end());
}

TEST_F(WorkerDaemonTest, AMalformedPdfTableFailsTheTaskAsAWorkerFault) {
  fake_.lease = make_prepass_lease(rect(0, 0, 4, 4));
  v1::PdfTable& table = *fake_.lease.mutable_task()->mutable_pdf_table();
  // Pixel (2, 1)'s CDF jumps to 65535 at its 4th value and falls back: not a valid table.
  std::string bytes = table.quantised_cdf();
  bytes[2 * 8 * 6 + 6] = char(0xff);
  bytes[2 * 8 * 6 + 7] = char(0xff);
  table.set_quantised_cdf(bytes);
  const v1::FailTaskRequest failure = expect_failure();
  EXPECT_EQ(failure.failure_class(), v1::FAILURE_CLASS_WORKER);
  EXPECT_NE(failure.message().find("pdf table"), std::string::npos) << failure.message();
}

TEST_F(WorkerDaemonTest, APdfTableOfAnotherSizeFailsTheTaskAsAWorkerFault) {
  fake_.lease = make_prepass_lease(rect(0, 0, 4, 4));
  fake_.lease.mutable_task()->mutable_pdf_table()->set_cells(12);
  const v1::FailTaskRequest failure = expect_failure();
  EXPECT_EQ(failure.failure_class(), v1::FAILURE_CLASS_WORKER);
  EXPECT_NE(failure.message().find("pdf table"), std::string::npos) << failure.message();
}

// The tile must lie in the film of its pass: 8x8 for this prepass, although the job's is 16x16.
TEST_F(WorkerDaemonTest, ATileOutsideItsPassFilmFailsTheTaskAsAWorkerFault) {
  fake_.lease = make_prepass_lease(rect(4, 4, 12, 8));
  const v1::FailTaskRequest failure = expect_failure();
  EXPECT_EQ(failure.failure_class(), v1::FAILURE_CLASS_WORKER);
  EXPECT_NE(failure.message().find("outside the 8x8 film"), std::string::npos) << failure.message();
}

TEST_F(WorkerDaemonTest, APrepassTaskWithIndexZeroFailsTheTaskAsAWorkerFault) {
  fake_.lease = make_prepass_lease(rect(0, 0, 4, 4));
  fake_.lease.mutable_task()->set_pass_index(0);
  const v1::FailTaskRequest failure = expect_failure();
  EXPECT_EQ(failure.failure_class(), v1::FAILURE_CLASS_WORKER);
  EXPECT_NE(failure.message().find("PASS_PREPASS"), std::string::npos) << failure.message();
}

#ifdef PRISM_WORKER_BINARY
// The prism-worker process itself: flags, the secret from the environment, SIGTERM.
class WorkerProcessTest : public WorkerDaemonTest {
 protected:
  // prism-worker against the fake coordinator, its secret from the environment only.
  std::unique_ptr<prism::testing::ChildProcess> spawn(const std::string& address,
                                                      const std::string& secret) {
    prism::testing::ChildOptions options;
    options.clear_environment = true;
    options.env = {"PRISM_WORKER_SECRET=" + secret};
    return prism::testing::ChildProcess::start(
        {PRISM_WORKER_BINARY, "--coordinator", address, "--threads", "1", "--cache-dir",
         cache_dir_.string(), "--host", "proc-host"},
        options);
  }

  // The exit status, or -1 if the process did not end within the timeout (it is killed then).
  static int wait_exit(prism::testing::ChildProcess& child, std::chrono::milliseconds timeout) {
    if (std::optional<int> code = child.wait(timeout)) return *code;
    child.kill();
    return -1;
  }
};

TEST_F(WorkerProcessTest, RendersTheLeaseAndExitsZeroOnSigterm) {
  fake_.lease = make_lease(rect(8, 8, 16, 16), 0, 8, 5);
  fake_.secret = "from-the-environment";
  const std::unique_ptr<prism::testing::ChildProcess> worker =
      spawn(start_server(), "from-the-environment");
  ASSERT_NE(worker, nullptr);
  const bool uploaded = fake_.wait([&] { return !fake_.uploads.empty(); }, 30s);
  worker->signal(SIGTERM);
  EXPECT_EQ(wait_exit(*worker, 10s), 0);
  ASSERT_TRUE(uploaded);
  std::lock_guard<std::mutex> lock(fake_.mutex);
  EXPECT_EQ(fake_.registrations.at(0).host(), "proc-host");
  EXPECT_EQ(fake_.registrations.at(0).threads(), 1u);
  EXPECT_TRUE(fake_.failures.empty());
  EXPECT_TRUE(fake_.uploads[0].bytes == render_in_process(fake_.lease));
}

TEST_F(WorkerProcessTest, ExitsNonZeroWhenTheCoordinatorRefusesItsSecret) {
  fake_.secret = "from-the-environment";
  const std::unique_ptr<prism::testing::ChildProcess> worker = spawn(start_server(), "wrong");
  ASSERT_NE(worker, nullptr);
  EXPECT_EQ(wait_exit(*worker, 20s), 1);
}

// A cache directory that cannot hold a bundle (a file, or under /proc) is refused at start: the
// worker registered and then failed every task it leased, while the farm listed it as idle and
// the job waited for ever.
TEST_F(WorkerProcessTest, AnUnusableCacheDirectoryIsRefusedAtStart) {
  const std::filesystem::path file = cache_dir_ / "a-file";  // removed with the test's directory
  std::ofstream(file) << "x";
  for (const std::string& dir : {file.string(), std::string("/proc/no-such-dir")}) {
    const prism::testing::RunResult run = prism::testing::run(
        {PRISM_WORKER_BINARY, "--coordinator", "127.0.0.1:1", "--cache-dir", dir});
    EXPECT_EQ(run.exit_code, 1) << dir;
    EXPECT_NE(run.err.find("--cache-dir " + dir + " is not a directory"), std::string::npos)
        << run.err;
  }
}
#endif

}  // namespace
}  // namespace prism::worker
