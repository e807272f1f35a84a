#include "coordinator/finished_tiles.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <optional>
#include <system_error>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/little_endian.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/tile_codec.h"

namespace prism::coordinator {

namespace fs = std::filesystem;

namespace {

constexpr char kRecordMagic[4] = {'P', 'R', 'T', 'R'};
constexpr char kLinkMagic[4] = {'P', 'R', 'T', 'L'};
constexpr std::size_t kHeaderBytes = 4 + 4 + 8 + 32;
constexpr std::size_t kLinkBytes = kHeaderBytes + 8;  // and the offset in the result pack

using base::get_le;
using base::put_le;

}  // namespace

absl::StatusOr<FinishedTiles> FinishedTiles::open(fs::path dir, TilePlan plan, int width, int bins,
                                                  std::shared_ptr<const ResultPack> results) {
  if (plan.tiles.empty() || width < 1 || bins < 1 || bins > image::kMaxChannels) {
    return absl::InvalidArgumentError(
        absl::StrCat("finished tiles need a plan with tiles, width ", width, " and bins ", bins));
  }
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    return absl::InternalError(
        absl::StrCat("cannot create the tile directory ", dir.string(), ": ", ec.message()));
  }
  const fs::path path = dir / "tiles.pack";
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    return absl::InternalError(
        absl::StrCat("cannot open the tile pack ", path.string(), ": ", std::strerror(errno)));
  }
  FinishedTiles tiles(std::move(dir), std::move(plan), width, bins, fd, std::move(results));
  PRISM_RETURN_IF_ERROR(tiles.scan());
  return tiles;
}

FinishedTiles::FinishedTiles(fs::path dir, TilePlan plan, int width, int bins, int fd,
                             std::shared_ptr<const ResultPack> results)
    : dir_(std::move(dir)),
      plan_(std::move(plan)),
      width_(width),
      bins_(bins),
      fd_(fd),
      results_(std::move(results)),
      mutex_(std::make_unique<std::mutex>()),
      records_(plan_.tiles.size()) {}

FinishedTiles::FinishedTiles(FinishedTiles&& other) noexcept
    : dir_(std::move(other.dir_)),
      plan_(std::move(other.plan_)),
      width_(other.width_),
      bins_(other.bins_),
      fd_(std::exchange(other.fd_, -1)),
      results_(std::move(other.results_)),
      mutex_(std::move(other.mutex_)),
      records_(std::move(other.records_)),
      end_(other.end_) {}

FinishedTiles::~FinishedTiles() {
  if (fd_ >= 0) ::close(fd_);
}

absl::Status FinishedTiles::scan() {
  struct stat st {};
  if (::fstat(fd_, &st) != 0) {
    return absl::InternalError(absl::StrCat("cannot stat the tile pack ", pack_path().string(),
                                            ": ", std::strerror(errno)));
  }
  const std::uint64_t size = std::uint64_t(st.st_size);
  std::uint64_t at = 0;
  char header[kLinkBytes];
  while (at + kHeaderBytes <= size) {
    if (!base::pread_all(fd_, header, kHeaderBytes, at, "tile pack").ok()) break;
    const bool link = std::memcmp(header, kLinkMagic, 4) == 0;
    if (!link && std::memcmp(header, kRecordMagic, 4) != 0) break;
    const std::uint64_t tile = get_le(header + 4, 4);
    const std::uint64_t bytes = get_le(header + 8, 8);
    if (tile >= records_.size()) break;
    Record record{at + kHeaderBytes, bytes, {}, link};
    std::memcpy(record.sha256.data(), header + 16, 32);
    if (link) {
      if (at + kLinkBytes > size) break;
      if (!base::pread_all(fd_, header + kHeaderBytes, 8, at + kHeaderBytes, "tile pack").ok()) {
        break;
      }
      record.offset = get_le(header + kHeaderBytes, 8);
      at += kLinkBytes;
    } else {
      if (bytes > size - at - kHeaderBytes) break;
      at += kHeaderBytes + bytes;
    }
    records_[tile] = record;
  }
  // A torn last record (a crash while appending) is written over.
  end_ = at;
  return absl::OkStatus();
}

absl::Status FinishedTiles::put(int tile, const image::TileResult& merged) {
  if (tile < 0 || static_cast<std::size_t>(tile) >= plan_.tiles.size() ||
      merged.rect() != plan_.tiles[static_cast<std::size_t>(tile)] || merged.bins() != bins_) {
    return absl::InvalidArgumentError(absl::StrCat("tile ", tile, " (", to_string(merged.rect()),
                                                   ") is not a tile of this job's plan"));
  }
  std::string record(kHeaderBytes, '\0');
  record += image::serialise_tile(merged);
  const std::uint64_t size = record.size() - kHeaderBytes;
  base::Sha256 hasher;
  hasher.update(std::string_view(record).substr(kHeaderBytes));
  const std::array<std::uint8_t, 32> digest = hasher.digest();
  std::memcpy(record.data(), kRecordMagic, 4);
  put_le(record.data() + 4, std::uint64_t(tile), 4);
  put_le(record.data() + 8, size, 8);
  std::memcpy(record.data() + 16, digest.data(), 32);
  return append(tile, record, Record{kHeaderBytes, size, digest, false});
}

absl::Status FinishedTiles::put_link(int tile, std::uint64_t offset, std::uint64_t size,
                                     const std::array<std::uint8_t, 32>& sha256) {
  if (tile < 0 || static_cast<std::size_t>(tile) >= plan_.tiles.size()) {
    return absl::InvalidArgumentError(
        absl::StrCat("tile ", tile, " is not a tile of this job's plan"));
  }
  if (results_ == nullptr) {
    return absl::FailedPreconditionError(
        absl::StrCat("tile ", tile, ": no result pack to link finished tiles to"));
  }
  std::string record(kLinkBytes, '\0');
  std::memcpy(record.data(), kLinkMagic, 4);
  put_le(record.data() + 4, std::uint64_t(tile), 4);
  put_le(record.data() + 8, size, 8);
  std::memcpy(record.data() + 16, sha256.data(), 32);
  put_le(record.data() + kHeaderBytes, offset, 8);
  return append(tile, record, Record{offset, size, sha256, true});
}

// Writes `record` at the end; `entry` is its index entry, with the offset of a record's bytes
// relative to the record's start.
absl::Status FinishedTiles::append(int tile, const std::string& record, const Record& entry) {
  std::lock_guard<std::mutex> lock(*mutex_);
  PRISM_RETURN_IF_ERROR(base::pwrite_all(fd_, record.data(), record.size(), end_,
                                         absl::StrCat("tile pack ", pack_path().string())));
  Record indexed = entry;
  if (!indexed.linked) indexed.offset += end_;
  records_[static_cast<std::size_t>(tile)] = indexed;
  end_ += record.size();
  return absl::OkStatus();
}

bool FinishedTiles::linked(int tile) const {
  std::lock_guard<std::mutex> lock(*mutex_);
  return tile >= 0 && static_cast<std::size_t>(tile) < records_.size() &&
         records_[static_cast<std::size_t>(tile)].has_value() &&
         records_[static_cast<std::size_t>(tile)]->linked;
}

absl::Status FinishedTiles::sync() const {
  if (::fdatasync(fd_) != 0) {
    return absl::InternalError(absl::StrCat("cannot sync the tile pack ", pack_path().string(),
                                            ": ", std::strerror(errno)));
  }
  return absl::OkStatus();
}

bool FinishedTiles::has(int tile) const {
  std::lock_guard<std::mutex> lock(*mutex_);
  return tile >= 0 && static_cast<std::size_t>(tile) < records_.size() &&
         records_[static_cast<std::size_t>(tile)].has_value();
}

absl::StatusOr<image::TileResult> FinishedTiles::get(int tile) const {
  auto fail = [&](const std::string& why) {
    return absl::DataLossError(
        absl::StrCat("finished tile ", tile, " in ", pack_path().string(), ": ", why));
  };
  if (tile < 0 || static_cast<std::size_t>(tile) >= plan_.tiles.size()) {
    return fail("not a tile of the plan");
  }
  std::optional<Record> record;
  {
    std::lock_guard<std::mutex> lock(*mutex_);
    record = records_[static_cast<std::size_t>(tile)];
  }
  if (!record.has_value()) return fail("not there");
  std::string bytes;
  if (record->linked) {
    if (results_ == nullptr) return fail("linked to a result pack that is not open");
    absl::StatusOr<std::string> linked =
        results_->read(record->offset, record->size, base::sha256_hex_of(record->sha256));
    if (!linked.ok()) return fail(std::string(linked.status().message()));
    bytes = *std::move(linked);
  } else {
    bytes.assign(record->size, '\0');
    PRISM_RETURN_IF_ERROR(
        base::pread_all(fd_, bytes.data(), bytes.size(), record->offset, "tile pack"));
    base::Sha256 hasher;
    hasher.update(bytes);
    if (hasher.digest() != record->sha256) return fail("its bytes do not match their hash");
  }
  absl::StatusOr<image::TileResult> result = image::parse_tile(bytes);
  if (!result.ok()) return fail(std::string(result.status().message()));
  if (result->rect() != plan_.tiles[static_cast<std::size_t>(tile)] || result->bins() != bins_) {
    return fail(absl::StrCat("holds ", to_string(result->rect()), " with ", result->bins(),
                             " bins, not this job's tile"));
  }
  return result;
}

image::SpectralRows FinishedTiles::rows(TileFinaliser finalise, std::vector<float>* buffer) const {
  return [this, finalise = std::move(finalise), buffer](int y0,
                                                        int rows) -> absl::StatusOr<const float*> {
    std::optional<image::SpectralImage> values;
    PRISM_RETURN_IF_ERROR(assemble_band(
        plan_, width_, bins_, y0, rows,
        [&](std::size_t t) -> absl::StatusOr<const float*> {
          PRISM_ASSIGN_OR_RETURN(image::TileResult merged, get(static_cast<int>(t)));
          PRISM_ASSIGN_OR_RETURN(values, finalise(merged));
          return values->data().data();
        },
        buffer));
    return buffer->data();
  };
}

absl::Status FinishedTiles::remove() const {
  std::error_code ec;
  fs::remove_all(dir_, ec);
  if (ec) {
    return absl::InternalError(
        absl::StrCat("cannot remove the tile directory ", dir_.string(), ": ", ec.message()));
  }
  return absl::OkStatus();
}

}  // namespace prism::coordinator
