// Test support: child processes for the tests that run Prism's real binaries (the CLI, the
// coordinator, the worker). One way to start them, wait for them to be ready, read what they
// print, and never leave one behind: a ChildProcess still running when it goes out of scope is
// killed and reaped, and when the test has failed its output is printed so the failure can be
// read from ctest's log. Also a free loopback port (and, from test_dir.h, a directory per test).
#pragma once

#include <sys/types.h>

#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "tests/testing/test_dir.h"

namespace prism::testing {

struct ChildOptions {
  std::vector<std::string> env;    // NAME=value entries added to (or replacing in) the test's own
  bool clear_environment = false;  // start from an empty environment instead of the test's
  std::filesystem::path working_dir;  // empty: the test's
  bool merge_stderr = false;          // stderr into the stdout pipe (as `2>&1`), in order
  // The child's RLIMIT_AS (as `ulimit -v`, in bytes); 0: the test's own.
  std::uint64_t address_space_limit = 0;
};

class ChildProcess {
 public:
  // Starts the child with its stdout and stderr on pipes that threads drain into memory, so a
  // chatty child never blocks. Fails the current test (and returns null) when it cannot start.
  // argv[0] is the binary's path.
  static std::unique_ptr<ChildProcess> start(std::vector<std::string> argv,
                                             const ChildOptions& options = {});
  ~ChildProcess();
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  pid_t pid() const { return pid_; }

  // The first stdout line containing `needle` (whole, without its newline), waiting up to
  // `timeout` for it; nullopt when the child closed its stdout or the time ran out first.
  std::optional<std::string> wait_for_line(std::string_view needle,
                                           std::chrono::milliseconds timeout);

  // Waits for the child to end: its exit code, or 128 + the signal that ended it; nullopt when it
  // is still running after `timeout` (it is left running). Once it has ended, out() and err()
  // hold all it wrote.
  std::optional<int> wait(std::chrono::milliseconds timeout);
  int wait();  // without a time limit

  void signal(int sig);  // e.g. SIGTERM to ask for a clean exit
  void kill();           // SIGKILL and reap (a crash, as kill -9 gives it)
  bool running();

  std::string out() const;  // stdout so far (with stderr when merged)
  std::string err() const;  // stderr so far

 private:
  ChildProcess() = default;
  void drain(int fd, std::string* into);
  std::optional<int> reap(bool block);

  std::string name_;  // argv[0], for the failure log
  pid_t pid_ = -1;
  std::optional<int> status_;  // once reaped
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::string out_, err_;
  int open_streams_ = 0;
  std::vector<std::thread> drains_;
};

// Runs a child to the end: its exit code (128 + signal), stdout and stderr. A child still running
// after `timeout` is killed and the test fails.
struct RunResult {
  int exit_code = -1;
  std::string out, err;
};
RunResult run(std::vector<std::string> argv, const ChildOptions& options = {},
              std::chrono::milliseconds timeout = std::chrono::minutes(10));

// The full path of an installed program (children start with execv, which searches nothing):
// $PATH, then /usr/sbin and /sbin (daemons). Fails the current test and returns the bare name
// when it is not found, so the failure names it.
std::string find_program(const std::string& name);

// `<prism> render scene.pbrt -o <out> <flags>` run in `scene_dir`, so that the EXR names its scene
// "scene.pbrt" as a farm job's bundle does: the farm's outputs must be these bytes. Fails the
// test when the render fails; returns the EXR's bytes.
std::string render_beside(const std::string& prism, const std::filesystem::path& scene_dir,
                          const std::filesystem::path& out, const std::vector<std::string>& flags);

// The API token and worker secret the farm process tests give their coordinator.
inline constexpr char kApiToken[] = "client-token";
inline constexpr char kWorkerSecret[] = "worker-secret";
// Their heartbeat interval (--heartbeat-ms): short, so lost workers are noticed within a second.
inline constexpr int kHeartbeatMs = 200;

// A test coordinator's command line: `binary` serving gRPC on `listen`, its data under
// `data_dir`, the test's worker secret and API token, logging at `log_level`, then `extra` (for
// example --http-listen, --heartbeat-ms, --lease-ms, TLS files).
std::vector<std::string> coordinator_command(const std::string& binary, const std::string& listen,
                                             const std::filesystem::path& data_dir,
                                             const std::string& worker_secret,
                                             const std::string& api_token,
                                             const std::vector<std::string>& extra,
                                             const std::string& log_level = "warn");

// `prism submit` of `scene` to the coordinator at `address` with the test's API token, then
// `extra` (render flags, --wait, -o ...).
std::vector<std::string> submit_command(const std::string& prism,
                                        const std::filesystem::path& scene,
                                        const std::string& address, const std::string& api_token,
                                        const std::vector<std::string>& extra);

// The ports a prism-coordinator started with --listen ...:0 and --http-listen ...:0 prints
// ("serving HTTP on port N", then "listening on port M"), waiting up to 20 s; fails the current
// test and returns zeros when it printed none.
struct CoordinatorPorts {
  int grpc = 0;
  int http = 0;
};
CoordinatorPorts coordinator_ports(ChildProcess& coordinator);

// A whole file's bytes ("" when it cannot be read).
std::string read_file(const std::filesystem::path& path);

// A loopback TCP port that was free a moment ago (for a server that must be restarted on the
// same address; servers that can should bind port 0 and print the port they got).
int free_port();

}  // namespace prism::testing
