// The coordinator's gRPC server: FarmService, WorkerService and the standard health service on
// one listening address (port 0 picks a free port, reported by port()). TLS when a certificate
// and key are given; message size limits are gRPC's defaults (payloads travel in 1 MiB chunks).
#pragma once

#include <grpcpp/server.h>
#include <spdlog/spdlog.h>

#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "coordinator/farm_coordinator.h"
#include "coordinator/rpc/farm_service.h"
#include "coordinator/rpc/worker_service.h"
#include "services/rpc/credentials.h"

namespace prism::coordinator::rpc {

struct ServerConfig {
  std::string listen = "127.0.0.1:0";
  std::string worker_secret;  // empty: workers are not authenticated
  std::string api_token;      // empty: clients are not authenticated
  prism::rpc::ServerTls tls;
};

class CoordinatorServer {
 public:
  // UNAVAILABLE when the address cannot be bound; the credentials' errors for bad TLS files.
  static absl::StatusOr<std::unique_ptr<CoordinatorServer>> start(
      FarmCoordinator& farm, const ServerConfig& config, std::shared_ptr<spdlog::logger> logger);
  ~CoordinatorServer();

  int port() const { return port_; }
  // Stops accepting calls and ends the ones in flight after `grace`.
  void shutdown(Millis grace = Millis(2000));
  void wait() { server_->Wait(); }

 private:
  CoordinatorServer() = default;
  std::unique_ptr<FarmServiceImpl> farm_service_;
  std::unique_ptr<WorkerServiceImpl> worker_service_;
  std::unique_ptr<grpc::Server> server_;
  int port_ = 0;
  bool shut_down_ = false;
};

}  // namespace prism::coordinator::rpc
