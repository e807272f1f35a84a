// The dashboard in a real browser: a prism-coordinator with its HTTP listener and one
// prism-worker on loopback, a running job and a queued one submitted with `prism submit`, then
// tests/browser/dashboard.cjs drives Debian's headless Chromium through playwright-core (log in,
// watch the tile map reach done, two preview screenshots that differ, the page's numbers
// against the API's, Cancel on the queued job). ctest label `browser`.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>

#include "tests/testing/child_process.h"

namespace prism {
namespace {

namespace fs = std::filesystem;

constexpr char kToken[] = "dashboard-token";
constexpr char kSecret[] = "dashboard-secret";

TEST(DashboardBrowserTest, TheDashboardFollowsAJobAndCancelsAnother) {
  // The white furnace looks like its environment everywhere, so every finished tile changes the
  // preview.
  const fs::path root =
      testing::fresh_scene_dir(fs::path(PRISM_SOURCE_DIR) / "worker/testdata/furnace.pbrt");
  auto coordinator = testing::ChildProcess::start(testing::coordinator_command(
      PRISM_COORDINATOR_BINARY, "127.0.0.1:0", root / "data", kSecret, kToken,
      {"--http-listen", "127.0.0.1:0", "--heartbeat-ms", "200"}));
  ASSERT_NE(coordinator, nullptr);
  const auto [grpc_port, http_port] = testing::coordinator_ports(*coordinator);
  ASSERT_GT(grpc_port, 0);
  const std::string address = "127.0.0.1:" + std::to_string(grpc_port);

  // Twelve tiles of a second or two each for one worker thread: the preview fills in.
  auto submit = [&](const std::string& spp, const std::string& seed) {
    testing::RunResult r = testing::run(testing::submit_command(
        PRISM_BINARY, root / "scene/scene.pbrt", address, kToken,
        {"--integrator", "hero", "--spp", spp, "--resolution", "64x48", "--tile", "16", "--bins",
         "8", "--seed", seed, "--samples-per-task", spp}));
    EXPECT_EQ(r.exit_code, 0) << r.err;
    return r.out.substr(0, r.out.find('\n'));
  };
  const std::string running = submit("8192", "1");
  const std::string queued = submit("8192", "2");
  ASSERT_FALSE(running.empty() || queued.empty());
  auto worker = testing::ChildProcess::start({PRISM_WORKER_BINARY, "--coordinator", address,
                                              "--threads", "1", "--secret", kSecret, "--cache-dir",
                                              (root / "cache").string(), "--log-level", "error"});
  ASSERT_NE(worker, nullptr);

  testing::ChildOptions in_browser_dir;
  in_browser_dir.working_dir = fs::path(PRISM_SOURCE_DIR) / "tests/browser";
  in_browser_dir.merge_stderr = true;
  const testing::RunResult browser = testing::run(
      {testing::find_program("node"), "dashboard.cjs",
       "http://127.0.0.1:" + std::to_string(http_port), kToken, running, queued, root.string()},
      in_browser_dir, std::chrono::minutes(4));
  EXPECT_EQ(browser.exit_code, 0) << browser.out;
  EXPECT_TRUE(fs::exists(root / "dashboard-running.png"));
}

}  // namespace
}  // namespace prism
