#include "coordinator/resource_plan.h"

#include <gtest/gtest.h>

#include <string>

#include "coordinator/spectral_stream.h"
#include "services/base/testing/status_says.h"

namespace prism::coordinator {
namespace {

std::uint64_t item(const std::vector<ResourceItem>& items, const std::string& what) {
  for (const ResourceItem& i : items) {
    if (i.what == what) return i.bytes;
  }
  return 0;
}

LocalRenderShape shape(int width, int height, int bins) {
  LocalRenderShape s;
  s.width = width;
  s.height = height;
  s.render.bins = bins;
  s.threads = 2;
  s.largest_tile_area = 32 * 32;
  return s;
}

TEST(ResourcePlanTest, LocalPlanHoldsTheImagesTheRenderAllocates) {
  const ResourcePlan plain = plan_local_render(shape(100, 50, 16));
  EXPECT_EQ(item(plain.memory, "spectral image"), 100u * 50 * 16 * 4);
  EXPECT_EQ(item(plain.memory, "RGB and standard errors"), 100u * 50 * 3 * 4 * 2);
  EXPECT_EQ(item(plain.memory, "primal and gradient images"), 0u);
  EXPECT_EQ(item(plain.memory, "prepass state"), 0u);
  EXPECT_EQ(item(plain.memory, "target-error sums"), 0u);
  // Two tiles per thread, each with float64 sums and squares per bin, a count, RGB sums and
  // squares, and the counters.
  EXPECT_EQ(item(plain.memory, "tiles in flight"), 2u * 2 * 32 * 32 * (16 * 16 + 8 + 48 + 64));
  EXPECT_TRUE(plain.disk.empty());

  LocalRenderShape gradient = shape(100, 50, 16);
  gradient.render.integrator = job::IntegratorKind::kGradient;
  gradient.keep_primal_and_gradients = true;
  gradient.prepass = true;
  gradient.target_error = true;
  const ResourcePlan more = plan_local_render(gradient);
  EXPECT_EQ(item(more.memory, "primal and gradient images"), 100u * 50 * 16 * 8);
  EXPECT_GT(item(more.memory, "prepass state"), item(more.memory, "spectral image"));
  EXPECT_GT(item(more.memory, "target-error sums"), 4 * item(more.memory, "spectral image"));
  EXPECT_GT(more.memory_bytes(), plain.memory_bytes());
}

// Issue 18, "found under load" case 3: 8192x8192 at 63 bins under a 16 GB address-space cap
// died in std::bad_alloc. Its plan alone is over the cap.
TEST(ResourcePlanTest, EightKAtSixtyThreeBinsDoesNotFitSixteenGigabytes) {
  const ResourcePlan plan = plan_local_render(shape(8192, 8192, 63));
  EXPECT_EQ(item(plan.memory, "spectral image"), 8192ull * 8192 * 63 * 4);
  const std::uint64_t cap = 16ull << 30;
  const absl::Status status = check_memory("rendering 8192x8192 with 63 bins", plan, 40ull << 20,
                                           cap, "RLIMIT_AS", "use fewer --bins");
  EXPECT_EQ(status.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_TRUE(status_says(status,
                          "rendering 8192x8192 with 63 bins needs about 18 GiB of memory "
                          "(spectral image 16 GiB, RGB and standard errors 1.5 GiB"))
      << status;
  EXPECT_TRUE(status_says(status,
                          "besides the 40 MiB in use, more than the 16 GiB allowed (RLIMIT_AS); "
                          "use fewer --bins"))
      << status;
  // The same job fits a machine with room for it, exactly at the boundary.
  EXPECT_TRUE(check_memory("x", plan, 0, plan.memory_bytes(), "s", "a").ok());
  EXPECT_FALSE(check_memory("x", plan, 1, plan.memory_bytes(), "s", "a").ok());
}

// Spooled, the bins are on disk and a row of tiles is in memory: an 8K frame at 64 bins plans
// under the 1.5 GiB issue 18 asks for (measured: 581 MiB, docs/benchmarks.md).
TEST(ResourcePlanTest, SpooledBinsAreDiskNotMemory) {
  LocalRenderShape s = shape(7680, 4320, 64);
  s.spooled = true;
  s.tile_size = 32;
  const ResourcePlan plan = plan_local_render(s);
  EXPECT_EQ(item(plan.memory, "spectral image"), 0u);
  EXPECT_EQ(item(plan.memory, "streamed bins' bands"), 32ull * 7680 * 64 * 4 * kStreamBandsHeld);
  EXPECT_EQ(item(plan.disk, "spooled bins"), 7680ull * 4320 * 64 * 4);
  EXPECT_LT(plan.memory_bytes(), std::uint64_t{3} << 29);
  EXPECT_GT(plan_local_render(shape(7680, 4320, 64)).memory_bytes(), std::uint64_t{8} << 30);
}

// Case 1: the farm accepted a 16384x16384 job whose finished tiles would take ~2 TB.
TEST(ResourcePlanTest, FarmPlanCountsTheFinishedTilesAndOutputsOnDisk) {
  job::JobParameters p;
  p.width = 16384;
  p.height = 16384;
  p.render.bins = 256;
  p.tile_size = 32;
  const ResourcePlan plan = plan_farm_job(p);
  const std::uint64_t n = 16384ull * 16384;
  EXPECT_EQ(item(plan.memory, "RGB image"), n * 12);
  // Float32 sums and squares, a count, float32 RGB sums and squares, the trace counters.
  EXPECT_EQ(item(plan.disk, "finished tiles"), n * (256 * 8 + 8 + 24 + 64));
  EXPECT_EQ(item(plan.disk, "outputs"), n * (259 * 4) + n * 15);
  const absl::Status status =
      check_disk("job 16384x16384 with 256 bins", plan, 75ull << 30, "free space", "fewer bins");
  EXPECT_EQ(status.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_TRUE(
      status_says(status, "needs about 799 GiB of disk (finished tiles 536 GiB, outputs 263 GiB)"))
      << status;
  EXPECT_TRUE(status_says(status, "more than the 75 GiB available (free space); fewer bins"))
      << status;

  // A small job fits; a target error adds its sums to the coordinator's memory.
  p.width = p.height = 64;
  p.render.bins = 16;
  const ResourcePlan small = plan_farm_job(p);
  EXPECT_TRUE(check_disk("x", small, 1ull << 30, "s", "a").ok());
  p.target_error = job::TargetError{};
  EXPECT_GT(plan_farm_job(p).memory_bytes(), small.memory_bytes());
}

// A tile's range results wait on disk for its last range: 64 ranges of a 64x64 tile at 64 bins
// took 35 MB where the plan had counted the finished tile's 0.5 MB, and a job admitted on a
// small disk could then never store a tile.
TEST(ResourcePlanTest, FarmPlanCountsTheRangeResultsOfTilesInFlight) {
  job::JobParameters p;
  p.width = p.height = 64;
  p.render.bins = 64;
  p.tile_size = 32;
  p.spp = 4096;
  const std::uint64_t per_pixel = 64 * 8 + 8 + 24 + 64;
  EXPECT_EQ(item(plan_farm_job(p).disk, "range results of the tiles in flight"), 0u);  // one range
  p.samples_per_task = 64;
  const ResourcePlan plan = plan_farm_job(p);
  EXPECT_EQ(item(plan.disk, "range results of the tiles in flight"), 2 * 32 * 32 * per_pixel * 64);
  const absl::Status status = check_disk("job", plan, 8ull << 20, "free space", "fewer ranges");
  EXPECT_EQ(status.code(), absl::StatusCode::kResourceExhausted) << status;
  // A target error goes up to its max_spp; a one-tile image has one tile in flight.
  p.target_error = job::TargetError{};
  p.target_error->max_spp = 8192;
  p.width = p.height = 16;
  EXPECT_EQ(item(plan_farm_job(p).disk, "range results of the tiles in flight"),
            16 * 16 * per_pixel * 128);
}

TEST(ResourcePlanTest, SaturatesInsteadOfWrapping) {
  LocalRenderShape huge = shape(65536, 65536, 4096);
  huge.largest_tile_area = ~std::uint64_t{0} / 2;
  const ResourcePlan plan = plan_local_render(huge);
  EXPECT_EQ(plan.memory_bytes(), ~std::uint64_t{0});
  EXPECT_FALSE(check_memory("x", plan, 0, ~std::uint64_t{0} - 1, "s", "a").ok());
}

TEST(ResourcePlanTest, BytesFormatAndParse) {
  EXPECT_EQ(format_bytes(0), "0 B");
  EXPECT_EQ(format_bytes(1023), "1023 B");
  EXPECT_EQ(format_bytes(1024), "1.0 KiB");
  EXPECT_EQ(format_bytes(1536ull << 20), "1.5 GiB");
  EXPECT_EQ(format_bytes(320ull << 20), "320 MiB");
  EXPECT_EQ(parse_bytes("1073741824").value(), 1ull << 30);
  EXPECT_EQ(parse_bytes("512M").value(), 512ull << 20);
  EXPECT_EQ(parse_bytes("12G").value(), 12ull << 30);
  EXPECT_EQ(parse_bytes("12GiB").value(), 12ull << 30);
  EXPECT_EQ(parse_bytes("1.5t").value(), 3ull << 39);
  EXPECT_EQ(parse_bytes("4KB").value(), 4096u);
  for (const char* bad : {"", "G", "12X", "12GB2", "-1G", "0", "0.1", "1e3", "99999999T"}) {
    EXPECT_FALSE(parse_bytes(bad).ok()) << bad;
  }
  EXPECT_TRUE(status_says(parse_bytes("12X").status(), "'12X' is not a byte count"));
}

TEST(ResourcePlanTest, MachineBudgetIsPositiveAndMemoryInUseIsMeasured) {
  const MemoryBudget budget = machine_memory_budget();
  EXPECT_GT(budget.bytes, 0u);
  EXPECT_FALSE(budget.source.empty());
  EXPECT_GT(memory_in_use(false), 0u);
  EXPECT_GE(memory_in_use(true), memory_in_use(false));
  EXPECT_GT(free_disk_bytes("/").value(), 0u);
  EXPECT_FALSE(free_disk_bytes("/no/such/dir").ok());
}

}  // namespace
}  // namespace prism::coordinator
