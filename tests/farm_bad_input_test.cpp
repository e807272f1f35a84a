// The farm's bad-input guarantee with real processes on loopback: one `prism-coordinator` (a
// small --max-bundle-bytes, a worker secret and an API token) and one `prism-worker`, started
// once for the whole sequence. A good job runs on the worker while this test sends every kind of
// bad input over gRPC and checks the exact status code and that the message says what is wrong:
// wrong or missing tokens (UNAUTHENTICATED), bytes that are not a bundle, a tampered bundle and
// a wrong claimed hash (INVALID_ARGUMENT), scenes that escape their directory (INVALID_ARGUMENT
// naming the path; a job for such a bundle is FAILED_PRECONDITION), oversized uploads
// (RESOURCE_EXHAUSTED), unknown job ids (NOT_FOUND) and results for stale, foreign or unknown
// leases (FAILED_PRECONDITION). The last step checks that the coordinator kept serving: the
// good job's pixels are byte-identical to `prism render`, and a job submitted after all the
// bad input completes too.
//
// The stale lease is made deterministic: a fake worker takes the only task of a very long job
// before the real worker starts, and never heartbeats. Once its lease has expired the task is
// requeued and the real worker spends (far) longer than the test on it, so the task cannot be
// done when the stale result arrives; the long job is cancelled afterwards.
#include <fcntl.h>
#include <grpcpp/create_channel.h>
#include <grpcpp/security/credentials.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <thread>

#include "prism/v1/farm.grpc.pb.h"
#include "prism/v1/worker.grpc.pb.h"
#include "services/base/sha256.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile.h"
#include "services/image/tile_codec.h"
#include "services/rpc/auth.h"
#include "services/rpc/chunks.h"
#include "services/rpc/result_upload.h"
#include "services/scene/bundle.h"
#include "tests/testing/child_process.h"

namespace prism {
namespace {

namespace fs = std::filesystem;
namespace v1 = prism::v1;
using Clock = std::chrono::steady_clock;

constexpr int kLeaseMs = 1000;
constexpr std::uint64_t kMaxBundleBytes = 64 << 10;
// The good job: 24x24 in 8-pixel tiles, 9 tasks of about 0.3 s each on one thread, so that it
// is still running while the bad input arrives.
constexpr int kGoodSpp = 4096;
constexpr std::uint64_t kGoodSeed = 11;

// `needle` occurs in the status message (for readable failures).
::testing::AssertionResult says(const grpc::Status& status, const std::string& needle) {
  if (status.error_message().find(needle) != std::string::npos) {
    return ::testing::AssertionSuccess();
  }
  return ::testing::AssertionFailure()
         << "message \"" << status.error_message() << "\" does not contain \"" << needle << "\"";
}

// The processes and ids the tests share: started by SetUpTestSuite, killed by TearDownTestSuite.
struct Farm {
  fs::path root;
  std::vector<std::unique_ptr<testing::ChildProcess>> children;
  int port = 0;
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::FarmService::Stub> farm;
  std::unique_ptr<v1::WorkerService::Stub> worker;
  std::string good_hash;
  std::string good_job;
  std::string long_job;
  std::string fake_worker;  // registered by the test, never heartbeats
  std::optional<v1::Lease> fake_lease;
};
Farm* farm_ = nullptr;

// Starts `argv`; the suite owns it until TearDownTestSuite.
testing::ChildProcess* spawn(std::vector<std::string> argv) {
  farm_->children.push_back(testing::ChildProcess::start(std::move(argv)));
  return farm_->children.back().get();
}

std::unique_ptr<grpc::ClientContext> call(const std::string& token) {
  auto context = std::make_unique<grpc::ClientContext>();
  prism::rpc::add_bearer(*context, token);
  context->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
  return context;
}
std::unique_ptr<grpc::ClientContext> client() {
  return call(testing::kApiToken);
}
std::unique_ptr<grpc::ClientContext> worker_call() {
  return call(testing::kWorkerSecret);
}

void write(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

// A scene directory holding scene.pbrt = the unbiased test scene plus `extra` lines.
fs::path make_scene_dir(const std::string& name, const std::string& extra) {
  const fs::path dir = farm_->root / name;
  std::ifstream in(fs::path(PRISM_SOURCE_DIR) / "worker/testdata/unbiased.pbrt", std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  write(dir / "scene.pbrt", text + extra);
  return dir;
}

std::string packed_bundle(const fs::path& dir) {
  auto bundle = scene::make_bundle(dir, "scene.pbrt", {});
  EXPECT_TRUE(bundle.ok()) << bundle.status();
  return bundle.ok() ? scene::pack(*bundle) : std::string();
}

// Streams `bytes` as an upload in 16 KiB chunks, each declaring `declared` total bytes.
grpc::Status upload(const std::string& bytes, std::string* hash = nullptr,
                    std::uint64_t declared = 0, const std::string& claimed_hash = "",
                    const std::string& token = testing::kApiToken) {
  auto context = call(token);
  v1::UploadBundleResponse response;
  auto writer = farm_->farm->UploadBundle(context.get(), &response);
  bool first = true;
  for (std::string_view piece : prism::rpc::split_chunks(bytes, 16 << 10)) {
    v1::BundleChunk chunk;
    if (first) chunk.set_bundle_hash(claimed_hash);
    first = false;
    chunk.set_total_bytes(declared);
    chunk.set_data(std::string(piece));
    if (!writer->Write(chunk)) break;  // the server has already answered
  }
  writer->WritesDone();
  grpc::Status status = writer->Finish();
  if (hash != nullptr) *hash = response.bundle_hash();
  return status;
}

// No prepass (the scene would have one by default): the tests count the 9 tile tasks.
v1::JobSpec good_spec(const std::string& hash, int spp) {
  v1::JobSpec s;
  s.mutable_prepass()->set_enabled(false);
  s.set_bundle_hash(hash);
  s.set_scene_path("scene.pbrt");
  s.set_spp(spp);
  s.set_tile_size(8);
  s.set_seed(kGoodSeed);
  return s;
}

grpc::Status submit(const v1::JobSpec& spec, std::string* job_id) {
  v1::SubmitJobRequest request;
  *request.mutable_spec() = spec;
  v1::SubmitJobResponse response;
  auto context = client();
  grpc::Status status = farm_->farm->SubmitJob(context.get(), request, &response);
  if (job_id != nullptr) *job_id = response.job().job_id();
  return status;
}

v1::JobInfo get_job(const std::string& job_id) {
  v1::GetJobRequest request;
  request.set_job_id(job_id);
  v1::JobInfo info;
  auto context = client();
  const grpc::Status status = farm_->farm->GetJob(context.get(), request, &info);
  EXPECT_TRUE(status.ok()) << status.error_message();
  return info;
}

bool terminal(const v1::JobInfo& info) {
  return info.state() == v1::JOB_STATE_DONE || info.state() == v1::JOB_STATE_FAILED ||
         info.state() == v1::JOB_STATE_CANCELLED;
}

v1::JobInfo wait_terminal(const std::string& job_id, double seconds) {
  const auto end = Clock::now() + std::chrono::duration<double>(seconds);
  v1::JobInfo info;
  while (Clock::now() < end) {
    info = get_job(job_id);
    if (terminal(info)) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return info;
}

std::string register_fake_worker(const std::string& host) {
  v1::RegisterRequest request;
  request.set_host(host);
  request.set_threads(1);
  v1::RegisterResponse response;
  auto context = worker_call();
  const grpc::Status status = farm_->worker->Register(context.get(), request, &response);
  EXPECT_TRUE(status.ok()) << status.error_message();
  return response.worker_id();
}

// The result a worker would send for `lease`: the tile codec's bytes of an all-zero TileResult
// of exactly the task's tile, sample range and bins (well-formed, so only fencing refuses it).
std::string zero_result(const v1::Lease& lease) {
  const v1::Task& task = lease.task();
  auto result = image::TileResult::create(
      {task.tile().x0(), task.tile().y0(), task.tile().x1(), task.tile().y1()},
      {task.samples().begin(), task.samples().end()}, static_cast<int>(task.spec().bins()));
  EXPECT_TRUE(result.ok()) << result.status();
  return result.ok() ? image::serialise_tile(*result) : std::string();
}

grpc::Status complete(const std::string& token, const std::string& worker_id,
                      const std::string& lease_id, const std::string& bytes,
                      bool* accepted = nullptr) {
  auto context = call(token);
  v1::CompleteTaskResponse response;
  auto writer = farm_->worker->CompleteTask(context.get(), &response);
  prism::rpc::ResultUploadHeader header;
  header.worker_id = worker_id;
  header.lease_id = lease_id;
  grpc::Status status = prism::rpc::upload_result(*writer, header, bytes, 64 << 10);
  if (accepted != nullptr) *accepted = response.accepted();
  return status;
}

std::vector<float> read_pixels(const fs::path& file) {
  auto exr = image::read_spectral_exr(file);
  EXPECT_TRUE(exr.ok()) << exr.status();
  if (!exr.ok()) return {};
  const auto data = exr->spectral.data();
  return {data.begin(), data.end()};
}

class FarmBadInputTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    farm_ = new Farm;
    farm_->root = testing::fresh_dir("farm_bad_input");

    testing::ChildProcess* coordinator = spawn(testing::coordinator_command(
        PRISM_COORDINATOR_BINARY, "127.0.0.1:0", farm_->root / "data", testing::kWorkerSecret,
        testing::kApiToken,
        {"--max-bundle-bytes", std::to_string(kMaxBundleBytes), "--heartbeat-ms",
         std::to_string(testing::kHeartbeatMs), "--lease-ms", std::to_string(kLeaseMs)},
        "error"));
    ASSERT_NE(coordinator, nullptr);
    const std::optional<std::string> line =
        coordinator->wait_for_line("listening on port", std::chrono::seconds(20));
    if (line.has_value()) std::sscanf(line->c_str(), "listening on port %d", &farm_->port);
    ASSERT_GT(farm_->port, 0) << "the coordinator did not print its port";
    farm_->channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(farm_->port),
                                         grpc::InsecureChannelCredentials());
    farm_->farm = v1::FarmService::NewStub(farm_->channel);
    farm_->worker = v1::WorkerService::NewStub(farm_->channel);

    ASSERT_TRUE(upload(packed_bundle(make_scene_dir("good", "")), &farm_->good_hash).ok());
    // The long job first, so that the fake worker's lease is its only task (jobs are served in
    // submission order): one 24x24 tile at a sample count far beyond the test's length.
    v1::JobSpec long_spec = good_spec(farm_->good_hash, 1 << 16);
    long_spec.set_tile_size(32);
    ASSERT_TRUE(submit(long_spec, &farm_->long_job).ok());
    farm_->fake_worker = register_fake_worker("fake");
    {
      v1::AcquireTaskRequest request;
      request.set_worker_id(farm_->fake_worker);
      request.set_wait_ms(1000);
      v1::AcquireTaskResponse response;
      auto context = worker_call();
      ASSERT_TRUE(farm_->worker->AcquireTask(context.get(), request, &response).ok());
      ASSERT_TRUE(response.has_lease());
      ASSERT_EQ(response.lease().task().job_id(), farm_->long_job);
      farm_->fake_lease = response.lease();
    }
    ASSERT_TRUE(submit(good_spec(farm_->good_hash, kGoodSpp), &farm_->good_job).ok());
    spawn({PRISM_WORKER_BINARY, "--coordinator", "127.0.0.1:" + std::to_string(farm_->port),
           "--threads", "1", "--secret", testing::kWorkerSecret, "--host", "real", "--cache-dir",
           (farm_->root / "cache").string(), "--log-level", "error"});
  }

  static void TearDownTestSuite() {
    farm_->children.clear();  // killed and reaped
    std::error_code ec;
    fs::remove_all(farm_->root, ec);
    delete farm_;
    farm_ = nullptr;
  }

  void SetUp() override {
    ASSERT_NE(farm_, nullptr);
    ASSERT_GT(farm_->port, 0) << "the suite's farm did not start";
  }
};

void wrong_or_missing_client_tokens_are_unauthenticated() {
  SCOPED_TRACE("wrong_or_missing_client_tokens_are_unauthenticated");
  v1::GetJobRequest request;
  request.set_job_id(farm_->good_job);
  v1::JobInfo info;
  auto wrong = call("not-the-token");
  grpc::Status status = farm_->farm->GetJob(wrong.get(), request, &info);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(says(status, "invalid token"));
  EXPECT_TRUE(info.job_id().empty()) << "a refused call leaked the job";

  auto missing = call("");
  status = farm_->farm->GetJob(missing.get(), request, &info);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(says(status, "missing authorization"));

  // The worker secret is not a client token.
  auto secret = call(testing::kWorkerSecret);
  v1::SubmitJobRequest submit_request;
  *submit_request.mutable_spec() = good_spec(farm_->good_hash, 1);
  v1::SubmitJobResponse submit_response;
  status = farm_->farm->SubmitJob(secret.get(), submit_request, &submit_response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(says(status, "invalid token"));

  // Uploads are refused before any byte is looked at.
  status = upload("whatever", nullptr, 0, "", "not-the-token");
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(says(status, "invalid token"));
}

void wrong_worker_secrets_are_unauthenticated() {
  SCOPED_TRACE("wrong_worker_secrets_are_unauthenticated");
  v1::RegisterRequest request;
  request.set_host("intruder");
  v1::RegisterResponse response;
  auto wrong = call("not-the-secret");
  grpc::Status status = farm_->worker->Register(wrong.get(), request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(says(status, "invalid token"));
  EXPECT_TRUE(response.worker_id().empty());

  // The client token is not the worker secret, for any worker call.
  v1::AcquireTaskRequest acquire;
  acquire.set_worker_id(farm_->fake_worker);
  v1::AcquireTaskResponse lease;
  auto token = call(testing::kApiToken);
  status = farm_->worker->AcquireTask(token.get(), acquire, &lease);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_FALSE(lease.has_lease());
  status = complete(testing::kApiToken, farm_->fake_worker, farm_->fake_lease->lease_id(),
                    zero_result(*farm_->fake_lease));
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(says(status, "invalid token"));

  // A real prism-worker with the wrong secret gives up with the server's message, exit 1.
  const testing::RunResult intruder = testing::run(
      {PRISM_WORKER_BINARY, "--coordinator", "127.0.0.1:" + std::to_string(farm_->port),
       "--threads", "1", "--secret", "not-the-secret", "--host", "intruder", "--cache-dir",
       (farm_->root / "intruder-cache").string(), "--log-level", "error"});
  const std::string& messages = intruder.err;
  EXPECT_EQ(intruder.exit_code, 1);
  EXPECT_NE(messages.find("invalid token"), std::string::npos) << messages;
}

void malformed_bundles_are_invalid_argument() {
  SCOPED_TRACE("malformed_bundles_are_invalid_argument");
  // Bytes that are not a bundle at all (long enough to have a header).
  grpc::Status status = upload(std::string(200, 'x'));
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_TRUE(says(status, "not a Prism scene bundle (bad magic)"));

  // Too short for the header.
  status = upload("PRISMBDL");
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_TRUE(says(status, "truncated"));

  // A real bundle with one byte of the scene file changed: the file no longer matches the
  // SHA-256 its manifest lists (the scene file is the last bytes of the packed form).
  std::string tampered = packed_bundle(make_scene_dir("tampered", "# one more line\n"));
  ASSERT_FALSE(tampered.empty());
  tampered.back() ^= 0x01;
  status = upload(tampered);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_TRUE(says(status, "file 'scene.pbrt' does not match its SHA-256"));

  // A genuine bundle uploaded under another bundle's hash.
  const std::string genuine = packed_bundle(make_scene_dir("mislabelled", "# mislabelled\n"));
  const std::string wrong_hash(64, 'a');
  status = upload(genuine, nullptr, 0, wrong_hash);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_TRUE(says(status, "bundle hash mismatch: the upload claims " + wrong_hash));

  // A declared size the stream does not deliver.
  status = upload(genuine, nullptr, genuine.size() + 10);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_TRUE(says(status, "upload ended after " + std::to_string(genuine.size())));
}

void escaping_scenes_are_refused_at_upload_and_submit() {
  SCOPED_TRACE("escaping_scenes_are_refused_at_upload_and_submit");
  write(farm_->root / "outside.pbrt", "# outside every scene directory\n");
  struct Case {
    std::string name;
    std::string include;
    std::string why;
  };
  const Case cases[] = {{"dotdot", "../outside.pbrt", "escapes the scene directory"},
                        {"absolute", (farm_->root / "outside.pbrt").string(), "absolute path"}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const fs::path dir = make_scene_dir(c.name, "Include \"" + c.include + "\"\n");
    auto bundle = scene::make_bundle(dir, "scene.pbrt", {});
    ASSERT_TRUE(bundle.ok()) << bundle.status();
    grpc::Status status = upload(scene::pack(*bundle));
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_TRUE(says(status, "the bundle's scene does not load"));
    EXPECT_TRUE(says(status, "scene.pbrt:"));
    EXPECT_TRUE(says(status, c.include));
    EXPECT_TRUE(says(status, c.why));

    // Nothing was kept: the bundle is unknown and a job naming it is refused.
    v1::HasBundleRequest has;
    has.set_bundle_hash(bundle->content_hash);
    v1::HasBundleResponse present;
    auto context = client();
    ASSERT_TRUE(farm_->farm->HasBundle(context.get(), has, &present).ok());
    EXPECT_FALSE(present.present());
    std::string job_id;
    status = submit(good_spec(bundle->content_hash, 1), &job_id);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
    EXPECT_TRUE(says(status, "bundle " + bundle->content_hash + " is not on the coordinator"));
    EXPECT_TRUE(job_id.empty());
  }
}

void oversized_uploads_are_resource_exhausted() {
  SCOPED_TRACE("oversized_uploads_are_resource_exhausted");
  const std::string big(2 * kMaxBundleBytes, 'x');
  // Declared up front: refused on the first message.
  grpc::Status status = upload(big, nullptr, big.size());
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_TRUE(says(status, "upload of " + std::to_string(big.size()) +
                               " bytes is over the limit of " + std::to_string(kMaxBundleBytes)));
  // Not declared: refused when the bytes pass the limit.
  status = upload(big, nullptr, 0);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_TRUE(says(status, "upload exceeds the limit of " + std::to_string(kMaxBundleBytes)));
}

void unknown_job_ids_are_not_found() {
  SCOPED_TRACE("unknown_job_ids_are_not_found");
  const std::string unknown = "j-999999";
  // GetJob and CancelJob take the same request fields.
  for (const bool cancel : {false, true}) {
    v1::GetJobRequest get;
    v1::CancelJobRequest cancel_request;
    get.set_job_id(unknown);
    cancel_request.set_job_id(unknown);
    v1::JobInfo info;
    auto context = client();
    const grpc::Status status = cancel
                                    ? farm_->farm->CancelJob(context.get(), cancel_request, &info)
                                    : farm_->farm->GetJob(context.get(), get, &info);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND) << cancel;
    EXPECT_TRUE(says(status, "no job")) << cancel << ": " << status.error_message();
    EXPECT_TRUE(says(status, unknown)) << cancel;
  }
  {
    v1::GetResultRequest request;
    request.set_job_id(unknown);
    auto context = client();
    auto reader = farm_->farm->GetResult(context.get(), request);
    v1::ResultChunk chunk;
    EXPECT_FALSE(reader->Read(&chunk));
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_TRUE(says(status, unknown));
  }
}

void stale_foreign_or_unknown_leases_are_failed_precondition() {
  SCOPED_TRACE("stale_foreign_or_unknown_leases_are_failed_precondition");
  ASSERT_TRUE(farm_->fake_lease.has_value());
  const v1::Lease& lease = *farm_->fake_lease;
  const std::string bytes = zero_result(lease);

  // Another worker's result for the fake worker's lease is refused whether or not it is
  // current: fencing is by lease and worker.
  const std::string other = register_fake_worker("other");
  grpc::Status status = complete(testing::kWorkerSecret, other, lease.lease_id(), bytes);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_TRUE(says(status, "lease " + lease.lease_id() + " belongs to worker " +
                               farm_->fake_worker + ", not " + other));

  status = complete(testing::kWorkerSecret, other, "l-no-such-lease", bytes);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_TRUE(says(status, "unknown lease l-no-such-lease"));

  // The fake worker never heartbeats: it is declared lost after three missed beats and its lease
  // expires at its deadline; either ends the lease. Wait past both (ticks are 100 ms apart).
  const auto deadline =
      std::chrono::system_clock::time_point(std::chrono::milliseconds(lease.deadline_unix_ms()));
  std::this_thread::sleep_until(deadline + std::chrono::milliseconds(3 * testing::kHeartbeatMs));
  bool accepted = true;
  status = complete(testing::kWorkerSecret, farm_->fake_worker, lease.lease_id(), bytes, &accepted);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_TRUE(says(status, "lease " + lease.lease_id() + " is no longer current"));
  EXPECT_FALSE(accepted);

  // The long job goes on (its task requeued) until it is cancelled.
  const v1::JobInfo info = get_job(farm_->long_job);
  EXPECT_FALSE(terminal(info)) << v1::JobState_Name(info.state()) << ": " << info.error();
  EXPECT_EQ(info.progress().tasks_done(), 0u);
}

// After all of the above: the coordinator kept serving.
void the_coordinator_keeps_serving_the_other_jobs() {
  SCOPED_TRACE("the_coordinator_keeps_serving_the_other_jobs");
  {
    v1::CancelJobRequest request;
    request.set_job_id(farm_->long_job);
    v1::JobInfo info;
    auto context = client();
    const grpc::Status status = farm_->farm->CancelJob(context.get(), request, &info);
    ASSERT_TRUE(status.ok()) << status.error_message();
    EXPECT_EQ(info.state(), v1::JOB_STATE_CANCELLED);
  }
  const v1::JobInfo done = wait_terminal(farm_->good_job, 25);
  ASSERT_EQ(done.state(), v1::JOB_STATE_DONE)
      << v1::JobState_Name(done.state()) << ": " << done.error();
  EXPECT_EQ(done.progress().tasks_done(), 9u);

  // A job submitted after all the bad input is served too: one 8x8 tile.
  v1::JobSpec tiny = good_spec(farm_->good_hash, 4);
  tiny.set_width(8);
  tiny.set_height(8);
  std::string tiny_job;
  ASSERT_TRUE(submit(tiny, &tiny_job).ok());
  const v1::JobInfo tiny_done = wait_terminal(tiny_job, 10);
  EXPECT_EQ(tiny_done.state(), v1::JOB_STATE_DONE) << tiny_done.error();

  // The good job's pixels are byte-identical to `prism render` of the same job.
  std::string bytes, sha;
  {
    v1::GetResultRequest request;
    request.set_job_id(farm_->good_job);
    request.add_kinds(v1::OUTPUT_KIND_SPECTRAL_EXR);
    auto context = client();
    auto reader = farm_->farm->GetResult(context.get(), request);
    v1::ResultChunk chunk;
    while (reader->Read(&chunk)) {
      bytes += chunk.data();
      if (chunk.last()) sha = chunk.sha256();
    }
    const grpc::Status status = reader->Finish();
    ASSERT_TRUE(status.ok()) << status.error_message();
  }
  EXPECT_EQ(sha, base::sha256_hex(bytes));
  write(farm_->root / "farm.exr", bytes);
  const std::vector<float> farm = read_pixels(farm_->root / "farm.exr");

  const fs::path cli_out = farm_->root / "cli" / "cli.exr";
  fs::create_directories(cli_out.parent_path());
  const testing::RunResult render = testing::run(
      {PRISM_BINARY, "render", (farm_->root / "good" / "scene.pbrt").string(), "-o",
       cli_out.string(), "--spp", std::to_string(kGoodSpp), "--seed", std::to_string(kGoodSeed),
       "--tile", "8", "--threads", "2", "--no-prepass", "--integrator", "hero"});
  ASSERT_EQ(render.exit_code, 0) << render.out << render.err;
  const std::vector<float> cli = read_pixels(cli_out);
  ASSERT_EQ(farm.size(), cli.size());
  ASSERT_EQ(farm.size(), 24u * 24u * 16u);
  EXPECT_EQ(std::memcmp(farm.data(), cli.data(), farm.size() * sizeof(float)), 0);
  double sum = 0;
  for (float v : farm) sum += v;
  EXPECT_GT(sum, 0.0);
}

// One coordinator and one worker for the whole sequence, so that the last step shows the
// coordinator still serving after every kind of bad input (ctest runs each TEST in a process).
TEST_F(FarmBadInputTest, BadInputIsRefusedPreciselyAndTheOtherJobsAreServed) {
  ASSERT_FALSE(terminal(get_job(farm_->good_job))) << "the good job ended before the bad input";
  wrong_or_missing_client_tokens_are_unauthenticated();
  wrong_worker_secrets_are_unauthenticated();
  malformed_bundles_are_invalid_argument();
  escaping_scenes_are_refused_at_upload_and_submit();
  oversized_uploads_are_resource_exhausted();
  unknown_job_ids_are_not_found();
  stale_foreign_or_unknown_leases_are_failed_precondition();
  the_coordinator_keeps_serving_the_other_jobs();
}

}  // namespace
}  // namespace prism
