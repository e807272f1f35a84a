#include "services/image/tile.h"

#include <gtest/gtest.h>

#include <limits>
#include <random>
#include <span>

namespace prism::image {
namespace {

TEST(TileRect, SizesContainsAndIntersect) {
  TileRect r{2, 3, 10, 7};
  EXPECT_EQ(r.width(), 8);
  EXPECT_EQ(r.height(), 4);
  EXPECT_EQ(r.area(), 32);
  EXPECT_TRUE(r.contains(2, 3));
  EXPECT_FALSE(r.contains(10, 3));
  EXPECT_FALSE(r.contains(2, 7));
  EXPECT_EQ(r.intersect({5, 0, 20, 5}), (TileRect{5, 3, 10, 5}));
  EXPECT_TRUE(r.intersect({10, 0, 20, 5}).empty());
  EXPECT_EQ(r.intersect({10, 0, 20, 5}), TileRect{});
  EXPECT_TRUE(r.contains(TileRect{3, 4, 9, 6}));
  EXPECT_FALSE(r.contains(TileRect{3, 4, 11, 6}));
}

TEST(SampleRange, Count) {
  EXPECT_EQ((SampleRange{4, 10}).count(), 6u);
  EXPECT_FALSE((SampleRange{5, 4}).valid());
}

TEST(SpectralImage, LayoutIsPixelInterleavedRowMajor) {
  auto image = SpectralImage::create(3, 2, 4);
  ASSERT_TRUE(image.ok());
  image->value(2, 1, 3) = 7.0f;
  EXPECT_EQ(image->data()[(1 * 3 + 2) * 4 + 3], 7.0f);
  EXPECT_EQ(image->pixel(2, 1)[3], 7.0f);
}

TEST(SpectralImage, ConstructionValidatesSizes) {
  EXPECT_FALSE(SpectralImage::create(0, 2, 4).ok());
  EXPECT_FALSE(SpectralImage::create(2, -1, 4).ok());
  EXPECT_FALSE(SpectralImage::create(2, 2, 0).ok());
  EXPECT_FALSE(SpectralImage::create(2, 2, kMaxChannels + 1).ok());
  EXPECT_FALSE(SpectralImage::from_data(2, 2, 4, std::vector<float>(15)).ok());
  EXPECT_TRUE(SpectralImage::from_data(2, 2, 4, std::vector<float>(16)).ok());
  EXPECT_FALSE(RgbImage::from_data(2, 2, std::vector<float>(11)).ok());
}

TEST(SpectralImage, CropAndPaste) {
  auto image = SpectralImage::create(5, 4, 2);
  ASSERT_TRUE(image.ok());
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 5; ++x)
      for (int b = 0; b < 2; ++b) image->value(x, y, b) = float(100 * y + 10 * x + b);
  auto crop = image->crop({1, 2, 4, 4});
  ASSERT_TRUE(crop.ok());
  EXPECT_EQ(crop->width(), 3);
  EXPECT_EQ(crop->height(), 2);
  EXPECT_EQ(crop->value(0, 0, 1), 211.0f);
  EXPECT_EQ(crop->value(2, 1, 0), 330.0f);
  EXPECT_FALSE(image->crop({1, 2, 6, 4}).ok());
  EXPECT_FALSE(image->crop({1, 2, 1, 4}).ok());
  EXPECT_FALSE(image->crop({-1, 0, 2, 2}).ok());

  auto target = SpectralImage::create(5, 4, 2);
  ASSERT_TRUE(target->paste(*crop, 1, 2).ok());
  EXPECT_EQ(target->value(3, 3, 0), 330.0f);
  EXPECT_EQ(target->value(0, 0, 0), 0.0f);
  EXPECT_FALSE(target->paste(*crop, 3, 3).ok());
  auto other_bins = SpectralImage::create(1, 1, 3);
  EXPECT_FALSE(target->paste(*other_bins, 0, 0).ok());
}

TEST(RgbImage, CropAndPaste) {
  auto image = RgbImage::create(4, 4);
  ASSERT_TRUE(image.ok());
  image->value(2, 3, 1) = 5.0f;
  auto crop = image->crop({2, 2, 4, 4});
  ASSERT_TRUE(crop.ok());
  EXPECT_EQ(crop->value(0, 1, 1), 5.0f);
  auto target = RgbImage::create(4, 4);
  ASSERT_TRUE(target->paste(*crop, 0, 0).ok());
  EXPECT_EQ(target->value(0, 1, 1), 5.0f);
  EXPECT_FALSE(target->paste(*crop, 3, 0).ok());
}

TEST(TileResult, CreateValidates) {
  EXPECT_FALSE(TileResult::create({0, 0, 0, 4}, {0, 1}, 4).ok());
  EXPECT_FALSE(TileResult::create({0, 0, 4, 4}, {2, 1}, 4).ok());
  EXPECT_FALSE(TileResult::create({0, 0, 4, 4}, {0, 1}, 0).ok());
  EXPECT_FALSE(TileResult::create({-1, 0, 4, 4}, {0, 1}, 4).ok());
  EXPECT_FALSE(TileResult::create({0, 0, 4, 4}, {0, 1}, 4, {false, false, {"a", "a"}}).ok());
  EXPECT_FALSE(TileResult::create({0, 0, 4, 4}, {0, 1}, 4, {false, false, {"has space"}}).ok());
  EXPECT_TRUE(TileResult::create({0, 0, 4, 4}, {0, 1}, 4, {true, true, {"rays"}}).ok());
}

// Fills a result the way a worker would, with sample values derived from the sample index.
// Values are multiples of 1/8, so every sum is exact and the comparison can be bitwise.
void render(TileResult& result, std::uint64_t s0, std::uint64_t s1) {
  const TileRect& r = result.rect();
  std::vector<double> spectrum(result.bins());
  for (int y = r.y0; y < r.y1; ++y) {
    for (int x = r.x0; x < r.x1; ++x) {
      for (std::uint64_t s = s0; s < s1; ++s) {
        std::mt19937_64 rng(s * 1000003 + std::uint64_t(y) * 1009 + x);
        for (double& v : spectrum) v = double(rng() % 16) / 8.0;
        result.add_sample(x, y, spectrum);
        result.add_gradient(x, y, int(s % result.bins()), double(rng() % 16) / 8.0 - 1.0);
        result.add_guides(x, y, 0.5f, 0.0f, 0.0f, 1.0f, 0.25f);
        result.add_counter(x, y, 0, 3);
      }
    }
  }
}

TEST(TileResult, MergingTwoSampleRangesEqualsOneAccumulation) {
  TileRect rect{8, 4, 12, 7};
  TileBuffers buffers{true, true, {"rays"}};
  auto whole = TileResult::create(rect, {0, 6}, 5, buffers);
  auto first = TileResult::create(rect, {0, 2}, 5, buffers);
  auto second = TileResult::create(rect, {2, 6}, 5, buffers);
  ASSERT_TRUE(whole.ok() && first.ok() && second.ok());
  render(*whole, 0, 6);
  render(*first, 0, 2);
  render(*second, 2, 6);
  ASSERT_TRUE(merge_into(*second, *first).ok());
  EXPECT_EQ(first->samples(), (SampleRange{0, 6}));
  EXPECT_EQ(*first, *whole);
  EXPECT_EQ(first->count(9, 5), 6u);
  EXPECT_EQ(first->counter(9, 5, 0), 18u);
}

TEST(TileResult, RoundingToFloat32TakesTheNearestFloatOfEverySumButOffsets) {
  TileBuffers buffers{true, false, {}, true, true, true, true};
  auto result = TileResult::create({0, 0, 2, 1}, {0, 3}, 2, buffers);
  ASSERT_TRUE(result.ok());
  const double third = 1.0 / 3.0;
  for (std::span<double> buffer :
       {result->mutable_sums(), result->mutable_sum_squares(), result->mutable_gradients(),
        result->mutable_gradient_squares(), result->mutable_half_sums(),
        result->mutable_half_sum_squares(), result->mutable_half_gradients(),
        result->mutable_half_gradient_squares(), result->mutable_rgb_sums(),
        result->mutable_rgb_squares(), result->mutable_filtered_sums(),
        result->mutable_filtered_rgb_sums(), result->mutable_offsets()}) {
    for (double& v : buffer) v = third;
  }
  result->mutable_sums()[1] = 1e39;  // finite, beyond float32: kept
  result->mutable_sums()[2] = -std::numeric_limits<double>::infinity();
  result->mutable_sums()[3] = 1e-50;  // below float32's smallest denormal: zero
  result->round_to_float32();
  const double nearest = static_cast<float>(third);
  EXPECT_NE(nearest, third);
  EXPECT_EQ(result->sums()[0], nearest);
  EXPECT_EQ(result->sums()[1], 1e39);
  EXPECT_EQ(result->sums()[2], -std::numeric_limits<double>::infinity());
  EXPECT_EQ(result->sums()[3], 0.0);
  for (std::span<const double> buffer :
       {result->sum_squares(), result->gradients(), result->gradient_squares(), result->half_sums(),
        result->half_sum_squares(), result->half_gradients(), result->half_gradient_squares(),
        result->rgb_sums(), result->rgb_squares(), result->filtered_sums(),
        result->filtered_rgb_sums()}) {
    for (double v : buffer) EXPECT_EQ(v, nearest);
  }
  for (double v : result->offsets()) EXPECT_EQ(v, third);
  TileResult again = *result;
  again.round_to_float32();
  EXPECT_EQ(again, *result);  // a second rounding changes nothing
}

TEST(TileResult, MergeRefusesMismatches) {
  auto base = TileResult::create({0, 0, 4, 4}, {0, 4}, 4);
  auto other_rect = TileResult::create({0, 0, 4, 5}, {4, 8}, 4);
  auto other_bins = TileResult::create({0, 0, 4, 4}, {4, 8}, 8);
  auto overlapping = TileResult::create({0, 0, 4, 4}, {2, 6}, 4);
  auto gap = TileResult::create({0, 0, 4, 4}, {5, 8}, 4);
  auto with_gradients = TileResult::create({0, 0, 4, 4}, {4, 8}, 4, {true, false, {}});
  auto before = TileResult::create({0, 0, 4, 4}, {0, 4}, 4);
  for (auto* bad : {&other_rect, &other_bins, &overlapping, &gap, &with_gradients}) {
    absl::Status status = merge_into(**bad, *base);
    EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << status;
  }
  EXPECT_EQ(*base, *before);
  auto earlier = TileResult::create({0, 0, 4, 4}, {0, 0}, 4);
  auto empty_start = TileResult::create({0, 0, 4, 4}, {4, 4}, 4);
  EXPECT_TRUE(merge_into(*base, *empty_start).ok());
  EXPECT_EQ(empty_start->samples(), (SampleRange{0, 4}));
  EXPECT_TRUE(merge_into(*earlier, *base).ok());
}

TEST(TileResult, FinaliseGivesMeansAndPastes) {
  auto result = TileResult::create({2, 1, 4, 3}, {0, 2}, 2);
  ASSERT_TRUE(result.ok());
  std::vector<double> a{1.0, 2.0}, b{3.0, 6.0};
  result->add_sample(2, 1, a);
  result->add_sample(2, 1, b);
  result->add_sample(3, 2, b);
  SpectralImage tile = finalise(*result);
  EXPECT_EQ(tile.width(), 2);
  EXPECT_EQ(tile.value(0, 0, 0), 2.0f);
  EXPECT_EQ(tile.value(0, 0, 1), 4.0f);
  EXPECT_EQ(tile.value(1, 1, 1), 6.0f);
  EXPECT_EQ(tile.value(1, 0, 0), 0.0f);  // no samples
  EXPECT_EQ(result->sum_squares(2, 1, 1), 40.0);

  auto image = SpectralImage::create(4, 3, 2);
  ASSERT_TRUE(paste_tile(tile, result->rect(), *image).ok());
  EXPECT_EQ(image->value(2, 1, 1), 4.0f);
  EXPECT_EQ(image->value(3, 2, 0), 3.0f);
  auto small = SpectralImage::create(3, 3, 2);
  EXPECT_FALSE(paste_tile(tile, result->rect(), *small).ok());
  EXPECT_FALSE(paste_tile(tile, {0, 0, 3, 3}, *image).ok());
}

}  // namespace
}  // namespace prism::image
