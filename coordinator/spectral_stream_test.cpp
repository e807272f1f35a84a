#include "coordinator/spectral_stream.h"

#include <gtest/gtest.h>

#include <atomic>
#include <fstream>
#include <iterator>
#include <thread>

#include "tests/testing/test_dir.h"

namespace prism::coordinator {
namespace {

namespace fs = std::filesystem;

// Every value distinct.
image::SpectralImage numbered(int width, int height, int bins) {
  image::SpectralImage image = image::SpectralImage::create(width, height, bins).value();
  for (std::size_t i = 0; i < image.data().size(); ++i) image.data()[i] = float(i) * 0.5f + 1.0f;
  return image;
}

image::RgbImage coloured(int width, int height) {
  image::RgbImage rgb = image::RgbImage::create(width, height).value();
  for (std::size_t i = 0; i < rgb.data().size(); ++i) rgb.data()[i] = float(i % 97) * 0.25f;
  return rgb;
}

// A w x h image of `bins` with 8-pixel tiles, its RGB, and an empty directory.
struct Setup {
  TilePlan plan;
  image::SpectralImage image;
  image::RgbImage rgb;
  fs::path dir;
};
Setup make_setup(int width, int height, int bins, const std::string& name) {
  return {plan_tiles({width, height, 8, 1, 0, false}).value(), numbered(width, height, bins),
          coloured(width, height), prism::testing::fresh_dir(name)};
}

std::string file_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// Two threads take the tiles in plan order, as the local render hands out its tasks, and a
// third band may not start before the first is written: the file is the bytes of writing the
// whole image afterwards, no more than two bands were held, and nothing is left in the
// directory but the output.
TEST(SpectralStreamTest, TilesInPlanOrderFromTwoThreadsWriteTheWholeImagesBytes) {
  const int width = 37, height = 45, bins = 5;
  const auto [plan, image, rgb, dir] = make_setup(width, height, bins, "spectral_stream");
  const image::ExrMetadata metadata{{"spp", "1"}};
  for (image::ExrCompression compression :
       {image::ExrCompression::kRle, image::ExrCompression::kZip}) {
    const image::ExrWriteOptions options{compression, 2};
    ASSERT_TRUE(image::write_spectral_exr(dir / "whole.exr", image, rgb, metadata, options).ok());
    auto stream = SpectralStream::create(
        dir, plan, width, height, bins, rgb.data().data(), options, [] { return false; }, 2);
    ASSERT_TRUE(stream.ok()) << stream.status();
    EXPECT_EQ((*stream)->band_rows(), 8);
    std::atomic<std::size_t> next{0};
    std::vector<std::thread> threads;
    for (int i = 0; i < 2; ++i) {
      threads.emplace_back([&] {
        for (std::size_t t; (t = next++) < plan.tiles.size();) {
          EXPECT_TRUE((*stream)->put(int(t), image.crop(plan.tiles[t]).value()).ok());
        }
      });
    }
    for (std::thread& t : threads) t.join();
    ASSERT_TRUE((*stream)->finish().ok());
    EXPECT_LE((*stream)->peak_bands_held(), 2);
    EXPECT_EQ((*stream)->put(0, image.crop(plan.tiles[0]).value()).code(),
              absl::StatusCode::kInvalidArgument)
        << "a tile put twice";
    ASSERT_TRUE((*stream)->write(dir / "streamed.exr", metadata).ok());
    EXPECT_TRUE(file_bytes(dir / "streamed.exr") == file_bytes(dir / "whole.exr"))
        << image::name(compression);
    stream->reset();
    EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2);
  }
}

// A render that stops leaves no thread waiting: a put beyond the bands held returns ABORTED
// once the stop flag is up, finish() says the file was not written, and write() makes nothing.
TEST(SpectralStreamTest, AStoppedRenderReleasesWaitingThreadsAndWritesNothing) {
  const int width = 16, height = 40, bins = 3;
  const auto [plan, image, rgb, dir] = make_setup(width, height, bins, "spectral_stream_stop");
  std::atomic<bool> stop{false};
  auto stream = SpectralStream::create(
      dir, plan, width, height, bins, rgb.data().data(), {}, [&] { return stop.load(); }, 1);
  ASSERT_TRUE(stream.ok()) << stream.status();
  // Band 1's tiles would wait for band 0, which never completes.
  ASSERT_EQ(plan.tiles.size(), 10u);
  ASSERT_TRUE((*stream)->put(0, image.crop(plan.tiles[0]).value()).ok());
  absl::Status waited;
  std::thread blocked([&] { waited = (*stream)->put(2, image.crop(plan.tiles[2]).value()); });
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  stop = true;
  blocked.join();
  EXPECT_EQ(waited.code(), absl::StatusCode::kAborted) << waited;
  EXPECT_EQ((*stream)->finish().code(), absl::StatusCode::kAborted);
  EXPECT_EQ((*stream)->write(dir / "out.exr", {}).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_FALSE(fs::exists(dir / "out.exr"));
  // Wrong shapes and indices are refused.
  EXPECT_EQ((*stream)->put(1, numbered(7, 8, bins)).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ((*stream)->put(99, numbered(8, 8, bins)).code(), absl::StatusCode::kInvalidArgument);
  stream->reset();
  EXPECT_TRUE(fs::is_empty(dir));
  // A plan that does not cover the image.
  EXPECT_EQ(
      SpectralStream::create(dir, plan, width, height + 1, bins, rgb.data().data(), {}, nullptr)
          .status()
          .code(),
      absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace prism::coordinator
