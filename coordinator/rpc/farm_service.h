// The client-facing gRPC service (proto/prism/v1/farm.proto) over the FarmCoordinator. Thin:
// every call checks the API token, converts the request, calls the domain and converts the
// reply; errors cross unchanged through rpc::to_grpc. Streams send 1 MiB chunks.
#pragma once

#include <spdlog/spdlog.h>

#include <functional>
#include <memory>
#include <string>

#include "coordinator/farm_coordinator.h"
#include "prism/v1/farm.grpc.pb.h"

namespace prism::coordinator::rpc {

class FarmServiceImpl final : public prism::v1::FarmService::Service {
 public:
  // `api_token` empty: no authentication (local use, tests).
  FarmServiceImpl(FarmCoordinator& farm, std::string api_token,
                  std::shared_ptr<spdlog::logger> logger);

  grpc::Status SubmitJob(grpc::ServerContext* context, const prism::v1::SubmitJobRequest* request,
                         prism::v1::SubmitJobResponse* response) override;
  grpc::Status GetJob(grpc::ServerContext* context, const prism::v1::GetJobRequest* request,
                      prism::v1::JobInfo* response) override;
  grpc::Status ListJobs(grpc::ServerContext* context, const prism::v1::ListJobsRequest* request,
                        prism::v1::ListJobsResponse* response) override;
  grpc::Status WatchJob(grpc::ServerContext* context, const prism::v1::WatchJobRequest* request,
                        grpc::ServerWriter<prism::v1::JobInfo>* writer) override;
  grpc::Status CancelJob(grpc::ServerContext* context, const prism::v1::CancelJobRequest* request,
                         prism::v1::JobInfo* response) override;
  grpc::Status GetResult(grpc::ServerContext* context, const prism::v1::GetResultRequest* request,
                         grpc::ServerWriter<prism::v1::ResultChunk>* writer) override;
  grpc::Status GetPreview(grpc::ServerContext* context, const prism::v1::GetPreviewRequest* request,
                          prism::v1::Preview* response) override;
  grpc::Status ListWorkers(grpc::ServerContext* context,
                           const prism::v1::ListWorkersRequest* request,
                           prism::v1::ListWorkersResponse* response) override;
  grpc::Status UploadBundle(grpc::ServerContext* context,
                            grpc::ServerReader<prism::v1::BundleChunk>* reader,
                            prism::v1::UploadBundleResponse* response) override;
  grpc::Status HasBundle(grpc::ServerContext* context, const prism::v1::HasBundleRequest* request,
                         prism::v1::HasBundleResponse* response) override;

 private:
  // Logs a refused call (with its peer) and converts the status.
  grpc::Status refused(const grpc::ServerContext& context, const absl::Status& status) const;

  FarmCoordinator& farm_;
  const std::string api_token_;
  std::shared_ptr<spdlog::logger> logger_;
};

// The wire forms of a job's and a worker's status (the gRPC and the HTTP/JSON API share them).
prism::v1::JobInfo to_proto(const JobStatus& status);
prism::v1::WorkerInfo to_proto(const WorkerStatus& status);

// Follows a job for a watch (gRPC WatchJob, the HTTP API's event stream): `send` gets its status
// at once and again whenever its state or counts change, until the job is over (OK), `send`
// returns false (the client went away: OK) or `stopped` returns true (CANCELLED). NOT_FOUND for
// an unknown job.
absl::Status follow_job(FarmView& farm, const std::string& job_id,
                        const std::function<bool()>& stopped,
                        const std::function<bool(const prism::v1::JobInfo&)>& send);

}  // namespace prism::coordinator::rpc
