#include "services/store/group_commit.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

namespace prism::store {
namespace {

TEST(GroupCommitTest, EveryWaiterIsCoveredByAFlushBegunAfterItsWriteAndFlushesAreShared) {
  constexpr int kThreads = 16;
  constexpr int kWrites = 100;
  GroupCommit* self = nullptr;
  std::atomic<std::uint64_t> durable_mark{0};
  std::atomic<int> flushing{0};
  std::atomic<bool> overlapped{false};
  GroupCommit group([&] {
    if (flushing.fetch_add(1) != 0) overlapped = true;
    // Everything noted before this point is what the flush covers.
    const std::uint64_t covers = self->last_ticket();
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
    std::uint64_t mark = durable_mark.load();
    while (mark < covers && !durable_mark.compare_exchange_weak(mark, covers)) {
    }
    flushing.fetch_sub(1);
    return absl::OkStatus();
  });
  self = &group;
  std::atomic<int> uncovered{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&] {
      for (int i = 0; i < kWrites; ++i) {
        const std::uint64_t ticket = group.note_write();
        ASSERT_TRUE(group.wait(ticket).ok());
        if (durable_mark.load() < ticket) ++uncovered;
      }
    });
  }
  for (std::thread& thread : threads) thread.join();
  EXPECT_EQ(uncovered.load(), 0);
  EXPECT_FALSE(overlapped.load()) << "two flushes ran at once";
  EXPECT_EQ(group.last_ticket(), std::uint64_t(kThreads * kWrites));
  // 16 writers arrive during each 2 ms flush: the next flush serves them all at once.
  EXPECT_LE(group.flushes(), std::uint64_t(kThreads * kWrites / 2));
  EXPECT_GE(group.flushes(), std::uint64_t(kWrites));
}

TEST(GroupCommitTest, ADurableTicketNeedsNoFlushAndNothingNotedNeedsNone) {
  int flushes = 0;
  GroupCommit group([&] {
    ++flushes;
    return absl::OkStatus();
  });
  EXPECT_TRUE(group.wait(0).ok());
  EXPECT_EQ(flushes, 0);
  const std::uint64_t first = group.note_write();
  const std::uint64_t second = group.note_write();
  EXPECT_TRUE(group.wait(first).ok());
  EXPECT_EQ(flushes, 1);
  // The flush covered both writes.
  EXPECT_TRUE(group.wait(second).ok());
  EXPECT_TRUE(group.wait(first).ok());
  EXPECT_EQ(flushes, 1);
  EXPECT_TRUE(group.wait(group.note_write()).ok());
  EXPECT_EQ(flushes, 2);
}

TEST(GroupCommitTest, AFailedFlushFailsEveryLaterWaitToo) {
  int flushes = 0;
  GroupCommit group([&] {
    ++flushes;
    if (flushes == 2) return absl::InternalError("cannot sync jobs.db-wal: Input/output error");
    return absl::OkStatus();
  });
  const std::uint64_t before = group.note_write();
  ASSERT_TRUE(group.wait(before).ok());
  const absl::Status failed = group.wait(group.note_write());
  EXPECT_EQ(failed.code(), absl::StatusCode::kInternal);
  EXPECT_NE(failed.message().find("Input/output error"), std::string::npos) << failed;
  EXPECT_NE(failed.message().find("may not be durable"), std::string::npos) << failed;
  // A later write is refused without another flush that could hide what the kernel dropped;
  // so is an earlier ticket, which the failure may have undone.
  EXPECT_EQ(group.wait(group.note_write()).code(), absl::StatusCode::kInternal);
  EXPECT_EQ(group.wait(before).code(), absl::StatusCode::kInternal);
  EXPECT_EQ(flushes, 2);
}

}  // namespace
}  // namespace prism::store
