// The farm across hosts, as network namespaces on one machine: the coordinator in one namespace,
// three workers in three more, each joined to the coordinator's by its own veth pair, with TLS
// on (the certificate names the coordinator's addresses). Mid-job one worker's link is cut for
// longer than a lease (`ip link set down`), then restored. The job must finish with
// `prism render`'s bytes, and every task must be merged exactly once: the coordinator's
// /metrics count one accepted result per task, whatever the cut worker sends late.
// Needs root (CAP_NET_ADMIN) for `ip netns`; ctest label `netns`.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <thread>

#include "tests/testing/child_process.h"
#include "tests/testing/tls_cert.h"

namespace prism {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

constexpr char kToken[] = "netns-token";
constexpr char kSecret[] = "netns-secret";
constexpr int kWorkers = 3;

class NetnsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = testing::fresh_scene_dir(fs::path(PRISM_SOURCE_DIR) / "worker/testdata/unbiased.pbrt");
    prefix_ = "pn" + std::to_string(::getpid() % 100000);
  }
  void TearDown() override {
    children_.clear();
    for (const std::string& ns : namespaces_) ip({"netns", "del", ns}, true);
    fs::remove_all(root_);
  }

  // `ip ARGS`; fails the test unless it succeeds (quiet: whatever happens).
  void ip(std::vector<std::string> args, bool quiet = false) {
    args.insert(args.begin(), testing::find_program("ip"));
    testing::RunResult r = testing::run(args, {}, std::chrono::seconds(30));
    if (!quiet) {
      EXPECT_EQ(r.exit_code, 0) << "ip failed: " << r.out << r.err;
    }
  }
  void in_ns(const std::string& ns, std::vector<std::string> args) {
    args.insert(args.begin(), {"netns", "exec", ns, testing::find_program("ip")});
    ip(args);
  }
  std::vector<std::string> exec_in(const std::string& ns, std::vector<std::string> argv) {
    argv.insert(argv.begin(), {testing::find_program("ip"), "netns", "exec", ns});
    return argv;
  }

  std::string ns(int i) const { return prefix_ + (i == 0 ? "c" : "w" + std::to_string(i)); }
  // Worker i's link: 10.77.i.1 (coordinator side, veth <prefix>c<i>) to 10.77.i.2.
  std::string coordinator_ip(int i) const { return "10.77." + std::to_string(i) + ".1"; }
  std::string coordinator_link(int i) const { return prefix_ + "c" + std::to_string(i); }

  void make_network() {
    for (int i = 0; i <= kWorkers; ++i) {
      ip({"netns", "add", ns(i)});
      namespaces_.push_back(ns(i));
      in_ns(ns(i), {"link", "set", "lo", "up"});
    }
    for (int i = 1; i <= kWorkers; ++i) {
      const std::string c = coordinator_link(i), w = prefix_ + "w" + std::to_string(i) + "e";
      ip({"link", "add", c, "type", "veth", "peer", "name", w});
      ip({"link", "set", c, "netns", ns(0)});
      ip({"link", "set", w, "netns", ns(i)});
      in_ns(ns(0), {"addr", "add", coordinator_ip(i) + "/24", "dev", c});
      in_ns(ns(i), {"addr", "add", "10.77." + std::to_string(i) + ".2/24", "dev", w});
      in_ns(ns(0), {"link", "set", c, "up"});
      in_ns(ns(i), {"link", "set", w, "up"});
    }
  }

  testing::ChildProcess* spawn(std::vector<std::string> argv) {
    children_.push_back(testing::ChildProcess::start(std::move(argv)));
    return children_.back().get();
  }

  fs::path root_;
  std::string prefix_;
  std::vector<std::string> namespaces_;
  std::vector<std::unique_ptr<testing::ChildProcess>> children_;
};

TEST_F(NetnsTest, ACutLinkLongerThanALeaseLosesNothingAndMergesNothingTwice) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root for ip netns";
  ASSERT_NO_FATAL_FAILURE(make_network());
  std::vector<std::string> ips;
  for (int i = 1; i <= kWorkers; ++i) ips.push_back(coordinator_ip(i));
  testing::make_self_signed(root_ / "cert.pem", root_ / "key.pem", ips);

  testing::ChildProcess* coordinator = spawn(exec_in(
      ns(0),
      testing::coordinator_command(
          PRISM_COORDINATOR_BINARY, "0.0.0.0:0", root_ / "data", kSecret, kToken,
          {"--http-listen", "127.0.0.1:0", "--tls-cert", (root_ / "cert.pem").string(), "--tls-key",
           (root_ / "key.pem").string(), "--heartbeat-ms", "200", "--lease-ms", "1000"})));
  ASSERT_NE(coordinator, nullptr);
  const auto [grpc_port, http_port] = testing::coordinator_ports(*coordinator);
  ASSERT_GT(grpc_port, 0);
  for (int i = 1; i <= kWorkers; ++i) {
    ASSERT_NE(
        spawn(exec_in(ns(i),
                      {PRISM_WORKER_BINARY, "--coordinator",
                       coordinator_ip(i) + ":" + std::to_string(grpc_port), "--threads", "1",
                       "--secret", kSecret, "--tls-ca", (root_ / "cert.pem").string(), "--host",
                       "w" + std::to_string(i), "--cache-dir",
                       (root_ / ("cache" + std::to_string(i))).string(), "--log-level", "error"})),
        nullptr);
  }

  // Tasks of about a second each, so worker 1 is still mid-task when its link goes.
  const std::vector<std::string> flags = {
      "--integrator", "hero", "--spp",  "16384", "--resolution",       "32x24", "--bins", "8",
      "--tile",       "8",    "--seed", "9",     "--samples-per-task", "16384"};
  std::vector<std::string> submit = testing::submit_command(
      PRISM_BINARY, root_ / "scene/scene.pbrt", "127.0.0.1:" + std::to_string(grpc_port), kToken,
      {"--tls-ca", (root_ / "cert.pem").string(), "--wait", "-o", (root_ / "farm.exr").string()});
  submit.insert(submit.end(), flags.begin(), flags.end());
  testing::ChildProcess* submitted = spawn(exec_in(ns(0), submit));

  // Once worker 1 renders, cut its link for three leases, then restore it.
  const auto busy_by = Clock::now() + std::chrono::seconds(60);
  bool busy = false;
  while (!busy && Clock::now() < busy_by) {
    testing::RunResult w = testing::run(exec_in(
        ns(0), {PRISM_BINARY, "workers", "--coordinator", "127.0.0.1:" + std::to_string(grpc_port),
                "--token", kToken, "--tls-ca", (root_ / "cert.pem").string()}));
    busy = std::regex_search(w.out, std::regex("  w1  busy"));
    if (!busy) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_TRUE(busy) << "worker 1 never held a task";
  in_ns(ns(0), {"link", "set", coordinator_link(1), "down"});
  std::this_thread::sleep_for(std::chrono::seconds(3));
  in_ns(ns(0), {"link", "set", coordinator_link(1), "up"});

  const std::optional<int> exit_code = submitted->wait(std::chrono::minutes(5));
  ASSERT_TRUE(exit_code.has_value()) << "the job did not finish";
  ASSERT_EQ(*exit_code, 0) << submitted->out() << submitted->err();

  // Every task accepted once: 12 tiles, one sample range each.
  testing::RunResult metrics = testing::run(
      exec_in(ns(0), {"/usr/bin/curl", "--silent", "--cacert", (root_ / "cert.pem").string(), "-H",
                      std::string("Authorization: Bearer ") + kToken,
                      "https://127.0.0.1:" + std::to_string(http_port) + "/metrics"}));
  EXPECT_NE(metrics.out.find("prism_results_total{outcome=\"accepted\"} 12\n"), std::string::npos)
      << metrics.out;
  EXPECT_NE(metrics.out.find("prism_jobs{state=\"done\"} 1\n"), std::string::npos);
  // The cut mattered: worker 1 was declared lost and its lease went to another worker.
  EXPECT_NE(metrics.out.find("prism_workers_lost_total 1\n"), std::string::npos) << metrics.out;
  EXPECT_EQ(metrics.out.find("prism_task_retries_total{reason=\"worker\"} 0\n"), std::string::npos)
      << metrics.out;

  // The same flags rendered by `prism render`: the same bytes.
  EXPECT_EQ(testing::read_file(root_ / "farm.exr"),
            testing::render_beside(PRISM_BINARY, root_ / "scene", root_ / "local.exr", flags))
      << "the farm's EXR across namespaces is not prism render's";
}

}  // namespace
}  // namespace prism
