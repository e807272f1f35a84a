// A finished job's output files as FarmService.GetResult streams them: each file in order-checked
// chunks, its SHA-256 on its last chunk. The CLI (`prism submit --wait`, `prism fetch`) and the
// tests that fetch results read the stream through this one function, so every reader checks it
// the same way.
#pragma once

#include <grpcpp/support/sync_stream.h>

#include <map>
#include <string>

#include "absl/status/statusor.h"
#include "prism/v1/farm.pb.h"

namespace prism::rpc {

struct ResultFiles {
  std::map<prism::v1::OutputKind, std::string> files;  // complete, each matching its SHA-256
  bool ended_inside_a_file = false;  // the stream stopped before some file's last chunk
};

// Reads `reader` to its end (it does not call Finish(): the caller does, and cancels the call
// after an error). DATA_LOSS naming the file for a chunk out of order or a file whose bytes do
// not match its SHA-256.
absl::StatusOr<ResultFiles> read_result_files(
    grpc::ClientReaderInterface<prism::v1::ResultChunk>& reader);

}  // namespace prism::rpc
