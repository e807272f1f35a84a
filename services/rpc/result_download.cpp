#include "services/rpc/result_download.h"

#include "absl/strings/str_cat.h"
#include "services/base/sha256.h"

namespace prism::rpc {

absl::StatusOr<ResultFiles> read_result_files(
    grpc::ClientReaderInterface<prism::v1::ResultChunk>& reader) {
  ResultFiles out;
  std::map<prism::v1::OutputKind, std::string> partial;
  prism::v1::ResultChunk chunk;
  while (reader.Read(&chunk)) {
    std::string& bytes = partial[chunk.kind()];
    if (chunk.offset() != bytes.size()) {
      return absl::DataLossError(absl::StrCat("result ", chunk.file_name(), ": chunk at ",
                                              chunk.offset(), ", expected ", bytes.size()));
    }
    bytes += chunk.data();
    if (!chunk.last()) continue;
    if (base::sha256_hex(bytes) != chunk.sha256()) {
      return absl::DataLossError(
          absl::StrCat("result ", chunk.file_name(), " does not match its SHA-256"));
    }
    out.files[chunk.kind()] = std::move(bytes);
    partial.erase(chunk.kind());
  }
  out.ended_inside_a_file = !partial.empty();
  return out;
}

}  // namespace prism::rpc
