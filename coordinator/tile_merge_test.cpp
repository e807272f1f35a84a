#include "coordinator/tile_merge.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <numeric>
#include <random>
#include <thread>
#include <vector>

namespace prism::coordinator {
namespace {

constexpr int kWidth = 20;
constexpr int kHeight = 12;
constexpr int kBins = 5;

TilePlan make_plan(int tile_size = 8, std::uint64_t spp = 12, std::uint64_t per_task = 3) {
  auto plan = plan_tiles({kWidth, kHeight, tile_size, spp, per_task});
  EXPECT_TRUE(plan.ok()) << plan.status();
  return *plan;
}

// A deterministic synthetic result for (tile, range): values spread over many orders of
// magnitude so that double additions round and their order shows in the bits.
image::TileResult make_result(const TilePlan& plan, int tile, int range, std::uint64_t salt = 0) {
  const image::TileRect& rect = plan.tiles[tile];
  const image::SampleRange& samples = plan.ranges[range];
  auto result = image::TileResult::create(rect, samples, kBins);
  EXPECT_TRUE(result.ok()) << result.status();
  std::mt19937_64 rng(1000003u * tile + 7919u * range + salt);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> spectrum(kBins);
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x) {
      for (std::uint64_t s = samples.s0; s < samples.s1; ++s) {
        for (double& v : spectrum) v = std::exp(30.0 * u(rng) - 15.0) * (1.0 + u(rng));
        result->add_sample(x, y, spectrum);
      }
    }
  }
  return *std::move(result);
}

struct Collected {
  std::mutex mutex;
  std::map<int, image::TileResult> merged;
  int calls = 0;
};

struct Assembly {
  std::unique_ptr<TileAssembler> assembler;
  std::shared_ptr<image::SpectralImage> image;  // shared: the callback keeps a pointer to it
  std::shared_ptr<Collected> collected;
};

Assembly make_assembly(const TilePlan& plan,
                       TileAssembler::Arrivals arrivals = TileAssembler::Arrivals::kAtLeastOnce) {
  auto image = image::SpectralImage::create(kWidth, kHeight, kBins);
  EXPECT_TRUE(image.ok());
  Assembly a{nullptr, std::make_shared<image::SpectralImage>(*std::move(image)),
             std::make_shared<Collected>()};
  auto collected = a.collected;
  auto target = a.image;
  auto assembler = TileAssembler::create(
      plan, kBins,
      [collected, target](int tile, const image::TileResult& merged,
                          const image::SpectralImage& finalised) {
        {
          std::lock_guard<std::mutex> lock(collected->mutex);
          collected->merged.emplace(tile, merged);
          ++collected->calls;
        }
        return image::paste_tile(finalised, merged.rect(), *target);
      },
      nullptr, arrivals);
  EXPECT_TRUE(assembler.ok()) << assembler.status();
  a.assembler = *std::move(assembler);
  return a;
}

std::vector<std::pair<int, int>> all_tasks(const TilePlan& plan) {
  std::vector<std::pair<int, int>> tasks;
  for (std::size_t t = 0; t < plan.tiles.size(); ++t)
    for (std::size_t r = 0; r < plan.ranges.size(); ++r) tasks.emplace_back(int(t), int(r));
  return tasks;
}

bool same_bits(std::span<const float> a, std::span<const float> b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

TEST(TileAssemblerTest, ArrivalOrderDoesNotChangeTheBytes) {
  const TilePlan plan = make_plan();
  ASSERT_EQ(plan.ranges.size(), 4u);
  auto tasks = all_tasks(plan);

  Assembly in_order = make_assembly(plan);
  for (auto [t, r] : tasks) ASSERT_TRUE(in_order.assembler->add(t, make_result(plan, t, r)).ok());
  ASSERT_TRUE(in_order.assembler->check_complete().ok());

  std::mt19937 rng(42);
  for (int trial = 0; trial < 5; ++trial) {
    std::shuffle(tasks.begin(), tasks.end(), rng);
    Assembly shuffled = make_assembly(plan);
    for (auto [t, r] : tasks) {
      ASSERT_TRUE(shuffled.assembler->add(t, make_result(plan, t, r)).ok());
    }
    ASSERT_TRUE(shuffled.assembler->check_complete().ok());
    EXPECT_TRUE(same_bits(in_order.image->data(), shuffled.image->data())) << "trial " << trial;
    for (std::size_t t = 0; t < plan.tiles.size(); ++t) {
      EXPECT_TRUE(in_order.collected->merged.at(int(t)) == shuffled.collected->merged.at(int(t)));
    }
  }
}

TEST(TileAssemblerTest, MergesInRangeOrderAndFinalisesMeans) {
  const TilePlan plan = make_plan();
  Assembly a = make_assembly(plan);
  // Reverse arrival for tile 0.
  for (int r = int(plan.ranges.size()) - 1; r >= 0; --r) {
    ASSERT_TRUE(a.assembler->add(0, make_result(plan, 0, r)).ok());
  }
  ASSERT_EQ(a.collected->calls, 1);
  // Each range rounded to float32, added in range order in double, the sum rounded again.
  auto rounded = [&](int r) {
    image::TileResult result = make_result(plan, 0, r);
    result.round_to_float32();
    return result;
  };
  image::TileResult expected = rounded(0);
  for (std::size_t r = 1; r < plan.ranges.size(); ++r) {
    ASSERT_TRUE(expected.add(rounded(int(r))).ok());
  }
  const image::TileResult unrounded = expected;
  expected.round_to_float32();
  const image::TileResult& merged = a.collected->merged.at(0);
  EXPECT_TRUE(merged == expected);
  EXPECT_FALSE(merged == unrounded);  // so the rounding of the sum is checked too
  EXPECT_EQ(merged.samples(), (image::SampleRange{0, 12}));

  // The order shows even after the rounding: ranges holding 1, 2^-24, 2^-53 and 2^-53 in one
  // value sum to 1 + 2^-24 in range order (each 2^-53 is a tie that rounds to even), which is
  // the float32 1; backwards the small ones add up first, and 1 + 2^-24 + 2^-52 is the float32
  // 1 + 2^-23.
  ASSERT_EQ(plan.ranges.size(), 4u);
  const double parts[4] = {1.0, std::ldexp(1.0, -24), std::ldexp(1.0, -53), std::ldexp(1.0, -53)};
  EXPECT_EQ(double(float(((parts[3] + parts[2]) + parts[1]) + parts[0])),
            1.0 + std::ldexp(1.0, -23));
  Assembly ties = make_assembly(plan);
  for (int r = 3; r >= 0; --r) {
    image::TileResult result = make_result(plan, 0, r);
    result.mutable_sums()[0] = parts[r];
    ASSERT_TRUE(ties.assembler->add(0, std::move(result)).ok());
  }
  EXPECT_EQ(ties.collected->merged.at(0).sums()[0], 1.0);

  const image::TileRect& rect = plan.tiles[0];
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x) {
      ASSERT_EQ(merged.count(x, y), 12u);
      for (int b = 0; b < kBins; ++b) {
        EXPECT_EQ(a.image->value(x, y, b), static_cast<float>(merged.sum(x, y, b) / 12.0));
      }
    }
  }
  // Pixels of tiles not finished yet stay zero.
  EXPECT_EQ(a.image->value(kWidth - 1, kHeight - 1, 0), 0.0f);
}

TEST(TileAssemblerTest, ConcurrentArrivalsGiveTheSameBytes) {
  const TilePlan plan = make_plan(4, 12, 2);
  auto tasks = all_tasks(plan);
  Assembly serial = make_assembly(plan);
  for (auto [t, r] : tasks) ASSERT_TRUE(serial.assembler->add(t, make_result(plan, t, r)).ok());

  std::mt19937 rng(7);
  std::shuffle(tasks.begin(), tasks.end(), rng);
  Assembly parallel = make_assembly(plan);
  std::atomic<std::size_t> next{0};
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (int i = 0; i < 4; ++i) {
    threads.emplace_back([&] {
      for (std::size_t k = next++; k < tasks.size(); k = next++) {
        auto [t, r] = tasks[k];
        if (!parallel.assembler->add(t, make_result(plan, t, r)).ok()) ++failures;
      }
    });
  }
  for (auto& th : threads) th.join();
  EXPECT_EQ(failures.load(), 0);
  ASSERT_TRUE(parallel.assembler->check_complete().ok());
  EXPECT_EQ(parallel.assembler->tiles_finished(), int(plan.tiles.size()));
  EXPECT_TRUE(same_bits(serial.image->data(), parallel.image->data()));
}

TEST(TileAssemblerTest, MemoryIsBoundedByTilesInFlight) {
  const TilePlan plan = make_plan();
  Assembly a = make_assembly(plan);
  for (auto [t, r] : all_tasks(plan)) {
    ASSERT_TRUE(a.assembler->add(t, make_result(plan, t, r)).ok());
    EXPECT_LE(a.assembler->tiles_in_flight(), 1);
  }
  EXPECT_EQ(a.assembler->peak_tiles_in_flight(), 1);
  EXPECT_EQ(a.assembler->tiles_in_flight(), 0);

  // Range-major arrival keeps every tile open until its last range.
  Assembly b = make_assembly(plan);
  for (std::size_t r = 0; r < plan.ranges.size(); ++r)
    for (std::size_t t = 0; t < plan.tiles.size(); ++t)
      ASSERT_TRUE(b.assembler->add(int(t), make_result(plan, int(t), int(r))).ok());
  EXPECT_EQ(b.assembler->peak_tiles_in_flight(), int(plan.tiles.size()));
  EXPECT_EQ(b.assembler->tiles_in_flight(), 0);
}

TEST(TileAssemblerTest, IdenticalDuplicatesAreHarmless) {
  const TilePlan plan = make_plan();
  Assembly a = make_assembly(plan);
  Assembly reference = make_assembly(plan);
  for (auto [t, r] : all_tasks(plan)) {
    ASSERT_TRUE(reference.assembler->add(t, make_result(plan, t, r)).ok());
    ASSERT_TRUE(a.assembler->add(t, make_result(plan, t, r)).ok());
    // Repeated while the tile is open, and (for the last range) after it finished.
    ASSERT_TRUE(a.assembler->add(t, make_result(plan, t, r)).ok());
  }
  EXPECT_EQ(a.assembler->duplicates_ignored(), all_tasks(plan).size());
  EXPECT_EQ(a.collected->calls, int(plan.tiles.size()));
  ASSERT_TRUE(a.assembler->check_complete().ok());
  EXPECT_TRUE(same_bits(a.image->data(), reference.image->data()));
}

TEST(TileAssemblerTest, DuplicatesWithDifferentBytesAreRefused) {
  const TilePlan plan = make_plan();
  Assembly a = make_assembly(plan);
  ASSERT_TRUE(a.assembler->add(1, make_result(plan, 1, 0)).ok());
  absl::Status open = a.assembler->add(1, make_result(plan, 1, 0, /*salt=*/99));
  EXPECT_EQ(open.code(), absl::StatusCode::kDataLoss) << open;
  EXPECT_NE(open.message().find("tile 1 samples [0,3)"), std::string::npos) << open;

  for (std::size_t r = 1; r < plan.ranges.size(); ++r)
    ASSERT_TRUE(a.assembler->add(1, make_result(plan, 1, int(r))).ok());
  ASSERT_EQ(a.collected->calls, 1);
  const std::vector<float> before(a.image->data().begin(), a.image->data().end());
  absl::Status finished = a.assembler->add(1, make_result(plan, 1, 2, /*salt=*/5));
  EXPECT_EQ(finished.code(), absl::StatusCode::kDataLoss) << finished;
  EXPECT_EQ(a.collected->calls, 1);
  EXPECT_TRUE(same_bits(before, a.image->data()));
}

TEST(TileAssemblerTest, TilesFinishedBeforeARestartTakeNoMoreResults) {
  const TilePlan plan = make_plan();
  Assembly a = make_assembly(plan);
  ASSERT_TRUE(a.assembler->mark_finished(0).ok());
  EXPECT_EQ(a.assembler->tiles_finished(), 1);
  EXPECT_EQ(a.assembler->mark_finished(0).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(a.assembler->mark_finished(int(plan.tiles.size())).code(),
            absl::StatusCode::kInvalidArgument);
  absl::Status late = a.assembler->add(0, make_result(plan, 0, 0));
  EXPECT_EQ(late.code(), absl::StatusCode::kFailedPrecondition) << late;
  EXPECT_NE(late.message().find("restarted"), std::string::npos) << late;
  ASSERT_TRUE(a.assembler->add(1, make_result(plan, 1, 0)).ok());
  EXPECT_EQ(a.assembler->mark_finished(1).code(), absl::StatusCode::kFailedPrecondition);
  for (auto [t, r] : all_tasks(plan)) {
    if (t == 0 || (t == 1 && r == 0)) continue;
    ASSERT_TRUE(a.assembler->add(t, make_result(plan, t, r)).ok());
  }
  EXPECT_TRUE(a.assembler->check_complete().ok());
  EXPECT_EQ(a.collected->calls, int(plan.tiles.size()) - 1);
}

TEST(TileAssemblerTest, MissingRangesAreListed) {
  const TilePlan plan = make_plan();
  Assembly a = make_assembly(plan);
  for (auto [t, r] : all_tasks(plan)) {
    if (t == 2 && r == 1) continue;
    ASSERT_TRUE(a.assembler->add(t, make_result(plan, t, r)).ok());
  }
  absl::Status status = a.assembler->check_complete();
  EXPECT_EQ(status.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(status.message().find("1 of 6 tiles are unfinished"), std::string::npos) << status;
  EXPECT_NE(status.message().find("tile 2 samples [3,6)"), std::string::npos) << status;
  EXPECT_EQ(a.assembler->tiles_in_flight(), 1);
  ASSERT_TRUE(a.assembler->add(2, make_result(plan, 2, 1)).ok());
  EXPECT_TRUE(a.assembler->check_complete().ok());
}

TEST(TileAssemblerTest, ResultsThatDoNotFitThePlanAreRefused) {
  const TilePlan plan = make_plan();
  Assembly a = make_assembly(plan);
  EXPECT_EQ(a.assembler->add(6, make_result(plan, 0, 0)).code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(a.assembler->add(-1, make_result(plan, 0, 0)).code(),
            absl::StatusCode::kInvalidArgument);
  // Tile 0's result handed in as tile 1.
  EXPECT_EQ(a.assembler->add(1, make_result(plan, 0, 0)).code(),
            absl::StatusCode::kInvalidArgument);
  // A range the plan does not have.
  auto odd = image::TileResult::create(plan.tiles[0], {1, 4}, kBins);
  ASSERT_TRUE(odd.ok());
  EXPECT_EQ(a.assembler->add(0, *odd).code(), absl::StatusCode::kInvalidArgument);
  auto wrong_bins = image::TileResult::create(plan.tiles[0], plan.ranges[0], kBins + 1);
  ASSERT_TRUE(wrong_bins.ok());
  EXPECT_EQ(a.assembler->add(0, *wrong_bins).code(), absl::StatusCode::kInvalidArgument);
  auto guides = image::TileResult::create(plan.tiles[0], plan.ranges[1], kBins, {false, true, {}});
  ASSERT_TRUE(guides.ok());
  ASSERT_TRUE(a.assembler->add(0, make_result(plan, 0, 0)).ok());
  EXPECT_EQ(a.assembler->add(0, *guides).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(a.collected->calls, 0);
  EXPECT_EQ(a.assembler->tiles_in_flight(), 1);
}

TEST(TileAssemblerTest, CallbackErrorsReachTheCaller) {
  const TilePlan plan = make_plan(8, 2, 0);
  auto assembler = TileAssembler::create(
      plan, kBins, [](int tile, const image::TileResult&, const image::SpectralImage&) {
        return tile == 3 ? absl::InternalError("disk full") : absl::OkStatus();
      });
  ASSERT_TRUE(assembler.ok());
  EXPECT_TRUE((*assembler)->add(2, make_result(plan, 2, 0)).ok());
  absl::Status status = (*assembler)->add(3, make_result(plan, 3, 0));
  EXPECT_EQ(status.code(), absl::StatusCode::kInternal);
  EXPECT_EQ(status.message(), "disk full");
}

TEST(TileAssemblerTest, CreateValidatesItsInputs) {
  auto noop = [](int, const image::TileResult&, const image::SpectralImage&) {
    return absl::OkStatus();
  };
  EXPECT_FALSE(TileAssembler::create(TilePlan{}, kBins, noop).ok());
  EXPECT_FALSE(TileAssembler::create(make_plan(), 0, noop).ok());
  TilePlan gap = make_plan();
  gap.ranges[1].s0 += 1;
  EXPECT_FALSE(TileAssembler::create(gap, kBins, noop).ok());
}

// A local render identifies no result; its bytes are those of a farm's assembly, and a task that
// arrived twice (which a render running each task once cannot send) is refused, not merged.
TEST(TileAssemblerTest, ExactlyOnceAssemblesTheSameBytesAndRefusesARepeat) {
  const TilePlan plan = make_plan();
  Assembly once = make_assembly(plan, TileAssembler::Arrivals::kExactlyOnce);
  Assembly reference = make_assembly(plan);
  for (auto [t, r] : all_tasks(plan)) {
    ASSERT_TRUE(reference.assembler->add(t, make_result(plan, t, r)).ok());
    ASSERT_TRUE(once.assembler->add(t, make_result(plan, t, r)).ok());
    if (r == 0) {
      const absl::Status repeat = once.assembler->add(t, make_result(plan, t, r));
      EXPECT_EQ(repeat.code(), absl::StatusCode::kInternal) << repeat;
      EXPECT_NE(repeat.message().find("arrived twice"), std::string::npos) << repeat;
    }
  }
  const absl::Status after = once.assembler->add(0, make_result(plan, 0, 1));
  EXPECT_EQ(after.code(), absl::StatusCode::kInternal) << after;
  EXPECT_EQ(once.assembler->duplicates_ignored(), 0u);
  EXPECT_EQ(once.collected->calls, int(plan.tiles.size()));
  ASSERT_TRUE(once.assembler->check_complete().ok());
  EXPECT_TRUE(same_bits(once.image->data(), reference.image->data()));
}

TEST(TileAssemblerTest, DigestSeesEveryByte) {
  const TilePlan plan = make_plan();
  image::TileResult a = make_result(plan, 0, 0);
  image::TileResult b = make_result(plan, 0, 0);
  EXPECT_EQ(tile_result_digest(a), tile_result_digest(b));
  b.mutable_counts()[5] += 1;
  EXPECT_NE(tile_result_digest(a), tile_result_digest(b));
  image::TileResult c = make_result(plan, 0, 0);
  c.mutable_sum_squares().back() = std::nextafter(c.sum_squares().back(), 1e300);
  EXPECT_NE(tile_result_digest(a), tile_result_digest(c));
}

}  // namespace
}  // namespace prism::coordinator
