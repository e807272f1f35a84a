#include "services/store/group_commit.h"

#include <algorithm>
#include <utility>

#include "absl/strings/str_cat.h"

namespace prism::store {

GroupCommit::GroupCommit(std::function<absl::Status()> flush) : flush_(std::move(flush)) {}

std::uint64_t GroupCommit::note_write() {
  std::lock_guard<std::mutex> lock(mutex_);
  return ++written_;
}

std::uint64_t GroupCommit::last_ticket() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return written_;
}

std::uint64_t GroupCommit::flushes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return flushes_;
}

absl::Status GroupCommit::wait(std::uint64_t ticket) {
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    if (!failure_.ok()) return failure_;
    if (durable_ >= ticket) return absl::OkStatus();
    if (flushing_) {
      // The running flush may have begun before this write: wait for it, then look again.
      flushed_.wait(lock);
      continue;
    }
    flushing_ = true;
    const std::uint64_t covered = written_;
    lock.unlock();
    absl::Status flushed = flush_();
    lock.lock();
    flushing_ = false;
    ++flushes_;
    if (flushed.ok()) {
      durable_ = std::max(durable_, covered);
    } else {
      failure_ = absl::Status(flushed.code(),
                              absl::StrCat("a flush of the store failed, so what was written since "
                                           "the last good flush may not be durable: ",
                                           flushed.message()));
    }
    flushed_.notify_all();
  }
}

}  // namespace prism::store
