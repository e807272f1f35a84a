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
  // The synchronous server keeps at most MAX_POLLERS threads waiting for calls and ends the
  // others as each call returns; at its default (2) a farm of a hundred workers made it create
  // and end a thread for most calls (thread stacks mapped and unmapped, TLB shootdowns, malloc
  // arenas freed: about a tenth of the coordinator's CPU per completion). It keeps more now.
  builder.SetSyncServerOption(grpc::ServerBuilder::SyncServerOption::MIN_POLLERS, 2);
  builder.SetSyncServerOption(grpc::ServerBuilder::SyncServerOption::MAX_POLLERS, 32);
  // gRPC sets SO_REUSEPORT by default, which lets a second coordinator bind the same address and
  // take a random share of the calls: one process per address.
  builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
  builder.AddListeningPort(config.listen, credentials, &server->port_);
  builder.RegisterService(server->farm_service_.get());
  builder.RegisterService(server->worker_service_.get());
  server->server_ = builder.BuildAndStart();
  if (server->server_ == nullptr || server->port_ == 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen on ", config.listen,
                                               " (is another process using the address?)"));
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
