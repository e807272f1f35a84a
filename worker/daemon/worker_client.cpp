#include "worker/daemon/worker_client.h"

#include <grpcpp/create_channel.h>
#include <grpcpp/security/credentials.h>
#include <grpcpp/support/channel_arguments.h>

#include <algorithm>

#include "absl/strings/str_cat.h"
#include "services/base/sha256.h"
#include "services/rpc/auth.h"
#include "services/rpc/chunks.h"
#include "services/rpc/credentials.h"
#include "services/rpc/result_upload.h"
#include "services/rpc/status_mapping.h"

namespace prism::worker {
namespace {

absl::Status named(const char* name, const grpc::Status& status) {
  const absl::Status s = rpc::from_grpc(status);
  return absl::Status(s.code(), absl::StrCat(name, ": ", s.message()));
}

}  // namespace

WorkerClient::WorkerClient(const ClientConfig& config, std::shared_ptr<spdlog::logger> logger)
    : config_(config), logger_(std::move(logger)) {
  grpc::ChannelArguments args = rpc::client_channel_arguments();
  // Bundles and results arrive in 1 MiB chunks; leave room for the envelope.
  args.SetMaxReceiveMessageSize(4 << 20);
  channel_ = grpc::CreateCustomChannel(
      config_.address,
      config_.credentials ? config_.credentials : grpc::InsecureChannelCredentials(), args);
  stub_ = v1::WorkerService::NewStub(channel_);
}

void WorkerClient::prepare(grpc::ClientContext& context, std::chrono::milliseconds timeout) const {
  context.set_deadline(std::chrono::system_clock::now() + timeout);
  rpc::add_bearer(context, config_.secret);
}

bool WorkerClient::acquire_cancelled() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return acquire_cancelled_;
}

template <typename Attempt>
absl::Status WorkerClient::with_retries(const char* name, Attempt&& attempt) {
  std::chrono::milliseconds backoff = config_.initial_backoff;
  for (int n = 1;; ++n) {
    const grpc::Status status = attempt();
    if (status.ok()) return absl::OkStatus();
    if (status.error_code() != grpc::StatusCode::UNAVAILABLE || n >= config_.max_attempts) {
      return named(name, status);
    }
    logger_->warn("{} unavailable (attempt {} of {}): {}; retrying in {} ms", name, n,
                  config_.max_attempts, status.error_message(), backoff.count());
    std::unique_lock<std::mutex> lock(mutex_);
    // A drain wakes a waiting AcquireTask at once; other calls simply wait out the backoff.
    wake_.wait_for(lock, backoff, [&] { return acquire_cancelled_; });
    if (acquire_cancelled_ && std::string_view(name) == "AcquireTask") {
      return absl::CancelledError("AcquireTask: the worker is draining");
    }
    backoff = std::min(backoff * 2, config_.max_backoff);
  }
}

absl::StatusOr<v1::RegisterResponse> WorkerClient::register_worker(
    const v1::RegisterRequest& request) {
  v1::RegisterResponse response;
  absl::Status status = with_retries("Register", [&] {
    grpc::ClientContext context;
    prepare(context, config_.call_timeout);
    return stub_->Register(&context, request, &response);
  });
  if (!status.ok()) return status;
  return response;
}

absl::StatusOr<v1::AcquireTaskResponse> WorkerClient::acquire(
    const v1::AcquireTaskRequest& request) {
  v1::AcquireTaskResponse response;
  absl::Status status = with_retries("AcquireTask", [&] {
    grpc::ClientContext context;
    prepare(context, std::chrono::milliseconds(request.wait_ms()) + config_.call_timeout);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (acquire_cancelled_) return grpc::Status(grpc::StatusCode::CANCELLED, "draining");
      acquire_context_ = &context;
    }
    grpc::Status s = stub_->AcquireTask(&context, request, &response);
    std::lock_guard<std::mutex> lock(mutex_);
    acquire_context_ = nullptr;
    return s;
  });
  if (!status.ok()) return status;
  return response;
}

void WorkerClient::cancel_acquire() {
  std::lock_guard<std::mutex> lock(mutex_);
  acquire_cancelled_ = true;
  if (acquire_context_ != nullptr) acquire_context_->TryCancel();
  wake_.notify_all();
}

absl::StatusOr<v1::HeartbeatResponse> WorkerClient::heartbeat(const v1::HeartbeatRequest& request,
                                                              std::chrono::milliseconds timeout) {
  v1::HeartbeatResponse response;
  absl::Status status = with_retries("Heartbeat", [&] {
    grpc::ClientContext context;
    prepare(context, timeout);
    return stub_->Heartbeat(&context, request, &response);
  });
  if (!status.ok()) return status;
  return response;
}

absl::StatusOr<std::string> WorkerClient::fetch_bundle(const std::string& hash,
                                                       std::uint64_t max_bytes) {
  std::string blob;
  absl::Status assembly;
  absl::Status status = with_retries("FetchBundle", [&] {
    blob.clear();
    assembly = absl::OkStatus();
    grpc::ClientContext context;
    prepare(context, config_.transfer_timeout);
    v1::FetchBundleRequest request;
    request.set_bundle_hash(hash);
    std::unique_ptr<grpc::ClientReader<v1::BundleData>> reader =
        stub_->FetchBundle(&context, request);
    v1::BundleData chunk;
    std::uint64_t declared = 0;
    while (reader->Read(&chunk)) {
      if (chunk.offset() != blob.size()) {
        assembly = absl::DataLossError(absl::StrCat("FetchBundle: chunk at offset ", chunk.offset(),
                                                    " after ", blob.size(), " bytes"));
      } else if (chunk.total_bytes() > max_bytes) {
        assembly = absl::ResourceExhaustedError(
            absl::StrCat("FetchBundle: bundle ", hash, " of ", chunk.total_bytes(),
                         " bytes exceeds the limit of ", max_bytes));
      } else if (declared != 0 && chunk.total_bytes() != declared) {
        assembly = absl::DataLossError("FetchBundle: the declared total changed mid-stream");
      } else if (blob.size() + chunk.data().size() > max_bytes) {
        assembly = absl::ResourceExhaustedError(
            absl::StrCat("FetchBundle: bundle ", hash, " exceeds the limit of ", max_bytes));
      }
      if (!assembly.ok()) {
        context.TryCancel();
        break;
      }
      declared = chunk.total_bytes();
      blob.append(chunk.data());
    }
    grpc::Status s = reader->Finish();
    if (assembly.ok() && s.ok() && declared != 0 && blob.size() != declared) {
      assembly = absl::DataLossError(
          absl::StrCat("FetchBundle: received ", blob.size(), " of ", declared, " bytes"));
    }
    return assembly.ok() ? s : grpc::Status::OK;
  });
  if (!status.ok()) return status;
  if (!assembly.ok()) return assembly;
  return blob;
}

absl::StatusOr<v1::CompleteTaskResponse> WorkerClient::complete_task(
    const std::string& worker_id, const std::string& lease_id, const std::string& bytes,
    double render_seconds, std::uint64_t rays,
    const std::vector<std::pair<std::string, std::uint64_t>>& counters) {
  grpc::ClientContext context;
  prepare(context, config_.transfer_timeout);
  v1::CompleteTaskResponse response;
  std::unique_ptr<grpc::ClientWriter<v1::ResultUpload>> writer =
      stub_->CompleteTask(&context, &response);
  const grpc::Status status =
      rpc::upload_result(*writer, {worker_id, lease_id, render_seconds, rays, counters, ""}, bytes);
  if (!status.ok()) return named("CompleteTask", status);
  return response;
}

absl::Status WorkerClient::fail_task(const v1::FailTaskRequest& request) {
  grpc::ClientContext context;
  prepare(context, config_.call_timeout);
  v1::FailTaskResponse response;
  const grpc::Status status = stub_->FailTask(&context, request, &response);
  if (!status.ok()) return named("FailTask", status);
  return absl::OkStatus();
}

absl::Status WorkerClient::leave(const std::string& worker_id) {
  grpc::ClientContext context;
  prepare(context, config_.call_timeout);
  v1::LeaveRequest request;
  request.set_worker_id(worker_id);
  v1::LeaveResponse response;
  const grpc::Status status = stub_->Leave(&context, request, &response);
  if (!status.ok()) return named("Leave", status);
  return absl::OkStatus();
}

}  // namespace prism::worker
