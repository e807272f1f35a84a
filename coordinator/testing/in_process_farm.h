// Test support: a FarmCoordinator and its gRPC server in this process on 127.0.0.1, port 0,
// with a small scene to submit. Tests of the RPC services and of the CLI's farm commands share
// it; tests that need separate processes (tests/farm_*_test.cpp) start the real daemons instead.
#pragma once

#include <filesystem>
#include <functional>
#include <memory>
#include <string>

#include "coordinator/farm_coordinator.h"
#include "coordinator/rpc/coordinator_server.h"

namespace prism::coordinator::testing {

inline constexpr char kApiToken[] = "client-token";
inline constexpr char kWorkerSecret[] = "worker-secret";

// A 16x16, 8-bin, 4 spp diffuse sphere under a constant environment: fast to render.
extern const char kSmallScene[];

// Writes `text` to root/scene.pbrt and returns the packed bundle of that scene.
std::string packed_bundle(const std::filesystem::path& root, const std::string& text);

class InProcessFarm {
 public:
  // Opens a coordinator on `data_dir` (fast heartbeats and ticks; `adjust` may change any
  // option) and serves it with kApiToken and kWorkerSecret. Fails the test on error (null).
  static std::unique_ptr<InProcessFarm> start(
      const std::filesystem::path& data_dir,
      const std::function<void(FarmOptions&)>& adjust = nullptr);
  ~InProcessFarm();

  int port() const { return server_->port(); }
  std::string address() const { return "127.0.0.1:" + std::to_string(port()); }
  FarmCoordinator& farm() { return *farm_; }

 private:
  InProcessFarm() = default;
  std::unique_ptr<FarmCoordinator> farm_;
  std::unique_ptr<rpc::CoordinatorServer> server_;
};

}  // namespace prism::coordinator::testing
