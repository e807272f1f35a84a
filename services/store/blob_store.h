// Content-addressed blob store on disk. A blob is named by the lowercase hex SHA-256 of its
// bytes and lives at <root>/<first two hex digits>/<hash>. Writes are atomic (temporary file +
// rename), so a reader sees a blob whole or not at all, and a crash never leaves a blob whose
// bytes do not match its name. Putting the same bytes twice is harmless. Thread-safe: the only
// shared state is the file system.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace prism::store {

class BlobStore {
 public:
  // Creates root if needed. Fails if root exists and is not a directory.
  static absl::StatusOr<BlobStore> open(const std::filesystem::path& root);

  // Stores bytes and returns their hash.
  absl::StatusOr<std::string> put(std::string_view bytes) const;

  // Stores bytes claimed to hash to `hash` (from a peer); INVALID_ARGUMENT if they do not.
  absl::Status put_verified(std::string_view hash, std::string_view bytes) const;

  // put_verified for bytes whose hash the caller has just computed from them (an upload
  // already checked against its claimed hash), without hashing them a second time.
  absl::Status put_hashed(std::string_view hash, std::string_view bytes) const;

  bool contains(std::string_view hash) const;

  // NOT_FOUND for an unknown hash, INVALID_ARGUMENT for a malformed one. The bytes are
  // re-hashed on read, so on-disk corruption is reported (DATA_LOSS) rather than served.
  absl::StatusOr<std::string> get(std::string_view hash,
                                  std::uint64_t max_bytes = std::uint64_t{1} << 32) const;

  // Deletes a blob; OK when it is not there (deleting twice is harmless). INVALID_ARGUMENT for
  // a malformed hash, INTERNAL on a file system error.
  absl::Status remove(std::string_view hash) const;
  // Moves a blob into `dir` (same file system, existing) as <dir>/<hash>, for the caller to
  // delete later: it is gone from the store at once (O(1) whatever its size), and a later put of
  // the same hash writes a fresh file. OK when it is not there; errors as remove().
  absl::Status discard(std::string_view hash, const std::filesystem::path& dir) const;

  // Size in bytes of a stored blob.
  absl::StatusOr<std::uint64_t> size(std::string_view hash) const;

  const std::filesystem::path& root() const { return root_; }

 private:
  explicit BlobStore(std::filesystem::path root) : root_(std::move(root)) {}
  std::filesystem::path path_of(std::string_view hash) const;

  std::filesystem::path root_;
};

}  // namespace prism::store
