// prism-coordinator: the farm's coordinator daemon. Parses and validates its configuration,
// opens the data directory (resuming unfinished jobs), serves FarmService, WorkerService and
// the gRPC health service, and on SIGINT/SIGTERM stops serving, then stops the coordinator.
#include <malloc.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <csignal>
#include <cstdint>
#include <filesystem>
#include <iostream>
#include <optional>
#include <string>
#include <thread>
#include <tuple>

#include "absl/synchronization/mutex.h"
#include "coordinator/farm_coordinator.h"
#include "coordinator/http/http_api.h"
#include "coordinator/resource_plan.h"
#include "coordinator/rpc/coordinator_server.h"
#include "services/base/file_lock.h"
#include "services/base/float_mode.h"
#include "services/rpc/address.h"

namespace {

// The outermost directory of `path` that does not exist yet (a dangling symlink exists): what
// opening the data directory creates, and what a start that fails after taking its lock removes
// again (nothing, where it existed).
std::optional<std::filesystem::path> first_missing(const std::filesystem::path& path) {
  std::error_code error;
  const std::filesystem::path absolute = std::filesystem::absolute(path, error);
  if (error) return std::nullopt;
  std::optional<std::filesystem::path> missing;
  for (std::filesystem::path p = absolute.lexically_normal(); !p.empty(); p = p.parent_path()) {
    std::error_code ignored;  // set for a path that is not there, which is what is asked
    if (std::filesystem::symlink_status(p, ignored).type() !=
        std::filesystem::file_type::not_found) {
      break;
    }
    missing = p;
    if (p == p.parent_path()) break;
  }
  return missing;
}

struct Config {
  std::string listen;
  std::string http_listen;
  std::string data_dir;
  std::string worker_secret;
  std::string api_token;
  std::string tls_cert;
  std::string tls_key;
  std::uint64_t max_bundle_bytes = std::uint64_t{1} << 30;
  std::uint64_t max_queued_jobs = 1000;
  std::string max_memory;
  std::string max_disk;
  int output_threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  std::int64_t heartbeat_ms = 1000;
  std::int64_t lease_ms = 30000;
  std::string log_level = "info";
};

}  // namespace

int main(int argc, char** argv) {
  prism::base::flush_denormals_to_zero();  // before any thread starts (float_mode.h)
  // Debian's Abseil checks every absl::Mutex acquisition (gRPC's locks) for lock-order cycles,
  // a debugging aid that cost the coordinator about 3 % of its CPU per completed task.
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  // Results are hundreds of KB each (a 32x32 tile at 64 bins is 557 KB) and come and go by the
  // thousand. glibc maps each buffer over its mmap threshold afresh and returns the memory to the
  // kernel when it is freed, so every result paid page faults and the kernel's zeroing of new
  // pages (a fifth of the coordinator's CPU on a 1-spp 64-bin job). Keep such buffers in the heap
  // and the freed memory in the process: it is reused by the next result.
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
  using prism::coordinator::Millis;
  Config config;
  CLI::App app{"prism-coordinator: the Prism render farm's coordinator"};
  app.add_option("--listen", config.listen, "address to serve on, e.g. 0.0.0.0:7070")->required();
  app.add_option("--http-listen", config.http_listen,
                 "also serve the HTTP/JSON API and /metrics here, e.g. 0.0.0.0:8080 (off when "
                 "absent; same token, HTTPS with --tls-cert)");
  app.add_option("--data-dir", config.data_dir, "job store, bundles, results and outputs")
      ->required();
  app.add_option("--worker-secret", config.worker_secret, "bearer token workers must send")
      ->envname("PRISM_WORKER_SECRET");
  app.add_option("--api-token", config.api_token, "bearer token clients must send")
      ->envname("PRISM_API_TOKEN");
  app.add_option("--tls-cert", config.tls_cert, "PEM certificate chain (enables TLS)");
  app.add_option("--tls-key", config.tls_key, "PEM private key for --tls-cert");
  app.add_option("--max-bundle-bytes", config.max_bundle_bytes, "largest scene bundle accepted")
      ->check(CLI::Range(std::uint64_t{1}, std::uint64_t{1} << 40));
  app.add_option("--max-queued-jobs", config.max_queued_jobs, "unfinished jobs accepted at once")
      ->check(CLI::Range(std::uint64_t{1}, std::uint64_t{1} << 20));
  app.add_option("--max-memory", config.max_memory,
                 "refuse a job when the unfinished jobs' planned memory would exceed this, e.g. "
                 "16G (default: the machine's memory or the process's limit, the smaller)");
  app.add_option("--max-disk", config.max_disk,
                 "refuse a job when the unfinished jobs' planned disk would exceed this, e.g. "
                 "500G (default: each job must fit the data dir's free space)");
  app.add_option("--output-threads", config.output_threads,
                 "threads compressing a finished job's EXR outputs (default: the hardware's)")
      ->check(CLI::Range(1, 256));
  app.add_option("--heartbeat-ms", config.heartbeat_ms, "worker heartbeat interval")
      ->check(CLI::Range(std::int64_t{10}, std::int64_t{600000}));
  app.add_option("--lease-ms", config.lease_ms, "lease duration, extended by heartbeats")
      ->check(CLI::Range(std::int64_t{10}, std::int64_t{86400000}));
  // Checked: spdlog reads any other name as "off", and a typo silenced every log line.
  app.add_option("--log-level", config.log_level, "trace, debug, info, warn, error, off")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}));
  bool insecure = false;
  app.add_flag("--insecure", insecure,
               "serve an address other machines can reach without --api-token and "
               "--worker-secret (anyone reaching it could submit jobs or pose as a worker)");
  CLI11_PARSE(app, argc, argv);
  if (absl::Status address = prism::rpc::check_address(config.listen, "--listen", true);
      !address.ok()) {
    std::cerr << "prism-coordinator: " << address.message() << "\n";
    return 2;
  }
  // A malformed --http-listen is told so first, not that it "can be reached from other
  // machines".
  if (!config.http_listen.empty()) {
    if (absl::Status address = prism::rpc::check_address(config.http_listen, "--http-listen", true);
        !address.ok()) {
      std::cerr << "prism-coordinator: " << address.message() << "\n";
      return 2;
    }
  }
  // Open to the network without both secrets only when asked for.
  if (!insecure && (config.api_token.empty() || config.worker_secret.empty())) {
    for (const std::string* listen : {&config.listen, &config.http_listen}) {
      if (listen->empty() || prism::rpc::is_loopback_address(*listen)) continue;
      std::cerr << "prism-coordinator: " << *listen
                << " can be reached from other machines, but --api-token and --worker-secret "
                   "(PRISM_API_TOKEN, PRISM_WORKER_SECRET) are not both set: anyone who reaches "
                   "it could submit jobs or pose as a worker. Set both, listen on 127.0.0.1, or "
                   "pass --insecure\n";
      return 2;
    }
  }
  if (config.tls_cert.empty() != config.tls_key.empty()) {
    std::cerr << "prism-coordinator: --tls-cert and --tls-key go together\n";
    return 2;
  }
  if (config.lease_ms <= config.heartbeat_ms) {
    std::cerr << "prism-coordinator: --lease-ms " << config.lease_ms
              << " must be longer than --heartbeat-ms " << config.heartbeat_ms << "\n";
    return 2;
  }

  auto logger = spdlog::stderr_color_mt("coordinator");
  logger->set_level(spdlog::level::from_str(config.log_level));

  // Signals are taken synchronously by sigwait below; block them before any thread starts.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  prism::coordinator::FarmOptions options;
  options.data_dir = config.data_dir;
  options.max_bundle_bytes = config.max_bundle_bytes;
  options.max_queued_jobs = config.max_queued_jobs;
  options.output_threads = config.output_threads;
  for (auto [flag, text, bytes] :
       {std::tuple{"--max-memory", &config.max_memory, &options.max_memory_bytes},
        std::tuple{"--max-disk", &config.max_disk, &options.max_disk_bytes}}) {
    if (text->empty()) continue;
    absl::StatusOr<std::uint64_t> parsed = prism::coordinator::parse_bytes(*text);
    if (!parsed.ok()) {
      std::cerr << "prism-coordinator: " << flag << " " << parsed.status().message() << "\n";
      return 2;
    }
    *bytes = *parsed;
  }
  options.scheduler.heartbeat_interval = Millis(config.heartbeat_ms);
  options.scheduler.lease_duration = Millis(config.lease_ms);
  options.tick_interval = Millis(std::max<std::int64_t>(10, config.heartbeat_ms / 2));
  options.logger = logger;
  // A start that fails (its address taken, say) leaves no data directory it created behind. Only
  // one that opened the directory (and so held its lock): one that failed to open it (another
  // coordinator holds it, having created it a moment after this one looked) removes nothing.
  const std::optional<std::filesystem::path> created = first_missing(config.data_dir);
  // After the farm has stopped (its threads write there until then): under the directory's lock
  // again, which another coordinator that started meanwhile would hold.
  auto forget_created = [&] {
    if (!created.has_value()) return;
    absl::StatusOr<prism::base::FileLock> lock = prism::base::FileLock::acquire(
        std::filesystem::path(config.data_dir) / "coordinator.lock", "the data directory");
    if (!lock.ok()) return;
    std::error_code ignored;
    std::filesystem::remove_all(*created, ignored);
  };
  auto farm = prism::coordinator::FarmCoordinator::open(std::move(options));
  if (!farm.ok()) {
    std::cerr << "prism-coordinator: " << farm.status().message() << "\n";
    return 1;
  }
  prism::coordinator::rpc::ServerConfig server_config;
  server_config.listen = config.listen;
  server_config.worker_secret = config.worker_secret;
  server_config.api_token = config.api_token;
  server_config.tls.cert_chain = config.tls_cert;
  server_config.tls.private_key = config.tls_key;
  auto server = prism::coordinator::rpc::CoordinatorServer::start(**farm, server_config, logger);
  if (!server.ok()) {
    std::cerr << "prism-coordinator: " << server.status().message() << "\n";
    (*farm)->shutdown();
    farm->reset();
    forget_created();
    return 1;
  }
  std::unique_ptr<prism::coordinator::http::HttpApi> http;
  if (!config.http_listen.empty()) {
    prism::coordinator::http::HttpConfig http_config;
    http_config.listen = config.http_listen;
    http_config.api_token = config.api_token;
    http_config.tls = server_config.tls;
    auto started = prism::coordinator::http::HttpApi::start(**farm, http_config, logger);
    if (!started.ok()) {
      std::cerr << "prism-coordinator: " << started.status().message() << "\n";
      (*server)->shutdown();
      (*server)->wait();
      server->reset();
      (*farm)->shutdown();
      farm->reset();
      forget_created();
      return 1;
    }
    http = *std::move(started);
    std::cout << "serving HTTP on port " << http->port() << std::endl;
    logger->info("HTTP API on {} (port {})", config.http_listen, http->port());
  }
  // The port lines are what scripts and tests read when --listen asks for port 0. A Unix
  // socket has no port (gRPC reports 1 for it): its line names the socket instead.
  const bool unix_socket =
      config.listen.starts_with("unix:") || config.listen.starts_with("unix-abstract:");
  if (unix_socket) {
    std::cout << "listening on " << config.listen << std::endl;
    logger->info("serving on {}, data in {}", config.listen, config.data_dir);
  } else {
    std::cout << "listening on port " << (*server)->port() << std::endl;
    logger->info("serving on {} (port {}), data in {}", config.listen, (*server)->port(),
                 config.data_dir);
  }

  int signal = 0;
  sigwait(&signals, &signal);
  logger->info("signal {}: shutting down", signal);
  if (http != nullptr) http->shutdown();
  (*server)->shutdown();
  (*server)->wait();
  (*farm)->shutdown();
  return 0;
}
