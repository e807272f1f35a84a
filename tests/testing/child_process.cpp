#include "tests/testing/child_process.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>

extern char** environ;

namespace prism::testing {
namespace {

constexpr std::size_t kFailureLogBytes = 16384;

// The last `bytes` of `text`, marked when cut.
std::string tail(const std::string& text, std::size_t bytes) {
  if (text.size() <= bytes) return text;
  return "[...]" + text.substr(text.size() - bytes);
}

int exit_code(int status) {
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return -1;
}

}  // namespace

std::unique_ptr<ChildProcess> ChildProcess::start(std::vector<std::string> argv_strings,
                                                  const ChildOptions& options) {
  if (argv_strings.empty()) {
    ADD_FAILURE() << "ChildProcess::start without a program";
    return nullptr;
  }
  // The environment, built before fork (no allocation in the child).
  std::map<std::string, std::string> env;
  if (!options.clear_environment) {
    for (char** e = environ; *e != nullptr; ++e) {
      const std::string entry = *e;
      env[entry.substr(0, entry.find('='))] = entry;
    }
  }
  for (const std::string& entry : options.env) env[entry.substr(0, entry.find('='))] = entry;
  std::vector<std::string> env_entries;
  for (auto& [name, entry] : env) env_entries.push_back(entry);
  std::vector<char*> envp, argv;
  for (std::string& e : env_entries) envp.push_back(e.data());
  envp.push_back(nullptr);
  for (std::string& a : argv_strings) argv.push_back(a.data());
  argv.push_back(nullptr);
  const std::string dir = options.working_dir.string();

  int out[2] = {-1, -1}, err[2] = {-1, -1};
  // O_CLOEXEC: children started later must not hold these pipes open.
  if (::pipe2(out, O_CLOEXEC) != 0 || (!options.merge_stderr && ::pipe2(err, O_CLOEXEC) != 0)) {
    ADD_FAILURE() << "pipe: " << std::strerror(errno);
    return nullptr;
  }
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::dup2(out[1], STDOUT_FILENO);
    ::dup2(options.merge_stderr ? out[1] : err[1], STDERR_FILENO);
    if (!dir.empty() && ::chdir(dir.c_str()) != 0) ::_exit(126);
    if (options.address_space_limit > 0) {
      const rlimit limit{options.address_space_limit, options.address_space_limit};
      if (::setrlimit(RLIMIT_AS, &limit) != 0) ::_exit(126);
    }
    ::execve(argv[0], argv.data(), envp.data());
    ::_exit(127);
  }
  ::close(out[1]);
  if (!options.merge_stderr) ::close(err[1]);
  if (pid < 0) {
    ADD_FAILURE() << "fork: " << std::strerror(errno);
    ::close(out[0]);
    if (!options.merge_stderr) ::close(err[0]);
    return nullptr;
  }
  std::unique_ptr<ChildProcess> child(new ChildProcess());
  child->name_ = argv_strings[0];
  child->pid_ = pid;
  child->open_streams_ = options.merge_stderr ? 1 : 2;
  ChildProcess* self = child.get();
  child->drains_.emplace_back([self, fd = out[0]] { self->drain(fd, &self->out_); });
  if (!options.merge_stderr) {
    child->drains_.emplace_back([self, fd = err[0]] { self->drain(fd, &self->err_); });
  }
  return child;
}

void ChildProcess::drain(int fd, std::string* into) {
  char buffer[4096];
  for (;;) {
    const ssize_t n = ::read(fd, buffer, sizeof(buffer));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    std::lock_guard<std::mutex> lock(mutex_);
    into->append(buffer, std::size_t(n));
    changed_.notify_all();
  }
  ::close(fd);
  std::lock_guard<std::mutex> lock(mutex_);
  --open_streams_;
  changed_.notify_all();
}

ChildProcess::~ChildProcess() {
  if (running()) kill();
  for (std::thread& t : drains_) t.join();
  if (::testing::Test::HasFailure()) {
    std::lock_guard<std::mutex> lock(mutex_);
    std::cerr << "---- " << name_ << " (pid " << pid_ << ") stdout ----\n"
              << tail(out_, kFailureLogBytes) << "\n";
    if (!err_.empty()) {
      std::cerr << "---- " << name_ << " (pid " << pid_ << ") stderr ----\n"
                << tail(err_, kFailureLogBytes) << "\n";
    }
  }
}

std::optional<std::string> ChildProcess::wait_for_line(std::string_view needle,
                                                       std::chrono::milliseconds timeout) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    std::size_t start = 0;
    for (std::size_t end = out_.find('\n'); end != std::string::npos;
         start = end + 1, end = out_.find('\n', start)) {
      const std::string_view line(out_.data() + start, end - start);
      if (line.find(needle) != std::string_view::npos) return std::string(line);
    }
    if (open_streams_ == 0) return std::nullopt;
    if (changed_.wait_until(lock, until) == std::cv_status::timeout) return std::nullopt;
  }
}

std::optional<int> ChildProcess::reap(bool block) {
  if (status_.has_value()) return status_;
  int status = 0;
  pid_t got;
  do {
    got = ::waitpid(pid_, &status, block ? 0 : WNOHANG);
  } while (got < 0 && errno == EINTR);
  if (got == pid_) {
    status_ = exit_code(status);
    // What it wrote is complete once its pipes close (a grandchild holding them open is given
    // a few seconds).
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait_for(lock, std::chrono::seconds(5), [this] { return open_streams_ == 0; });
  }
  return status_;
}

std::optional<int> ChildProcess::wait(std::chrono::milliseconds timeout) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    if (std::optional<int> code = reap(false)) return code;
    if (std::chrono::steady_clock::now() >= until) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

int ChildProcess::wait() {
  return reap(true).value_or(-1);
}

void ChildProcess::signal(int sig) {
  if (!status_.has_value()) ::kill(pid_, sig);
}

void ChildProcess::kill() {
  if (status_.has_value()) return;
  ::kill(pid_, SIGKILL);
  reap(true);
}

bool ChildProcess::running() {
  return !reap(false).has_value();
}

std::string ChildProcess::out() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return out_;
}

std::string ChildProcess::err() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return err_;
}

RunResult run(std::vector<std::string> argv, const ChildOptions& options,
              std::chrono::milliseconds timeout) {
  RunResult result;
  std::unique_ptr<ChildProcess> child = ChildProcess::start(std::move(argv), options);
  if (child == nullptr) return result;
  std::optional<int> code = child->wait(timeout);
  if (!code.has_value()) {
    ADD_FAILURE() << "the child did not end within " << timeout.count() << " ms";
    child->kill();
    code = child->wait();
  }
  result.exit_code = *code;
  result.out = child->out();
  result.err = child->err();
  return result;
}

int free_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  EXPECT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)), 0);
  socklen_t len = sizeof(addr);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  ::close(fd);
  return ntohs(addr.sin_port);
}

std::string find_program(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::string dirs = path != nullptr ? path : "/usr/bin:/bin";
  dirs += ":/usr/sbin:/sbin";
  std::istringstream list(dirs);
  for (std::string dir; std::getline(list, dir, ':');) {
    const std::filesystem::path candidate = std::filesystem::path(dir) / name;
    if (::access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  ADD_FAILURE() << name << " is not installed (deploy/install-deps.sh installs it)";
  return name;
}

std::string read_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

std::string render_beside(const std::string& prism, const std::filesystem::path& scene_dir,
                          const std::filesystem::path& out, const std::vector<std::string>& flags) {
  std::vector<std::string> argv = {prism, "render", "scene.pbrt", "-o", out.string()};
  argv.insert(argv.end(), flags.begin(), flags.end());
  ChildOptions beside;
  beside.working_dir = scene_dir;
  const RunResult rendered = run(argv, beside);
  EXPECT_EQ(rendered.exit_code, 0) << "prism render failed: " << rendered.err;
  return read_file(out);
}

std::vector<std::string> coordinator_command(const std::string& binary, const std::string& listen,
                                             const std::filesystem::path& data_dir,
                                             const std::string& worker_secret,
                                             const std::string& api_token,
                                             const std::vector<std::string>& extra,
                                             const std::string& log_level) {
  std::vector<std::string> argv = {
      binary,        "--listen",    listen,    "--data-dir",  data_dir.string(), "--worker-secret",
      worker_secret, "--api-token", api_token, "--log-level", log_level};
  argv.insert(argv.end(), extra.begin(), extra.end());
  return argv;
}

std::vector<std::string> submit_command(const std::string& prism,
                                        const std::filesystem::path& scene,
                                        const std::string& address, const std::string& api_token,
                                        const std::vector<std::string>& extra) {
  std::vector<std::string> argv = {prism,   "submit",  scene.string(), "--coordinator",
                                   address, "--token", api_token};
  argv.insert(argv.end(), extra.begin(), extra.end());
  return argv;
}

CoordinatorPorts coordinator_ports(ChildProcess& coordinator) {
  CoordinatorPorts ports;
  const auto http = coordinator.wait_for_line("serving HTTP on port", std::chrono::seconds(20));
  const auto grpc = coordinator.wait_for_line("listening on port", std::chrono::seconds(20));
  if (http.has_value()) std::sscanf(http->c_str(), "serving HTTP on port %d", &ports.http);
  if (grpc.has_value()) std::sscanf(grpc->c_str(), "listening on port %d", &ports.grpc);
  EXPECT_GT(ports.http, 0) << "the coordinator printed no HTTP port";
  EXPECT_GT(ports.grpc, 0) << "the coordinator printed no gRPC port";
  return ports;
}

}  // namespace prism::testing
