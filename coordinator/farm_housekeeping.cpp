// FarmCoordinator's housekeeping (farm_coordinator.h): a finished job's files leave the data
// directory at once (renamed into the trash, under the lock) and are deleted by the janitor
// thread, which also rewrites finished jobs' convergence series and counts the data directory
// for /metrics, all without the farm's lock.
#include <sys/stat.h>

#include <algorithm>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "coordinator/farm_coordinator.h"
#include "services/base/atomic_file.h"

namespace prism::coordinator {

namespace fs = std::filesystem;
using SteadyClock = std::chrono::steady_clock;

void FarmCoordinator::clean_up_locked(const std::string& job_id) {
  close_convergence_locked(job_id);
  // A fresh name per clean-up: a job cleaned up again (after a restart) never meets its old
  // trash.
  const fs::path trash =
      trash_dir() / absl::StrCat(job_id, "-", ++temp_counter_, "-", now().count());
  std::error_code ec;
  const fs::path job_dir = options_.data_dir / "jobs" / job_id;
  if (fs::exists(job_dir, ec)) {
    fs::rename(job_dir, trash, ec);
    if (ec) {
      options_.logger->warn("[job {}] cannot move its tiles to the trash: {}", job_id,
                            ec.message());
      fs::remove_all(job_dir, ec);
    }
  }
  absl::StatusOr<std::vector<std::string>> unshared = store_->unshared_results(job_id);
  if (!unshared.ok()) {
    options_.logger->warn("[job {}] cannot list its results: {}", job_id,
                          unshared.status().ToString());
  } else if (!unshared->empty()) {
    const fs::path blobs = trash.string() + "-results";
    if (absl::Status made = base::make_directories(blobs); !made.ok()) {
      options_.logger->warn("[job {}] {}", job_id, made.ToString());
    }
    for (const std::string& hash : *unshared) {
      // The blob leaves the store now: a later job's identical result is written afresh.
      absl::Status moved = blobs_->discard(hash, blobs);
      if (!moved.ok()) moved = blobs_->remove(hash);
      if (!moved.ok()) {
        options_.logger->warn("[job {}] cannot delete result {}: {}", job_id, hash,
                              moved.ToString());
      }
    }
  }
  {
    std::lock_guard<std::mutex> lock(janitor_mutex_);
    janitor_pending_ = true;
  }
  janitor_wake_.notify_one();
}

void FarmCoordinator::reclaim_locked(const std::string& job_id, ActiveJob& job) {
  if (job.reclaimable.empty() || job.tiles == nullptr || job.results == nullptr) return;
  {
    std::lock_guard<std::mutex> lock(janitor_mutex_);
    janitor_reclaim_.push_back({job_id, job.tiles, job.results, std::move(job.reclaimable)});
  }
  job.reclaimable.clear();
  janitor_wake_.notify_one();
}

void FarmCoordinator::janitor_loop() {
  std::unique_lock<std::mutex> lock(janitor_mutex_);
  SteadyClock::time_point counted;  // the data directory's last count (none yet)
  while (true) {
    // Woken by clean-ups (the trash to empty) and at least every kDataDirBytesInterval, to
    // count the data directory for /metrics: a walk over many jobs' files takes too long for
    // the scrape to wait on it.
    if (counted != SteadyClock::time_point()) {
      janitor_wake_.wait_for(lock, kDataDirBytesInterval, [this] {
        return janitor_pending_ || janitor_stopping_ || !janitor_reclaim_.empty();
      });
    }
    if (janitor_stopping_) {
      // The finished series are small and quick to write; the trash waits for the next start.
      auto series = std::move(janitor_series_);
      janitor_series_.clear();
      lock.unlock();
      for (auto& [job_id, points] : series) finish_convergence(job_id, std::move(points));
      return;
    }
    const bool empty_trash = janitor_pending_;
    janitor_pending_ = false;
    auto series = std::move(janitor_series_);
    janitor_series_.clear();
    std::vector<Reclaim> reclaim = std::move(janitor_reclaim_);
    janitor_reclaim_.clear();
    lock.unlock();
    for (auto& [job_id, points] : series) finish_convergence(job_id, std::move(points));
    // A job's tile records first, then the range results they hold merged. A job that ended
    // meanwhile has its files in the trash already: releasing their bytes is harmless.
    // One sync per tile pack covers every entry of this batch (their records were put before
    // they were queued).
    std::vector<const FinishedTiles*> synced;
    for (const Reclaim& r : reclaim) {
      if (reclaim_unsupported_) break;
      absl::Status done;
      if (std::find(synced.begin(), synced.end(), r.tiles.get()) == synced.end()) {
        done = r.tiles->sync();
        if (done.ok()) synced.push_back(r.tiles.get());
      }
      std::uint64_t bytes = 0;
      for (const store::ResultLocation& range : r.ranges) {
        if (!done.ok()) break;
        done = r.results->release(std::uint64_t(range.offset), range.size);
        bytes += range.size;
      }
      if (absl::IsUnimplemented(done)) {
        reclaim_unsupported_ = true;
        options_.logger->warn("{}; finished tiles' results stay on disk until their job ends",
                              done.ToString());
      } else if (!done.ok()) {
        options_.logger->warn("[job {}] {}", r.job_id, done.ToString());
      } else {
        metrics_.results_released(r.ranges.size(), bytes);
        options_.logger->debug("[job {}] released {} bytes of {} merged results", r.job_id, bytes,
                               r.ranges.size());
      }
    }
    if (empty_trash) {
      // Entries are whole: clean_up_locked renames each in complete. A crash midway leaves the
      // rest for the next start.
      std::error_code ec;
      for (const auto& entry : fs::directory_iterator(trash_dir(), ec)) {
        std::error_code removed;
        fs::remove_all(entry.path(), removed);
        if (removed) {
          options_.logger->warn("cannot delete {}: {}", entry.path().string(), removed.message());
        }
      }
    }
    // A disk reserve a cancel used is made again once there is room (the trash emptied).
    keep_disk_reserve();
    if (SteadyClock::now() - counted >= kDataDirBytesInterval) {
      data_dir_bytes_.store(count_data_dir_bytes(), std::memory_order_relaxed);
      counted = SteadyClock::now();
    }
    lock.lock();
  }
}

std::uint64_t FarmCoordinator::count_data_dir_bytes() const {
  // Needs no farm lock: the files are published atomically, and one that vanishes while it is
  // counted is skipped.
  std::uint64_t total = 0;
  std::error_code ec;
  for (auto it = std::filesystem::recursive_directory_iterator(options_.data_dir, ec);
       !ec && it != std::filesystem::recursive_directory_iterator(); it.increment(ec)) {
    // The blocks a file holds, not its length: result packs have holes (released results).
    struct stat st {};
    if (::lstat(it->path().c_str(), &st) == 0 && S_ISREG(st.st_mode)) {
      total += std::uint64_t(st.st_blocks) * 512;
    }
  }
  return total;
}

}  // namespace prism::coordinator
