// A job's finished tiles, on disk. The coordinator keeps in memory only the tiles in flight
// (their range results, in the TileAssembler) and the job's linear sRGB (3 floats per pixel,
// for previews and the RGB outputs); a finished tile's merged result (the tile codec's bytes:
// sums, sums of squares, counts, and gradients or guides when present) is appended to one file,
// <dir>/tiles.pack, as a record (magic "PRTR", tile index, size, SHA-256, bytes), and the
// spectral EXR is streamed from it one row of tiles at a time. A tile of one sample range (the
// default: all of a pixel's samples in one task) is its range result, already stored in the
// job's result pack: its record is a link (magic "PRTL", tile, size, SHA-256, offset in
// results.pack), and its bytes are written once. One file, not one per tile: creating files cost
// the coordinator more kernel time than merging the results in them.
//
// The pack is also what a restarted coordinator resumes finished tiles from: open() reads the
// record headers and stops at the first that is not whole. Records are not flushed as they are
// put: the range results a tile was merged from are durable, and a record a power loss damaged
// fails get() (its hash), so the tile is merged from them again. Once a record is synced
// (sync()), the farm frees its range results' bytes (ResultPack::release); a restart then finds
// the tile here and never reads them.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/result_pack.h"
#include "coordinator/tile_finaliser.h"
#include "coordinator/tile_plan.h"
#include "services/image/exr_spectral.h"
#include "services/image/tile.h"

namespace prism::coordinator {

class FinishedTiles {
 public:
  // Creates `dir` (and its parents) if needed; keeps what is already there. `results`: the
  // job's result pack, which linked tiles (put_link) are read from.
  static absl::StatusOr<FinishedTiles> open(std::filesystem::path dir, TilePlan plan, int width,
                                            int bins,
                                            std::shared_ptr<const ResultPack> results = nullptr);

  // Appends tile `tile`'s merged result (a rewrite supersedes the earlier record).
  // INVALID_ARGUMENT when the index or the rect is not the plan's; INTERNAL naming the file on
  // an I/O error. Thread-safe, as are has and get.
  absl::Status put(int tile, const image::TileResult& merged);
  // Records tile `tile` as the result stored at [offset, offset + size) of the result pack, with
  // that SHA-256: a tile of one sample range whose merged result is that result (its sums
  // already float32), so its bytes are not written twice. FAILED_PRECONDITION without a result
  // pack; INVALID_ARGUMENT as put.
  absl::Status put_link(int tile, std::uint64_t offset, std::uint64_t size,
                        const std::array<std::uint8_t, 32>& sha256);
  // True when the tile's record is a link (its range result must stay in the result pack).
  bool linked(int tile) const;
  bool has(int tile) const;
  // DATA_LOSS naming the pack and the tile when it is missing, damaged or not this tile of this
  // job.
  absl::StatusOr<image::TileResult> get(int tile) const;

  // The finished image for image::write_spectral_exr_rows, in bands of band_rows() rows (one
  // row of tiles): each band reads and finalises that row's tiles into `buffer`.
  image::SpectralRows rows(TileFinaliser finalise, std::vector<float>* buffer) const;
  int band_rows() const { return plan_.tiles.empty() ? 1 : plan_.tiles.front().height(); }

  // fdatasync of the pack: every record put before the call is durable. Before a tile's range
  // results are released from the result pack (FarmCoordinator's janitor), so that a restart
  // finds the tile whole. Thread-safe.
  absl::Status sync() const;

  // Deletes the directory and everything in it (the job is over).
  absl::Status remove() const;

  const std::filesystem::path& dir() const { return dir_; }
  std::filesystem::path pack_path() const { return dir_ / "tiles.pack"; }

  FinishedTiles(FinishedTiles&&) noexcept;
  ~FinishedTiles();

 private:
  struct Record {
    std::uint64_t offset = 0;  // of the bytes: after the header, or in the result pack (linked)
    std::uint64_t size = 0;
    std::array<std::uint8_t, 32> sha256{};
    bool linked = false;
  };
  FinishedTiles(std::filesystem::path dir, TilePlan plan, int width, int bins, int fd,
                std::shared_ptr<const ResultPack> results);
  absl::Status append(int tile, const std::string& record, const Record& entry);
  absl::Status scan();

  std::filesystem::path dir_;
  TilePlan plan_;
  int width_;
  int bins_;
  int fd_ = -1;
  std::shared_ptr<const ResultPack> results_;
  std::unique_ptr<std::mutex> mutex_;           // guards records_ and end_
  std::vector<std::optional<Record>> records_;  // by tile
  std::uint64_t end_ = 0;
};

}  // namespace prism::coordinator
