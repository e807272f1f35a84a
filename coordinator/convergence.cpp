#include "coordinator/convergence.h"

#include <fcntl.h>
#include <unistd.h>

#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <string>
#include <system_error>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/little_endian.h"
#include "services/base/status.h"

namespace prism::coordinator {

ConvergenceTracker::ConvergenceTracker(std::uint64_t spp) : spp_(spp) {}

double ConvergenceTracker::variance_of_mean(const Pixel& p) {
  if (p.n < 2) return 0.0;
  const double n = double(p.n);
  const double variance = std::max(0.0, (p.squares - p.sum * p.sum / n) / (n - 1.0));
  return variance / n;
}

ConvergencePoint ConvergenceTracker::add(const image::TileResult& result, double seconds) {
  if (!result.has_rgb()) return {seconds, samples_, relative_error()};
  const image::TileRect& r = result.rect();
  const auto counts = result.counts();
  const auto sums = result.rgb_sums();
  const auto squares = result.rgb_squares();
  const auto key = std::make_pair(r.x0, r.y0);
  auto it = tiles_.find(key);
  if (it == tiles_.end()) {
    it = tiles_.emplace(key, Tile{std::vector<Pixel>(std::size_t(r.area())), 0}).first;
  }
  Tile& tile = it->second;
  for (std::size_t local = 0; local < counts.size(); ++local) {
    if (counts[local] == 0) continue;
    Pixel& p = tile.pixels[local];
    variance_total_ -= variance_of_mean(p);
    mean_total_ -= mean(p);
    p.n += counts[local];
    p.sum += sums[local * 3 + 1];
    p.squares += squares[local * 3 + 1];
    variance_total_ += variance_of_mean(p);
    mean_total_ += mean(p);
    samples_ += counts[local];
    tile.samples += counts[local];
  }
  // Every pixel has all its samples: nothing more comes for this tile.
  if (tile.samples >= std::uint64_t(r.area()) * spp_) tiles_.erase(it);
  return {seconds, samples_, relative_error()};
}

void append_point(std::vector<ConvergencePoint>& points, const ConvergencePoint& point) {
  points.push_back(point);
  if (points.size() <= kMaxConvergencePoints) return;
  std::vector<ConvergencePoint> thinned;
  for (std::size_t i = 0; i < points.size(); ++i)
    if (i % 2 == 0 || i + 1 == points.size()) thinned.push_back(points[i]);
  points = std::move(thinned);
}

double ConvergenceTracker::relative_error() const {
  if (mean_total_ == 0.0) return 0.0;
  return std::sqrt(std::max(0.0, variance_total_)) / std::abs(mean_total_);
}

namespace {

constexpr std::size_t kRecordBytes = 24;

std::string encode(const ConvergencePoint& point) {
  std::string out;
  base::append_le(out, std::bit_cast<std::uint64_t>(point.seconds), 8);
  base::append_le(out, point.samples, 8);
  base::append_le(out, std::bit_cast<std::uint64_t>(point.relative_error), 8);
  return out;
}

// The valid records at the start of `bytes`: each a finite, later point than the one before
// (more samples, no earlier time), its error finite and not negative.
std::vector<ConvergencePoint> decode(const std::string& bytes, std::uint64_t* valid_bytes) {
  std::vector<ConvergencePoint> points;
  std::size_t at = 0;
  ConvergencePoint previous;
  for (; at + kRecordBytes <= bytes.size(); at += kRecordBytes) {
    ConvergencePoint p;
    p.seconds = std::bit_cast<double>(base::get_le(bytes.data() + at, 8));
    p.samples = base::get_le(bytes.data() + at + 8, 8);
    p.relative_error = std::bit_cast<double>(base::get_le(bytes.data() + at + 16, 8));
    const bool later = p.samples > previous.samples && p.seconds >= previous.seconds;
    if (!std::isfinite(p.seconds) || !std::isfinite(p.relative_error) || p.relative_error < 0 ||
        !later) {
      break;
    }
    append_point(points, p);
    previous = p;
  }
  if (valid_bytes != nullptr) *valid_bytes = at;
  return points;
}

}  // namespace

absl::StatusOr<ConvergenceLog> ConvergenceLog::open(const std::filesystem::path& path,
                                                    std::vector<ConvergencePoint>* points) {
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    return absl::InternalError(
        absl::StrCat("cannot open ", path.string(), ": ", std::strerror(errno)));
  }
  std::string bytes;
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  if (!ec && size > 0) {
    bytes.resize(size);
    if (absl::Status read = base::pread_all(fd, bytes.data(), bytes.size(), 0, path.string());
        !read.ok()) {
      ::close(fd);
      return read;
    }
  }
  std::uint64_t valid = 0;
  std::vector<ConvergencePoint> read = decode(bytes, &valid);
  if (points != nullptr) *points = std::move(read);
  return ConvergenceLog(fd, valid);
}

ConvergenceLog::ConvergenceLog(ConvergenceLog&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)), size_(other.size_) {}

ConvergenceLog& ConvergenceLog::operator=(ConvergenceLog&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(other.fd_, -1);
    size_ = other.size_;
  }
  return *this;
}

ConvergenceLog::~ConvergenceLog() {
  if (fd_ >= 0) ::close(fd_);
}

absl::Status ConvergenceLog::append(const ConvergencePoint& point) {
  const std::string record = encode(point);
  // At the end of the valid records: a torn or stale tail left by a crash is overwritten.
  PRISM_RETURN_IF_ERROR(
      base::pwrite_all(fd_, record.data(), record.size(), size_, "the convergence series"));
  size_ += record.size();
  return absl::OkStatus();
}

std::vector<ConvergencePoint> read_convergence(const std::filesystem::path& path) {
  absl::StatusOr<std::string> bytes = base::read_file(path);
  if (!bytes.ok()) return {};
  return decode(*bytes, nullptr);
}

absl::Status write_convergence(const std::filesystem::path& path,
                               const std::vector<ConvergencePoint>& points) {
  std::string bytes;
  for (const ConvergencePoint& p : points) bytes += encode(p);
  return base::write_file_atomic(path, bytes);
}

}  // namespace prism::coordinator
