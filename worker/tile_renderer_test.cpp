#include "worker/tile_renderer.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <filesystem>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

class TileRendererTest : public ::testing::Test {
 protected:
  void SetUp() override {
    library_ = std::make_unique<spectral::SpectrumLibrary>(*spectral::SpectrumLibrary::load_builtin());
    auto loaded = scene::load_scene(fs::path(PRISM_SOURCE_DIR) / "worker/testdata/furnace.pbrt",
                                    scene::LoadOptions{});
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    RenderOptions options;
    options.bins = 8;
    auto built = RenderScene::build(device_, loaded->description, *library_, options, 16, 16);
    ASSERT_TRUE(built.ok()) << built.status();
    scene_ = std::move(*built);
  }
  EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<RenderScene> scene_;
};

TEST_F(TileRendererTest, CountsSamplesAndReportsProgressAndRays) {
  TileRenderer renderer(*scene_);
  std::atomic<std::uint64_t> progress{0};
  TileStats stats;
  RenderTask task{{2, 3, 10, 7}, {5, 9}, 0};
  auto result = renderer.render(task, &stats, nullptr, &progress);
  ASSERT_TRUE(result.ok()) << result.status();
  EXPECT_EQ(progress.load(), 8u * 4u * 4u);
  EXPECT_EQ(result->samples(), (image::SampleRange{5, 9}));
  for (int y = 3; y < 7; ++y)
    for (int x = 2; x < 10; ++x) EXPECT_EQ(result->count(x, y), 4u);
  EXPECT_EQ(stats.counters.camera_rays, 8u * 4u * 4u);
  EXPECT_GE(stats.counters.rays, stats.counters.camera_rays);
  EXPECT_GT(stats.seconds, 0.0);
}

TEST_F(TileRendererTest, GuideBuffersHoldFirstHitFeatures) {
  TileRenderer renderer(*scene_);
  RenderTask task{{0, 0, 16, 16}, {0, 4}, 0, /*want_guides=*/true};
  auto result = renderer.render(task, nullptr);
  ASSERT_TRUE(result.ok());
  ASSERT_TRUE(result->has_guides());
  int covered = 0, empty = 0;
  for (int p = 0; p < 256; ++p) {
    float depth = result->depth()[p] / 4;
    float nx = result->normals()[3 * p] / 4, ny = result->normals()[3 * p + 1] / 4,
          nz = result->normals()[3 * p + 2] / 4;
    float albedo = result->albedo()[p] / 4;
    EXPECT_GE(depth, 0.0f);
    EXPECT_LE(depth, 1.0f);
    EXPECT_LE(albedo, 1.0f + 1e-6f);
    float length = std::sqrt(nx * nx + ny * ny + nz * nz);
    // Means of unit normals (0 for a miss) never exceed unit length.
    EXPECT_LE(length, 1.0f + 1e-5f);
    if (length > 0.9f) ++covered;
    if (depth == 1.0f) {
      ++empty;
      EXPECT_EQ(length, 0.0f);
      EXPECT_EQ(albedo, 0.0f);
    }
  }
  // The two spheres cover part of the image and the environment the rest.
  EXPECT_GT(covered, 20);
  EXPECT_GT(empty, 20);
}

TEST_F(TileRendererTest, CancelledTaskReturnsNoResult) {
  TileRenderer renderer(*scene_);
  std::atomic<bool> cancel{true};
  auto result = renderer.render({{0, 0, 16, 16}, {0, 64}, 0}, nullptr, &cancel);
  EXPECT_EQ(result.status().code(), absl::StatusCode::kCancelled);
}

TEST_F(TileRendererTest, RefusesSampleIndicesBeyond32Bits) {
  TileRenderer renderer(*scene_);
  auto result = renderer.render({{0, 0, 4, 4}, {0, (std::uint64_t{1} << 32) + 1}, 0}, nullptr);
  EXPECT_EQ(result.status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace prism::worker
