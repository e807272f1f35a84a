#include "coordinator/local_render.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <vector>

#include "coordinator/outputs.h"
#include "services/base/status.h"
#include "services/scene/scene_loader.h"
#include "tests/testing/test_dir.h"

namespace prism::coordinator {
namespace {

class LocalRenderTest : public ::testing::Test {
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

TEST_F(LocalRenderTest, ReusedGeometryGivesTheSameBytesUnderOtherOptions) {
  LocalRenderOptions first = options(2, 8, 0);
  auto a = LocalRender::create(device_, *scene_, *library_, first);
  ASSERT_TRUE(a.ok()) << a.status();
  // Another seed, integrator and depth, with the first render's geometry and without it.
  LocalRenderOptions other = options(2, 8, 0);
  other.render.seed = 12;
  other.render.integrator = job::IntegratorKind::kUniform;
  other.render.max_depth = 5;
  const LocalRenderOptions built_again = other;
  other.geometry = (*a)->shared_geometry();
  auto reused = LocalRender::create(device_, *scene_, *library_, other);
  ASSERT_TRUE(reused.ok()) << reused.status();
  EXPECT_EQ(&(*reused)->scene().geometry(), &(*a)->scene().geometry());  // not built again
  auto fresh = LocalRender::create(device_, *scene_, *library_, built_again);
  ASSERT_TRUE(fresh.ok()) << fresh.status();
  EXPECT_NE(&(*fresh)->scene().geometry(), &(*a)->scene().geometry());
  auto x = (*reused)->render();
  auto y = (*fresh)->render();
  ASSERT_TRUE(x.ok()) << x.status();
  ASSERT_TRUE(y.ok()) << y.status();
  EXPECT_TRUE(same_bits(x->image.data(), y->image.data()));
  EXPECT_EQ(x->stats.counters.rays, y->stats.counters.rays);
  // The geometry outlives the render that built it.
  a->reset();
  auto z = (*reused)->render();
  ASSERT_TRUE(z.ok()) << z.status();
  EXPECT_TRUE(same_bits(z->image.data(), y->image.data()));
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

// A sodium-like line lamp (588–590.6 nm) over a grey floor, with a dispersive BK7 sphere: the
// case where RGB made from bin averages depended on --bins (a bin's spectrum taken as flat).
constexpr char kLineLamp[] = R"(LookAt 0 2 -5  0 0.5 0  0 1 0
Camera "perspective" "float fov" 40
WorldBegin
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" [587 0 588 1 590.6 1 591.6 0] "float scale" 6
  Translate 0 3 0
  Rotate 90 1 0 0
  Shape "bilinearmesh" "point3 P" [-1 -1 0  1 -1 0  -1 1 0  1 1 0]
AttributeEnd
Material "diffuse" "rgb reflectance" [0.5 0.5 0.5]
Shape "trianglemesh" "point3 P" [-4 0 -4  4 0 -4  4 0 4  -4 0 4] "integer indices" [0 1 2 0 2 3]
Material "dielectric" "spectrum eta" "glass-BK7"
Translate 0 0.8 0
Shape "sphere" "float radius" 0.8
)";

class RgbOutputTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto library = spectral::SpectrumLibrary::load_builtin();
    ASSERT_TRUE(library.ok()) << library.status();
    library_ = std::make_unique<spectral::SpectrumLibrary>(*std::move(library));
    const std::filesystem::path file = prism::testing::test_dir() / "line_lamp.pbrt";
    std::ofstream(file) << kLineLamp;
    auto loaded = scene::load_scene(file, scene::with_library_names(*library_));
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    scene_ = std::make_unique<scene::SceneDescription>(std::move(loaded->description));
  }

  absl::StatusOr<LocalRenderResult> render(job::IntegratorKind integrator, int bins,
                                           std::uint64_t seed, std::uint64_t spp) {
    LocalRenderOptions o;
    o.render.integrator = integrator;
    o.render.bins = bins;
    o.render.max_depth = 5;
    o.render.seed = seed;
    if (integrator == job::IntegratorKind::kGradient) {
      PRISM_ASSIGN_OR_RETURN(o.render.gradient_offset_bins, job::gradient_offset_bins(0.15, bins));
    }
    o.width = 24;
    o.height = 18;
    o.spp = spp;
    o.tile_size = 8;
    o.threads = 2;
    PRISM_ASSIGN_OR_RETURN(auto r, LocalRender::create(device_, *scene_, *library_, o));
    return r->render();
  }

  static std::array<double, 3> mean_rgb(const image::RgbImage& rgb) {
    std::array<double, 3> m{};
    for (int y = 0; y < rgb.height(); ++y) {
      for (int x = 0; x < rgb.width(); ++x) {
        for (int c = 0; c < 3; ++c) m[c] += rgb.value(x, y, c);
      }
    }
    for (double& v : m) v /= double(rgb.width()) * rgb.height();
    return m;
  }

  worker::EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<scene::SceneDescription> scene_;
};

// Every sample adds its X, Y, Z at its own wavelengths, and nothing that picks a path depends on
// the bins, so hero's and uniform's RGB are the same bits at 4, 16, 64 and 256 bins, while the
// RGB of the bin averages is not (at 4 bins the line's 2.6 nm sit in a 117 nm bin taken as flat).
TEST_F(RgbOutputTest, HeroAndUniformRgbDoNotDependOnTheBins) {
  for (auto integrator : {job::IntegratorKind::kHero, job::IntegratorKind::kUniform}) {
    auto reference = render(integrator, 256, 3, 16);
    ASSERT_TRUE(reference.ok()) << reference.status();
    const std::array<double, 3> mean = mean_rgb(reference->rgb);
    ASSERT_GT(mean[0], 0.0);
    // At 256 bins (1.8 nm) the bins' RGB of the same samples is nearly exact: the scale agrees.
    auto fine = to_linear_srgb(reference->image, spectral::ColorMatching::cie1931());
    ASSERT_TRUE(fine.ok());
    const std::array<double, 3> fine_mean = mean_rgb(*fine);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(fine_mean[c] / mean[c], 1.0, 0.01) << "channel " << c;
    for (int bins : {4, 16, 64}) {
      SCOPED_TRACE(bins);
      auto r = render(integrator, bins, 3, 16);
      ASSERT_TRUE(r.ok()) << r.status();
      EXPECT_TRUE(same_bits(r->rgb.data(), reference->rgb.data()));
    }
    auto coarse = render(integrator, 4, 3, 16);
    ASSERT_TRUE(coarse.ok());
    auto from_bins = to_linear_srgb(coarse->image, spectral::ColorMatching::cie1931());
    ASSERT_TRUE(from_bins.ok());
    const std::array<double, 3> binned = mean_rgb(*from_bins);
    double worst = 0;
    for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(binned[c] / mean[c] - 1));
    EXPECT_GT(worst, 0.2) << "the bins' RGB was expected to be off at 4 bins";
  }
}

// The gradient integrator's RGB is the samples' exact XYZ plus the reconstruction's change of
// the bins' RGB, whose expectation is zero: the image means at 4 and 256 bins agree within the
// noise measured over independent seeds.
TEST_F(RgbOutputTest, GradientRgbAgreesAcrossBinsWithinNoise) {
  constexpr int kSeeds = 8;
  std::array<std::array<double, 3>, 2> mean{}, square{};
  const int bins[2] = {4, 256};
  for (int i = 0; i < 2; ++i) {
    for (int seed = 0; seed < kSeeds; ++seed) {
      auto r = render(job::IntegratorKind::kGradient, bins[i], 100 + seed, 32);
      ASSERT_TRUE(r.ok()) << r.status();
      const std::array<double, 3> m = mean_rgb(r->rgb);
      for (int c = 0; c < 3; ++c) {
        mean[i][c] += m[c] / kSeeds;
        square[i][c] += m[c] * m[c] / kSeeds;
      }
    }
  }
  for (int c = 0; c < 3; ++c) {
    double variance = 0;
    for (int i = 0; i < 2; ++i) {
      variance += (square[i][c] - mean[i][c] * mean[i][c]) * kSeeds / (kSeeds - 1) / kSeeds;
    }
    ASSERT_GT(variance, 0.0);
    const double z = (mean[0][c] - mean[1][c]) / std::sqrt(variance);
    EXPECT_LT(std::abs(z), 4.0) << "channel " << c << ": " << mean[0][c] << " at 4 bins, "
                                << mean[1][c] << " at 256";
  }
}

}  // namespace
}  // namespace prism::coordinator
