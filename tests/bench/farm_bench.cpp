// prism-bench-farm: what the farm costs. Three measurements, each printed as a table (figures,
// no assertions):
//
//  overhead  The same job (scenes/cornell-two-lights.pbrt, fixed seed) by `prism render
//            --threads 2` and by a real prism-coordinator + 2 x `prism-worker --threads 1` +
//            `prism submit --wait` (wall time from starting the submit to its outputs written,
//            the bundle upload included), alternating in one run, best of --repeats. ratio =
//            render time / farm time (goal >= 0.9). The two spectral EXRs' pixel bytes are
//            compared. The coordinator's and workers' CPU seconds per farm run are printed too.
//  capacity  A real prism-coordinator and --workers synthetic workers (threads here, one gRPC
//            channel each unless --channels) that Register, heartbeat at the interval the
//            coordinator asks for, AcquireTask and at once CompleteTask with a valid result of
//            the task's shape (a constant TileResult encoded by the tile codec once per tile
//            shape; only its rect and sample range are patched per task, and the SHA-256 of
//            every task's bytes is computed before the clock starts). One job of many small
//            tiles. Completions per second and coordinator CPU per 1000 completions are taken
//            between 10 % and 90 % of the tasks (steady state) and over the whole job (submit
//            planning and the output files included); peak RSS is VmHWM.
//  wire      Bytes per pixel per bin of one task's result: the tile codec's bytes, and the gRPC
//            payload of the CompleteTask stream as the worker sends it (ResultUpload messages
//            of at most 1 MiB plus gRPC's 5-byte message prefix), for 16/64/256 bins with and
//            without gradients and guides. A real rendered task is encoded too, to show that
//            the size depends only on the shape (the codec does not compress). Then measured:
//            the TCP bytes of real CompleteTask calls to a prism-coordinator through a counting
//            loopback relay (HTTP/2 frames and headers included), for 16/64/256 bins.
//
//  load      (only when asked for) A real prism-coordinator with its HTTP API, --workers
//            synthetic workers as in capacity, and --load-jobs jobs kept queued (a new job is
//            submitted whenever one finishes) for --load-seconds, while one client sends 20 HTTP
//            API requests per second (jobs list, a job, workers, /metrics): the coordinator's
//            RSS and CPU over time, jobs lost (failed, cancelled or missing: must be zero) and
//            the API's latency percentiles.
//
// Usage: prism-bench-farm [overhead] [capacity] [wire] [load]  (none: the first three)
//          [--resolution 320x240] [--spp 256] [--tile 32] [--repeats 2]          (overhead)
//          [--workers 100] [--channels 100] [--capacity-resolution 1024x1024]
//          [--capacity-tile 16] [--capacity-bins 16] [--capacity-repeats 1]      (capacity)
//          [--wire-tile 32]                                                      (wire)
//          [--workers 100] [--load-jobs 200] [--load-seconds 1800]
//          [--load-resolution 128x128]                                           (load)
#include <arpa/inet.h>
#include <fcntl.h>
#include <grpcpp/create_channel.h>
#include <grpcpp/security/credentials.h>
#include <httplib.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "prism/v1/farm.grpc.pb.h"
#include "prism/v1/worker.grpc.pb.h"
#include "services/base/little_endian.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile.h"
#include "services/image/tile_codec.h"
#include "services/rpc/auth.h"
#include "services/rpc/chunks.h"
#include "services/rpc/result_upload.h"
#include "services/scene/bundle.h"
#include "tests/bench/bench_common.h"
#include "worker/embree_device.h"
#include "worker/render_scene.h"
#include "worker/tile_renderer.h"

namespace prism::bench {
namespace {

namespace fs = std::filesystem;
namespace v1 = prism::v1;
using Clock = std::chrono::steady_clock;

constexpr char kToken[] = "bench-token";
constexpr char kSecret[] = "bench-secret";
constexpr char kProgram[] = "prism-bench-farm";

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// ---------------------------------------------------------------------------------------------
// Child processes and /proc.

// Seconds the process's threads have spent runnable but waiting for a CPU (the second field of
// /proc/<pid>/task/<tid>/schedstat), summed over its live threads. On a machine where our own
// processes fit the cores, this is the time other processes took from them.
double runqueue_wait_seconds(pid_t pid) {
  double total = 0;
  std::error_code ec;
  for (const fs::directory_entry& entry :
       fs::directory_iterator("/proc/" + std::to_string(pid) + "/task", ec)) {
    std::ifstream in(entry.path() / "schedstat");
    unsigned long long run = 0, wait = 0;
    if (in >> run >> wait) total += double(wait) * 1e-9;
  }
  return total;
}

// Every child started here; killed (SIGKILL) and reaped on destruction, so an early return
// leaves nothing running.
class Children {
 public:
  Children() = default;
  Children(const Children&) = delete;
  Children& operator=(const Children&) = delete;
  ~Children() {
    for (pid_t pid : pids_) {
      ::kill(pid, SIGKILL);
      int status = 0;
      ::waitpid(pid, &status, 0);
    }
  }

  // Starts argv with stdout and stderr appended to `log`; with `out`, stdout is a pipe instead.
  pid_t spawn(std::vector<std::string> argv, const fs::path& log, FILE** out = nullptr) {
    int fds[2] = {-1, -1};
    if (out != nullptr && ::pipe2(fds, O_CLOEXEC) != 0) return -1;
    const pid_t pid = ::fork();
    if (pid == 0) {
      const int log_fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (log_fd >= 0) {
        ::dup2(log_fd, STDERR_FILENO);
        ::dup2(log_fd, STDOUT_FILENO);
      }
      if (out != nullptr) ::dup2(fds[1], STDOUT_FILENO);
      std::vector<char*> args;
      for (std::string& a : argv) args.push_back(a.data());
      args.push_back(nullptr);
      ::execv(args[0], args.data());
      ::_exit(127);
    }
    if (pid < 0) return -1;
    pids_.push_back(pid);
    if (out != nullptr) {
      ::close(fds[1]);
      *out = ::fdopen(fds[0], "r");
    }
    return pid;
  }

  // Waits for the child; true when it exited with status 0. `cpu_seconds`: its user + system
  // time (threads included). `runqueue_wait`: its threads' time waiting for a CPU, sampled every
  // 20 ms while it runs (the last sample before it exits).
  bool wait_ok(pid_t pid, double* cpu_seconds = nullptr, double* runqueue_wait = nullptr) {
    int status = 0;
    rusage usage{};
    if (runqueue_wait == nullptr) {
      ::wait4(pid, &status, 0, &usage);
    } else {
      while (true) {
        const double sample = runqueue_wait_seconds(pid);
        if (::wait4(pid, &status, WNOHANG, &usage) == pid) break;
        *runqueue_wait = sample;
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
    }
    std::erase(pids_, pid);
    if (cpu_seconds != nullptr) {
      *cpu_seconds = double(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
                     1e-6 * double(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
    }
    return WIFEXITED(status) && WEXITSTATUS(status) == 0;
  }

  // SIGTERM, then waits.
  void stop(pid_t pid) {
    ::kill(pid, SIGTERM);
    wait_ok(pid);
  }

 private:
  std::vector<pid_t> pids_;
};

// utime + stime of a process, in seconds (fields 14 and 15 of /proc/<pid>/stat).
double cpu_seconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::size_t paren = text.rfind(')');
  if (paren == std::string::npos) return 0;
  std::istringstream fields(text.substr(paren + 2));
  std::string field;
  unsigned long long utime = 0, stime = 0;
  // After "pid (comm) ", field 3 (state) comes first: utime is the 12th token, stime the 13th.
  for (int i = 3; i <= 15 && fields >> field; ++i) {
    if (i == 14) utime = std::stoull(field);
    if (i == 15) stime = std::stoull(field);
  }
  return double(utime + stime) / double(::sysconf(_SC_CLK_TCK));
}

// A "Key:   N kB" line of /proc/<pid>/status, in MiB (0 when absent).
double status_mib(pid_t pid, const std::string& key) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(key, 0) == 0) return std::stod(line.substr(key.size())) / 1024.0;
  }
  return 0;
}

// The 1-minute load average: how busy the shared machine was.
double load_average() {
  std::ifstream in("/proc/loadavg");
  double load = 0;
  in >> load;
  return load;
}

double self_cpu_seconds() {
  rusage usage{};
  ::getrusage(RUSAGE_SELF, &usage);
  return double(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
         1e-6 * double(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

// ---------------------------------------------------------------------------------------------
// A loopback TCP relay that counts the bytes each way: what a gRPC call really puts on the wire
// (HTTP/2 frames and HPACK headers around the gRPC-framed protobuf messages).

class CountingProxy {
 public:
  static absl::StatusOr<std::unique_ptr<CountingProxy>> start(int target_port) {
    std::unique_ptr<CountingProxy> proxy(new CountingProxy(target_port));
    proxy->listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t len = sizeof(addr);
    if (proxy->listen_fd_ < 0 ||
        ::bind(proxy->listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0 ||
        ::listen(proxy->listen_fd_, 8) != 0 ||
        ::getsockname(proxy->listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) {
      return absl::InternalError(absl::StrCat("counting proxy: ", std::strerror(errno)));
    }
    proxy->port_ = ntohs(addr.sin_port);
    proxy->acceptor_ = std::thread([p = proxy.get()] { p->accept_loop(); });
    return proxy;
  }
  ~CountingProxy() {
    stop_ = true;
    if (acceptor_.joinable()) acceptor_.join();
    for (std::thread& t : relays_) t.join();
    if (listen_fd_ >= 0) ::close(listen_fd_);
  }
  CountingProxy(const CountingProxy&) = delete;
  CountingProxy& operator=(const CountingProxy&) = delete;

  int port() const { return port_; }
  // Bytes relayed from the clients to the target so far. A byte is counted before it is
  // forwarded, so once the target has answered a call, every byte of the request is counted.
  std::uint64_t upstream() const { return upstream_.load(); }

 private:
  explicit CountingProxy(int target_port) : target_port_(target_port) {}

  void accept_loop() {
    while (!stop_.load()) {
      pollfd pfd{listen_fd_, POLLIN, 0};
      if (::poll(&pfd, 1, 100) <= 0) continue;
      const int client = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
      if (client < 0) continue;
      const int server = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
      sockaddr_in addr{};
      addr.sin_family = AF_INET;
      addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
      addr.sin_port = htons(static_cast<std::uint16_t>(target_port_));
      if (server < 0 || ::connect(server, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
        ::close(client);
        if (server >= 0) ::close(server);
        continue;
      }
      relays_.emplace_back([this, client, server] { relay(client, server); });
    }
  }

  static bool send_all(int fd, const char* data, std::size_t size) {
    while (size > 0) {
      const ssize_t n = ::send(fd, data, size, MSG_NOSIGNAL);
      if (n <= 0) return false;
      data += n;
      size -= static_cast<std::size_t>(n);
    }
    return true;
  }

  void relay(int client, int server) {
    std::vector<char> buffer(std::size_t{1} << 16);
    bool open = true;
    while (open && !stop_.load()) {
      pollfd fds[2] = {{client, POLLIN, 0}, {server, POLLIN, 0}};
      if (::poll(fds, 2, 100) <= 0) continue;
      for (int i = 0; i < 2 && open; ++i) {
        if ((fds[i].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
        const ssize_t n = ::read(fds[i].fd, buffer.data(), buffer.size());
        if (n <= 0) {
          open = false;
          break;
        }
        if (i == 0) upstream_ += static_cast<std::uint64_t>(n);
        open = send_all(fds[1 - i].fd, buffer.data(), static_cast<std::size_t>(n));
      }
    }
    ::close(client);
    ::close(server);
  }

  const int target_port_;
  int listen_fd_ = -1;
  int port_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> upstream_{0};
  std::thread acceptor_;
  std::vector<std::thread> relays_;  // touched only by the acceptor until it is joined
};

// ---------------------------------------------------------------------------------------------
// The coordinator and its clients.

std::unique_ptr<grpc::ClientContext> call(const std::string& token, double seconds = 60) {
  auto context = std::make_unique<grpc::ClientContext>();
  prism::rpc::add_bearer(*context, token);
  context->set_deadline(std::chrono::system_clock::now() +
                        std::chrono::milliseconds(static_cast<long>(seconds * 1000)));
  return context;
}

absl::Status grpc_error(const std::string& what, const grpc::Status& status) {
  return absl::UnknownError(absl::StrCat(what, ": ", status.error_message(), " (code ",
                                         static_cast<int>(status.error_code()), ")"));
}

struct Coordinator {
  pid_t pid = -1;
  int port = 0;
  int http_port = 0;  // with --http-listen
  std::string address;
  std::unique_ptr<v1::FarmService::Stub> farm;
};

absl::StatusOr<Coordinator> start_coordinator(Children& children, const fs::path& root,
                                              std::vector<std::string> extra = {}) {
  std::vector<std::string> argv = {PRISM_COORDINATOR_BINARY,
                                   "--listen",
                                   "127.0.0.1:0",
                                   "--data-dir",
                                   (root / "data").string(),
                                   "--worker-secret",
                                   kSecret,
                                   "--api-token",
                                   kToken,
                                   "--log-level",
                                   "warn"};
  argv.insert(argv.end(), extra.begin(), extra.end());
  FILE* out = nullptr;
  Coordinator c;
  c.pid = children.spawn(argv, root / "coordinator.log", &out);
  if (c.pid < 0 || out == nullptr) return absl::InternalError("cannot start prism-coordinator");
  char line[512];
  while (std::fgets(line, sizeof(line), out) != nullptr) {
    std::sscanf(line, "serving HTTP on port %d", &c.http_port);
    if (std::sscanf(line, "listening on port %d", &c.port) == 1) break;
  }
  // Keep draining so the coordinator never blocks on a full pipe.
  std::thread([out] {
    char sink[512];
    while (std::fgets(sink, sizeof(sink), out) != nullptr) {
    }
    std::fclose(out);
  }).detach();
  if (c.port <= 0) {
    return absl::InternalError(absl::StrCat("prism-coordinator did not print its port; see ",
                                            (root / "coordinator.log").string()));
  }
  c.address = "127.0.0.1:" + std::to_string(c.port);
  c.farm =
      v1::FarmService::NewStub(grpc::CreateChannel(c.address, grpc::InsecureChannelCredentials()));
  return c;
}

// Uploads a small packed bundle (one message).
absl::Status upload_bundle(Coordinator& c, const std::string& packed) {
  auto context = call(kToken);
  v1::UploadBundleResponse response;
  auto writer = c.farm->UploadBundle(context.get(), &response);
  v1::BundleChunk chunk;
  chunk.set_total_bytes(packed.size());
  chunk.set_data(packed);
  writer->Write(chunk);
  writer->WritesDone();
  const grpc::Status status = writer->Finish();
  if (!status.ok()) return grpc_error("UploadBundle", status);
  return absl::OkStatus();
}

absl::StatusOr<v1::JobInfo> get_job(Coordinator& c, const std::string& job_id) {
  v1::GetJobRequest request;
  request.set_job_id(job_id);
  v1::JobInfo info;
  auto context = call(kToken);
  const grpc::Status status = c.farm->GetJob(context.get(), request, &info);
  if (!status.ok()) return grpc_error("GetJob", status);
  return info;
}

absl::StatusOr<int> worker_count(Coordinator& c) {
  v1::ListWorkersRequest request;
  v1::ListWorkersResponse response;
  auto context = call(kToken);
  const grpc::Status status = c.farm->ListWorkers(context.get(), request, &response);
  if (!status.ok()) return grpc_error("ListWorkers", status);
  int live = 0;
  for (const v1::WorkerInfo& w : response.workers()) live += w.state() != "lost" ? 1 : 0;
  return live;
}

absl::StatusOr<std::vector<float>> spectral_pixels(const fs::path& file) {
  PRISM_ASSIGN_OR_RETURN(image::SpectralExr exr, image::read_spectral_exr(file));
  const auto data = exr.spectral.data();
  return std::vector<float>(data.begin(), data.end());
}

// ---------------------------------------------------------------------------------------------
// overhead

// Where a farm run's wall time went, from the workers' debug logs (one line when a lease is
// acquired, one when its result was accepted, with the render time).
struct Breakdown {
  int tasks = 0;
  double render = 0;    // in the tile renderer, summed over workers
  double per_task = 0;  // acquired to accepted minus render: scene fetch/build, encode, upload
  double between = 0;   // accepted to the next acquired, on the same worker
  double before = 0;    // submit started to each worker's first lease, summed
  double after = 0;     // each worker's last accepted result to the submit's end, summed
};

// Milliseconds since the epoch of the log line's "%Y-%m-%dT%H:%M:%S.%e" local-time prefix.
std::optional<double> log_time_ms(const std::string& line) {
  std::tm tm{};
  int ms = 0;
  if (std::sscanf(line.c_str(), "%d-%d-%dT%d:%d:%d.%d", &tm.tm_year, &tm.tm_mon, &tm.tm_mday,
                  &tm.tm_hour, &tm.tm_min, &tm.tm_sec, &ms) != 7) {
    return std::nullopt;
  }
  tm.tm_year -= 1900;
  tm.tm_mon -= 1;
  tm.tm_isdst = -1;
  return double(std::mktime(&tm)) * 1000.0 + ms;
}

double unix_ms_now() {
  return double(std::chrono::duration_cast<std::chrono::milliseconds>(
                    std::chrono::system_clock::now().time_since_epoch())
                    .count());
}

// Adds one worker's log lines from `offset` on, for a run from `start_ms` to `end_ms`.
void add_worker_log(const fs::path& log, std::uintmax_t offset, double start_ms, double end_ms,
                    Breakdown& b) {
  std::ifstream in(log);
  in.seekg(static_cast<std::streamoff>(offset));
  std::string line;
  double acquired = -1;  // of the lease in progress; -1: none
  std::optional<double> last_done;
  while (std::getline(in, line)) {
    const std::optional<double> t = log_time_ms(line);
    if (!t.has_value()) continue;
    if (line.find("] acquired (attempt ") != std::string::npos) {
      if (!last_done.has_value()) {
        b.before += *t - start_ms;
      } else {
        b.between += *t - *last_done;
      }
      acquired = *t;
    } else if (const std::size_t at = line.find("] completed: "); at != std::string::npos) {
      const std::size_t in_at = line.find(" bytes in ", at);
      if (in_at == std::string::npos || acquired < 0) continue;
      const double render = 1000.0 * std::atof(line.c_str() + in_at + 10);
      b.render += render;
      b.per_task += (*t - acquired) - render;
      ++b.tasks;
      last_done = t;
      acquired = -1;
    }
  }
  if (last_done.has_value()) b.after += end_ms - *last_done;
}

absl::Status run_overhead(const Flags& flags, const fs::path& root) {
  PRISM_ASSIGN_OR_RETURN(auto size, parse_size(flags.get("--resolution", "320x240")));
  PRISM_ASSIGN_OR_RETURN(const double spp, flags.number("--spp", 256, 1, 1 << 20));
  PRISM_ASSIGN_OR_RETURN(const double tile, flags.number("--tile", 32, 4, 1024));
  PRISM_ASSIGN_OR_RETURN(const double repeats, flags.number("--repeats", 2, 1, 100));
  const std::string scene = source_path("scenes/cornell-two-lights.pbrt").string();
  const std::string resolution = absl::StrCat(size.first, "x", size.second);
  const std::vector<std::string> render_flags = {
      "--spp",  std::to_string(int(spp)), "--resolution", resolution, "--seed", "7",
      "--tile", std::to_string(int(tile))};
  fs::create_directories(root);

  Children children;
  PRISM_ASSIGN_OR_RETURN(Coordinator coordinator, start_coordinator(children, root));
  std::vector<pid_t> workers;
  for (int i = 0; i < 2; ++i) {
    workers.push_back(
        children.spawn({PRISM_WORKER_BINARY, "--coordinator", coordinator.address, "--threads", "1",
                        "--secret", kSecret, "--host", absl::StrCat("bench-", i), "--cache-dir",
                        (root / absl::StrCat("cache-", i)).string(), "--log-level", "debug"},
                       root / absl::StrCat("worker-", i, ".log")));
  }
  const Clock::time_point registering = Clock::now();
  while (true) {
    PRISM_ASSIGN_OR_RETURN(const int live, worker_count(coordinator));
    if (live == 2) break;
    if (seconds_since(registering) > 30) {
      return absl::DeadlineExceededError("the two workers did not register within 30 s");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }

  struct Run {
    double render_s = 0, farm_s = 0;
    double render_cpu = 0, coordinator_cpu = 0, worker_cpu = 0, client_cpu = 0;
    double render_wait = 0, worker_wait = 0;  // runqueue waits: time others took from us
    double load = 0;                          // 1-minute load average after the run
    bool identical = false;
    Breakdown breakdown;
    double farm_cpu() const { return coordinator_cpu + worker_cpu + client_cpu; }
  };
  std::vector<Run> runs;
  for (int r = 0; r < int(repeats); ++r) {
    Run run;
    const fs::path render_out = root / absl::StrCat("render-", r, ".exr");
    const fs::path farm_out = root / absl::StrCat("farm-", r, ".exr");
    auto render = [&]() -> absl::Status {
      std::vector<std::string> argv = {PRISM_BINARY,        "render",    scene, "-o",
                                       render_out.string(), "--threads", "2"};
      argv.insert(argv.end(), render_flags.begin(), render_flags.end());
      const Clock::time_point start = Clock::now();
      const pid_t pid = children.spawn(argv, root / "render.log");
      if (!children.wait_ok(pid, &run.render_cpu, &run.render_wait)) {
        return absl::InternalError(
            absl::StrCat("prism render failed; see ", (root / "render.log").string()));
      }
      run.render_s = seconds_since(start);
      return absl::OkStatus();
    };
    auto farm = [&]() -> absl::Status {
      // A fresh client token per run: the same token would return the finished job at once.
      std::vector<std::string> argv = {PRISM_BINARY,
                                       "submit",
                                       scene,
                                       "--coordinator",
                                       coordinator.address,
                                       "--token",
                                       kToken,
                                       "--wait",
                                       "-o",
                                       farm_out.string(),
                                       "--client-token",
                                       absl::StrCat("bench-", ::getpid(), "-", r)};
      argv.insert(argv.end(), render_flags.begin(), render_flags.end());
      const double coordinator_cpu = cpu_seconds(coordinator.pid);
      double worker_cpu = 0, worker_wait = 0;
      for (pid_t w : workers) {
        worker_cpu += cpu_seconds(w);
        worker_wait += runqueue_wait_seconds(w);
      }
      std::vector<std::uintmax_t> offsets;
      for (int i = 0; i < 2; ++i) {
        std::error_code ec;
        offsets.push_back(fs::file_size(root / absl::StrCat("worker-", i, ".log"), ec));
      }
      const double start_ms = unix_ms_now();
      const Clock::time_point start = Clock::now();
      const pid_t pid = children.spawn(argv, root / "submit.log");
      if (!children.wait_ok(pid, &run.client_cpu)) {
        return absl::InternalError(
            absl::StrCat("prism submit failed; see ", (root / "submit.log").string()));
      }
      run.farm_s = seconds_since(start);
      const double end_ms = unix_ms_now();
      for (int i = 0; i < 2; ++i) {
        add_worker_log(root / absl::StrCat("worker-", i, ".log"), offsets[i], start_ms, end_ms,
                       run.breakdown);
      }
      run.coordinator_cpu = cpu_seconds(coordinator.pid) - coordinator_cpu;
      for (pid_t w : workers) run.worker_cpu += cpu_seconds(w);
      run.worker_cpu -= worker_cpu;
      for (pid_t w : workers) run.worker_wait += runqueue_wait_seconds(w);
      run.worker_wait -= worker_wait;
      return absl::OkStatus();
    };
    // Alternate the order so that drifting load on the machine favours neither.
    if (r % 2 == 0) {
      PRISM_RETURN_IF_ERROR(render());
      PRISM_RETURN_IF_ERROR(farm());
    } else {
      PRISM_RETURN_IF_ERROR(farm());
      PRISM_RETURN_IF_ERROR(render());
    }
    PRISM_ASSIGN_OR_RETURN(const std::vector<float> a, spectral_pixels(render_out));
    PRISM_ASSIGN_OR_RETURN(const std::vector<float> b, spectral_pixels(farm_out));
    run.identical = a.size() == b.size() && !a.empty() &&
                    std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
    run.load = load_average();
    std::fprintf(stderr, "%s: overhead run %d: render %.2f s, farm %.2f s, load %.2f\n", kProgram,
                 r + 1, run.render_s, run.farm_s, run.load);
    runs.push_back(run);
  }

  const auto best_render = std::min_element(
      runs.begin(), runs.end(), [](const Run& a, const Run& b) { return a.render_s < b.render_s; });
  const auto best_farm = std::min_element(
      runs.begin(), runs.end(), [](const Run& a, const Run& b) { return a.farm_s < b.farm_s; });
  const bool identical =
      std::all_of(runs.begin(), runs.end(), [](const Run& r) { return r.identical; });
  const int tiles_x = (size.first + int(tile) - 1) / int(tile);
  const int tiles_y = (size.second + int(tile) - 1) / int(tile);
  std::printf(
      "\n### Farm overhead: cornell-two-lights.pbrt, %s, %d spp, %d px tiles (%d tasks), "
      "seed 7\n\n",
      resolution.c_str(), int(spp), int(tile), tiles_x * tiles_y);
  std::printf(
      "| run | render s | farm s | ratio render/farm | render CPU s | farm CPU s "
      "(coordinator + workers + client) | CPU ratio render/farm | render threads' "
      "runqueue wait s | workers' runqueue wait s | load avg | pixels identical |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const Run& run = runs[r];
    std::printf(
        "| %zu | %.2f | %.2f | %.3f | %.2f | %.2f (%.2f + %.2f + %.2f) | %.3f | %.2f | "
        "%.2f | %.2f | %s |\n",
        r + 1, run.render_s, run.farm_s, run.render_s / run.farm_s, run.render_cpu, run.farm_cpu(),
        run.coordinator_cpu, run.worker_cpu, run.client_cpu, run.render_cpu / run.farm_cpu(),
        run.render_wait, run.worker_wait, run.load, run.identical ? "yes" : "NO");
  }
  std::printf("| best | %.2f | %.2f | **%.3f** | | | | | | | %s |\n", best_render->render_s,
              best_farm->farm_s, best_render->render_s / best_farm->farm_s,
              identical ? "yes" : "NO");
  std::printf(
      "\nWhere the farm runs' worker time went (seconds summed over the 2 workers; the "
      "total is 2 x farm s):\n\n");
  std::printf(
      "| run | tasks | rendering | per task: scene, encode, upload | between tasks | "
      "submit to first lease | last result to outputs written |\n");
  std::printf("|---|---|---|---|---|---|---|\n");
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const Breakdown& b = runs[r].breakdown;
    std::printf("| %zu | %d | %.2f | %.2f | %.2f | %.2f | %.2f |\n", r + 1, b.tasks,
                b.render / 1000, b.per_task / 1000, b.between / 1000, b.before / 1000,
                b.after / 1000);
  }
  std::printf(
      "\nrender: `prism render --threads 2`; farm: prism-coordinator + 2 x prism-worker "
      "--threads 1 + `prism submit --wait` (bundle upload to outputs written). Runs "
      "alternate which goes first; the load average shows how busy the shared machine "
      "was.\n");
  std::fflush(stdout);
  for (pid_t w : workers) children.stop(w);
  children.stop(coordinator.pid);
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// capacity

const char kCapacityScene[] = R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 30
Film "spectral" "integer xresolution" 64 "integer yresolution" 64 "integer nbuckets" 16
Sampler "zsobol" "integer pixelsamples" 1
Integrator "volpath" "integer maxdepth" 5
WorldBegin
LightSource "infinite" "spectrum L" [360 1 830 1] "float scale" 1
AttributeBegin
  Material "diffuse" "float reflectance" 0.5
  Shape "sphere" "float radius" 0.8
AttributeEnd
)";

// Offsets of the rect and sample range in the tile codec's header (tile_codec.h).
constexpr std::size_t kRectOffset = 16;
constexpr std::size_t kSamplesOffset = 32;

// A template result's bytes made the result of `rect` and `samples`.
void retarget(std::string& bytes, const image::TileRect& rect, const image::SampleRange& samples) {
  base::put_le(bytes.data() + kRectOffset + 0, static_cast<std::uint32_t>(rect.x0), 4);
  base::put_le(bytes.data() + kRectOffset + 4, static_cast<std::uint32_t>(rect.y0), 4);
  base::put_le(bytes.data() + kRectOffset + 8, static_cast<std::uint32_t>(rect.x1), 4);
  base::put_le(bytes.data() + kRectOffset + 12, static_cast<std::uint32_t>(rect.y1), 4);
  base::put_le(bytes.data() + kSamplesOffset + 0, samples.s0, 8);
  base::put_le(bytes.data() + kSamplesOffset + 8, samples.s1, 8);
}

// Task results of one tile shape: a constant TileResult, encoded once; per task only the rect
// and sample range are rewritten.
class ResultFactory {
 public:
  // `float64`: sums that are not float32 values, so the codec keeps them as doubles (what every
  // result was before workers rounded their sums).
  explicit ResultFactory(int bins, bool float64 = false) : bins_(bins), float64_(float64) {}

  // The bytes for `rect` x `samples` (the template of the rect's shape, patched).
  absl::StatusOr<std::string> bytes(const image::TileRect& rect,
                                    const image::SampleRange& samples) {
    const std::pair<int, int> shape{rect.width(), rect.height()};
    auto it = templates_.find(shape);
    if (it == templates_.end()) {
      // With the RGB sums every final-pass result carries (the coordinator refuses one
      // without them).
      image::TileBuffers buffers;
      buffers.rgb = true;
      PRISM_ASSIGN_OR_RETURN(image::TileResult result,
                             image::TileResult::create({0, 0, shape.first, shape.second},
                                                       {0, samples.count()}, bins_, buffers));
      const double scale = float64_ ? 1.0 + std::ldexp(1.0, -40) : 1.0;
      for (double& v : result.mutable_rgb_sums()) v = 0.5 * double(samples.count()) * scale;
      for (double& v : result.mutable_sums()) v = 0.5 * double(samples.count()) * scale;
      for (double& v : result.mutable_sum_squares()) v = 0.25 * double(samples.count()) * scale;
      for (std::uint64_t& n : result.mutable_counts()) n = samples.count();
      it = templates_.emplace(shape, image::serialise_tile(result)).first;
    }
    std::string out = it->second;
    retarget(out, rect, samples);
    return out;
  }

 private:
  int bins_;
  bool float64_;
  std::map<std::pair<int, int>, std::string> templates_;
};

using TaskKey = std::array<std::int64_t, 6>;
TaskKey key_of(const image::TileRect& r, const image::SampleRange& s) {
  return {r.x0, r.y0, r.x1, r.y1, static_cast<std::int64_t>(s.s0), static_cast<std::int64_t>(s.s1)};
}

// The synthetic workers' kind of job: kCapacityScene at `size`, 1 spp, in `tile` px tiles.
v1::SubmitJobRequest one_spp_job(const std::string& bundle_hash, std::pair<int, int> size, int bins,
                                 int tile, std::uint64_t seed) {
  v1::SubmitJobRequest request;
  v1::JobSpec& spec = *request.mutable_spec();
  spec.set_bundle_hash(bundle_hash);
  spec.set_scene_path("scene.pbrt");
  spec.set_width(size.first);
  spec.set_height(size.second);
  spec.set_bins(bins);
  spec.set_tile_size(tile);
  spec.set_spp(1);
  spec.set_seed(seed);
  return request;
}

struct CapacityShared {
  int total_tasks = 0;
  int bins = 0;
  std::map<std::pair<int, int>, std::string> templates;  // read-only once the clock starts
  std::map<TaskKey, std::string> sha;                    // read-only once the clock starts
  pid_t coordinator_pid = -1;
  std::atomic<bool> stop{false};
  std::atomic<int> registered{0};
  std::atomic<int> completed{0};
  std::atomic<std::uint64_t> heartbeats{0};
  std::atomic<std::uint64_t> acquires{0};
  std::atomic<std::uint64_t> hash_misses{0};
  std::atomic<std::uint64_t> errors{0};
  std::mutex mutex;  // guards the marks below and first_error
  std::optional<Clock::time_point> first_lease;
  Clock::time_point at10, at90, last;
  double cpu10 = 0, cpu90 = 0, cpu_last = 0;
  std::string first_error;
};

void note_error(CapacityShared& shared, const std::string& what) {
  ++shared.errors;
  std::lock_guard<std::mutex> lock(shared.mutex);
  if (shared.first_error.empty()) shared.first_error = what;
}

// CompleteTask as the real worker streams it (worker_client.cpp): 1 MiB chunks, the ids on
// the first, the SHA-256 on the last.
grpc::Status send_result(v1::WorkerService::Stub& stub, const std::string& worker_id,
                         const std::string& lease_id, const std::string& bytes,
                         const std::string& sha, bool* accepted) {
  auto context = call(kSecret);
  v1::CompleteTaskResponse done;
  auto writer = stub.CompleteTask(context.get(), &done);
  prism::rpc::ResultUploadHeader header;
  header.worker_id = worker_id;
  header.lease_id = lease_id;
  header.render_seconds = 0.5;  // the real worker's statistics, for the same size
  header.rays = 1000000;
  header.sha256 = sha;
  grpc::Status status = prism::rpc::upload_result(*writer, header, bytes);
  *accepted = done.accepted();
  return status;
}

void synthetic_worker(int index, std::shared_ptr<grpc::Channel> channel, CapacityShared& shared) {
  auto stub = v1::WorkerService::NewStub(channel);
  std::string worker_id;
  std::uint32_t heartbeat_ms = 1000;
  {
    v1::RegisterRequest request;
    request.set_host(absl::StrCat("synthetic-", index));
    request.set_threads(1);
    v1::RegisterResponse response;
    auto context = call(kSecret);
    const grpc::Status status = stub->Register(context.get(), request, &response);
    ++shared.registered;
    if (!status.ok()) {
      note_error(shared, absl::StrCat("Register: ", status.error_message()));
      return;
    }
    worker_id = response.worker_id();
    heartbeat_ms = std::max<std::uint32_t>(response.heartbeat_interval_ms(), 10);
  }
  Clock::time_point last_beat = Clock::now();
  std::string bytes;
  while (!shared.stop.load()) {
    if (Clock::now() - last_beat >= std::chrono::milliseconds(heartbeat_ms)) {
      v1::HeartbeatRequest beat;
      beat.set_worker_id(worker_id);
      v1::HeartbeatResponse reply;
      auto context = call(kSecret);
      const grpc::Status status = stub->Heartbeat(context.get(), beat, &reply);
      if (!status.ok()) note_error(shared, absl::StrCat("Heartbeat: ", status.error_message()));
      ++shared.heartbeats;
      last_beat = Clock::now();
    }
    v1::AcquireTaskRequest request;
    request.set_worker_id(worker_id);
    // Short enough that the heartbeat above is never late.
    request.set_wait_ms(std::min<std::uint32_t>(500, heartbeat_ms / 2));
    v1::AcquireTaskResponse response;
    {
      auto context = call(kSecret);
      const grpc::Status status = stub->AcquireTask(context.get(), request, &response);
      ++shared.acquires;
      if (!status.ok()) {
        note_error(shared, absl::StrCat("AcquireTask: ", status.error_message()));
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
        continue;
      }
    }
    if (!response.has_lease()) continue;
    {
      std::lock_guard<std::mutex> lock(shared.mutex);
      if (!shared.first_lease.has_value()) shared.first_lease = Clock::now();
    }
    const v1::Lease& lease = response.lease();
    const v1::TileRect& t = lease.task().tile();
    const image::TileRect rect{t.x0(), t.y0(), t.x1(), t.y1()};
    const image::SampleRange samples{lease.task().samples().begin(), lease.task().samples().end()};
    auto it = shared.templates.find({rect.width(), rect.height()});
    if (it == shared.templates.end()) {
      note_error(shared,
                 absl::StrCat("no template for a ", rect.width(), "x", rect.height(), " tile"));
      continue;
    }
    bytes = it->second;
    retarget(bytes, rect, samples);
    std::string sha;
    if (auto h = shared.sha.find(key_of(rect, samples)); h != shared.sha.end()) {
      sha = h->second;
    } else {
      ++shared.hash_misses;
      sha = base::sha256_hex(bytes);
    }
    bool accepted = false;
    const grpc::Status status =
        send_result(*stub, worker_id, lease.lease_id(), bytes, sha, &accepted);
    if (!status.ok() || !accepted) {
      note_error(shared, absl::StrCat("CompleteTask: ",
                                      status.ok() ? "not accepted" : status.error_message()));
      continue;
    }
    const int n = ++shared.completed;
    const int at10 = std::max(1, shared.total_tasks / 10);
    const int at90 = std::max(at10 + 1, shared.total_tasks * 9 / 10);
    if (n == at10 || n == at90 || n == shared.total_tasks) {
      const double cpu = cpu_seconds(shared.coordinator_pid);
      std::lock_guard<std::mutex> lock(shared.mutex);
      if (n == at10) {
        shared.at10 = Clock::now();
        shared.cpu10 = cpu;
      }
      if (n == at90) {
        shared.at90 = Clock::now();
        shared.cpu90 = cpu;
      }
      if (n == shared.total_tasks) {
        shared.last = Clock::now();
        shared.cpu_last = cpu;
      }
    }
  }
}

// One capacity job, with results whose sums the codec keeps as float32 or (`float64`) as doubles;
// prints its row of the table.
absl::Status run_capacity_once(const Flags& flags, const fs::path& root, bool float64) {
  PRISM_ASSIGN_OR_RETURN(const double workers, flags.number("--workers", 100, 1, 10000));
  PRISM_ASSIGN_OR_RETURN(const double channels, flags.number("--channels", workers, 1, 10000));
  PRISM_ASSIGN_OR_RETURN(auto size, parse_size(flags.get("--capacity-resolution", "1024x1024")));
  PRISM_ASSIGN_OR_RETURN(const double tile, flags.number("--capacity-tile", 16, 4, 1024));
  PRISM_ASSIGN_OR_RETURN(const double bins, flags.number("--capacity-bins", 16, 4, 256));
  fs::create_directories(root / "scene");
  std::ofstream(root / "scene" / "scene.pbrt", std::ios::binary) << kCapacityScene;
  PRISM_ASSIGN_OR_RETURN(scene::Bundle bundle,
                         scene::make_bundle(root / "scene", "scene.pbrt", {}));
  const std::string packed = scene::pack(bundle);

  Children children;
  PRISM_ASSIGN_OR_RETURN(Coordinator coordinator, start_coordinator(children, root));
  PRISM_RETURN_IF_ERROR(upload_bundle(coordinator, packed));

  // Precompute: one template per tile shape, the SHA-256 of every task of the plan (tiles of
  // `tile` pixels, one sample range [0, 1)).
  CapacityShared shared;
  shared.coordinator_pid = coordinator.pid;
  shared.bins = int(bins);
  ResultFactory factory{static_cast<int>(bins), float64};
  const int t = int(tile);
  for (int y = 0; y < size.second; y += t) {
    for (int x = 0; x < size.first; x += t) {
      const image::TileRect rect{x, y, std::min(x + t, size.first), std::min(y + t, size.second)};
      const image::SampleRange samples{0, 1};
      PRISM_ASSIGN_OR_RETURN(std::string bytes, factory.bytes(rect, samples));
      shared.sha[key_of(rect, samples)] = base::sha256_hex(bytes);
      std::pair<int, int> shape{rect.width(), rect.height()};
      if (!shared.templates.contains(shape)) {
        // The patched bytes parse back to exactly this task: the offsets above are right.
        PRISM_ASSIGN_OR_RETURN(image::TileResult parsed, image::parse_tile(bytes));
        if (!(parsed.rect() == rect) || !(parsed.samples() == samples)) {
          return absl::InternalError("the patched tile header does not round-trip");
        }
        shared.templates[shape] = bytes;
      }
    }
  }
  shared.total_tasks = static_cast<int>(shared.sha.size());
  const std::size_t result_bytes = shared.templates.begin()->second.size();

  std::vector<std::shared_ptr<grpc::Channel>> pool;
  for (int i = 0; i < int(channels); ++i) {
    grpc::ChannelArguments args;
    args.SetInt("bench.channel", i);  // distinct arguments: a connection per channel
    pool.push_back(
        grpc::CreateCustomChannel(coordinator.address, grpc::InsecureChannelCredentials(), args));
  }
  std::vector<std::thread> threads;
  for (int i = 0; i < int(workers); ++i) {
    threads.emplace_back(synthetic_worker, i, pool[i % pool.size()], std::ref(shared));
  }
  while (shared.registered.load() < int(workers)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  const double rss_idle = status_mib(coordinator.pid, "VmRSS:");
  const double self_cpu0 = self_cpu_seconds();
  const double cpu0 = cpu_seconds(coordinator.pid);
  const Clock::time_point submitted = Clock::now();
  std::string job_id;
  {
    const v1::SubmitJobRequest request = one_spp_job(bundle.content_hash, size, int(bins), t, 1);
    v1::SubmitJobResponse response;
    auto context = call(kToken);
    const grpc::Status status = coordinator.farm->SubmitJob(context.get(), request, &response);
    if (!status.ok()) {
      shared.stop = true;
      for (std::thread& th : threads) th.join();
      return grpc_error("SubmitJob", status);
    }
    job_id = response.job().job_id();
    if (response.job().progress().tasks_total() != std::uint64_t(shared.total_tasks)) {
      shared.stop = true;
      for (std::thread& th : threads) th.join();
      return absl::InternalError(absl::StrCat("the job has ",
                                              response.job().progress().tasks_total(),
                                              " tasks, the bench planned ", shared.total_tasks));
    }
  }
  const double submit_s = seconds_since(submitted);
  v1::JobInfo info;
  while (true) {
    PRISM_ASSIGN_OR_RETURN(info, get_job(coordinator, job_id));
    if (info.state() == v1::JOB_STATE_DONE || info.state() == v1::JOB_STATE_FAILED ||
        info.state() == v1::JOB_STATE_CANCELLED) {
      break;
    }
    if (seconds_since(submitted) > 600) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  const double done_s = seconds_since(submitted);
  const double cpu_done = cpu_seconds(coordinator.pid);
  const double hwm = status_mib(coordinator.pid, "VmHWM:");
  shared.stop = true;
  for (std::thread& th : threads) th.join();
  const double self_cpu = self_cpu_seconds() - self_cpu0;
  children.stop(coordinator.pid);
  if (info.state() != v1::JOB_STATE_DONE) {
    return absl::InternalError(absl::StrCat("the capacity job ended ",
                                            v1::JobState_Name(info.state()), ": ", info.error(),
                                            " (first worker error: ", shared.first_error, ")"));
  }

  const int n = shared.total_tasks;
  const int n10 = std::max(1, n / 10);
  const int n90 = std::max(n10 + 1, n * 9 / 10);
  const double steady_s = std::chrono::duration<double>(shared.at90 - shared.at10).count();
  const double steady_rate = double(n90 - n10) / steady_s;
  const double steady_cpu_per_1000 = (shared.cpu90 - shared.cpu10) / double(n90 - n10) * 1000.0;
  const double whole_s = std::chrono::duration<double>(shared.last - *shared.first_lease).count();
  std::printf(
      "| %s | %d | %d | %dx%d, %d px tiles, %d bins, 1 spp | %d | %zu | %.0f | %.3f | %.0f | "
      "%.3f | %.2f | %.2f | %.0f (%.0f) | %.1f | %llu | %llu |\n",
      float64 ? "float64" : "float32", int(workers), int(channels), size.first, size.second, t,
      int(bins), n, result_bytes, steady_rate, steady_cpu_per_1000, double(n) / whole_s,
      (cpu_done - cpu0) / n * 1000.0, submit_s,
      done_s - std::chrono::duration<double>(shared.last - submitted).count(), hwm, rss_idle,
      self_cpu, static_cast<unsigned long long>(shared.heartbeats.load()),
      static_cast<unsigned long long>(shared.errors.load()));
  if (shared.errors.load() > 0) {
    std::printf("first error: %s\n", shared.first_error.c_str());
  }
  if (shared.hash_misses.load() > 0) {
    std::printf("%llu hashes computed after the clock started\n",
                static_cast<unsigned long long>(shared.hash_misses.load()));
  }
  std::fflush(stdout);
  return absl::OkStatus();
}

// Capacity with float32 sums (what workers send) and with float64 sums (what they sent before),
// alternately, `--capacity-repeats` times each: the bytes' share of the coordinator's cost,
// measured side by side.
absl::Status run_capacity(const Flags& flags, const fs::path& root) {
  PRISM_ASSIGN_OR_RETURN(const double repeats, flags.number("--capacity-repeats", 1, 1, 20));
  std::printf("\n### Coordinator capacity\n\n");
  std::printf(
      "| sums | workers | channels | job | tasks | result bytes | completions/s (10-90 %%) | "
      "coordinator CPU s / 1000 (10-90 %%) | completions/s (first lease to last) | "
      "coordinator CPU s / 1000 (submit to DONE) | submit s | last completion to DONE seen s | "
      "peak RSS MiB (idle RSS) | bench CPU s | heartbeats | errors |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  std::fflush(stdout);
  for (int r = 0; r < int(repeats); ++r) {
    for (bool float64 : {false, true}) {
      PRISM_RETURN_IF_ERROR(run_capacity_once(
          flags, root / absl::StrCat(float64 ? "float64-" : "float32-", r), float64));
    }
  }
  std::printf(
      "\ncoordinator CPU: utime+stime from /proc/<pid>/stat; peak RSS: VmHWM; DONE is "
      "polled every 20 ms. bench CPU: the synthetic workers' own cost, on the same 2 cores. "
      "sums: how the results' sums were encoded (float64: values that are not float32, as "
      "every result was before workers rounded them).\n");
  std::fflush(stdout);
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// load

// Latencies of one kind of API request, in milliseconds.
struct Latencies {
  std::vector<double> ms;
  std::uint64_t errors = 0;
  double quantile(double q) const {
    if (ms.empty()) return 0;
    std::vector<double> sorted = ms;
    std::sort(sorted.begin(), sorted.end());
    return sorted[std::min(sorted.size() - 1, std::size_t(q * double(sorted.size())))];
  }
};

absl::Status run_load(const Flags& flags, const fs::path& root) {
  PRISM_ASSIGN_OR_RETURN(const double workers, flags.number("--workers", 100, 1, 10000));
  PRISM_ASSIGN_OR_RETURN(const double queued, flags.number("--load-jobs", 200, 1, 1000));
  PRISM_ASSIGN_OR_RETURN(const double seconds, flags.number("--load-seconds", 1800, 10, 86400));
  PRISM_ASSIGN_OR_RETURN(auto size, parse_size(flags.get("--load-resolution", "128x128")));
  constexpr int kTile = 16, kBins = 16;
  fs::create_directories(root / "scene");
  std::ofstream(root / "scene" / "scene.pbrt", std::ios::binary) << kCapacityScene;
  PRISM_ASSIGN_OR_RETURN(scene::Bundle bundle,
                         scene::make_bundle(root / "scene", "scene.pbrt", {}));
  Children children;
  PRISM_ASSIGN_OR_RETURN(Coordinator coordinator, start_coordinator(children, root,
                                                                    {"--http-listen", "127.0.0.1:0",
                                                                     "--max-queued-jobs", "1000"}));
  if (coordinator.http_port <= 0) return absl::InternalError("no HTTP port");
  PRISM_RETURN_IF_ERROR(upload_bundle(coordinator, scene::pack(bundle)));

  // Synthetic workers as in `capacity`; results are hashed as they are sent.
  CapacityShared shared;
  shared.coordinator_pid = coordinator.pid;
  shared.bins = kBins;
  shared.total_tasks = std::numeric_limits<int>::max();  // no 10/90 % marks
  ResultFactory factory{kBins};
  for (int w : {kTile, size.first % kTile}) {
    for (int h : {kTile, size.second % kTile}) {
      if (w == 0 || h == 0) continue;
      PRISM_ASSIGN_OR_RETURN(std::string bytes, factory.bytes({0, 0, w, h}, {0, 1}));
      shared.templates[{w, h}] = bytes;
    }
  }
  std::vector<std::thread> threads;
  auto channel = grpc::CreateChannel(coordinator.address, grpc::InsecureChannelCredentials());
  for (int i = 0; i < int(workers); ++i)
    threads.emplace_back(synthetic_worker, i, channel, std::ref(shared));

  std::vector<std::string> submitted;
  auto submit = [&]() -> absl::Status {
    v1::SubmitJobRequest request =
        one_spp_job(bundle.content_hash, size, kBins, kTile, submitted.size() + 1);
    request.set_client_token(absl::StrCat("load-", submitted.size()));
    v1::SubmitJobResponse response;
    auto context = call(kToken);
    const grpc::Status status = coordinator.farm->SubmitJob(context.get(), request, &response);
    if (!status.ok()) return grpc_error("SubmitJob", status);
    submitted.push_back(response.job().job_id());
    return absl::OkStatus();
  };
  auto unfinished = [&]() -> absl::StatusOr<int> {
    v1::ListJobsRequest request;
    for (v1::JobState s : {v1::JOB_STATE_QUEUED, v1::JOB_STATE_PREPASS, v1::JOB_STATE_RENDERING,
                           v1::JOB_STATE_FINALISING})
      request.add_states(s);
    v1::ListJobsResponse response;
    auto context = call(kToken);
    const grpc::Status status = coordinator.farm->ListJobs(context.get(), request, &response);
    if (!status.ok()) return grpc_error("ListJobs", status);
    return response.jobs_size();
  };

  // API clients: a steady mix of HTTP requests, 20 per second, timed.
  std::map<std::string, Latencies> latencies;
  std::mutex latency_mutex;
  std::atomic<bool> stop_api{false};
  std::thread api([&] {
    httplib::Client http("127.0.0.1", coordinator.http_port);
    http.set_read_timeout(30, 0);
    const httplib::Headers auth = {{"Authorization", std::string("Bearer ") + kToken}};
    int i = 0;
    while (!stop_api.load()) {
      std::string kind, path;
      switch (i++ % 4) {
        case 0:
          kind = "GET /api/v1/jobs?limit=20";
          path = "/api/v1/jobs?limit=20";
          break;
        case 1: {
          kind = "GET /api/v1/jobs/{id}";
          std::lock_guard<std::mutex> lock(latency_mutex);
          // The newest job (the lists first, until one is submitted).
          path = submitted.empty() ? "/api/v1/jobs?limit=20" : "/api/v1/jobs/" + submitted.back();
          if (submitted.empty()) kind = "GET /api/v1/jobs?limit=20";
          break;
        }
        case 2:
          kind = "GET /api/v1/workers";
          path = "/api/v1/workers";
          break;
        default:
          kind = "GET /metrics";
          path = "/metrics";
          break;
      }
      const Clock::time_point start = Clock::now();
      auto result = http.Get(path, auth);
      const double ms = seconds_since(start) * 1000.0;
      std::lock_guard<std::mutex> lock(latency_mutex);
      Latencies& l = latencies[kind];
      if (!result || result->status != 200)
        ++l.errors;
      else
        l.ms.push_back(ms);
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  });

  struct Sample {
    double t, rss_mib, cpu_s;
    int done, unfinished;
  };
  std::vector<Sample> samples;
  const Clock::time_point start = Clock::now();
  const double cpu0 = cpu_seconds(coordinator.pid);
  absl::Status failed;
  double next_sample = 0;
  while (seconds_since(start) < seconds && failed.ok()) {
    absl::StatusOr<int> open = unfinished();
    if (!open.ok()) {
      failed = open.status();
      break;
    }
    int now_open = *open;
    for (; now_open < int(queued) && failed.ok(); ++now_open) {
      std::lock_guard<std::mutex> lock(latency_mutex);
      failed = submit();
    }
    if (seconds_since(start) >= next_sample) {
      samples.push_back({seconds_since(start), status_mib(coordinator.pid, "VmRSS:"),
                         cpu_seconds(coordinator.pid) - cpu0, int(submitted.size()) - now_open,
                         now_open});
      next_sample += std::max(10.0, seconds / 30);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
  stop_api = true;
  api.join();
  shared.stop = true;
  for (std::thread& th : threads) th.join();
  PRISM_RETURN_IF_ERROR(failed);

  // Every job submitted is done or still in the queue; none failed, vanished or was cancelled.
  std::map<v1::JobState, int> states;
  int lost = 0;
  for (const std::string& id : submitted) {
    absl::StatusOr<v1::JobInfo> info = get_job(coordinator, id);
    if (!info.ok()) {
      ++lost;
      continue;
    }
    ++states[info->state()];
    if (info->state() == v1::JOB_STATE_FAILED || info->state() == v1::JOB_STATE_CANCELLED) ++lost;
  }
  const double hwm = status_mib(coordinator.pid, "VmHWM:");
  children.stop(coordinator.pid);

  std::printf("\n### Load: %d queued jobs, %d synthetic workers, %.0f s\n\n", int(queued),
              int(workers), seconds);
  std::printf(
      "Jobs of %dx%d, %d px tiles, %d bins, 1 spp (%d tasks each). Submitted %zu, done %d, "
      "unfinished %d, **lost %d** (failed, cancelled or missing). Coordinator peak RSS "
      "(VmHWM) %.0f MiB.\n\n",
      size.first, size.second, kTile, kBins,
      ((size.first + kTile - 1) / kTile) * ((size.second + kTile - 1) / kTile), submitted.size(),
      states[v1::JOB_STATE_DONE], int(submitted.size()) - states[v1::JOB_STATE_DONE] - lost, lost,
      hwm);
  std::printf(
      "| time s | coordinator RSS MiB | coordinator CPU s | jobs done | jobs unfinished |\n");
  std::printf("|---|---|---|---|---|\n");
  for (const Sample& s : samples)
    std::printf("| %.0f | %.0f | %.0f | %d | %d |\n", s.t, s.rss_mib, s.cpu_s, s.done,
                s.unfinished);
  std::printf(
      "\n| API request (20/s in all, one client) | n | p50 ms | p99 ms | max ms | errors |\n");
  std::printf("|---|---|---|---|---|---|\n");
  for (const auto& [kind, l] : latencies) {
    std::printf("| %s | %zu | %.1f | %.1f | %.1f | %llu |\n", kind.c_str(), l.ms.size(),
                l.quantile(0.5), l.quantile(0.99), l.quantile(1.0),
                static_cast<unsigned long long>(l.errors));
  }
  std::printf("\n%llu task results sent by the synthetic workers, %llu worker errors%s%s\n",
              static_cast<unsigned long long>(shared.completed.load()),
              static_cast<unsigned long long>(shared.errors.load()),
              shared.first_error.empty() ? "" : "; first: ", shared.first_error.c_str());
  std::fflush(stdout);
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// wire

struct WireSize {
  std::uint64_t codec = 0;
  std::uint64_t grpc = 0;  // serialised ResultUpload messages + 5-byte gRPC prefixes
};

// The CompleteTask stream the worker sends for `bytes` (worker_client.cpp).
WireSize wire_size(const std::string& bytes) {
  WireSize size;
  size.codec = bytes.size();
  const std::vector<std::string_view> chunks = prism::rpc::split_chunks(bytes);
  std::uint64_t offset = 0;
  const std::string sha = base::sha256_hex(bytes);
  for (std::size_t i = 0; i < chunks.size(); ++i) {
    v1::ResultUpload upload;
    if (i == 0) {
      upload.set_worker_id("w-000001");
      upload.set_lease_id("l-123456");
    }
    upload.set_offset(offset);
    upload.set_data(std::string(chunks[i]));
    upload.set_total_bytes(bytes.size());
    if (i + 1 == chunks.size()) {
      upload.set_last(true);
      upload.set_sha256(sha);
      upload.set_render_seconds(0.5);
      upload.set_rays(1000000);
    }
    offset += chunks[i].size();
    size.grpc += upload.ByteSizeLong() + 5;
  }
  return size;
}

// The TCP bytes of real CompleteTask calls: a prism-coordinator, one job of one `tile` x `tile`
// task per bin count, and a worker whose channel goes through a CountingProxy. The result is
// the constant TileResult of the capacity measurement (sums, squares and counts: what the
// coordinator accepts for a final-pass task today).
absl::Status measure_wire(int tile, const fs::path& root) {
  fs::create_directories(root / "scene");
  std::ofstream(root / "scene" / "scene.pbrt", std::ios::binary) << kCapacityScene;
  PRISM_ASSIGN_OR_RETURN(scene::Bundle bundle,
                         scene::make_bundle(root / "scene", "scene.pbrt", {}));
  Children children;
  PRISM_ASSIGN_OR_RETURN(Coordinator coordinator, start_coordinator(children, root));
  PRISM_RETURN_IF_ERROR(upload_bundle(coordinator, scene::pack(bundle)));
  PRISM_ASSIGN_OR_RETURN(std::unique_ptr<CountingProxy> proxy,
                         CountingProxy::start(coordinator.port));
  struct Row {
    int bins = 0;
    std::uint64_t codec = 0, grpc = 0, tcp = 0;
  };
  std::vector<Row> rows;
  {
    auto stub = v1::WorkerService::NewStub(grpc::CreateChannel(
        "127.0.0.1:" + std::to_string(proxy->port()), grpc::InsecureChannelCredentials()));
    std::string worker_id;
    {
      v1::RegisterRequest request;
      request.set_host("wire");
      request.set_threads(1);
      v1::RegisterResponse response;
      auto context = call(kSecret);
      const grpc::Status status = stub->Register(context.get(), request, &response);
      if (!status.ok()) return grpc_error("Register", status);
      worker_id = response.worker_id();
    }
    for (int bins : {16, 64, 256}) {
      v1::SubmitJobRequest submit;
      v1::JobSpec& spec = *submit.mutable_spec();
      spec.set_bundle_hash(bundle.content_hash);
      spec.set_scene_path("scene.pbrt");
      spec.set_width(tile);
      spec.set_height(tile);
      spec.set_tile_size(tile);
      spec.set_bins(bins);
      spec.set_spp(1);
      v1::SubmitJobResponse submitted;
      {
        auto context = call(kToken);
        const grpc::Status status = coordinator.farm->SubmitJob(context.get(), submit, &submitted);
        if (!status.ok()) return grpc_error("SubmitJob", status);
      }
      v1::AcquireTaskRequest request;
      request.set_worker_id(worker_id);
      request.set_wait_ms(5000);
      v1::AcquireTaskResponse response;
      {
        auto context = call(kSecret);
        const grpc::Status status = stub->AcquireTask(context.get(), request, &response);
        if (!status.ok()) return grpc_error("AcquireTask", status);
      }
      if (!response.has_lease() || response.lease().task().job_id() != submitted.job().job_id()) {
        return absl::InternalError("the wire job's task was not leased to the measuring worker");
      }
      const v1::Lease& lease = response.lease();
      const v1::TileRect& t = lease.task().tile();
      ResultFactory factory{bins};
      PRISM_ASSIGN_OR_RETURN(std::string bytes, factory.bytes({t.x0(), t.y0(), t.x1(), t.y1()},
                                                              {lease.task().samples().begin(),
                                                               lease.task().samples().end()}));
      const std::string sha = base::sha256_hex(bytes);
      const std::uint64_t before = proxy->upstream();
      bool accepted = false;
      const grpc::Status status =
          send_result(*stub, worker_id, lease.lease_id(), bytes, sha, &accepted);
      if (!status.ok() || !accepted) {
        return absl::InternalError(
            absl::StrCat("CompleteTask: ", status.ok() ? "not accepted" : status.error_message()));
      }
      rows.push_back({bins, bytes.size(), wire_size(bytes).grpc, proxy->upstream() - before});
    }
  }
  const double pixels = double(tile) * tile;
  std::printf(
      "\nMeasured on the wire: TCP bytes from the worker to the coordinator during one "
      "CompleteTask call (through a counting loopback relay), one %dx%d task:\n\n",
      tile, tile);
  std::printf(
      "| bins | codec bytes | gRPC bytes (computed) | TCP bytes (measured) | TCP B/px/bin | "
      "TCP over codec |\n");
  std::printf("|---|---|---|---|---|---|\n");
  for (const Row& r : rows) {
    std::printf("| %d | %llu | %llu | %llu | %.3f | +%.3f %% |\n", r.bins,
                static_cast<unsigned long long>(r.codec), static_cast<unsigned long long>(r.grpc),
                static_cast<unsigned long long>(r.tcp), double(r.tcp) / (pixels * r.bins),
                100.0 * (double(r.tcp) / double(r.codec) - 1.0));
  }
  std::fflush(stdout);
  proxy.reset();
  children.stop(coordinator.pid);
  return absl::OkStatus();
}

absl::Status run_wire(const Flags& flags, const fs::path& root) {
  PRISM_ASSIGN_OR_RETURN(const double tile_d, flags.number("--wire-tile", 32, 4, 1024));
  const int tile = int(tile_d);
  const image::TileRect rect{0, 0, tile, tile};
  const image::SampleRange samples{0, 64};
  const double pixels = double(rect.area());
  std::printf("\n### Bytes on the wire per pixel per bin (one %dx%d task)\n\n", tile, tile);
  std::printf("| bins | buffers | codec bytes | codec B/px/bin | gRPC bytes | gRPC B/px/bin |\n");
  std::printf("|---|---|---|---|---|---|\n");
  std::uint64_t synthetic_64 = 0;
  for (int bins : {16, 64, 256}) {
    for (int b = 0; b < 4; ++b) {
      image::TileBuffers buffers;
      buffers.gradients = (b & 1) != 0;
      buffers.guides = (b & 2) != 0;
      PRISM_ASSIGN_OR_RETURN(image::TileResult result,
                             image::TileResult::create(rect, samples, bins, buffers));
      const std::string bytes = image::serialise_tile(result);
      if (bins == 64 && b == 0) synthetic_64 = bytes.size();
      const WireSize size = wire_size(bytes);
      const char* names[] = {"sums, squares, counts", "+ gradients", "+ guides",
                             "+ gradients + guides"};
      const double per = pixels * bins;
      std::printf("| %d | %s | %llu | %.2f | %llu | %.2f |\n", bins, names[b],
                  static_cast<unsigned long long>(size.codec), double(size.codec) / per,
                  static_cast<unsigned long long>(size.grpc), double(size.grpc) / per);
    }
  }

  // A real task: the Cornell box's top-left tile at 64 bins, 4 samples, as a worker renders it.
  PRISM_ASSIGN_OR_RETURN(LoadedBenchScene scene,
                         load_bench_scene(source_path("scenes/cornell-two-lights.pbrt")));
  worker::EmbreeDevice device;
  job::RenderOptions options;
  options.bins = 64;
  options.max_depth = scene.description.integrator.max_depth;
  options.seed = 7;
  PRISM_ASSIGN_OR_RETURN(
      std::unique_ptr<worker::RenderScene> render_scene,
      worker::RenderScene::build(device, scene.description, *scene.library, options, 256, 256));
  worker::TileRenderer renderer(*render_scene);
  worker::RenderTask task;
  task.tile = rect;
  task.samples = {0, 4};
  worker::TileStats stats;
  PRISM_ASSIGN_OR_RETURN(image::TileResult real, renderer.render(task, &stats));
  const std::string real_bytes = image::serialise_task_result(std::move(real));
  const WireSize real_size = wire_size(real_bytes);
  std::printf(
      "\nA real rendered task (cornell-two-lights, %dx%d tile, 64 bins, 4 spp): %llu codec "
      "bytes (%.2f B/px/bin), %llu gRPC bytes; the synthetic 64-bin row: %llu codec bytes "
      "(%s: the codec does not compress, so the size is a function of the shape).\n",
      tile, tile, static_cast<unsigned long long>(real_size.codec),
      double(real_size.codec) / (pixels * 64), static_cast<unsigned long long>(real_size.grpc),
      static_cast<unsigned long long>(synthetic_64),
      real_size.codec == synthetic_64 ? "the same" : "DIFFERENT");
  std::fflush(stdout);
  return measure_wire(tile, root);
}

int run(int argc, char** argv) {
  auto flags = parse_flags(
      argc, argv,
      {"--resolution", "--spp", "--tile", "--repeats", "--workers", "--channels",
       "--capacity-resolution", "--capacity-tile", "--capacity-bins", "--capacity-repeats",
       "--wire-tile", "--load-jobs", "--load-seconds", "--load-resolution"});
  if (!flags.ok()) {
    std::cerr << kProgram << ": " << flags.status().message() << "\n";
    return 2;
  }
  std::vector<std::string> which = flags->positional;
  if (which.empty()) which = {"overhead", "capacity", "wire"};
  for (const std::string& w : which) {
    if (w != "overhead" && w != "capacity" && w != "wire" && w != "load") {
      std::cerr << kProgram << ": unknown measurement '" << w
                << "': want overhead, capacity, wire or load\n";
      return 2;
    }
  }
  // Children get SIGKILL from the Children destructor; SIGPIPE must not end the bench.
  ::signal(SIGPIPE, SIG_IGN);
  const fs::path root = fs::temp_directory_path() / absl::StrCat("prism-bench-farm-", ::getpid());
  fs::remove_all(root);
  int exit_code = 0;
  for (const std::string& w : which) {
    const Clock::time_point start = Clock::now();
    absl::Status status;
    if (w == "overhead") status = run_overhead(*flags, root / "overhead");
    if (w == "capacity") status = run_capacity(*flags, root / "capacity");
    if (w == "wire") status = run_wire(*flags, root / "wire");
    if (w == "load") status = run_load(*flags, root / "load");
    if (!status.ok()) {
      std::cerr << kProgram << ": " << w << ": " << status.message() << " (logs under "
                << (root / w).string() << ")\n";
      exit_code = 1;
      continue;
    }
    std::fprintf(stderr, "%s: %s took %.1f s\n", kProgram, w.c_str(), seconds_since(start));
    std::error_code ec;
    fs::remove_all(root / w, ec);
  }
  if (exit_code == 0) {
    std::error_code ec;
    fs::remove_all(root, ec);
  }
  return exit_code;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
