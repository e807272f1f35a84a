// Large payloads (bundles, task results, output files) cross gRPC as streams of chunks well
// under the default 4 MiB message limit. The sender splits the bytes; the receiver assembles
// them, insisting that chunks arrive in order without gaps, that the declared total and a limit
// are respected, and that the SHA-256 the sender sends at the end matches the bytes.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/base/sha256.h"

namespace prism::rpc {

inline constexpr std::size_t kChunkBytes = std::size_t{1} << 20;  // 1 MiB per message

// Consecutive views of `bytes`, each at most chunk_bytes long (one empty view for empty input).
std::vector<std::string_view> split_chunks(std::string_view bytes,
                                           std::size_t chunk_bytes = kChunkBytes);

class ChunkAssembler {
 public:
  // `limit`: the most bytes accepted (RESOURCE_EXHAUSTED beyond it).
  explicit ChunkAssembler(std::uint64_t limit) : limit_(limit) {}

  // A chunk at `offset` (must equal the bytes received so far). `declared_total`, when not 0,
  // must stay the same on every chunk and is checked against the limit at once, so an oversized
  // upload is refused on its first message.
  absl::Status add(std::uint64_t offset, std::string_view data, std::uint64_t declared_total = 0);

  // The bytes, once the sender's SHA-256 (lowercase hex) is known: DATA_LOSS when it does not
  // match, INVALID_ARGUMENT when fewer bytes than declared arrived.
  absl::StatusOr<std::string> finish(std::string_view sha256_hex);

  std::uint64_t received() const { return bytes_.size(); }

 private:
  std::uint64_t limit_;
  std::uint64_t declared_total_ = 0;
  std::string bytes_;
  base::Sha256 hasher_;
};

}  // namespace prism::rpc
