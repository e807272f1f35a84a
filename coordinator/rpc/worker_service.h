// The worker-facing gRPC service (proto/prism/v1/worker.proto) over the FarmCoordinator. Thin:
// every call checks the worker secret, converts, calls the domain and converts back. A result
// arrives as a client stream assembled with rpc::ChunkAssembler (order, declared size, SHA-256);
// a stale lease is FAILED_PRECONDITION with the Scheduler's reason, a duplicate is OK with
// accepted = false.
#pragma once

#include <spdlog/spdlog.h>

#include <memory>
#include <string>

#include "coordinator/farm_coordinator.h"
#include "prism/v1/worker.grpc.pb.h"

namespace prism::coordinator::rpc {

// The longest a worker's AcquireTask may be held.
inline constexpr Millis kMaxAcquireWait{30000};

class WorkerServiceImpl final : public prism::v1::WorkerService::Service {
 public:
  // `worker_secret` empty: no authentication (local use, tests).
  WorkerServiceImpl(FarmCoordinator& farm, std::string worker_secret,
                    std::shared_ptr<spdlog::logger> logger);

  grpc::Status Register(grpc::ServerContext* context, const prism::v1::RegisterRequest* request,
                        prism::v1::RegisterResponse* response) override;
  grpc::Status AcquireTask(grpc::ServerContext* context,
                           const prism::v1::AcquireTaskRequest* request,
                           prism::v1::AcquireTaskResponse* response) override;
  grpc::Status Heartbeat(grpc::ServerContext* context, const prism::v1::HeartbeatRequest* request,
                         prism::v1::HeartbeatResponse* response) override;
  grpc::Status CompleteTask(grpc::ServerContext* context,
                            grpc::ServerReader<prism::v1::ResultUpload>* reader,
                            prism::v1::CompleteTaskResponse* response) override;
  grpc::Status FailTask(grpc::ServerContext* context, const prism::v1::FailTaskRequest* request,
                        prism::v1::FailTaskResponse* response) override;
  grpc::Status FetchBundle(grpc::ServerContext* context,
                           const prism::v1::FetchBundleRequest* request,
                           grpc::ServerWriter<prism::v1::BundleData>* writer) override;
  grpc::Status Leave(grpc::ServerContext* context, const prism::v1::LeaveRequest* request,
                     prism::v1::LeaveResponse* response) override;

 private:
  // Logs a refused call (with its peer) and converts the status.
  grpc::Status refused(const grpc::ServerContext& context, const absl::Status& status) const;

  FarmCoordinator& farm_;
  const std::string worker_secret_;
  std::shared_ptr<spdlog::logger> logger_;
};

// The wire form of a lease.
prism::v1::Lease to_proto(const LeaseGrant& grant);

}  // namespace prism::coordinator::rpc
