// A task result's upload (WorkerService.CompleteTask) as the worker sends it: the canonical
// TileResult bytes in chunks (chunks.h), the lease on the first, the SHA-256 of all the bytes and
// the task's statistics on the last. The worker and every test or benchmark that plays a worker
// send it through this one function, so the coordinator's assembler is always fed the same
// protocol.
#pragma once

#include <grpcpp/support/sync_stream.h>

#include <cstdint>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "prism/v1/worker.pb.h"
#include "services/rpc/chunks.h"

namespace prism::rpc {

struct ResultUploadHeader {
  std::string worker_id;
  std::string lease_id;
  double render_seconds = 0;
  std::uint64_t rays = 0;
  // The task's event counters by name; zeros are left out (an absent key reads as 0).
  std::vector<std::pair<std::string, std::uint64_t>> counters;
  // The bytes' SHA-256 (lowercase hex) when the caller has it already; empty: computed here.
  std::string sha256;
};

// Writes `bytes` to `writer` in chunks of at most `chunk_bytes`, then WritesDone() and Finish():
// the call's status. A failed write ends the stream early; Finish() then says why.
grpc::Status upload_result(grpc::ClientWriterInterface<prism::v1::ResultUpload>& writer,
                           const ResultUploadHeader& header, std::string_view bytes,
                           std::size_t chunk_bytes = kChunkBytes);

}  // namespace prism::rpc
