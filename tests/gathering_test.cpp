// Gathering (coordinator/gather.h) on eye-traced caustics: scenes/crossing-caustics.pbrt, two
// rainbows crossing on a floor, small. Against an unbiased reference (hero with light-traced
// caustics at 1024 spp, another seed), hero's gathered image is never worse than its unbiased
// one at 64 and 256 spp, seeds 1 and 2 (relative squared error over the image); the eye paths
// recorded offsets, some pixels where the rainbows cross were left alone, and the unbiased image
// does not change when gathering is on.
#include <gtest/gtest.h>

#include <cstdio>

#include "services/base/atomic_file.h"
#include "tests/render_fixture.h"

namespace prism::coordinator {
namespace {

using GatheringTest = RenderFixtureBase<>;

double relative_error(const image::SpectralImage& image, const image::SpectralImage& reference) {
  double sum = 0, norm = 0;
  for (std::size_t i = 0; i < image.data().size(); ++i) {
    const double r = reference.data()[i], d = image.data()[i] - r;
    sum += d * d;
    norm += r * r;
  }
  return sum / norm;
}

TEST_F(GatheringTest, NeverWorseThanTheUnbiasedImageWhereCausticsCross) {
  auto text =
      base::read_file(std::filesystem::path(PRISM_SOURCE_DIR) / "scenes/crossing-caustics.pbrt");
  ASSERT_TRUE(text.ok()) << text.status();
  auto scene = load("crossing.pbrt", *text);
  ASSERT_TRUE(scene.ok()) << scene.status();
  auto small = [](LocalRenderOptions& o) {
    o.width = 64;
    o.height = 48;
    o.render.bins = 16;
  };
  auto reference = render(*scene, job::IntegratorKind::kHero, 1024, 99, 8, [&](auto& o) {
    small(o);
    o.render.light_caustics = true;
  });
  ASSERT_TRUE(reference.ok()) << reference.status();
  // Eye paths reach the slit lamps through a prism about once in 20,000 samples here, so a
  // 64-spp run (196,608 samples) can catch no caustic at all (seed 1 does since the D series
  // runs to 830 nm, which moved its samples); what gathering filters is counted over all runs.
  // Two caustic events with disagreeing offsets in one pixel are rarer still: the four small
  // runs caught none once the floor's patch took its own uv (which turned its shading frames
  // and so moved the samples), so a 1024-spp run (seed 3) is among them.
  std::uint64_t filtered_pixels = 0;
  std::uint64_t incoherent = 0;
  for (auto [seed, spp] :
       {std::pair<std::uint64_t, std::uint64_t>{1, 64}, {1, 256}, {2, 64}, {2, 256}, {3, 1024}}) {
    {
      auto plain = render(*scene, job::IntegratorKind::kHero, spp, seed, 8, small);
      auto gathered = render(*scene, job::IntegratorKind::kHero, spp, seed, 8, [&](auto& o) {
        small(o);
        o.render.gather_width_nm = 100.0f;
      });
      ASSERT_TRUE(plain.ok() && gathered.ok());
      ASSERT_TRUE(gathered->filtered.has_value() && gathered->stats.gather.has_value());
      EXPECT_TRUE(std::ranges::equal(plain->image.data(), gathered->image.data()));
      filtered_pixels += gathered->stats.gather->pixels_filtered;
      incoherent += gathered->stats.gather->pixels_incoherent;
      const double unbiased = relative_error(gathered->image, reference->image);
      const double filtered = relative_error(*gathered->filtered, reference->image);
      std::printf("seed %llu, %llu spp: gathered %.4g, unbiased %.4g\n", (unsigned long long)seed,
                  (unsigned long long)spp, filtered, unbiased);
      EXPECT_LE(filtered, unbiased) << "seed " << seed << ", " << spp << " spp";
    }
  }
  EXPECT_GT(filtered_pixels, 80u);
  EXPECT_GT(incoherent, 0u);  // where the rainbows cross, some offsets disagree
}

}  // namespace
}  // namespace prism::coordinator
