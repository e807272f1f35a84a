#include "services/rpc/result_upload.h"

#include "services/base/sha256.h"

namespace prism::rpc {

grpc::Status upload_result(grpc::ClientWriterInterface<prism::v1::ResultUpload>& writer,
                           const ResultUploadHeader& header, std::string_view bytes,
                           std::size_t chunk_bytes) {
  const std::vector<std::string_view> chunks = split_chunks(bytes, chunk_bytes);
  std::uint64_t offset = 0;
  for (std::size_t i = 0; i < chunks.size(); ++i) {
    prism::v1::ResultUpload upload;
    if (i == 0) {
      upload.set_worker_id(header.worker_id);
      upload.set_lease_id(header.lease_id);
    }
    upload.set_offset(offset);
    upload.set_data(std::string(chunks[i]));
    upload.set_total_bytes(bytes.size());
    if (i + 1 == chunks.size()) {
      upload.set_last(true);
      upload.set_sha256(header.sha256.empty() ? base::sha256_hex(bytes) : header.sha256);
      upload.set_render_seconds(header.render_seconds);
      upload.set_rays(header.rays);
      for (const auto& [name, value] : header.counters) {
        if (value != 0) (*upload.mutable_counters())[name] = value;
      }
    }
    offset += chunks[i].size();
    if (!writer.Write(upload)) break;
  }
  writer.WritesDone();
  return writer.Finish();
}

}  // namespace prism::rpc
