// prism-worker: the render farm's worker process. main() parses and validates the flags once,
// then builds, in order, the logger, the Embree device, the TBB arena, the spectrum library, the
// bundle cache directory, the coordinator client and the daemon; it tears them down in reverse.
// SIGTERM and SIGINT are blocked in every thread and taken by one thread with sigwait, which
// starts the daemon's drain; the process exits 0 once the drain is over.
#include <pthread.h>
#include <signal.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <tbb/info.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <thread>

#include "services/base/float_mode.h"
#include "services/job/job_parameters.h"
#include "services/rpc/address.h"
#include "services/rpc/credentials.h"
#include "services/spectral/named_spectra.h"
#include "worker/daemon/worker_client.h"
#include "worker/daemon/worker_daemon.h"
#include "worker/embree_device.h"

#ifndef PRISM_VERSION
#define PRISM_VERSION "0.0.0"
#endif

namespace {

std::string default_host() {
  char name[256] = {};
  if (::gethostname(name, sizeof(name) - 1) != 0) return "unknown";
  return name;
}

int fail(const std::string& message) {
  std::cerr << "prism-worker: " << message << "\n";
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  prism::base::flush_denormals_to_zero();  // before any thread starts (float_mode.h)
  // Before any thread exists (gRPC and TBB start their own), so every thread inherits the mask
  // and only the signal thread below ever sees these signals.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  CLI::App app{"prism-worker: renders tasks for a Prism coordinator"};
  std::string coordinator;
  int threads = 0;
  std::string cache_dir;
  std::string secret;
  std::string tls_ca;
  std::string host = default_host();
  std::string log_level = "info";
  app.add_option("--coordinator", coordinator, "coordinator address, host:port")->required();
  app.add_option("--threads", threads, "render threads (0: all hardware threads)")
      ->check(CLI::Range(0, prism::job::kMaxThreads));
  app.add_option("--cache-dir", cache_dir, "scene bundle cache (default: $TMPDIR/prism-worker)");
  app.add_option("--secret", secret, "worker secret")->envname("PRISM_WORKER_SECRET");
  app.add_option("--tls-ca", tls_ca, "PEM CA bundle to verify the coordinator (enables TLS)");
  app.add_option("--host", host, "host name reported to the coordinator");
  double drain_timeout = 0;
  app.add_option("--drain-timeout", drain_timeout,
                 "seconds a drain (SIGTERM) waits for the task in progress before handing it "
                 "back (0: up to its lease's deadline)")
      ->check(CLI::Range(0.0, 86400.0));
  int uploads_in_flight = 1;
  app.add_option("--uploads-in-flight", uploads_in_flight,
                 "finished results that may wait for or be in upload while the next task renders "
                 "(0: upload each before taking the next)")
      ->check(CLI::Range(0, 16));
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
  CLI11_PARSE(app, argc, argv);
  if (!std::isfinite(drain_timeout)) return fail("--drain-timeout must be a number of seconds");
  if (absl::Status address = prism::rpc::check_address(coordinator, "--coordinator", false);
      !address.ok()) {
    return fail(std::string(address.message()));
  }

  auto logger = spdlog::stderr_color_mt("worker");
  logger->set_level(spdlog::level::from_str(log_level));
  logger->set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %n: %v");

  if (threads == 0) threads = tbb::info::default_concurrency();
  if (cache_dir.empty()) {
    std::error_code ec;
    cache_dir = (std::filesystem::temp_directory_path(ec) / "prism-worker").string();
    if (ec) return fail("no --cache-dir and no temporary directory: " + ec.message());
  }
  // Checked before registering: a worker whose cache cannot hold a bundle fails every task it
  // leases, and the farm would keep it as a healthy, idle worker.
  {
    std::error_code ec;
    std::filesystem::create_directories(cache_dir, ec);
    if (!std::filesystem::is_directory(cache_dir)) {
      return fail("--cache-dir " + cache_dir + " is not a directory" +
                  (ec ? " and cannot be created: " + ec.message() : std::string()));
    }
    const std::filesystem::path probe =
        std::filesystem::path(cache_dir) / (".probe." + std::to_string(::getpid()));
    if (std::FILE* f = std::fopen(probe.c_str(), "wb"); f != nullptr) {
      std::fclose(f);
      std::filesystem::remove(probe, ec);
    } else {
      return fail("--cache-dir " + cache_dir + " is not writable: " + std::strerror(errno));
    }
  }

  absl::StatusOr<std::shared_ptr<grpc::ChannelCredentials>> credentials =
      prism::rpc::channel_credentials({tls_ca});
  if (!credentials.ok()) return fail(std::string(credentials.status().message()));

  prism::worker::EmbreeDevice device;
  if (!device.valid()) {
    return fail("cannot create the Embree device: " + std::string(device.take_error().message()));
  }
  tbb::task_arena arena(threads);
  absl::StatusOr<prism::spectral::SpectrumLibrary> library =
      prism::spectral::SpectrumLibrary::load_builtin();
  if (!library.ok()) return fail(std::string(library.status().message()));

  prism::worker::ClientConfig client_config;
  client_config.address = coordinator;
  client_config.secret = secret;
  client_config.credentials = *credentials;
  prism::worker::WorkerClient client(client_config, logger);

  prism::worker::WorkerConfig config;
  config.host = host;
  config.version = PRISM_VERSION;
  config.threads = threads;
  config.cache_dir = cache_dir;
  config.drain_timeout = std::chrono::milliseconds(std::int64_t(drain_timeout * 1000));
  config.uploads_in_flight = uploads_in_flight;
  prism::worker::WorkerDaemon daemon(config, client, device, *library, arena, logger);
  logger->info("prism-worker {} on {}: coordinator {}, {} threads, cache {}", PRISM_VERSION, host,
               coordinator, threads, cache_dir);

  std::atomic<bool> finished{false};
  std::thread signal_thread([&] {
    const timespec poll{0, 200'000'000};
    while (!finished.load()) {
      const int signal = sigtimedwait(&signals, nullptr, &poll);
      if (signal == SIGTERM || signal == SIGINT) {
        logger->info("signal {}: draining", signal);
        daemon.drain();
      }
    }
  });

  const absl::Status status = daemon.run();
  finished.store(true);
  signal_thread.join();
  if (!status.ok()) {
    logger->error("{}", std::string(status.message()));
    return 1;
  }
  return 0;
}
