#include "worker/tile_renderer.h"

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "worker/testing/skewed_tables.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

class TileRendererTest : public ::testing::Test {
 protected:
  // The gradient integrator at 8 bins, its offsets `offset_bins` bins apart.
  static job::RenderOptions gradient_options(int offset_bins) {
    job::RenderOptions options;
    options.bins = 8;
    options.integrator = job::IntegratorKind::kGradient;
    options.gradient_offset_bins = offset_bins;
    return options;
  }

  void SetUp() override {
    library_ =
        std::make_unique<spectral::SpectrumLibrary>(*spectral::SpectrumLibrary::load_builtin());
    auto loaded = scene::load_scene(fs::path(PRISM_SOURCE_DIR) / "worker/testdata/furnace.pbrt",
                                    scene::LoadOptions{});
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    description_ = loaded->description;
    job::RenderOptions options;
    options.bins = 8;
    scene_ = build(options);
    ASSERT_TRUE(scene_);
  }
  std::unique_ptr<RenderScene> build(const job::RenderOptions& options) {
    auto built = RenderScene::build(device_, description_, *library_, options, 16, 16);
    EXPECT_TRUE(built.ok()) << built.status();
    return built.ok() ? std::move(*built) : nullptr;
  }
  EmbreeDevice device_;
  scene::SceneDescription description_;
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

// Per-pixel tables keep the result a pure function of (seed, pass, pixel, sample): the same
// bytes for one thread or two, for a final-pass task and for a prepass with early stop, with the
// tables sampled by their two searches (8 samples per pixel) or their composite CDFs (enough
// samples per pixel for the tile renderer to build them, reused pixel after pixel).
TEST_F(TileRendererTest, TablesGiveTheSameBytesForAnyThreadCount) {
  TileRenderer renderer(*scene_);
  const spectral::PixelTables tables =
      testing::skewed_tables(10, 7, 8, [](int x, int y) { return (x + y) % 4 == 0; });
  for (std::uint64_t samples : {std::uint64_t{8}, spectral::CompositeCdf::kMinSamples}) {
    for (bool prepass : {false, true}) {
      RenderTask task{{3, 5, 13, 12}, {0, samples}, prepass ? 2u : 0u, /*want_guides=*/prepass};
      task.prepass = prepass;
      task.early_stop = prepass;
      task.tables = &tables;
      auto one = tbb::task_arena(1).execute([&] { return renderer.render(task, nullptr); });
      auto two = tbb::task_arena(2).execute([&] { return renderer.render(task, nullptr); });
      ASSERT_TRUE(one.ok()) << one.status();
      ASSERT_TRUE(two.ok()) << two.status();
      EXPECT_TRUE(*one == *two) << "prepass " << prepass << ", " << samples << " samples";
    }
  }
}

// A pixel whose row is all zeros has no table: it samples the job's default distribution, so it
// renders exactly as without tables; the pixels with tables render differently.
TEST_F(TileRendererTest, PixelsWithoutATableRenderAsWithoutTables) {
  TileRenderer renderer(*scene_);
  const image::TileRect rect{2, 1, 14, 11};
  auto uses_default = [](int x, int y) { return (x + 2 * y) % 3 == 0; };
  const spectral::PixelTables tables = testing::skewed_tables(12, 10, 8, uses_default);
  RenderTask plain{rect, {0, 16}, 0};
  RenderTask with_tables = plain;
  with_tables.tables = &tables;
  auto a = renderer.render(plain, nullptr);
  auto b = renderer.render(with_tables, nullptr);
  ASSERT_TRUE(a.ok() && b.ok());
  int defaults = 0, differing = 0;
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x) {
      bool same = true;
      for (int bin = 0; bin < 8; ++bin) {
        same = same && a->sum(x, y, bin) == b->sum(x, y, bin) &&
               a->sum_squares(x, y, bin) == b->sum_squares(x, y, bin);
      }
      if (uses_default(x - rect.x0, y - rect.y0)) {
        EXPECT_TRUE(same) << "pixel " << x << "," << y;
        ++defaults;
      } else if (!same) {
        ++differing;
      }
    }
  }
  EXPECT_EQ(defaults, tables.default_pixels());
  EXPECT_GT(differing, (120 - defaults) * 9 / 10);
}

// In a prepass, a pixel without a table fell back in an earlier pass: it is skipped (no samples,
// no guides), and every other pixel renders as in a final pass with the same tables.
TEST_F(TileRendererTest, APrepassSkipsThePixelsThatFellBack) {
  TileRenderer renderer(*scene_);
  const image::TileRect rect{2, 1, 14, 11};
  auto uses_default = [](int x, int y) { return (x + 2 * y) % 3 == 0; };
  const spectral::PixelTables tables = testing::skewed_tables(12, 10, 8, uses_default);
  RenderTask prepass{rect, {0, 8}, 1, /*want_guides=*/true};
  prepass.prepass = true;
  prepass.tables = &tables;
  auto result = renderer.render(prepass, nullptr);
  ASSERT_TRUE(result.ok()) << result.status();
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x) {
      const bool skipped = uses_default(x - rect.x0, y - rect.y0);
      EXPECT_EQ(result->count(x, y), skipped ? 0u : 8u) << x << "," << y;
      const std::size_t p = std::size_t(y - rect.y0) * rect.width() + (x - rect.x0);
      if (skipped) {
        EXPECT_EQ(result->depth()[p], 0.0f);
        for (int b = 0; b < result->bins(); ++b) EXPECT_EQ(result->sum(x, y, b), 0.0);
      }
    }
  }
}

TEST_F(TileRendererTest, RefusesTablesOfAnotherSizeAndEarlyStopOutsideAPrepass) {
  TileRenderer renderer(*scene_);
  const spectral::PixelTables tables = testing::skewed_tables(4, 4, 8);
  RenderTask task{{0, 0, 4, 5}, {0, 1}, 0};
  task.tables = &tables;
  auto wrong_size = renderer.render(task, nullptr);
  EXPECT_EQ(wrong_size.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(wrong_size.status().message().find("4x4"), std::string::npos) << wrong_size.status();
  // A table holds one mass per bin of the job (8 here).
  const spectral::PixelTables other_cells = testing::skewed_tables(4, 4, 16);
  RenderTask cells{{0, 0, 4, 4}, {0, 1}, 0};
  cells.tables = &other_cells;
  auto wrong_cells = renderer.render(cells, nullptr);
  EXPECT_EQ(wrong_cells.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(wrong_cells.status().message().find("16 cells"), std::string::npos)
      << wrong_cells.status();
  RenderTask early{{0, 0, 4, 4}, {0, 1}, 0};
  early.early_stop = true;
  EXPECT_EQ(renderer.render(early, nullptr).status().code(), absl::StatusCode::kInvalidArgument);
}

// A prepass task of a `gradient` job is traced by the hero path tracer with 4 lanes: no
// gradients buffer, and the same bytes as the same pass of a `hero` job. Its final-pass tasks
// still carry gradients.
TEST_F(TileRendererTest, APrepassOfAGradientJobIsAFourLaneHeroRenderWithoutGradients) {
  job::RenderOptions options = gradient_options(2);
  auto gradient = build(options);
  options.integrator = job::IntegratorKind::kHero;
  auto hero = build(options);
  ASSERT_TRUE(gradient && hero);
  const spectral::PixelTables tables = testing::skewed_tables(16, 16, 8);

  RenderTask prepass{{0, 0, 16, 16}, {0, 4}, 1, /*want_guides=*/true};
  prepass.prepass = true;
  prepass.tables = &tables;
  auto from_gradient = TileRenderer(*gradient).render(prepass, nullptr);
  ASSERT_TRUE(from_gradient.ok()) << from_gradient.status();
  EXPECT_FALSE(from_gradient->has_gradients());
  EXPECT_TRUE(from_gradient->has_guides());
  auto from_hero = TileRenderer(*hero).render(prepass, nullptr);
  ASSERT_TRUE(from_hero.ok()) << from_hero.status();
  EXPECT_TRUE(*from_gradient == *from_hero);
  // The hero job's own final-pass render of that pass: a prepass adds nothing but C = 4, and
  // leaves out the samples' XYZ (only the final pass makes the RGB outputs).
  RenderTask same_pass = prepass;
  same_pass.prepass = false;
  auto same = TileRenderer(*hero).render(same_pass, nullptr);
  ASSERT_TRUE(same.ok()) << same.status();
  EXPECT_FALSE(from_hero->has_rgb());
  EXPECT_TRUE(same->has_rgb());
  EXPECT_TRUE(std::ranges::equal(same->sums(), from_hero->sums()));
  EXPECT_TRUE(std::ranges::equal(same->sum_squares(), from_hero->sum_squares()));
  EXPECT_TRUE(std::ranges::equal(same->counts(), from_hero->counts()));
  EXPECT_TRUE(std::ranges::equal(same->depth(), from_hero->depth()));

  RenderTask final_pass{{0, 0, 16, 16}, {0, 4}, 0};
  auto final_result = TileRenderer(*gradient).render(final_pass, nullptr);
  ASSERT_TRUE(final_result.ok()) << final_result.status();
  EXPECT_TRUE(final_result->has_gradients());
  EXPECT_TRUE(final_result->has_rgb());
}

// With gradient_variances the gradient integrator also sums each sample's G[b]² (bin and
// bin − k get one value each per sample) and keeps the even-indexed samples' sums apart, and
// nothing else changes: the same sums, squares and gradients bit for bit. One sample makes each
// square exactly the gradient's square; n samples bound it below by Cauchy–Schwarz,
// Σ G² >= (Σ G)²/n. The halves of [0, 4) are the totals of samples 0 and 2, rendered alone.
TEST_F(TileRendererTest, GradientVariancesAddSquaresAndHalves) {
  job::RenderOptions options = gradient_options(3);
  auto plain = build(options);
  options.gradient_variances = true;
  auto with_halves = build(options);
  ASSERT_TRUE(plain && with_halves);
  const image::TileRect rect{0, 0, 16, 16};
  auto render = [&](RenderScene& scene, std::uint64_t s0, std::uint64_t s1) {
    auto result = TileRenderer(scene).render(RenderTask{rect, {s0, s1}, 0}, nullptr);
    EXPECT_TRUE(result.ok()) << result.status();
    return std::move(result).value();
  };
  for (std::uint64_t spp : {1u, 16u}) {
    const image::TileResult a = render(*plain, 0, spp);
    const image::TileResult b = render(*with_halves, 0, spp);
    EXPECT_FALSE(a.has_halves());
    ASSERT_TRUE(b.has_halves());
    EXPECT_TRUE(std::ranges::equal(a.sums(), b.sums()));
    EXPECT_TRUE(std::ranges::equal(a.sum_squares(), b.sum_squares()));
    EXPECT_TRUE(std::ranges::equal(a.gradients(), b.gradients()));
    int nonzero = 0;
    for (std::size_t i = 0; i < b.gradients().size(); ++i) {
      const double g = b.gradients()[i], g2 = b.gradient_squares()[i];
      if (spp == 1) {
        EXPECT_EQ(g2, g * g) << i;
      } else {
        EXPECT_GE(g2 * (1 + 1e-12), g * g / double(spp)) << i;
      }
      nonzero += g2 > 0;
    }
    EXPECT_GT(nonzero, 0);
  }
  const image::TileResult four = render(*with_halves, 0, 4);
  image::TileResult even = render(*with_halves, 0, 1);
  image::TileResult two = render(*with_halves, 2, 3);
  for (std::size_t i = 0; i < even.sums().size(); ++i) {
    EXPECT_EQ(four.half_sums()[i], even.sums()[i] + two.sums()[i]) << i;
    EXPECT_EQ(four.half_sum_squares()[i], even.sum_squares()[i] + two.sum_squares()[i]) << i;
    EXPECT_EQ(four.half_gradients()[i], even.gradients()[i] + two.gradients()[i]) << i;
    EXPECT_EQ(four.half_gradient_squares()[i],
              even.gradient_squares()[i] + two.gradient_squares()[i])
        << i;
  }
  for (std::uint64_t c : four.half_counts()) EXPECT_EQ(c, 2u);
  const image::TileResult odd = render(*with_halves, 1, 2);
  const image::TileResult five = render(*with_halves, 3, 8);
  for (std::uint64_t c : odd.half_counts()) EXPECT_EQ(c, 0u);
  for (std::uint64_t c : five.half_counts()) EXPECT_EQ(c, 2u);
}

}  // namespace
}  // namespace prism::worker
