// The farm on a real single-host Slurm, from Debian's packages: the test starts munged,
// slurmctld and slurmd with a configuration of its own on loopback ports, then runs
// deploy/slurm/coordinator.sbatch and a two-task deploy/slurm/workers.sbatch array with sbatch,
// renders a job through them, scancels one worker mid-job (it drains: its task is finished or
// handed back, and it is listed as left), and checks the output is `prism render`'s bytes; and
// ends the coordinator's job mid-render and starts it again, which the worker array follows.
#include <gtest/gtest.h>
#include <pwd.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "tests/testing/child_process.h"

namespace prism {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

class SlurmTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = testing::fresh_dir();
    for (const char* d : {"state", "spool", "log", "shared", "scene", "bin", "out"})
      fs::create_directories(root_ / d);
    fs::copy_file(fs::path(PRISM_SOURCE_DIR) / "worker/testdata/unbiased.pbrt",
                  root_ / "scene" / "scene.pbrt");
    // The sbatch scripts take one directory of binaries.
    fs::create_symlink(PRISM_COORDINATOR_BINARY, root_ / "bin" / "prism-coordinator");
    fs::create_symlink(PRISM_WORKER_BINARY, root_ / "bin" / "prism-worker");
    env_ = {"SLURM_CONF=" + (root_ / "slurm.conf").string(),
            "PRISM_SHARED=" + (root_ / "shared").string(), "PRISM_BIN=" + (root_ / "bin").string(),
            "PRISM_DRAIN_TIMEOUT=60", "PRISM_COORDINATOR_ARGS=--heartbeat-ms 200 --lease-ms 5000"};
  }
  void TearDown() override {
    if (slurmctld_ != nullptr) {
      // Every job ends (its slurmstepd with it) before the daemons go.
      run_slurm({"scancel", "--full", "--user", user()}, true);
      const auto end = Clock::now() + std::chrono::seconds(60);
      while (Clock::now() < end && !run_slurm({"squeue", "--noheader"}, true).empty()) {
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
      }
    }
    children_.clear();
    fs::remove_all(root_);
  }

  static std::string user() {
    const passwd* pw = ::getpwuid(::getuid());
    return pw != nullptr ? pw->pw_name : "root";
  }

  testing::ChildProcess* spawn(std::vector<std::string> argv) {
    testing::ChildOptions options;
    options.env = env_;
    children_.push_back(testing::ChildProcess::start(std::move(argv), options));
    return children_.back().get();
  }

  // A Slurm client command with the test's SLURM_CONF; its stdout.
  std::string run_slurm(std::vector<std::string> argv, bool quiet = false) {
    argv[0] = testing::find_program(argv[0]);
    testing::ChildOptions options;
    options.env = env_;
    testing::RunResult r = testing::run(argv, options, std::chrono::minutes(1));
    if (!quiet) {
      EXPECT_EQ(r.exit_code, 0) << argv[0] << ": " << r.out << r.err;
    }
    return r.out;
  }

  // munged, slurmctld and slurmd on loopback, until the node is idle.
  void start_slurm() {
    const fs::path key = root_ / "munge.key";
    {
      std::ofstream out(key, std::ios::binary);
      std::ifstream random("/dev/urandom", std::ios::binary);
      std::string bytes(1024, '\0');
      random.read(bytes.data(), std::streamsize(bytes.size()));
      out << bytes;
    }
    ::chmod(key.c_str(), 0400);
    const fs::path socket = root_ / "munge.sock";
    munged_ = spawn({testing::find_program("munged"), "--foreground", "--force",
                     "--key-file=" + key.string(), "--socket=" + socket.string(),
                     "--pid-file=" + (root_ / "munged.pid").string(),
                     "--log-file=" + (root_ / "log/munged.log").string(),
                     "--seed-file=" + (root_ / "munge.seed").string()});
    ASSERT_NE(munged_, nullptr);
    for (int i = 0; i < 100 && !fs::exists(socket); ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    ASSERT_TRUE(fs::exists(socket))
        << "munged did not start: " << testing::read_file(root_ / "log/munged.log");

    char host[256] = {};
    ::gethostname(host, sizeof(host) - 1);
    std::string node = host;
    node = node.substr(0, node.find('.'));
    const std::string r = root_.string();
    std::ofstream(root_ / "slurm.conf")
        << "ClusterName=prismtest\n"
        << "SlurmctldHost=" << node << "(127.0.0.1)\n"
        << "SlurmctldPort=" << testing::free_port() << "\n"
        << "SlurmdPort=" << testing::free_port() << "\n"
        << "SlurmUser=" << user() << "\nSlurmdUser=" << user() << "\n"
        << "AuthType=auth/munge\nCredType=cred/munge\nAuthInfo=socket=" << socket.string() << "\n"
        << "StateSaveLocation=" << r << "/state\nSlurmdSpoolDir=" << r << "/spool\n"
        << "SlurmctldPidFile=" << r << "/slurmctld.pid\nSlurmdPidFile=" << r << "/slurmd.pid\n"
        << "SlurmctldLogFile=" << r << "/log/slurmctld.log\n"
        << "SlurmdLogFile=" << r << "/log/slurmd.log\n"
        << "ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\n"
        << "SelectType=select/cons_tres\nSelectTypeParameters=CR_CPU\n"
        << "JobAcctGatherType=jobacct_gather/none\nAccountingStorageType=accounting_storage/none\n"
        << "MpiDefault=none\nReturnToService=2\nKillWait=30\n"
        // Four CPUs on any machine (the coordinator and two workers take one each).
        << "SlurmdParameters=config_overrides\n"
        << "NodeName=" << node << " NodeAddr=127.0.0.1 CPUs=4 State=UNKNOWN\n"
        << "PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP\n";
    slurmctld_ = spawn({testing::find_program("slurmctld"), "-D", "-i"});
    ASSERT_NE(slurmctld_, nullptr);
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    ASSERT_NE(spawn({testing::find_program("slurmd"), "-D"}), nullptr);
    const auto end = Clock::now() + std::chrono::seconds(60);
    std::string state;
    while (Clock::now() < end) {
      state = run_slurm({"sinfo", "--noheader", "--format=%T"}, true);
      if (state.rfind("idle", 0) == 0) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(250));
    }
    FAIL() << "the Slurm node never became idle (sinfo: " << state << ")\n"
           << testing::read_file(root_ / "log/slurmctld.log")
           << testing::read_file(root_ / "log/slurmd.log");
  }

  // The published coordinator.env as a map, waiting for it.
  std::map<std::string, std::string> coordinator_env() {
    const fs::path file = root_ / "shared" / "coordinator.env";
    const auto end = Clock::now() + std::chrono::seconds(60);
    while (Clock::now() < end && !fs::exists(file))
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    std::map<std::string, std::string> values;
    std::istringstream lines(testing::read_file(file));
    for (std::string line; std::getline(lines, line);) {
      const std::size_t eq = line.find('=');
      if (eq != std::string::npos) values[line.substr(0, eq)] = line.substr(eq + 1);
    }
    return values;
  }

  fs::path root_;
  std::vector<std::string> env_;
  std::vector<std::unique_ptr<testing::ChildProcess>> children_;
  testing::ChildProcess* munged_ = nullptr;
  testing::ChildProcess* slurmctld_ = nullptr;
};

TEST_F(SlurmTest, SbatchStartedWorkersRenderTheSameBytesAndAScancelledOneDrains) {
  ASSERT_NO_FATAL_FAILURE(start_slurm());
  const std::string scripts = (fs::path(PRISM_SOURCE_DIR) / "deploy/slurm").string();
  run_slurm({"sbatch", "--export=ALL,PRISM_HTTP_LISTEN=127.0.0.1:0",
             "--output=" + (root_ / "out/coordinator-%j.out").string(),
             scripts + "/coordinator.sbatch"});
  std::map<std::string, std::string> published = coordinator_env();
  ASSERT_TRUE(published.contains("PRISM_COORDINATOR"))
      << testing::read_file(root_ / "log/slurmctld.log");
  ASSERT_FALSE(published["PRISM_WORKER_SECRET"].empty());
  // The HTTP API's address is published with its real port (it was not published at all).
  ASSERT_TRUE(published.contains("PRISM_HTTP"));
  const std::string http = published["PRISM_HTTP"];
  const std::string http_port = http.substr(http.rfind(':') + 1);
  EXPECT_FALSE(http_port.empty()) << http;
  EXPECT_NE(http_port, "0") << http;
  const std::string array = run_slurm({"sbatch", "--parsable", "--array=0-1", "--cpus-per-task=1",
                                       "--output=" + (root_ / "out/worker-%A_%a.out").string(),
                                       scripts + "/workers.sbatch"});
  const std::string array_id = array.substr(0, array.find_first_of(";\n"));
  ASSERT_FALSE(array_id.empty());

  // The client needs only what the coordinator published.
  // Twelve tasks of about a second each: both workers stay busy long enough to be seen so, and
  // the scancelled one is mid-task.
  const std::vector<std::string> flags = {
      "--integrator", "hero", "--spp",  "8192", "--resolution",       "32x24", "--bins", "8",
      "--tile",       "8",    "--seed", "5",    "--samples-per-task", "8192"};
  testing::ChildOptions client;
  client.env = {"PRISM_COORDINATOR=" + published["PRISM_COORDINATOR"],
                "PRISM_API_TOKEN=" + published["PRISM_API_TOKEN"]};
  std::vector<std::string> submit = {PRISM_BINARY, "submit", (root_ / "scene/scene.pbrt").string(),
                                     "--wait",     "-o",     (root_ / "farm.exr").string()};
  submit.insert(submit.end(), flags.begin(), flags.end());
  children_.push_back(testing::ChildProcess::start(submit, client));
  testing::ChildProcess* submitted = children_.back().get();

  // Once both workers render, scancel the second array task.
  const auto busy_by = Clock::now() + std::chrono::seconds(90);
  int busy = 0;
  while (Clock::now() < busy_by && busy < 2 && submitted->running()) {
    testing::RunResult w = testing::run({PRISM_BINARY, "workers"}, client);
    busy = 0;
    for (std::size_t at = w.out.find("busy"); at != std::string::npos;
         at = w.out.find("busy", at + 1))
      ++busy;
    if (busy < 2) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ASSERT_EQ(busy, 2) << "both sbatch workers should be rendering (the job "
                     << (submitted->running() ? "is still running" : "already ended") << ")";
  run_slurm({"scancel", array_id + "_1"});

  const std::optional<int> exit_code = submitted->wait(std::chrono::minutes(5));
  ASSERT_TRUE(exit_code.has_value()) << "the job did not finish";
  EXPECT_EQ(*exit_code, 0) << submitted->out() << submitted->err();

  // The scancelled worker (host "<node>/<array>_1") drained and left; none was lost.
  const auto left_by = Clock::now() + std::chrono::seconds(60);
  std::string workers, state_of_1;
  while (Clock::now() < left_by && state_of_1 != "left") {
    workers = testing::run({PRISM_BINARY, "workers"}, client).out;
    std::istringstream lines(workers);
    for (std::string line; std::getline(lines, line);) {
      std::istringstream fields(line);
      std::string id, host, state;
      fields >> id >> host >> state;
      if (host.size() > 2 && host.substr(host.size() - 2) == "_1") state_of_1 = state;
    }
    if (state_of_1 != "left") std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  EXPECT_EQ(state_of_1, "left") << workers;
  EXPECT_EQ(workers.find("lost"), std::string::npos) << workers;

  // The same flags rendered by `prism render`: the same bytes.
  EXPECT_EQ(testing::read_file(root_ / "farm.exr"),
            testing::render_beside(PRISM_BINARY, root_ / "scene", root_ / "local.exr", flags))
      << "the Slurm farm's EXR is not prism render's";
}

// The coordinator's job ends (scancel, its time limit) and is submitted again: it comes back on
// another port with the secret and token it had (kept beside the data), the running worker array
// sees the new coordinator.env and reconnects, and the job that was in flight finishes with
// `prism render`'s bytes. (Before, the worker retried the old address until its time limit, or
// was refused with the new secret, and the job waited for a worker forever.)
TEST_F(SlurmTest, AWorkerArrayFollowsACoordinatorJobStartedAgain) {
  ASSERT_NO_FATAL_FAILURE(start_slurm());
  const std::string scripts = (fs::path(PRISM_SOURCE_DIR) / "deploy/slurm").string();
  auto start_coordinator = [&] {
    const std::string id = run_slurm({"sbatch", "--parsable",
                                      "--output=" + (root_ / "out/coordinator-%j.out").string(),
                                      scripts + "/coordinator.sbatch"});
    return id.substr(0, id.find_first_of(";\n"));
  };
  const std::string first = start_coordinator();
  std::map<std::string, std::string> before = coordinator_env();
  ASSERT_TRUE(before.contains("PRISM_COORDINATOR"))
      << testing::read_file(root_ / "log/slurmctld.log");
  run_slurm({"sbatch", "--array=0-0", "--cpus-per-task=1",
             "--output=" + (root_ / "out/worker-%A_%a.out").string(), scripts + "/workers.sbatch"});

  // Twelve tasks of about a second each for the one worker.
  const std::vector<std::string> flags = {
      "--integrator", "hero", "--spp",  "8192", "--resolution",       "32x24", "--bins", "8",
      "--tile",       "8",    "--seed", "5",    "--samples-per-task", "8192"};
  auto client = [&](const std::map<std::string, std::string>& published) {
    testing::ChildOptions o;
    o.env = {"PRISM_COORDINATOR=" + published.at("PRISM_COORDINATOR"),
             "PRISM_API_TOKEN=" + published.at("PRISM_API_TOKEN")};
    return o;
  };
  std::vector<std::string> submit = {PRISM_BINARY, "submit", (root_ / "scene/scene.pbrt").string()};
  submit.insert(submit.end(), flags.begin(), flags.end());
  const testing::RunResult submitted = testing::run(submit, client(before));
  ASSERT_EQ(submitted.exit_code, 0) << submitted.out << submitted.err;
  const std::size_t at = submitted.out.find("j-");
  ASSERT_NE(at, std::string::npos) << submitted.out;
  const std::string job = submitted.out.substr(at, submitted.out.find_first_of(" \n", at) - at);

  // Once the worker renders, the coordinator's job ends and a new one starts.
  const auto busy_by = Clock::now() + std::chrono::seconds(90);
  std::string workers;
  while (Clock::now() < busy_by && workers.find("busy") == std::string::npos) {
    workers = testing::run({PRISM_BINARY, "workers"}, client(before)).out;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ASSERT_NE(workers.find("busy"), std::string::npos) << workers;
  run_slurm({"scancel", first});
  const fs::path env_file = root_ / "shared" / "coordinator.env";
  const auto gone_by = Clock::now() + std::chrono::seconds(60);
  while (Clock::now() < gone_by && fs::exists(env_file))
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  ASSERT_FALSE(fs::exists(env_file)) << "the stopped coordinator job left its env file";
  start_coordinator();
  std::map<std::string, std::string> after = coordinator_env();
  ASSERT_TRUE(after.contains("PRISM_COORDINATOR"));
  EXPECT_EQ(after["PRISM_WORKER_SECRET"], before["PRISM_WORKER_SECRET"]);
  EXPECT_EQ(after["PRISM_API_TOKEN"], before["PRISM_API_TOKEN"]);

  // The job finishes on the new coordinator, with the array's worker.
  const testing::RunResult watched =
      testing::run({PRISM_BINARY, "watch", job}, client(after), std::chrono::minutes(4));
  ASSERT_EQ(watched.exit_code, 0) << watched.out << watched.err
                                  << testing::read_file(root_ / "log/slurmctld.log");
  const testing::RunResult fetched = testing::run(
      {PRISM_BINARY, "fetch", job, "-o", (root_ / "farm.exr").string()}, client(after));
  ASSERT_EQ(fetched.exit_code, 0) << fetched.out << fetched.err;
  EXPECT_EQ(testing::read_file(root_ / "farm.exr"),
            testing::render_beside(PRISM_BINARY, root_ / "scene", root_ / "local.exr", flags))
      << "the Slurm farm's EXR is not prism render's";
}

}  // namespace
}  // namespace prism
