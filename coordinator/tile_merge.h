// Merging task results into finished tiles. A job's plan (tile_plan.h) splits every tile into
// the same sample ranges; results arrive in any order, from any thread or worker, possibly
// more than once (retries, duplicated leases). The TileAssembler keeps a tile's partial results
// until every range of that tile is in, then adds them in range order: the merged doubles are
// therefore bit-identical whatever the arrival order (docs/estimators.md §7). Each result is
// rounded to float32 as it is added (a worker has rounded it already) and so is the merged
// tile (TileResult::round_to_float32): a local render and the farm merge the same values, and
// the codec stores both at half the bytes. The finished tile
// goes to a callback and its partial results are freed, so memory is bounded by the tiles in
// flight, not by the image.
//
// Duplicates are checked by content: every accepted (tile, range) keeps a SHA-256 of its
// result, also after the tile is finished, so a repeat with identical bytes is accepted and
// ignored, and a repeat with different bytes (a non-deterministic or faulty worker) is refused
// with DATA_LOSS and changes nothing.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "coordinator/tile_finaliser.h"
#include "coordinator/tile_plan.h"
#include "services/image/tile.h"

namespace prism::coordinator {

// Receives one finished tile: `merged` is the sum over all its ranges (samples() = [0, spp)),
// `finalised` its output values (the assembler's TileFinaliser: per-pixel means, or for a
// gradient job the reconstruction). Called exactly once per tile, outside the
// assembler's lock, possibly concurrently for different tiles. An error is returned by the
// add() that completed the tile.
using TileCallback = std::function<absl::Status(int tile_index, const image::TileResult& merged,
                                                const image::SpectralImage& finalised)>;

class TileAssembler {
 public:
  // How often a task's result can arrive.
  enum class Arrivals {
    // A farm: a task can be leased again and its result sent twice. Each accepted result's
    // identity (its encoded SHA-256, or tile_result_digest) is kept, so that a repeat is ignored
    // when its bytes are the same and refused when they differ.
    kAtLeastOnce,
    // A local render: each task runs once, so no result is identified (hashing every result
    // cost a quarter of a 1-spp render's CPU). A second arrival is a program error (INTERNAL).
    kExactlyOnce,
  };

  // INVALID_ARGUMENT when the plan has no tiles or ranges, or bins is outside [1,
  // image::kMaxChannels]. `finalise` (default: mean_finaliser()) runs on each finished tile before
  // the callback; its error is returned by the add() that completed the tile, and the tile counts
  // as finished.
  static absl::StatusOr<std::unique_ptr<TileAssembler>> create(
      TilePlan plan, int bins, TileCallback on_tile, TileFinaliser finalise = nullptr,
      Arrivals arrivals = Arrivals::kAtLeastOnce);

  // Accepts the result of task (tile_index, result.samples()). Thread-safe.
  //  - INVALID_ARGUMENT (nothing kept) when the tile index is out of range, the rect is not the
  //    plan's rect for that tile, the bins differ, the sample range is not one of the plan's,
  //    or the optional buffers differ from the tile's other ranges.
  //  - OK and ignored when the same bytes were already accepted for that (tile, range);
  //    DATA_LOSS when different bytes were (INTERNAL for any repeat under kExactlyOnce).
  //  - Otherwise OK; when this completes the tile, the callback's status.
  // `encoded_sha256`: the SHA-256 of the result's tile-codec bytes when the caller has it (the
  // farm checked it on upload; one encoding per result, so it identifies the result as well as
  // tile_result_digest, which is computed otherwise; neither under kExactlyOnce). One job's
  // results must all be added with it or all without.
  absl::Status add(int tile_index, image::TileResult result,
                   const std::optional<std::array<std::uint8_t, 32>>& encoded_sha256 = {});

  // Records tile `tile_index` as finished without its ranges: a restarted coordinator's tile
  // that was finished (and stored, see finished_tiles.h) before the restart. The callback is not
  // called. Later results for its ranges are refused with FAILED_PRECONDITION (the scheduler
  // never leases a done task again, so only a stale worker can send one). INVALID_ARGUMENT for
  // an index outside the plan; FAILED_PRECONDITION when the tile has results or is finished.
  absl::Status mark_finished(int tile_index);

  // OK when every tile is finished; FAILED_PRECONDITION listing (up to 8) missing
  // (tile, range) pairs otherwise.
  absl::Status check_complete() const;

  const TilePlan& plan() const { return plan_; }
  int tiles_finished() const;
  // Tiles holding partial results now, and the most there ever were.
  int tiles_in_flight() const;
  int peak_tiles_in_flight() const;
  // Results whose bytes repeated an accepted one.
  std::uint64_t duplicates_ignored() const;

 private:
  using Digest = std::array<std::uint8_t, 32>;
  struct TileState {
    std::vector<std::optional<image::TileResult>> parts;  // per range, until finished
    std::vector<std::optional<Digest>> digests;           // per range, kept for good (all
                                                          // zero under kExactlyOnce)
    int received = 0;
    bool finished = false;
  };

  TileAssembler(TilePlan plan, int bins, TileCallback on_tile, TileFinaliser finalise,
                Arrivals arrivals);
  // Index of `range` in the plan, or -1.
  int range_index(const image::SampleRange& range) const;

  const TilePlan plan_;
  const int bins_;
  const TileCallback on_tile_;
  const TileFinaliser finalise_;
  const Arrivals arrivals_;
  mutable std::mutex mutex_;
  std::vector<TileState> tiles_;
  int finished_ = 0;
  int in_flight_ = 0;
  int peak_in_flight_ = 0;
  std::uint64_t duplicates_ = 0;
};

// SHA-256 over everything that identifies a result: rect, samples, bins, buffer flags, counter
// names and every buffer's bytes.
std::array<std::uint8_t, 32> tile_result_digest(const image::TileResult& result);

}  // namespace prism::coordinator
