#include "coordinator/tile_merge.h"

#include <algorithm>
#include <string_view>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/sha256.h"

namespace prism::coordinator {
namespace {

template <typename T>
void hash_span(base::Sha256& hasher, std::span<const T> values) {
  hasher.update(
      std::string_view(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(T)));
}

template <typename T>
void hash_value(base::Sha256& hasher, const T& value) {
  hash_span(hasher, std::span<const T>(&value, 1));
}

std::string task_name(int tile, const image::SampleRange& range) {
  return absl::StrCat("tile ", tile, " samples [", range.s0, ",", range.s1, ")");
}

}  // namespace

std::array<std::uint8_t, 32> tile_result_digest(const image::TileResult& result) {
  base::Sha256 hasher;
  const image::TileRect& r = result.rect();
  const std::int64_t header[] = {r.x0,
                                 r.y0,
                                 r.x1,
                                 r.y1,
                                 static_cast<std::int64_t>(result.samples().s0),
                                 static_cast<std::int64_t>(result.samples().s1),
                                 result.bins(),
                                 result.has_gradients(),
                                 result.has_guides(),
                                 result.counter_count(),
                                 result.has_halves(),
                                 result.has_rgb(),
                                 result.has_filtered(),
                                 result.has_offsets()};
  hash_span(hasher, std::span<const std::int64_t>(header));
  for (const std::string& name : result.buffers().counter_names) {
    hash_value(hasher, name.size());
    hasher.update(name);
  }
  hash_span(hasher, result.sums());
  hash_span(hasher, result.sum_squares());
  hash_span(hasher, result.counts());
  hash_span(hasher, result.gradients());
  hash_span(hasher, result.gradient_squares());
  hash_span(hasher, result.half_sums());
  hash_span(hasher, result.half_sum_squares());
  hash_span(hasher, result.half_gradients());
  hash_span(hasher, result.half_gradient_squares());
  hash_span(hasher, result.half_counts());
  hash_span(hasher, result.rgb_sums());
  hash_span(hasher, result.rgb_squares());
  hash_span(hasher, result.filtered_sums());
  hash_span(hasher, result.filtered_rgb_sums());
  hash_span(hasher, result.offsets());
  hash_span(hasher, result.depth());
  hash_span(hasher, result.normals());
  hash_span(hasher, result.albedo());
  hash_span(hasher, result.counters());
  return hasher.digest();
}

absl::StatusOr<std::unique_ptr<TileAssembler>> TileAssembler::create(TilePlan plan, int bins,
                                                                     TileCallback on_tile,
                                                                     TileFinaliser finalise,
                                                                     Arrivals arrivals) {
  if (plan.tiles.empty() || plan.ranges.empty()) {
    return absl::InvalidArgumentError("cannot assemble a plan without tiles or sample ranges");
  }
  if (bins < 1 || bins > image::kMaxChannels) {
    return absl::InvalidArgumentError(absl::StrCat("bins ", bins, " is out of range"));
  }
  for (std::size_t i = 1; i < plan.ranges.size(); ++i) {
    if (plan.ranges[i].s0 != plan.ranges[i - 1].s1) {
      return absl::InvalidArgumentError("the plan's sample ranges must be adjacent and ascending");
    }
  }
  PRISM_CHECK(on_tile != nullptr);
  if (!finalise) finalise = mean_finaliser();
  return std::unique_ptr<TileAssembler>(
      new TileAssembler(std::move(plan), bins, std::move(on_tile), std::move(finalise), arrivals));
}

TileAssembler::TileAssembler(TilePlan plan, int bins, TileCallback on_tile, TileFinaliser finalise,
                             Arrivals arrivals)
    : plan_(std::move(plan)),
      bins_(bins),
      on_tile_(std::move(on_tile)),
      finalise_(std::move(finalise)),
      arrivals_(arrivals) {
  tiles_.resize(plan_.tiles.size());
  for (TileState& tile : tiles_) tile.digests.resize(plan_.ranges.size());
}

int TileAssembler::range_index(const image::SampleRange& range) const {
  auto it = std::lower_bound(
      plan_.ranges.begin(), plan_.ranges.end(), range,
      [](const image::SampleRange& a, const image::SampleRange& b) { return a.s0 < b.s0; });
  if (it == plan_.ranges.end() || *it != range) return -1;
  return static_cast<int>(it - plan_.ranges.begin());
}

absl::Status TileAssembler::add(int tile_index, image::TileResult result,
                                const std::optional<Digest>& encoded_sha256) {
  if (tile_index < 0 || static_cast<std::size_t>(tile_index) >= plan_.tiles.size()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "tile index ", tile_index, " is outside the plan's ", plan_.tiles.size(), " tiles"));
  }
  const std::string name = task_name(tile_index, result.samples());
  if (result.rect() != plan_.tiles[tile_index]) {
    return absl::InvalidArgumentError(absl::StrCat(name, ": rect ", to_string(result.rect()),
                                                   " is not the plan's ",
                                                   to_string(plan_.tiles[tile_index])));
  }
  if (result.bins() != bins_) {
    return absl::InvalidArgumentError(
        absl::StrCat(name, ": ", result.bins(), " bins, the job has ", bins_));
  }
  const int range = range_index(result.samples());
  if (range < 0) {
    return absl::InvalidArgumentError(absl::StrCat(name, ": not a sample range of the plan"));
  }
  // What a worker sends is rounded already; a local render's results are rounded here, so both
  // merge the same values.
  result.round_to_float32();
  // Hashing reads the whole result: do it before taking the lock.
  const bool identify = arrivals_ == Arrivals::kAtLeastOnce;
  const Digest digest = !identify                    ? Digest{}
                        : encoded_sha256.has_value() ? *encoded_sha256
                                                     : tile_result_digest(result);

  std::vector<image::TileResult> parts;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    TileState& tile = tiles_[tile_index];
    if (tile.digests[range].has_value()) {
      if (!identify) {
        return absl::InternalError(
            absl::StrCat(name, " arrived twice in a render that runs each task once"));
      }
      if (*tile.digests[range] != digest) {
        return absl::DataLossError(absl::StrCat(
            name,
            " arrived twice with different contents: the renderer is not deterministic "
            "or the result was corrupted"));
      }
      ++duplicates_;
      return absl::OkStatus();
    }
    if (tile.finished) {
      return absl::FailedPreconditionError(absl::StrCat(
          name,
          ": the tile was finished before the coordinator restarted; results for it are "
          "no longer taken"));
    }
    for (const auto& other : tile.parts) {
      if (other.has_value() && other->buffers() != result.buffers()) {
        return absl::InvalidArgumentError(absl::StrCat(
            name, ": its optional buffers differ from those of the tile's other ranges"));
      }
    }
    if (tile.received == 0) {
      tile.parts.resize(plan_.ranges.size());
      ++in_flight_;
      peak_in_flight_ = std::max(peak_in_flight_, in_flight_);
    }
    tile.digests[range] = digest;
    tile.parts[range] = std::move(result);
    ++tile.received;
    if (tile.received < static_cast<int>(plan_.ranges.size())) return absl::OkStatus();
    parts.reserve(tile.parts.size());
    for (auto& part : tile.parts) parts.push_back(std::move(*part));
    tile.parts.clear();
    tile.parts.shrink_to_fit();
  }

  // Fixed order: range 0 first, then each following range; every range is present and adjacent,
  // so add() cannot fail here.
  image::TileResult merged = std::move(parts.front());
  for (std::size_t i = 1; i < parts.size(); ++i) {
    absl::Status added = merged.add(parts[i]);
    PRISM_CHECK_MSG(added.ok(), "ranges of one plan always merge");
  }
  // One range was rounded as it came in; the sum of several is rounded again.
  if (parts.size() > 1) merged.round_to_float32();
  parts.clear();
  absl::StatusOr<image::SpectralImage> finalised = finalise_(merged);
  absl::Status status =
      finalised.ok() ? on_tile_(tile_index, merged, *finalised) : finalised.status();
  std::lock_guard<std::mutex> lock(mutex_);
  tiles_[tile_index].finished = true;
  ++finished_;
  --in_flight_;
  return status;
}

absl::Status TileAssembler::mark_finished(int tile_index) {
  if (tile_index < 0 || static_cast<std::size_t>(tile_index) >= plan_.tiles.size()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "tile index ", tile_index, " is outside the plan's ", plan_.tiles.size(), " tiles"));
  }
  std::lock_guard<std::mutex> lock(mutex_);
  TileState& tile = tiles_[tile_index];
  if (tile.finished || tile.received > 0) {
    return absl::FailedPreconditionError(absl::StrCat(
        "tile ", tile_index, tile.finished ? " is already finished" : " already has results"));
  }
  tile.finished = true;
  ++finished_;
  return absl::OkStatus();
}

absl::Status TileAssembler::check_complete() const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_ == static_cast<int>(tiles_.size())) return absl::OkStatus();
  std::string missing;
  int listed = 0;
  std::uint64_t total = 0;
  for (std::size_t t = 0; t < tiles_.size(); ++t) {
    if (tiles_[t].finished) continue;
    for (std::size_t r = 0; r < plan_.ranges.size(); ++r) {
      if (tiles_[t].digests[r].has_value()) continue;
      ++total;
      if (listed < 8) {
        absl::StrAppend(&missing, listed == 0 ? "" : ", ",
                        task_name(static_cast<int>(t), plan_.ranges[r]));
        ++listed;
      }
    }
  }
  return absl::FailedPreconditionError(
      absl::StrCat(tiles_.size() - finished_, " of ", tiles_.size(), " tiles are unfinished; ",
                   total, " task results missing",
                   total == 0 ? "" : absl::StrCat(": ", missing, total > 8 ? ", ..." : "")));
}

int TileAssembler::tiles_finished() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return finished_;
}

int TileAssembler::tiles_in_flight() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return in_flight_;
}

int TileAssembler::peak_tiles_in_flight() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return peak_in_flight_;
}

std::uint64_t TileAssembler::duplicates_ignored() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return duplicates_;
}

}  // namespace prism::coordinator
