#include "services/rpc/chunks.h"

#include "absl/strings/str_cat.h"

namespace prism::rpc {

std::vector<std::string_view> split_chunks(std::string_view bytes, std::size_t chunk_bytes) {
  std::vector<std::string_view> chunks;
  if (bytes.empty()) {
    chunks.push_back(bytes);
    return chunks;
  }
  for (std::size_t offset = 0; offset < bytes.size(); offset += chunk_bytes) {
    chunks.push_back(bytes.substr(offset, chunk_bytes));
  }
  return chunks;
}

absl::Status ChunkAssembler::add(std::uint64_t offset, std::string_view data,
                                 std::uint64_t declared_total) {
  if (declared_total != 0) {
    if (declared_total > limit_) {
      return absl::ResourceExhaustedError(absl::StrCat(
          "upload of ", declared_total, " bytes is over the limit of ", limit_, " bytes"));
    }
    if (declared_total_ != 0 && declared_total != declared_total_) {
      return absl::InvalidArgumentError(
          absl::StrCat("declared size changed from ", declared_total_, " to ", declared_total));
    }
    // Room for all of it at once: growing by doubling copied a large upload several times.
    if (declared_total_ == 0) bytes_.reserve(declared_total);
    declared_total_ = declared_total;
  }
  if (offset != bytes_.size()) {
    return absl::InvalidArgumentError(
        absl::StrCat("chunk at offset ", offset, " but ", bytes_.size(), " bytes received"));
  }
  if (bytes_.size() + data.size() > limit_) {
    return absl::ResourceExhaustedError(
        absl::StrCat("upload exceeds the limit of ", limit_, " bytes"));
  }
  if (declared_total_ != 0 && bytes_.size() + data.size() > declared_total_) {
    return absl::InvalidArgumentError(
        absl::StrCat("upload exceeds its declared size of ", declared_total_, " bytes"));
  }
  bytes_.append(data);
  hasher_.update(data);
  return absl::OkStatus();
}

absl::StatusOr<std::string> ChunkAssembler::finish(std::string_view sha256_hex) {
  if (declared_total_ != 0 && bytes_.size() != declared_total_) {
    return absl::InvalidArgumentError(
        absl::StrCat("upload ended after ", bytes_.size(), " of ", declared_total_, " bytes"));
  }
  std::string actual = hasher_.hex();
  if (actual != sha256_hex) {
    return absl::DataLossError(absl::StrCat("content hash mismatch: received bytes hash to ",
                                            actual, ", sender said ",
                                            std::string(sha256_hex.substr(0, 64))));
  }
  return std::move(bytes_);
}

}  // namespace prism::rpc
