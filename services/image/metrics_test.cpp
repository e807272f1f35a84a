#include "services/image/metrics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "services/image/exr_spectral.h"

namespace prism::image {
namespace {

namespace fs = std::filesystem;

RgbImage rgb_of(int w, int h, std::vector<float> values) {
  return RgbImage::from_data(w, h, std::move(values)).value();
}

TEST(Metrics, MseAndRelMseOnHandComputedPixel) {
  RgbImage test = rgb_of(1, 1, {1, 2, 3});
  RgbImage ref = rgb_of(1, 1, {1, 1, 1});
  auto m = compare_rgb(test, ref);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_DOUBLE_EQ(m->mse, 5.0 / 3.0);
  EXPECT_DOUBLE_EQ(m->rel_mse, (1.0 / 1.01 + 4.0 / 1.01) / 3.0);
  EXPECT_EQ(m->nonfinite_fraction, 0.0);
  EXPECT_EQ(m->channels, 3);
  // One-pixel window: sigma terms vanish, SSIM = (2tr + C1)/(t^2 + r^2 + C1), L = 1.
  double c1 = 1e-4;
  double expected = (1.0 + (4 + c1) / (5 + c1) + (6 + c1) / (10 + c1)) / 3.0;
  EXPECT_NEAR(m->ssim, expected, 1e-12);
}

TEST(Metrics, SpectralMseOverCrop) {
  // 3x1 pixels, 2 bins; the crop keeps pixels 1..2.
  auto test = SpectralImage::from_data(3, 1, 2, {9, 9, 1, 2, 0.5f, 0});
  auto ref = SpectralImage::from_data(3, 1, 2, {0, 0, 1, 1, 0, 0});
  auto m = compare_spectral(*test, *ref, Crop{1, 0, 2, 1});
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_DOUBLE_EQ(m->mse, (0.0 + 1.0 + 0.25 + 0.0) / 4.0);
  EXPECT_DOUBLE_EQ(m->rel_mse, (1.0 / 1.01 + 0.25 / 0.01) / 4.0);
  auto whole = compare_spectral(*test, *ref);
  EXPECT_DOUBLE_EQ(whole->mse, (81.0 + 81.0 + 1.0 + 0.25) / 6.0);
}

TEST(Metrics, SsimIsOneForIdenticalImages) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 20.0f);
  std::vector<float> v(20 * 17 * 8);
  for (float& f : v) f = u(rng);
  auto a = SpectralImage::from_data(20, 17, 8, v);
  auto m = compare_spectral(*a, *a);
  ASSERT_TRUE(m.ok());
  EXPECT_NEAR(m->ssim, 1.0, 1e-12);
  EXPECT_EQ(m->mse, 0.0);
  EXPECT_EQ(m->rel_mse, 0.0);
}

TEST(Metrics, SsimOfConstantImagesIsTheLuminanceTerm) {
  // Constant test a = 0.5, reference b = 2: no variance, so SSIM = (2ab + C1)/(a^2 + b^2 + C1)
  // with L = max reference = 2, C1 = (0.01 * 2)^2.
  RgbImage test = rgb_of(12, 13, std::vector<float>(12 * 13 * 3, 0.5f));
  RgbImage ref = rgb_of(12, 13, std::vector<float>(12 * 13 * 3, 2.0f));
  auto m = compare_rgb(test, ref);
  ASSERT_TRUE(m.ok());
  double c1 = 0.02 * 0.02;
  EXPECT_NEAR(m->ssim, (2.0 + c1) / (0.25 + 4.0 + c1), 1e-12);
}

TEST(Metrics, SsimIsScaleInvariantAndBelowOneForNoise) {
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0.0f, 0.1f);
  std::vector<float> r(16 * 16 * 3), t(r.size()), r2(r.size()), t2(r.size());
  for (std::size_t i = 0; i < r.size(); ++i) {
    r[i] = 1.0f + float(i % 7) * 0.1f;
    t[i] = r[i] + noise(rng);
    r2[i] = r[i] * 8.0f;
    t2[i] = t[i] * 8.0f;
  }
  auto m = compare_rgb(rgb_of(16, 16, t), rgb_of(16, 16, r));
  auto m2 = compare_rgb(rgb_of(16, 16, t2), rgb_of(16, 16, r2));
  ASSERT_TRUE(m.ok() && m2.ok());
  EXPECT_LT(m->ssim, 0.99);
  EXPECT_GT(m->ssim, 0.0);
  EXPECT_NEAR(m->ssim, m2->ssim, 1e-9);
}

TEST(Metrics, NonFiniteTestValuesAreCountedAndTreatedAsZero) {
  float nan = std::numeric_limits<float>::quiet_NaN();
  float inf = std::numeric_limits<float>::infinity();
  RgbImage test = rgb_of(2, 2, {nan, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, -inf});
  RgbImage ref = rgb_of(2, 2, std::vector<float>(12, 1.0f));
  auto m = compare_rgb(test, ref);
  ASSERT_TRUE(m.ok());
  EXPECT_DOUBLE_EQ(m->nonfinite_fraction, 2.0 / 12.0);
  EXPECT_DOUBLE_EQ(m->mse, 2.0 / 12.0);
  EXPECT_TRUE(std::isfinite(m->ssim));
  // A non-finite reference is an error, not a metric.
  EXPECT_EQ(compare_rgb(ref, test).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(Metrics, CropAndSizeValidation) {
  RgbImage a = rgb_of(4, 3, std::vector<float>(36, 1.0f));
  EXPECT_TRUE(compare_rgb(a, a, Crop{0, 0, 4, 3}).ok());
  for (Crop bad : {Crop{0, 0, 0, 3}, Crop{0, 0, 4, 0}, Crop{-1, 0, 2, 2}, Crop{0, -1, 2, 2},
                   Crop{3, 0, 2, 1}, Crop{0, 2, 1, 2}, Crop{1, 1, 2147483647, 1}}) {
    auto m = compare_rgb(a, a, bad);
    EXPECT_EQ(m.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(m.status().message().find("crop"), std::string::npos);
  }
  RgbImage b = rgb_of(3, 4, std::vector<float>(36, 1.0f));
  EXPECT_EQ(compare_rgb(a, b).status().code(), absl::StatusCode::kInvalidArgument);
  auto s4 = SpectralImage::create(4, 3, 4);
  auto s8 = SpectralImage::create(4, 3, 8);
  EXPECT_EQ(compare_spectral(*s4, *s8).status().code(), absl::StatusCode::kInvalidArgument);
}

class CompareFilesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("prism_metrics_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(CompareFilesTest, ComparesSpectralAndRgbAndRefusesMismatches) {
  auto ref = SpectralImage::create(4, 4, 8);
  auto test = SpectralImage::create(4, 4, 8);
  for (float& v : ref->data()) v = 1.0f;
  for (float& v : test->data()) v = 2.0f;
  RgbImage rgb_ref = rgb_of(4, 4, std::vector<float>(48, 1.0f));
  RgbImage rgb_test = rgb_of(4, 4, std::vector<float>(48, 3.0f));
  ASSERT_TRUE(write_spectral_exr(dir_ / "ref.exr", *ref, rgb_ref).ok());
  ASSERT_TRUE(write_spectral_exr(dir_ / "test.exr", *test, rgb_test).ok());
  auto c = compare_exr_files(dir_ / "test.exr", dir_ / "ref.exr");
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_TRUE(c->spectral && c->rgb);
  EXPECT_DOUBLE_EQ(c->spectral->mse, 1.0);
  EXPECT_DOUBLE_EQ(c->rgb->mse, 4.0);
  EXPECT_EQ(c->region, (TileRect{0, 0, 4, 4}));

  auto cropped = compare_exr_files(dir_ / "test.exr", dir_ / "ref.exr", Crop{1, 1, 2, 2});
  ASSERT_TRUE(cropped.ok());
  EXPECT_EQ(cropped->region, (TileRect{1, 1, 3, 3}));
  EXPECT_FALSE(compare_exr_files(dir_ / "test.exr", dir_ / "ref.exr", Crop{3, 3, 2, 2}).ok());

  // Plain RGB against spectral + RGB: only RGB is compared.
  ASSERT_TRUE(write_rgb_exr(dir_ / "plain.exr", rgb_test).ok());
  auto mixed = compare_exr_files(dir_ / "plain.exr", dir_ / "ref.exr");
  ASSERT_TRUE(mixed.ok()) << mixed.status();
  EXPECT_FALSE(mixed->spectral.has_value());
  EXPECT_DOUBLE_EQ(mixed->rgb->mse, 4.0);

  auto other_bins = SpectralImage::create(4, 4, 16);
  ASSERT_TRUE(write_spectral_exr(dir_ / "b16.exr", *other_bins, rgb_ref).ok());
  auto bins = compare_exr_files(dir_ / "b16.exr", dir_ / "ref.exr");
  EXPECT_EQ(bins.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(bins.status().message().find("b16.exr"), std::string::npos) << bins.status();
  EXPECT_NE(bins.status().message().find("bins"), std::string::npos) << bins.status();

  auto small = SpectralImage::create(3, 4, 8);
  ASSERT_TRUE(
      write_spectral_exr(dir_ / "small.exr", *small, rgb_of(3, 4, std::vector<float>(36))).ok());
  auto size = compare_exr_files(dir_ / "small.exr", dir_ / "ref.exr");
  EXPECT_EQ(size.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(size.status().message().find("3x4"), std::string::npos) << size.status();
  EXPECT_EQ(compare_exr_files(dir_ / "none.exr", dir_ / "ref.exr").status().code(),
            absl::StatusCode::kNotFound);

  std::string text = format_comparison_text(*c);
  EXPECT_NE(text.find("spectral"), std::string::npos);
  EXPECT_NE(text.find("MSE 1 "), std::string::npos) << text;
  std::string json = format_comparison_json(*mixed);
  EXPECT_NE(json.find("\"spectral\":null"), std::string::npos) << json;
  EXPECT_NE(json.find("\"mse\":4,"), std::string::npos) << json;
  EXPECT_EQ(json.front(), '{');
  EXPECT_EQ(json.back(), '}');
}

}  // namespace
}  // namespace prism::image
