#include "coordinator/spectral_spool.h"

#include <gtest/gtest.h>

#include <cstring>
#include <thread>

#include "tests/testing/test_dir.h"

namespace prism::coordinator {
namespace {

// A 37x21 image of 5 bins with 8-pixel tiles (edge tiles clipped): every value distinct.
image::SpectralImage numbered(int width, int height, int bins) {
  image::SpectralImage image = image::SpectralImage::create(width, height, bins).value();
  for (std::size_t i = 0; i < image.data().size(); ++i) image.data()[i] = float(i) * 0.5f + 1.0f;
  return image;
}

TEST(SpectralSpoolTest, TilesPutInAnyOrderFromAnyThreadReadBackAsTheImagesRows) {
  const int width = 37, height = 21, bins = 5;
  const TilePlan plan = plan_tiles({width, height, 8, 1, 0, false}).value();
  const image::SpectralImage image = numbered(width, height, bins);
  const std::filesystem::path dir = prism::testing::fresh_dir("spectral_spool");
  auto spool = SpectralSpool::create(dir, plan, width, height, bins);
  ASSERT_TRUE(spool.ok()) << spool.status();
  EXPECT_TRUE(std::filesystem::is_empty(dir)) << "the spool file has no name";
  // Two threads, each putting every other tile, last tile first.
  std::vector<std::thread> threads;
  for (int parity = 0; parity < 2; ++parity) {
    threads.emplace_back([&, parity] {
      for (int t = int(plan.tiles.size()) - 1 - parity; t >= 0; t -= 2) {
        EXPECT_TRUE((*spool)->put(t, image.crop(plan.tiles[std::size_t(t)]).value()).ok());
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ((*spool)->band_rows(), 8);
  std::vector<float> buffer;
  const image::SpectralRows rows = (*spool)->rows(&buffer);
  for (int y0 = 0; y0 < height; y0 += 8) {
    const int n = std::min(8, height - y0);
    absl::StatusOr<const float*> band = rows(y0, n);
    ASSERT_TRUE(band.ok()) << band.status();
    const std::size_t values = std::size_t(width) * n * bins;
    EXPECT_EQ(std::memcmp(*band, image.data().data() + std::size_t(y0) * width * bins,
                          values * sizeof(float)),
              0)
        << "band at " << y0;
  }
  EXPECT_FALSE(rows(3, 8).ok()) << "no row of tiles starts at y 3";
  EXPECT_FALSE(rows(16, 8).ok()) << "the last row of tiles is 5 rows high";
  // A tile of the wrong shape or index is refused.
  EXPECT_EQ((*spool)->put(0, numbered(7, 8, bins)).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ((*spool)->put(0, numbered(8, 8, 4)).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ((*spool)->put(int(plan.tiles.size()), numbered(8, 8, bins)).code(),
            absl::StatusCode::kInvalidArgument);
  spool->reset();
  EXPECT_TRUE(std::filesystem::is_empty(dir));
  EXPECT_FALSE(SpectralSpool::create(dir / "missing", plan, width, height, bins).ok());
}

}  // namespace
}  // namespace prism::coordinator
