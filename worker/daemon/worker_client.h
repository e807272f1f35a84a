// The worker's side of the WorkerService: one method per RPC, each with a deadline and the worker
// secret as a bearer token. Idempotent calls (Register, AcquireTask, Heartbeat, FetchBundle) are
// retried on UNAVAILABLE with exponential backoff (100 ms doubling up to a cap, a bounded number
// of attempts); CompleteTask and FailTask are sent once, since the coordinator's answer to a
// repeat depends on what it did with the first. Errors come back as absl::Status with the call
// named in the message. This is the worker's gRPC adapter: generated types stop here and in the
// daemon that drives it.
#pragma once

#include <grpcpp/channel.h>
#include <grpcpp/client_context.h>
#include <grpcpp/security/credentials.h>
#include <spdlog/logger.h>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "prism/v1/worker.grpc.pb.h"

namespace prism::worker {

struct ClientConfig {
  std::string address;                                    // host:port of the coordinator
  std::string secret;                                     // worker secret; empty: none sent
  std::shared_ptr<grpc::ChannelCredentials> credentials;  // null: plaintext
  std::chrono::milliseconds call_timeout{10'000};         // Register, FailTask, Heartbeat
  std::chrono::milliseconds transfer_timeout{300'000};    // FetchBundle, CompleteTask
  int max_attempts = 5;                                   // per idempotent call
  std::chrono::milliseconds initial_backoff{100};
  std::chrono::milliseconds max_backoff{5'000};
};

class WorkerClient {
 public:
  WorkerClient(const ClientConfig& config, std::shared_ptr<spdlog::logger> logger);

  absl::StatusOr<v1::RegisterResponse> register_worker(const v1::RegisterRequest& request);
  // Long poll: the deadline is the request's wait_ms plus call_timeout. CANCELLED once
  // cancel_acquire() has been called.
  absl::StatusOr<v1::AcquireTaskResponse> acquire(const v1::AcquireTaskRequest& request);
  absl::StatusOr<v1::HeartbeatResponse> heartbeat(const v1::HeartbeatRequest& request,
                                                  std::chrono::milliseconds timeout);
  // The packed bundle, assembled in order (offsets without gaps, the declared total kept and
  // at most `max_bytes`); the caller verifies its content hash.
  absl::StatusOr<std::string> fetch_bundle(const std::string& hash, std::uint64_t max_bytes);
  // Streams `bytes` in 1 MiB chunks: the lease on the first, the total on every one, the
  // SHA-256 and the statistics on the last: the render time, the rays traced and the task's
  // event counters by name (counter_list in worker/integrator.h; zero ones are left out).
  absl::StatusOr<v1::CompleteTaskResponse> complete_task(
      const std::string& worker_id, const std::string& lease_id, const std::string& bytes,
      double render_seconds, std::uint64_t rays,
      const std::vector<std::pair<std::string, std::uint64_t>>& counters);
  absl::Status fail_task(const v1::FailTaskRequest& request);
  // Tells the coordinator a drained worker is leaving (sent once).
  absl::Status leave(const std::string& worker_id);

  // Cancels an AcquireTask in flight and refuses further ones (a draining worker never acquires
  // again). Thread-safe.
  void cancel_acquire();

 private:
  void prepare(grpc::ClientContext& context, std::chrono::milliseconds timeout) const;
  // Calls `attempt` (which makes one call with a fresh context) until it succeeds, fails with
  // something other than UNAVAILABLE, or the attempts run out.
  template <typename Attempt>
  absl::Status with_retries(const char* name, Attempt&& attempt);
  bool acquire_cancelled() const;

  ClientConfig config_;
  std::shared_ptr<spdlog::logger> logger_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::WorkerService::Stub> stub_;

  mutable std::mutex mutex_;
  std::condition_variable wake_;
  bool acquire_cancelled_ = false;
  grpc::ClientContext* acquire_context_ = nullptr;  // the AcquireTask in flight, if any
};

}  // namespace prism::worker
