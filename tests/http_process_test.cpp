// The coordinator's HTTP/JSON API and /metrics as their users meet them: a real
// `prism-coordinator --http-listen` and `prism-worker` on loopback, driven by the real `curl`
// (over HTTPS, with the gRPC side on TLS too) and scraped by a real Prometheus server from
// Debian's packages, which this test starts on a loopback port with its own configuration and
// queries through its HTTP API. The job's EXR fetched over HTTP must be the bytes `prism render`
// writes for the same flags.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "services/job/trace_counters.h"
#include "tests/testing/child_process.h"
#include "tests/testing/tls_cert.h"

namespace prism {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

constexpr char kToken[] = "http-token";
constexpr char kSecret[] = "worker-secret";

class HttpProcessTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = testing::fresh_scene_dir(fs::path(PRISM_SOURCE_DIR) / "worker/testdata/unbiased.pbrt");
  }
  void TearDown() override {
    children_.clear();
    fs::remove_all(root_);
  }

  testing::ChildProcess* spawn(std::vector<std::string> argv) {
    children_.push_back(testing::ChildProcess::start(std::move(argv)));
    return children_.back().get();
  }

  // Starts the coordinator with the HTTP listener (HTTPS and TLS gRPC with `tls`); reads both
  // ports.
  void start_coordinator(bool tls) {
    std::vector<std::string> argv = testing::coordinator_command(
        PRISM_COORDINATOR_BINARY, "127.0.0.1:0", root_ / "data", kSecret, kToken,
        {"--http-listen", "127.0.0.1:0", "--heartbeat-ms", "200", "--lease-ms", "2000"});
    if (tls) {
      testing::make_self_signed(root_ / "cert.pem", root_ / "key.pem");
      for (const char* a : {"--tls-cert", "cert.pem", "--tls-key", "key.pem"}) {
        std::string arg = a;
        argv.push_back(arg.rfind("--", 0) == 0 ? arg : (root_ / arg).string());
      }
    }
    testing::ChildProcess* c = spawn(argv);
    ASSERT_NE(c, nullptr);
    const testing::CoordinatorPorts ports = testing::coordinator_ports(*c);
    http_port_ = ports.http;
    grpc_port_ = ports.grpc;
    ASSERT_GT(http_port_, 0);
    ASSERT_GT(grpc_port_, 0);
    base_ = std::string(tls ? "https" : "http") + "://127.0.0.1:" + std::to_string(http_port_);
    tls_ = tls;
  }

  void start_worker() {
    std::vector<std::string> argv = {PRISM_WORKER_BINARY,
                                     "--coordinator",
                                     "127.0.0.1:" + std::to_string(grpc_port_),
                                     "--threads",
                                     "1",
                                     "--secret",
                                     kSecret,
                                     "--cache-dir",
                                     (root_ / "cache").string(),
                                     "--log-level",
                                     "error"};
    if (tls_) {
      argv.push_back("--tls-ca");
      argv.push_back((root_ / "cert.pem").string());
    }
    ASSERT_NE(spawn(argv), nullptr);
  }

  // `curl` with the token (and the CA for HTTPS), failing the test unless it exits with 0.
  // Returns its stdout; `status` gets the HTTP status when given.
  std::string curl(std::vector<std::string> args, int* status = nullptr,
                   const std::string& token = kToken) {
    std::vector<std::string> argv = {testing::find_program("curl"), "--silent", "--show-error",
                                     "--max-time", "120"};
    if (!token.empty()) {
      argv.push_back("-H");
      argv.push_back("Authorization: Bearer " + token);
    }
    if (tls_) {
      argv.push_back("--cacert");
      argv.push_back((root_ / "cert.pem").string());
    }
    if (status != nullptr) {
      argv.push_back("--write-out");
      argv.push_back("\n%{http_code}");
    }
    argv.insert(argv.end(), args.begin(), args.end());
    testing::RunResult r = testing::run(argv, {}, std::chrono::minutes(3));
    EXPECT_EQ(r.exit_code, 0) << "curl failed: " << r.err;
    if (status != nullptr) {
      const std::size_t nl = r.out.rfind('\n');
      if (nl == std::string::npos) return r.out;
      *status = std::atoi(r.out.c_str() + nl + 1);
      r.out.resize(nl);
    }
    return r.out;
  }

  std::vector<std::string> render_flags() {
    return {"--integrator", "hero", "--spp",  "16", "--resolution", "24x16",
            "--bins",       "8",    "--tile", "8",  "--seed",       "3"};
  }

  fs::path root_;
  std::vector<std::unique_ptr<testing::ChildProcess>> children_;
  int http_port_ = 0, grpc_port_ = 0;
  bool tls_ = false;
  std::string base_;
};

TEST_F(HttpProcessTest, CurlUploadsSubmitsWatchesFetchesAndCancelsOverHttps) {
  ASSERT_NO_FATAL_FAILURE(start_coordinator(/*tls=*/true));
  // What `prism submit` would send, as files for curl.
  std::vector<std::string> pack = {PRISM_BINARY, "pack", (root_ / "scene/scene.pbrt").string(),
                                   "--bundle", (root_ / "scene.bundle").string()};
  for (const std::string& f : render_flags()) pack.push_back(f);
  testing::RunResult packed = testing::run(pack);
  ASSERT_EQ(packed.exit_code, 0) << packed.err;
  std::ofstream(root_ / "request.json") << packed.out;

  int status = 0;
  json bundle = json::parse(
      curl({"--data-binary", "@" + (root_ / "scene.bundle").string(), base_ + "/api/v1/bundles"},
           &status));
  ASSERT_EQ(status, 200) << bundle.dump();
  EXPECT_EQ(bundle["bundleHash"], json::parse(packed.out)["spec"]["bundleHash"]);
  json submitted =
      json::parse(curl({"-H", "Content-Type: application/json", "--data-binary",
                        "@" + (root_ / "request.json").string(), base_ + "/api/v1/jobs"},
                       &status));
  ASSERT_EQ(status, 200) << submitted.dump();
  const std::string id = submitted["job"]["jobId"];

  // Without the token: 401 and nothing listed.
  curl({base_ + "/api/v1/jobs"}, &status, "");
  EXPECT_EQ(status, 401);

  ASSERT_NO_FATAL_FAILURE(start_worker());
  // The event stream ends when the job does.
  const std::string events = curl({"--no-buffer", base_ + "/api/v1/jobs/" + id + ":watch"});
  const std::size_t last = events.rfind("data: ");
  ASSERT_NE(last, std::string::npos) << events;
  EXPECT_EQ(json::parse(events.substr(last + 6))["state"], "JOB_STATE_DONE") << events;

  json jobs = json::parse(curl({base_ + "/api/v1/jobs?state=done"}));
  ASSERT_EQ(jobs["jobs"].size(), 1u);
  EXPECT_EQ(jobs["jobs"][0]["jobId"], id);
  curl({"--output", (root_ / "farm.exr").string(),
        base_ + "/api/v1/jobs/" + id + "/outputs/" + id + ".exr"},
       &status);
  EXPECT_EQ(status, 200);

  // The same flags rendered by `prism render`: the same bytes.
  EXPECT_EQ(
      testing::read_file(root_ / "farm.exr"),
      testing::render_beside(PRISM_BINARY, root_ / "scene", root_ / "local.exr", render_flags()))
      << "the EXR fetched over HTTP is not the embedded render's";

  // A long job, cancelled over HTTP while the worker renders it.
  json request = json::parse(packed.out);
  request["spec"]["spp"] = 1 << 16;
  request["clientToken"] = "long";
  std::ofstream(root_ / "long.json") << request.dump();
  const std::string long_id =
      json::parse(curl({"--data-binary", "@" + (root_ / "long.json").string(),
                        base_ + "/api/v1/jobs"}))["job"]["jobId"];
  json cancelled =
      json::parse(curl({"-X", "POST", base_ + "/api/v1/jobs/" + long_id + ":cancel"}, &status));
  EXPECT_EQ(status, 200) << cancelled.dump();
  EXPECT_EQ(cancelled["state"], "JOB_STATE_CANCELLED");
  EXPECT_EQ(json::parse(curl({base_ + "/api/v1/jobs/" + long_id}))["state"], "JOB_STATE_CANCELLED");
}

// Prometheus scrapes /metrics with the bearer token; its query API then returns the farm's
// figures, and `promtool` accepts the exposition.
// gRPC and httplib both set SO_REUSEPORT by default, so a second coordinator could bind the
// first one's addresses and take a random share of the calls; and nothing stopped two
// coordinators from sharing a data directory. Each is refused now, and the first goes on serving.
// A refused start removes the data directory it had created; it keeps one that was there.
// A client without --tls-ca against a TLS coordinator saw only "Socket closed"; it is told to
// give the CA, and with it the same command works.
TEST_F(HttpProcessTest, APlaintextClientOfATlsCoordinatorIsToldToGiveTheCa) {
  ASSERT_NO_FATAL_FAILURE(start_coordinator(/*tls=*/true));
  const std::string address = "127.0.0.1:" + std::to_string(grpc_port_);
  testing::RunResult plain =
      testing::run({PRISM_BINARY, "jobs", "--coordinator", address, "--token", kToken});
  EXPECT_NE(plain.exit_code, 0);
  EXPECT_NE((plain.out + plain.err).find("serves TLS, give its certificate's CA with --tls-ca"),
            std::string::npos)
      << plain.out << plain.err;
  testing::RunResult with_ca =
      testing::run({PRISM_BINARY, "jobs", "--coordinator", address, "--token", kToken, "--tls-ca",
                    (root_ / "cert.pem").string()});
  EXPECT_EQ(with_ca.exit_code, 0) << with_ca.out << with_ca.err;
}

TEST_F(HttpProcessTest, ASecondCoordinatorSharesNeitherAnAddressNorADataDirectory) {
  ASSERT_NO_FATAL_FAILURE(start_coordinator(/*tls=*/false));
  const std::string grpc = "127.0.0.1:" + std::to_string(grpc_port_);
  const std::string http = "127.0.0.1:" + std::to_string(http_port_);
  const struct {
    std::string listen, http_listen;
    fs::path data;
    std::string message;
  } cases[] = {
      {grpc, "", root_ / "data2", "cannot listen on " + grpc},
      {"127.0.0.1:0", http, root_ / "data3", "cannot listen for HTTP on " + http},
      {"127.0.0.1:0", "", root_ / "data",
       "the data directory " + (root_ / "data").string() + " is in use by process"},
  };
  for (const auto& c : cases) {
    std::vector<std::string> extra;
    if (!c.http_listen.empty()) extra = {"--http-listen", c.http_listen};
    testing::RunResult second = testing::run(testing::coordinator_command(
        PRISM_COORDINATOR_BINARY, c.listen, c.data, kSecret, kToken, extra));
    EXPECT_EQ(second.exit_code, 1) << second.out << second.err;
    EXPECT_NE(second.err.find(c.message), std::string::npos) << second.err;
    // A start that failed leaves no data directory it created (it left a job store behind).
    if (c.data != root_ / "data") EXPECT_FALSE(fs::exists(c.data)) << c.data;
  }
  EXPECT_TRUE(fs::exists(root_ / "data" / "jobs.sqlite"));
  // A dangling symlink given as the data directory exists: a failed start leaves it (it was
  // removed as if the start had created it).
  fs::create_symlink(root_ / "nowhere", root_ / "link");
  testing::RunResult linked = testing::run(testing::coordinator_command(
      PRISM_COORDINATOR_BINARY, grpc, root_ / "link", kSecret, kToken, {}));
  EXPECT_NE(linked.exit_code, 0) << linked.out << linked.err;
  EXPECT_TRUE(fs::is_symlink(root_ / "link"));
  // Every call still reaches the first: a job list, many times over.
  for (int i = 0; i < 20; ++i) {
    int status = 0;
    curl({base_ + "/api/v1/jobs"}, &status);
    EXPECT_EQ(status, 200);
  }
}

// A coordinator on a Unix socket says so on its "listening" line (it said "port 1", gRPC's port
// for a socket, which scripts would take for a TCP port), and clients reach it there.
TEST_F(HttpProcessTest, ACoordinatorOnAUnixSocketNamesItAndServesThere) {
  const std::string address = "unix:" + (root_ / "c.sock").string();
  testing::ChildOptions options;
  auto coordinator = testing::ChildProcess::start(
      testing::coordinator_command(PRISM_COORDINATOR_BINARY, address, root_ / "data-unix", kSecret,
                                   kToken, {}),
      options);
  ASSERT_NE(coordinator, nullptr);
  const std::optional<std::string> line =
      coordinator->wait_for_line("listening on", std::chrono::seconds(20));
  ASSERT_TRUE(line.has_value()) << coordinator->out() << coordinator->err();
  EXPECT_EQ(*line, "listening on " + address);
  testing::RunResult jobs =
      testing::run({PRISM_BINARY, "jobs", "--coordinator", address, "--token", kToken});
  EXPECT_EQ(jobs.exit_code, 0) << jobs.out << jobs.err;
  EXPECT_EQ(jobs.out, "no jobs\n");
}

// spdlog reads an unknown level name as "off": `--log-level verbose` started a coordinator that
// never logged a line. Refused now, before anything starts.
TEST_F(HttpProcessTest, AnUnknownLogLevelIsRefused) {
  testing::RunResult run = testing::run(
      testing::coordinator_command(PRISM_COORDINATOR_BINARY, "127.0.0.1:0", root_ / "data-verbose",
                                   kSecret, kToken, {}, "verbose"));
  EXPECT_NE(run.exit_code, 0) << run.out << run.err;
  EXPECT_NE(run.err.find("--log-level"), std::string::npos) << run.err;
  EXPECT_FALSE(fs::exists(root_ / "data-verbose"));
}

TEST_F(HttpProcessTest, PrometheusScrapesTheMetrics) {
  ASSERT_NO_FATAL_FAILURE(start_coordinator(/*tls=*/false));
  ASSERT_NO_FATAL_FAILURE(start_worker());
  std::vector<std::string> submit = testing::submit_command(
      PRISM_BINARY, root_ / "scene/scene.pbrt", "127.0.0.1:" + std::to_string(grpc_port_), kToken,
      {"--wait", "-o", (root_ / "out.exr").string()});
  for (const std::string& f : render_flags()) submit.push_back(f);
  testing::RunResult submitted = testing::run(submit);
  ASSERT_EQ(submitted.exit_code, 0) << submitted.err;
  // The fetched report names the fetched files, not the coordinator's copies.
  {
    std::ifstream in(root_ / "out.json");
    const nlohmann::json report = nlohmann::json::parse(in, nullptr, false);
    ASSERT_FALSE(report.is_discarded());
    EXPECT_EQ(report["outputs"]["spectral_exr"], (root_ / "out.exr").string());
    EXPECT_EQ(report["outputs"]["json"], (root_ / "out.json").string());
    EXPECT_EQ(report["outputs"]["png"], (root_ / "out.png").string());
    // Every counter a local render reports, zeros included (the farm's listed only those that
    // moved), in the same order.
    std::ifstream again(root_ / "out.json");
    const nlohmann::ordered_json ordered = nlohmann::ordered_json::parse(again, nullptr, false);
    ASSERT_FALSE(ordered.is_discarded());
    std::vector<std::string> counters;
    for (const auto& [name, value] : ordered["counters"].items()) counters.push_back(name);
    ASSERT_GE(counters.size(), prism::job::kTraceCounterNames.size()) << report["counters"];
    for (std::size_t i = 0; i < prism::job::kTraceCounterNames.size(); ++i) {
      EXPECT_EQ(counters[i], prism::job::kTraceCounterNames[i]);
    }
    EXPECT_EQ(report["counters"]["non_finite"], 0);
  }
  // `prism fetch` without -o names the files after the scene's Film, as `prism render` does
  // (this scene's Film has no filename: pbrt-v4's default, pbrt.exr).
  {
    const nlohmann::json jobs = nlohmann::json::parse(curl({base_ + "/api/v1/jobs?state=done"}));
    ASSERT_EQ(jobs["jobs"].size(), 1u);
    fs::create_directories(root_ / "fetched");
    testing::ChildOptions in_dir;
    in_dir.working_dir = root_ / "fetched";
    testing::RunResult fetched = testing::run(
        {PRISM_BINARY, "fetch", jobs["jobs"][0]["jobId"].get<std::string>(), "--coordinator",
         "127.0.0.1:" + std::to_string(grpc_port_), "--token", kToken},
        in_dir);
    ASSERT_EQ(fetched.exit_code, 0) << fetched.err;
    EXPECT_TRUE(fs::exists(root_ / "fetched" / "pbrt.exr")) << fetched.out;
    EXPECT_TRUE(fs::exists(root_ / "fetched" / "pbrt.json")) << fetched.out;
    EXPECT_EQ(testing::read_file(root_ / "fetched" / "pbrt.exr"),
              testing::read_file(root_ / "out.exr"));
    // -o DIR: the same names inside it.
    testing::RunResult into =
        testing::run({PRISM_BINARY, "fetch", jobs["jobs"][0]["jobId"].get<std::string>(), "-o",
                      (root_ / "fetched").string(), "--coordinator",
                      "127.0.0.1:" + std::to_string(grpc_port_), "--token", kToken});
    ASSERT_EQ(into.exit_code, 0) << into.err;
    EXPECT_NE(into.out.find((root_ / "fetched" / "pbrt.exr").string()), std::string::npos)
        << into.out;
  }

  // The exposition passes Prometheus's own linter.
  const std::string metrics = curl({base_ + "/metrics"});
  std::ofstream(root_ / "metrics.txt") << metrics;
  testing::RunResult lint = testing::run(
      {testing::find_program("sh"), "-c",
       testing::find_program("promtool") + " check metrics < " + (root_ / "metrics.txt").string()});
  EXPECT_EQ(lint.exit_code, 0) << lint.out << lint.err;

  const int prometheus_port = testing::free_port();
  std::ofstream(root_ / "prometheus.yml")
      << "global:\n  scrape_interval: 1s\n  scrape_timeout: 1s\n"
      << "scrape_configs:\n  - job_name: prism\n    authorization:\n      type: Bearer\n"
      << "      credentials: " << kToken << "\n    static_configs:\n"
      << "      - targets: ['127.0.0.1:" << http_port_ << "']\n";
  testing::ChildProcess* prometheus = spawn(
      {testing::find_program("prometheus"), "--config.file=" + (root_ / "prometheus.yml").string(),
       "--storage.tsdb.path=" + (root_ / "tsdb").string(),
       "--web.listen-address=127.0.0.1:" + std::to_string(prometheus_port)});
  ASSERT_NE(prometheus, nullptr);
  const std::string api = "http://127.0.0.1:" + std::to_string(prometheus_port) + "/api/v1/query";
  // Polls a PromQL query until it returns one sample; its value.
  auto query = [&](const std::string& promql) -> std::optional<double> {
    const auto end = Clock::now() + std::chrono::seconds(60);
    while (Clock::now() < end) {
      testing::RunResult r =
          testing::run({testing::find_program("curl"), "--silent", "--max-time", "5", "--get",
                        "--data-urlencode", "query=" + promql, api});
      json body = json::parse(r.out, nullptr, false);
      if (!body.is_discarded() && body.value("status", "") == "success" &&
          body["data"]["result"].size() == 1) {
        return std::stod(body["data"]["result"][0]["value"][1].get<std::string>());
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(250));
    }
    return std::nullopt;
  };
  EXPECT_EQ(query("up{job=\"prism\"} == 1"), 1.0) << prometheus->out() << prometheus->err();
  EXPECT_EQ(query("prism_jobs{state=\"done\"}"), 1.0);
  // 24x16 in 8-pixel tiles: 6 final-pass tasks (no prepass by default), all accepted.
  EXPECT_EQ(query("prism_results_total{outcome=\"accepted\"}"), 6.0);
  EXPECT_EQ(query("prism_samples_total"), 24.0 * 16 * 16);
  EXPECT_EQ(query("prism_task_latency_seconds_count"), 6.0);
  const std::optional<double> rss = query("process_resident_memory_bytes");
  ASSERT_TRUE(rss.has_value());
  EXPECT_GT(*rss, 1e6);
  EXPECT_EQ(query("prism_workers{state=\"idle\"}"), 1.0);
}

}  // namespace
}  // namespace prism
