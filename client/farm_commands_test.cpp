// The farm subcommands against the coordinator's gRPC server in process on 127.0.0.1 port 0,
// with no worker: jobs stay queued, which is all submit, status, jobs and cancel need.
#include "client/farm_commands.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <future>
#include <sstream>
#include <thread>

#include "coordinator/testing/in_process_farm.h"
#include "google/protobuf/util/json_util.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "tests/testing/test_dir.h"

namespace prism::client {
namespace {

namespace fs = std::filesystem;

using coordinator::testing::kApiToken;
using coordinator::testing::kSmallScene;

int count(const std::string& text, const std::string& needle) {
  int n = 0;
  for (auto at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1)) ++n;
  return n;
}

class FarmCommandsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = prism::testing::fresh_dir();
    fs::create_directories(root_ / "scene");
    std::ofstream(root_ / "scene" / "scene.pbrt") << kSmallScene;
    farm_ = coordinator::testing::InProcessFarm::start(root_ / "data");
    ASSERT_NE(farm_, nullptr);
    connection_.address = farm_->address();
    connection_.token = kApiToken;
    connection_.deadline = std::chrono::milliseconds(5000);
  }
  void TearDown() override { farm_.reset(); }

  SubmitOptions submit_options(std::ostream* log) {
    SubmitOptions options;
    options.render.scene = root_ / "scene" / "scene.pbrt";
    options.render.spp = 2;
    options.render.tile = 8;
    options.progress = log;
    return options;
  }

  fs::path root_;
  std::unique_ptr<coordinator::testing::InProcessFarm> farm_;
  FarmConnection connection_;
};

TEST_F(FarmCommandsTest, SubmitUploadsOnceAndIsIdempotent) {
  std::ostringstream log;
  auto first = run_submit(connection_, submit_options(&log));
  ASSERT_TRUE(first.ok()) << first.status();
  EXPECT_EQ(count(log.str(), "uploading bundle"), 1) << log.str();
  auto second = run_submit(connection_, submit_options(&log));
  ASSERT_TRUE(second.ok()) << second.status();
  EXPECT_EQ(count(log.str(), "uploading bundle"), 1) << log.str();  // not uploaded again
  EXPECT_EQ(*first, *second);
  ASSERT_FALSE(first->empty());
  const std::string id = first->substr(0, first->size() - 1);

  // Different options are a different job, sharing the bundle.
  SubmitOptions other = submit_options(&log);
  other.render.seed = 5;
  auto third = run_submit(connection_, other);
  ASSERT_TRUE(third.ok()) << third.status();
  EXPECT_NE(*third, *first);
  EXPECT_EQ(count(log.str(), "uploading bundle"), 1);

  auto status = run_status(connection_, id);
  ASSERT_TRUE(status.ok()) << status.status();
  EXPECT_NE(status->find(id), std::string::npos) << *status;
  EXPECT_NE(status->find("scene.pbrt"), std::string::npos) << *status;
  EXPECT_NE(status->find("samples 0/512"), std::string::npos) << *status;  // 16x16, 2 spp

  auto jobs = run_jobs(connection_);
  ASSERT_TRUE(jobs.ok()) << jobs.status();
  EXPECT_EQ(count(*jobs, "\n"), 2) << *jobs;
  EXPECT_NE(jobs->find(id), std::string::npos) << *jobs;

  auto cancelled = run_cancel(connection_, id);
  ASSERT_TRUE(cancelled.ok()) << cancelled.status();
  auto after = run_status(connection_, id);
  ASSERT_TRUE(after.ok()) << after.status();
  EXPECT_NE(after->find("cancelled"), std::string::npos) << *after;
  // What was done before the cancel (nothing here: no worker), of the job's 4 tiles.
  EXPECT_NE(after->find("tiles 0/4"), std::string::npos) << *after;

  // Watching a cancelled job fails, saying so.
  std::ostringstream progress;
  auto watched = run_watch(connection_, id, progress, false);
  ASSERT_FALSE(watched.ok());
  EXPECT_NE(watched.status().message().find("cancelled"), std::string::npos) << watched.status();

  auto workers = run_workers(connection_);
  ASSERT_TRUE(workers.ok()) << workers.status();
  EXPECT_EQ(*workers, "no workers\n");
}

// `prism pack` writes the bundle and the request `prism submit` sends: uploading the one and
// submitting the other (as a curl user of the HTTP API would) is the same job as `prism submit`.
TEST_F(FarmCommandsTest, PackWritesWhatSubmitSends) {
  const fs::path bundle = root_ / "out" / "scene.bundle";
  fs::create_directories(bundle.parent_path());
  auto json = run_pack(submit_options(nullptr), bundle);
  ASSERT_TRUE(json.ok()) << json.status();
  prism::v1::SubmitJobRequest request;
  ASSERT_TRUE(google::protobuf::util::JsonStringToMessage(*json, &request).ok()) << *json;
  EXPECT_EQ(request.spec().spp(), 2u);
  EXPECT_EQ(request.spec().tile_size(), 8u);
  EXPECT_EQ(request.client_token().size(), 64u);
  std::ifstream in(bundle, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto uploaded = farm_->farm().upload_bundle("", bytes);
  ASSERT_TRUE(uploaded.ok()) << uploaded.status();
  EXPECT_EQ(*uploaded, request.spec().bundle_hash());
  auto job = farm_->farm().submit(request.spec(), request.client_token());
  ASSERT_TRUE(job.ok()) << job.status();
  auto submitted = run_submit(connection_, submit_options(nullptr));
  ASSERT_TRUE(submitted.ok()) << submitted.status();
  EXPECT_EQ(*submitted, job->record.id + "\n");

  // A bad scene writes nothing.
  SubmitOptions bad = submit_options(nullptr);
  bad.render.scene = root_ / "missing.pbrt";
  const fs::path none = root_ / "out" / "none.bundle";
  EXPECT_FALSE(run_pack(bad, none).ok());
  EXPECT_FALSE(fs::exists(none));
}

// A gradient job without --tau: the client's pilot chooses τ before submitting, so the spec the
// workers get carries it (with the pilot's figures), it is the τ `prism render` chooses for the
// same flags, and submitting again is the same job.
TEST_F(FarmCommandsTest, AGradientSubmitCarriesThePilotsTau) {
  SubmitOptions options = submit_options(nullptr);
  options.render.integrator = "gradient";
  options.render.gradient_lanes = 1;  // the small scene has no glass: single-wavelength shifts
  options.render.spp = 4;
  auto first = run_submit(connection_, options);
  ASSERT_TRUE(first.ok()) << first.status();
  auto second = run_submit(connection_, options);
  ASSERT_TRUE(second.ok()) << second.status();
  EXPECT_EQ(*first, *second);
  auto spec = farm_->farm().job_spec(first->substr(0, first->size() - 1));
  ASSERT_TRUE(spec.ok()) << spec.status();
  ASSERT_TRUE(spec->gradient().has_tau_pilot());
  EXPECT_GT(spec->gradient().tau_pilot().events(), 0u);
  EXPECT_LE(spec->gradient().tau_pilot().lost_benefit_fraction(),
            spec->gradient().tau_pilot().epsilon());

  // The embedded render's choice for the same flags, on one thread.
  auto library = spectral::SpectrumLibrary::load_builtin();
  ASSERT_TRUE(library.ok());
  auto loaded = scene::load_scene(options.render.scene, {});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  auto local = job_spec_of(options.render, loaded->description, std::string(64, '0'), "scene.pbrt");
  ASSERT_TRUE(local.ok()) << local.status();
  RenderCommandOptions one_thread = options.render;
  one_thread.threads = 1;
  worker::EmbreeDevice device;
  auto seconds = choose_tau(one_thread, device, loaded->description, *library, *local);
  ASSERT_TRUE(seconds.ok()) << seconds.status();
  EXPECT_TRUE(seconds->has_value());
  EXPECT_EQ(local->gradient().tau(), spec->gradient().tau());
  EXPECT_EQ(local->gradient().tau_pilot().SerializeAsString(),
            spec->gradient().tau_pilot().SerializeAsString());

  // A τ given is kept, and no pilot runs.
  options.render.tau = 0.25;
  auto given = run_submit(connection_, options);
  ASSERT_TRUE(given.ok()) << given.status();
  auto given_spec = farm_->farm().job_spec(given->substr(0, given->size() - 1));
  ASSERT_TRUE(given_spec.ok());
  EXPECT_EQ(given_spec->gradient().tau(), 0.25f);
  EXPECT_FALSE(given_spec->gradient().has_tau_pilot());
}

// `auto` runs gradient's τ pilot for its own pilot; a gradient job reuses it when it is a pilot
// of the very same job (same τ, same figures, its seconds) and runs its own otherwise.
TEST_F(FarmCommandsTest, ATauPilotIsReusedOnlyForTheSameJob) {
  RenderCommandOptions options = submit_options(nullptr).render;
  options.integrator = "gradient";
  options.gradient_lanes = 1;
  options.spp = 4;
  options.threads = 1;
  auto library = spectral::SpectrumLibrary::load_builtin();
  ASSERT_TRUE(library.ok());
  auto loaded = scene::load_scene(options.scene, {});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const std::string hash(64, '0');
  worker::EmbreeDevice device;
  auto spec_of = [&](const RenderCommandOptions& o) {
    auto spec = job_spec_of(o, loaded->description, hash, "scene.pbrt");
    EXPECT_TRUE(spec.ok()) << spec.status();
    return spec.value_or(v1::JobSpec{});
  };
  v1::JobSpec piloted = spec_of(options);
  auto seconds = choose_tau(options, device, loaded->description, *library, piloted);
  ASSERT_TRUE(seconds.ok()) << seconds.status();
  ASSERT_TRUE(seconds->has_value());
  const std::optional<TauPilotRun> ran = TauPilotRun{piloted, 123.0};
  // The job `o` describes, its τ chosen or reused from `ran`.
  auto with_tau = [&](const RenderCommandOptions& o) {
    v1::JobSpec spec = spec_of(o);
    auto choice = choose_or_reuse_tau(o, ran, device, loaded->description, *library, spec);
    EXPECT_TRUE(choice.ok()) << choice.status();
    return std::make_pair(spec, choice.value_or(TauChoice{}));
  };

  auto [same, reused] = with_tau(options);
  EXPECT_TRUE(reused.reused);
  EXPECT_EQ(reused.seconds, 123.0);
  EXPECT_EQ(same.SerializeAsString(), piloted.SerializeAsString());

  // Another job (twice the spp) runs its own pilot, whose figures are its own.
  RenderCommandOptions other_options = options;
  other_options.spp = 8;
  auto [other, own] = with_tau(other_options);
  EXPECT_FALSE(own.reused);
  ASSERT_TRUE(own.seconds.has_value());
  EXPECT_NE(*own.seconds, 123.0);
  v1::JobSpec expected = spec_of(other_options);
  ASSERT_TRUE(choose_tau(other_options, device, loaded->description, *library, expected).ok());
  EXPECT_EQ(other.gradient().tau(), expected.gradient().tau());
  EXPECT_EQ(other.gradient().tau_pilot().SerializeAsString(),
            expected.gradient().tau_pilot().SerializeAsString());

  // A τ given runs no pilot and reuses none.
  RenderCommandOptions given_options = options;
  given_options.tau = 0.25;
  auto [given, none] = with_tau(given_options);
  EXPECT_FALSE(none.reused);
  EXPECT_FALSE(none.seconds.has_value());
  EXPECT_EQ(given.gradient().tau(), 0.25f);
}

// No worker, so nothing changes for longer than the per-message deadline: the watch probes the
// coordinator instead of failing, and ends with the cancellation's error.
TEST_F(FarmCommandsTest, WatchOutlivesQuietPeriodsAndFailsOnCancel) {
  auto submitted = run_submit(connection_, submit_options(nullptr));
  ASSERT_TRUE(submitted.ok()) << submitted.status();
  const std::string id = submitted->substr(0, submitted->size() - 1);
  connection_.deadline = std::chrono::milliseconds(150);
  std::ostringstream progress;
  auto watching =
      std::async(std::launch::async, [&] { return run_watch(connection_, id, progress, false); });
  std::this_thread::sleep_for(std::chrono::milliseconds(600));
  ASSERT_EQ(watching.wait_for(std::chrono::seconds(0)), std::future_status::timeout);
  ASSERT_TRUE(run_cancel(connection_, id).ok());
  auto watched = watching.get();
  ASSERT_FALSE(watched.ok());
  EXPECT_EQ(watched.status().code(), absl::StatusCode::kCancelled) << watched.status();
  EXPECT_NE(progress.str().find(id + " cancelled"), std::string::npos) << progress.str();
}

TEST_F(FarmCommandsTest, WrongTokenGetsTheServersMessage) {
  connection_.token = "not-the-token";
  auto jobs = run_jobs(connection_);
  ASSERT_FALSE(jobs.ok());
  EXPECT_EQ(jobs.status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(jobs.status().message(), "invalid token");
  std::ostringstream log;
  auto submitted = run_submit(connection_, submit_options(&log));
  ASSERT_FALSE(submitted.ok());
  EXPECT_EQ(submitted.status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(log.str(), "");  // refused before any upload
}

TEST_F(FarmCommandsTest, UnknownJobIsNotFound) {
  for (auto result :
       {run_status(connection_, "no-such-job"), run_cancel(connection_, "no-such-job"),
        run_fetch(connection_, "no-such-job", root_ / "out.exr")}) {
    ASSERT_FALSE(result.ok());
    EXPECT_EQ(result.status().code(), absl::StatusCode::kNotFound) << result.status();
    EXPECT_NE(result.status().message().find("no-such-job"), std::string::npos) << result.status();
  }
  EXPECT_FALSE(fs::exists(root_ / "out.exr"));
}

TEST_F(FarmCommandsTest, MissingAddressIsRefused) {
  FarmConnection none;
  ::unsetenv("PRISM_COORDINATOR");
  EXPECT_EQ(resolve_connection(none).code(), absl::StatusCode::kInvalidArgument);
  ::setenv("PRISM_COORDINATOR", "127.0.0.1:1", 1);
  EXPECT_TRUE(resolve_connection(none).ok());
  EXPECT_EQ(none.address, "127.0.0.1:1");
  ::unsetenv("PRISM_COORDINATOR");
}

}  // namespace
}  // namespace prism::client
