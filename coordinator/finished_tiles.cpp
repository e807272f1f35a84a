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
constexpr std::size_t kHeaderBytes = 4 + 4 + 8 + 32;

using base::get_le;
using base::put_le;

}  // namespace

absl::StatusOr<FinishedTiles> FinishedTiles::open(fs::path dir, TilePlan plan, int width,
                                                  int bins) {
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
  FinishedTiles tiles(std::move(dir), std::move(plan), width, bins, fd);
  PRISM_RETURN_IF_ERROR(tiles.scan());
  return tiles;
}

FinishedTiles::FinishedTiles(fs::path dir, TilePlan plan, int width, int bins, int fd)
    : dir_(std::move(dir)),
      plan_(std::move(plan)),
      width_(width),
      bins_(bins),
      fd_(fd),
      mutex_(std::make_unique<std::mutex>()),
      records_(plan_.tiles.size()) {}

FinishedTiles::FinishedTiles(FinishedTiles&& other) noexcept
    : dir_(std::move(other.dir_)),
      plan_(std::move(other.plan_)),
      width_(other.width_),
      bins_(other.bins_),
      fd_(std::exchange(other.fd_, -1)),
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
  char header[kHeaderBytes];
  while (at + kHeaderBytes <= size) {
    if (!base::pread_all(fd_, header, kHeaderBytes, at, "tile pack").ok()) break;
    if (std::memcmp(header, kRecordMagic, 4) != 0) break;
    const std::uint64_t tile = get_le(header + 4, 4);
    const std::uint64_t bytes = get_le(header + 8, 8);
    if (tile >= records_.size() || bytes > size - at - kHeaderBytes) break;
    Record record{at + kHeaderBytes, bytes, {}};
    std::memcpy(record.sha256.data(), header + 16, 32);
    records_[tile] = record;
    at += kHeaderBytes + bytes;
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
  std::lock_guard<std::mutex> lock(*mutex_);
  PRISM_RETURN_IF_ERROR(base::pwrite_all(fd_, record.data(), record.size(), end_,
                                         absl::StrCat("tile pack ", pack_path().string())));
  records_[static_cast<std::size_t>(tile)] = Record{end_ + kHeaderBytes, size, digest};
  end_ += record.size();
  return absl::OkStatus();
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
  std::string bytes(record->size, '\0');
  PRISM_RETURN_IF_ERROR(
      base::pread_all(fd_, bytes.data(), bytes.size(), record->offset, "tile pack"));
  base::Sha256 hasher;
  hasher.update(bytes);
  if (hasher.digest() != record->sha256) return fail("its bytes do not match their hash");
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
