// A running job's error estimate against time, for the dashboard's convergence plot. Each
// accepted final-pass result adds its samples' linear-sRGB green (a luminance proxy whose
// per-sample squares the results carry) to per-pixel sums; the estimate is the relative standard
// error of the image's mean green over the pixels sampled so far:
//   sqrt(Σ_p s²_p / n_p) / |Σ_p m_p|,  s²_p the sample variance and m_p the mean of pixel p.
// Pixels with fewer than two samples add no variance. Updating is O(the result's pixels). A
// tile's per-pixel sums are kept only until its pixels have all their samples (their share of
// the totals stays), so memory follows the tiles in flight, not the image (an 8K image's sums
// would be 0.8 GB).
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "services/image/tile.h"

namespace prism::coordinator {

struct ConvergencePoint {
  double seconds = 0;         // since the job started (this coordinator's incarnation)
  std::uint64_t samples = 0;  // pixel samples accepted so far
  double relative_error = 0;  // 0 until two samples of one pixel are in
};

class ConvergenceTracker {
 public:
  // `spp`: the most samples a pixel gets (a target-error job's max_spp).
  explicit ConvergenceTracker(std::uint64_t spp);
  // Adds a final-pass result (ignored without RGB buffers); the estimate after it, at `seconds`.
  ConvergencePoint add(const image::TileResult& result, double seconds);
  double relative_error() const;
  // Tiles whose per-pixel sums are kept (some pixel has fewer than spp samples).
  std::size_t tiles_in_flight() const { return tiles_.size(); }

 private:
  struct Pixel {
    std::uint64_t n = 0;
    double sum = 0, squares = 0;
  };
  static double variance_of_mean(const Pixel& p);
  static double mean(const Pixel& p) { return p.n > 0 ? p.sum / double(p.n) : 0.0; }

  struct Tile {
    std::vector<Pixel> pixels;
    std::uint64_t samples = 0;
  };
  // Tiles being rendered, by their rect's corner.
  std::map<std::pair<int, int>, Tile> tiles_;
  std::uint64_t spp_;
  double variance_total_ = 0;  // Σ_p s²_p / n_p
  double mean_total_ = 0;      // Σ_p m_p
  std::uint64_t samples_ = 0;
};

// Appends `point` to a job's series, keeping at most kMaxConvergencePoints: beyond that every
// other point is dropped (the first and the last stay).
inline constexpr std::size_t kMaxConvergencePoints = 2048;
void append_point(std::vector<ConvergencePoint>& points, const ConvergencePoint& point);

// A job's series on disk (data/convergence/<job id>), so the dashboard's plot survives a
// coordinator restart and the job's end. A running job appends one 24-byte record (seconds,
// samples, error; little-endian) per point, unsynced: a crash may tear the last record or leave
// zeros, and reading stops at the first record that is not a later point than the one before.
// When the job is over its file is rewritten with the thinned series (at most
// kMaxConvergencePoints records).
class ConvergenceLog {
 public:
  // Opens (creating) the file for appending; its valid points so far in `*points`, thinned.
  static absl::StatusOr<ConvergenceLog> open(const std::filesystem::path& path,
                                             std::vector<ConvergencePoint>* points);
  ConvergenceLog(ConvergenceLog&& other) noexcept;
  ConvergenceLog& operator=(ConvergenceLog&& other) noexcept;
  ConvergenceLog(const ConvergenceLog&) = delete;
  ConvergenceLog& operator=(const ConvergenceLog&) = delete;
  ~ConvergenceLog();

  absl::Status append(const ConvergencePoint& point);

 private:
  ConvergenceLog(int fd, std::uint64_t size) : fd_(fd), size_(size) {}
  int fd_ = -1;
  std::uint64_t size_ = 0;  // bytes of whole, valid records
};

// The valid points of a series file, thinned; empty when there is none.
std::vector<ConvergencePoint> read_convergence(const std::filesystem::path& path);
// Replaces the file with `points` (atomically).
absl::Status write_convergence(const std::filesystem::path& path,
                               const std::vector<ConvergencePoint>& points);

}  // namespace prism::coordinator
