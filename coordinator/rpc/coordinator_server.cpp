#include "coordinator/rpc/coordinator_server.h"

#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/server_builder.h>

#include <chrono>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"

namespace prism::coordinator::rpc {

absl::StatusOr<std::unique_ptr<CoordinatorServer>> CoordinatorServer::start(
    FarmCoordinator& farm, const ServerConfig& config, std::shared_ptr<spdlog::logger> logger) {
  PRISM_ASSIGN_OR_RETURN(std::shared_ptr<grpc::ServerCredentials> credentials,
                         prism::rpc::server_credentials(config.tls));
  std::unique_ptr<CoordinatorServer> server(new CoordinatorServer());
  server->farm_service_ = std::make_unique<FarmServiceImpl>(farm, config.api_token, logger);
  server->worker_service_ = std::make_unique<WorkerServiceImpl>(farm, config.worker_secret, logger);
  grpc::EnableDefaultHealthCheckService(true);
  grpc::ServerBuilder builder;
  builder.AddListeningPort(config.listen, credentials, &server->port_);
  builder.RegisterService(server->farm_service_.get());
  builder.RegisterService(server->worker_service_.get());
  server->server_ = builder.BuildAndStart();
  if (server->server_ == nullptr || server->port_ == 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen on ", config.listen));
  }
  return server;
}

void CoordinatorServer::shutdown(Millis grace) {
  if (shut_down_) return;
  shut_down_ = true;
  server_->Shutdown(std::chrono::system_clock::now() + grace);
}

CoordinatorServer::~CoordinatorServer() {
  if (server_ != nullptr) shutdown();
}

}  // namespace prism::coordinator::rpc
