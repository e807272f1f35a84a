// Group commit: many writers, one flush. Writers that must not acknowledge anything before
// their write is on stable storage take a ticket after writing (note_write) and then wait for
// it (wait): the first waiter to find no flush running flushes everything written so far, and
// the writers that arrive meanwhile wait for the next flush, which covers all of them. Under
// load one fsync then serves a whole batch of writers instead of one each.
//
// A failed flush is final: after fsync reports an error the kernel may have dropped dirty
// pages that a later fsync would not report again, so nothing written before or after is
// confirmed durable any more, and every later wait returns that error (the process must be
// restarted and recover from what is on disk). Thread-safe.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>

#include "absl/status/status.h"

namespace prism::store {

class GroupCommit {
 public:
  // `flush` makes every write noted before it was called durable.
  explicit GroupCommit(std::function<absl::Status()> flush);

  GroupCommit(const GroupCommit&) = delete;
  GroupCommit& operator=(const GroupCommit&) = delete;

  // Counts one write that has reached the operating system; returns its ticket.
  std::uint64_t note_write();
  // The ticket of the latest write noted.
  std::uint64_t last_ticket() const;

  // Returns once a flush that began after write `ticket` was noted has finished (at once when
  // one already has), or that flush's error (see above).
  absl::Status wait(std::uint64_t ticket);

  // Flushes run so far, for measurements and tests.
  std::uint64_t flushes() const;

 private:
  std::function<absl::Status()> flush_;
  mutable std::mutex mutex_;
  std::condition_variable flushed_;
  std::uint64_t written_ = 0;  // tickets handed out
  std::uint64_t durable_ = 0;  // every ticket up to this one is durable
  bool flushing_ = false;
  std::uint64_t flushes_ = 0;
  absl::Status failure_;  // the first failed flush, final
};

}  // namespace prism::store
