// The coordinator's gRPC server in process on 127.0.0.1 port 0, driven by a test client and a
// fake worker that renders its leases with worker::TileRenderer in this process.
#include "coordinator/farm_server_fixture.h"

namespace prism::coordinator {
namespace {

using namespace farm_server_testing;  // also fs (std::filesystem) and v1 (prism::v1)

TEST_F(FarmServerTest, AFakeWorkerRendersAJobBitIdenticalToTheEmbeddedRender) {
  const std::string hash = upload_scene();
  ASSERT_FALSE(hash.empty());
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

}  // namespace
}  // namespace prism::coordinator
