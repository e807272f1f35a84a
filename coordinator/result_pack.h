// A job's task results in one file, jobs/<id>/results.pack, instead of a file each: creating a
// file per result cost the coordinator more kernel time (inode allocation, directory entries,
// one journal commit per fsync) than everything else it does with a result. A result gets a
// range at the end of the file (reserve), is written there without the farm's lock (write),
// and the task's record in the job store names the range and the result's SHA-256.
//
// Durability is the caller's group commit (group_commit.h): it syncs every pack written since
// the last flush (DirtyPacks), then the job store's WAL, before it acknowledges any result. A
// record can still reach the disk before its bytes (another commit may sync the WAL first), so
// reads check the hash: after a power loss a damaged or missing range is DATA_LOSS, and its
// task, never acknowledged, is rendered again. A result whose tile is finished and stored (the
// tile pack synced) has its bytes released as the job runs, so a job's disk holds each tile
// about once. Deleting the job's directory deletes its pack.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace prism::coordinator {

class ResultPack {
 public:
  // Opens the pack at `path`, creating it when missing; new results go after what it holds.
  static absl::StatusOr<std::shared_ptr<ResultPack>> open(const std::filesystem::path& path);
  ~ResultPack();
  ResultPack(const ResultPack&) = delete;
  ResultPack& operator=(const ResultPack&) = delete;

  // A range of `size` bytes at the end, never handed out twice; its offset. Thread-safe.
  std::uint64_t reserve(std::uint64_t size);
  // Writes `bytes` at `offset` (a reserved range). Thread-safe.
  absl::Status write(std::uint64_t offset, std::string_view bytes) const;
  // fdatasync: everything written before the call is durable. Thread-safe.
  absl::Status sync() const;
  // Frees the disk blocks of the `size` bytes at `offset` (a hole: they read as zeros, so a
  // later read is DATA_LOSS, and offsets do not move). For results a synced finished tile holds
  // merged (finished_tiles.h). UNIMPLEMENTED where the file system cannot punch holes.
  // Thread-safe.
  absl::Status release(std::uint64_t offset, std::uint64_t size) const;
  // The `size` bytes at `offset` if they hash to `sha256` (hex); DATA_LOSS naming the pack and
  // the range when they are missing or do not. Thread-safe.
  absl::StatusOr<std::string> read(std::uint64_t offset, std::uint64_t size,
                                   std::string_view sha256) const;

  const std::filesystem::path& path() const { return path_; }

 private:
  ResultPack(std::filesystem::path path, int fd, std::uint64_t end);
  std::filesystem::path path_;
  int fd_;
  std::atomic<std::uint64_t> end_;
};

// The packs written since the last flush of a group commit.
class DirtyPacks {
 public:
  // Thread-safe; adding a pack twice is harmless.
  void add(std::shared_ptr<ResultPack> pack);
  // Syncs every pack added before the call (and forgets it). The first error is returned; the
  // packs that failed stay listed.
  absl::Status sync();

 private:
  std::mutex mutex_;
  std::vector<std::shared_ptr<ResultPack>> dirty_;
};

}  // namespace prism::coordinator
