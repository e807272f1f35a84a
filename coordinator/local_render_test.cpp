#include "coordinator/local_render.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <vector>

#include "services/base/status.h"
#include "services/scene/scene_loader.h"

namespace prism::coordinator {
namespace {

class LocalRenderTest : public testing::Test {
 protected:
  void SetUp() override {
    auto library = spectral::SpectrumLibrary::load_builtin();
    ASSERT_TRUE(library.ok()) << library.status();
    library_ = std::make_unique<spectral::SpectrumLibrary>(*std::move(library));
    scene::LoadOptions load = scene::with_library_names(*library_);
    auto loaded = scene::load_scene(
        std::filesystem::path(PRISM_SOURCE_DIR) / "scenes/cornell-two-lights.pbrt", load);
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    scene_ = std::make_unique<scene::SceneDescription>(std::move(loaded->description));
  }

  LocalRenderOptions options(int threads, int tile, std::uint64_t per_task) const {
    LocalRenderOptions o;
    o.render.bins = 16;
    o.render.max_depth = 3;
    o.render.seed = 11;
    o.width = 24;
    o.height = 20;
    o.spp = 4;
    o.tile_size = tile;
    o.threads = threads;
    o.samples_per_task = per_task;
    return o;
  }

  absl::StatusOr<LocalRenderResult> render(const LocalRenderOptions& o,
                                           const std::atomic<bool>* cancel = nullptr) {
    PRISM_ASSIGN_OR_RETURN(auto r, LocalRender::create(device_, *scene_, *library_, o));
    return r->render(cancel);
  }

  worker::EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<scene::SceneDescription> scene_;
};

bool same_bits(std::span<const float> a, std::span<const float> b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

TEST_F(LocalRenderTest, SplitTasksAreDeterministicAcrossThreadsAndTiles) {
  auto a = render(options(1, 8, 1));
  ASSERT_TRUE(a.ok()) << a.status();
  auto b = render(options(2, 32, 1));
  ASSERT_TRUE(b.ok()) << b.status();
  auto c = render(options(2, 4, 1));
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_TRUE(same_bits(a->image.data(), b->image.data()));
  EXPECT_TRUE(same_bits(a->image.data(), c->image.data()));
  EXPECT_EQ(a->stats.tasks, 3u * 3u * 4u);
  EXPECT_EQ(a->stats.samples, 24u * 20u * 4u);
  EXPECT_EQ(a->stats.counters.camera_rays, 24u * 20u * 4u);
  EXPECT_EQ(a->stats.counters.rays, b->stats.counters.rays);
  // One thread finishes a tile's ranges in order: one tile in flight at a time.
  EXPECT_EQ(a->stats.peak_tiles_in_flight, 1);

  // The same samples summed in one task: equal up to the order of the double additions.
  auto whole = render(options(2, 16, 0));
  ASSERT_TRUE(whole.ok()) << whole.status();
  double total = 0;
  for (std::size_t i = 0; i < whole->image.data().size(); ++i) {
    const float x = whole->image.data()[i], y = a->image.data()[i];
    ASSERT_NEAR(x, y, 1e-5 * std::fabs(y) + 1e-30) << i;
    total += x;
  }
  EXPECT_GT(total, 0.0);
}

TEST_F(LocalRenderTest, StatisticsDescribeTheImage) {
  auto r = render(options(2, 8, 2));
  ASSERT_TRUE(r.ok()) << r.status();
  const int bins = r->image.bins();
  ASSERT_EQ(r->statistics.mean.size(), std::size_t(bins));
  std::vector<double> mean(bins, 0.0);
  for (int y = 0; y < r->image.height(); ++y)
    for (int x = 0; x < r->image.width(); ++x)
      for (int b = 0; b < bins; ++b) mean[b] += r->image.value(x, y, b);
  for (int b = 0; b < bins; ++b) {
    mean[b] /= r->image.width() * r->image.height();
    EXPECT_NEAR(r->statistics.mean[b], mean[b], 1e-6 * mean[b] + 1e-30) << b;
    EXPECT_GE(r->statistics.standard_error[b], 0.0);
  }
  EXPECT_EQ(r->statistics.pixels_with_error, 24u * 20u);
}

TEST_F(LocalRenderTest, ProgressIsMonotoneAndEndsAtTheTotal) {
  LocalRenderOptions o = options(2, 8, 1);
  o.progress_interval_seconds = 0;
  std::vector<RenderProgress> reports;
  o.progress = [&](const RenderProgress& p) { reports.push_back(p); };
  auto r = render(o);
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_FALSE(reports.empty());
  for (std::size_t i = 1; i < reports.size(); ++i) {
    EXPECT_GE(reports[i].samples_done, reports[i - 1].samples_done);
    EXPECT_GE(reports[i].seconds, reports[i - 1].seconds);
  }
  EXPECT_EQ(reports.back().samples_done, 24u * 20u * 4u);
  EXPECT_EQ(reports.back().samples_total, 24u * 20u * 4u);
}

TEST_F(LocalRenderTest, CancelledRendersReturnNoImage) {
  std::atomic<bool> cancel{true};
  auto r = render(options(2, 8, 1), &cancel);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kCancelled);
}

TEST_F(LocalRenderTest, RefusesSizesOutOfRange) {
  LocalRenderOptions o = options(1, 8, 0);
  o.width = 0;
  EXPECT_EQ(render(o).status().code(), absl::StatusCode::kInvalidArgument);
  o = options(1, 2, 0);
  EXPECT_EQ(render(o).status().code(), absl::StatusCode::kInvalidArgument);
  o = options(1, 8, 0);
  o.spp = 0;
  EXPECT_EQ(render(o).status().code(), absl::StatusCode::kInvalidArgument);
  o = options(-1, 8, 0);
  EXPECT_EQ(render(o).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace prism::coordinator
