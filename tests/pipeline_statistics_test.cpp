// Unbiasedness of the whole pipelines against the single-wavelength `uniform` path tracer
// (docs/estimators.md §8), through coordinator::LocalRender exactly as `prism render` runs them:
//  - spectral gradient sampling: the workers' I and G, merged, then the per-pixel L2 screened
//    Poisson reconstruction, with τ = 0 and τ = 1 (which skips the shifts of about a fifth of
//    the base paths in these scenes), on a prism casting a dispersive caustic, a
//    diffuse object inside smooth glass, and a rough-glass object with coloured caustics;
//  - the multi-pass prepass: the final pass sampling each pixel's learned table, on a scene with
//    three emitters of different spectra, an absorbing medium and dispersive glass;
//  - hero's lane termination at coats whose index varies with wavelength.
//
// Statistic. The reconstruction mixes the bins of a pixel, so per-bin errors are not available
// from one render's sums of squares; instead each method renders the same small film with R
// independent seeds and the image mean per bin is compared between methods with a z-score from
// the spread over the seeds. Seeds are fixed, so the test is deterministic; the bound (|z| < 5 for
// every bin, Student's t with R − 1 degrees of freedom per side) was chosen so that an unbiased
// method passes for almost any choice of seeds (p ≈ 1e-4 per bin). Power, checked by hand when
// this test was written: scaling every reconstructed tile's G by 0.8 fails all six gradient
// cases at these sample counts (at 128 spp it failed only two). The estimators' own
// mutations (halved MIS weights, wrong Jacobians, wrong λ' factors) are caught by the worker's
// per-sample tests; this one proves the pipeline around them: merging, tables, reconstruction.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "coordinator/local_render.h"
#include "services/base/status.h"
#include "services/scene/scene_loader.h"

namespace prism {
namespace {

using coordinator::LocalRender;
using coordinator::LocalRenderOptions;
using coordinator::LocalRenderResult;

struct SeedStats {
  std::vector<double> mean;      // per bin, over the seeds
  std::vector<double> variance;  // of that mean
};

class PipelineStatisticsTest : public testing::Test {
 protected:
  void SetUp() override {
    auto library = spectral::SpectrumLibrary::load_builtin();
    ASSERT_TRUE(library.ok()) << library.status();
    library_ = std::make_unique<spectral::SpectrumLibrary>(*std::move(library));
  }

  absl::StatusOr<scene::SceneDescription> load(const std::string& name) const {
    scene::LoadOptions load = scene::with_library_names(*library_);
    PRISM_ASSIGN_OR_RETURN(scene::LoadedScene loaded,
                           scene::load_scene(std::filesystem::path(PRISM_SOURCE_DIR) / name, load));
    return std::move(loaded.description);
  }

  // The image's mean spectrum for each of `seeds` renders, reduced to a mean and its variance.
  SeedStats over_seeds(const scene::SceneDescription& scene, LocalRenderOptions o, int seeds,
                       coordinator::PrepassOutcome* prepass = nullptr) {
    SeedStats stats;
    std::vector<std::vector<double>> runs;
    for (int s = 0; s < seeds; ++s) {
      o.render.seed = 1000 + static_cast<std::uint64_t>(s);
      auto render = LocalRender::create(device_, scene, *library_, o);
      EXPECT_TRUE(render.ok()) << render.status();
      if (!render.ok()) return stats;
      absl::StatusOr<LocalRenderResult> result = (*render)->render();
      EXPECT_TRUE(result.ok()) << result.status();
      if (!result.ok()) return stats;
      if (prepass != nullptr) {
        EXPECT_TRUE(result->stats.prepass.has_value());
        if (result->stats.prepass.has_value()) *prepass = *result->stats.prepass;
      }
      const image::SpectralImage& image = result->image;
      std::vector<double> mean(image.bins(), 0.0);
      for (int y = 0; y < image.height(); ++y) {
        for (int x = 0; x < image.width(); ++x) {
          for (int b = 0; b < image.bins(); ++b) {
            EXPECT_TRUE(std::isfinite(image.value(x, y, b))) << x << "," << y << " bin " << b;
            mean[b] += image.value(x, y, b);
          }
        }
      }
      for (double& m : mean) m /= double(image.width()) * image.height();
      runs.push_back(std::move(mean));
    }
    const int bins = static_cast<int>(runs.front().size());
    stats.mean.assign(bins, 0.0);
    stats.variance.assign(bins, 0.0);
    for (const auto& run : runs) {
      for (int b = 0; b < bins; ++b) stats.mean[b] += run[b] / seeds;
    }
    for (const auto& run : runs) {
      for (int b = 0; b < bins; ++b) {
        const double d = run[b] - stats.mean[b];
        stats.variance[b] += d * d / (seeds - 1) / seeds;
      }
    }
    return stats;
  }

  // The largest |z| over the bins; every bin's z is printed on failure.
  static double max_z(const SeedStats& a, const SeedStats& b, std::string* detail) {
    double worst = 0;
    for (std::size_t i = 0; i < a.mean.size(); ++i) {
      const double se = std::sqrt(a.variance[i] + b.variance[i]);
      // A bin with no light in either method: both exactly 0.
      const double z = se > 0 ? (a.mean[i] - b.mean[i]) / se : (a.mean[i] == b.mean[i] ? 0 : 1e9);
      worst = std::max(worst, std::fabs(z));
      *detail += "bin " + std::to_string(i) + ": " + std::to_string(a.mean[i]) + " vs " +
                 std::to_string(b.mean[i]) + " z " + std::to_string(z) + "\n";
    }
    return worst;
  }

  // `integrator` at 16 bins, max depth 6, in 16 px tiles on every thread.
  static LocalRenderOptions base_options(job::IntegratorKind integrator, int width, int height,
                                         std::uint64_t spp) {
    LocalRenderOptions o;
    o.render.integrator = integrator;
    o.render.bins = 16;
    o.render.max_depth = 6;
    o.width = width;
    o.height = height;
    o.spp = spp;
    o.tile_size = 16;
    o.threads = 0;
    return o;
  }

  worker::EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
};

struct GradientCase {
  const char* scene;
  float tau;
  job::PoissonNorm norm = job::PoissonNorm::kL2;
};

class GradientPipelineTest : public PipelineStatisticsTest,
                             public testing::WithParamInterface<GradientCase> {};

// L2 is unbiased; the variance-weighted solve takes its weights from the same samples, so it is
// only consistent, but at 512 spp its bias must already be lost in the noise of 24 seeds.
TEST_P(GradientPipelineTest, ReconstructionAgreesWithUniformPerBin) {
  const GradientCase& c = GetParam();
  auto scene = load(c.scene);
  ASSERT_TRUE(scene.ok()) << scene.status();
  constexpr int kSeeds = 24;
  LocalRenderOptions uniform = base_options(job::IntegratorKind::kUniform, 12, 12, 512);
  LocalRenderOptions gradient = uniform;
  gradient.render.integrator = job::IntegratorKind::kGradient;
  gradient.render.gradient_offset_bins = *job::gradient_offset_bins(0.15, uniform.render.bins);
  gradient.render.gradient_tau = c.tau;
  gradient.poisson_norm = c.norm;
  const SeedStats u = over_seeds(*scene, uniform, kSeeds);
  const SeedStats g = over_seeds(*scene, gradient, kSeeds);
  ASSERT_EQ(u.mean.size(), g.mean.size());
  std::string detail;
  EXPECT_LT(max_z(g, u, &detail), 5.0)
      << c.scene << " tau " << c.tau << " " << job::to_string(c.norm) << "\n"
      << detail;
}

INSTANTIATE_TEST_SUITE_P(
    Scenes, GradientPipelineTest,
    testing::Values(GradientCase{"worker/testdata/gradient_prism.pbrt", 0.0f},
                    GradientCase{"worker/testdata/gradient_prism.pbrt", 1.0f},
                    GradientCase{"worker/testdata/gradient_glass_diffuse.pbrt", 0.0f},
                    GradientCase{"worker/testdata/gradient_glass_diffuse.pbrt", 1.0f},
                    GradientCase{"worker/testdata/gradient_rough_glass.pbrt", 0.0f},
                    GradientCase{"worker/testdata/gradient_rough_glass.pbrt", 1.0f},
                    GradientCase{"worker/testdata/gradient_prism.pbrt", 0.0f,
                                 job::PoissonNorm::kWeighted},
                    GradientCase{"worker/testdata/gradient_glass_diffuse.pbrt", 0.0f,
                                 job::PoissonNorm::kWeighted},
                    GradientCase{"worker/testdata/gradient_rough_glass.pbrt", 1.0f,
                                 job::PoissonNorm::kWeighted}),
    [](const testing::TestParamInfo<GradientCase>& info) {
      std::string name = std::filesystem::path(info.param.scene).stem().string();
      for (char& ch : name) {
        if (ch == '-') ch = '_';
      }
      return name + (info.param.tau > 0 ? "_tau" : "_tau0") +
             (info.param.norm == job::PoissonNorm::kWeighted ? "_weighted" : "");
    });

struct PrepassCase {
  const char* name;
  job::IntegratorKind integrator;
  bool image_scaled;
};

class PrepassPipelineTest : public PipelineStatisticsTest,
                            public testing::WithParamInterface<PrepassCase> {};

// The final pass samples every pixel's learned table (hero: its C = 4 CMIS lanes; gradient: the
// base wavelength, the offsets' MIS weights use the same table): second-moment bin masses with the
// default's shape inside each bin, mixed with the default by a per-pixel α; sample-scaled and
// image-scaled passes.
TEST_P(PrepassPipelineTest, FinalPassWithLearnedTablesAgreesWithUniformPerBin) {
  const PrepassCase& c = GetParam();
  auto scene = load("tests/testdata/pipeline/three_emitters.pbrt");
  ASSERT_TRUE(scene.ok()) << scene.status();
  constexpr int kSeeds = 24;
  LocalRenderOptions uniform = base_options(job::IntegratorKind::kUniform, 24, 24, 64);
  LocalRenderOptions prepass = uniform;
  prepass.render.integrator = c.integrator;
  prepass.render.gradient_offset_bins = *job::gradient_offset_bins(0.15, uniform.render.bins);
  // The unbiased reconstruction: what is tested is the sampling of the tables.
  prepass.poisson_norm = job::PoissonNorm::kL2;
  job::PrepassParameters params;
  params.spp = 16;
  params.image_scaled = c.image_scaled;
  // Whatever gain they predict, the tables are used: they are what is tested.
  params.fallback = 0.0;
  params.min_image_gain = params.min_final_gain = -1.0;
  prepass.prepass = params;
  coordinator::PrepassOutcome outcome;
  const SeedStats u = over_seeds(*scene, uniform, kSeeds);
  const SeedStats p = over_seeds(*scene, prepass, kSeeds, &outcome);
  // The learned tables are used (the last seed's): not every pixel fell back to the default
  // distribution, and pixels took several mixture weights.
  EXPECT_FALSE(outcome.stopped_early);
  EXPECT_LT(outcome.fallback_fraction, 0.9);
  int weights = 0;
  for (int a = 1; a < coordinator::kAlphaChoices; ++a) weights += outcome.alpha_histogram[a] > 0;
  EXPECT_GT(outcome.shape_histogram[0] + outcome.shape_histogram[1], 0);
  EXPECT_GE(weights, 2) << outcome.alpha_histogram[0] << " " << outcome.alpha_histogram[1] << " "
                        << outcome.alpha_histogram[2] << " " << outcome.alpha_histogram[3] << " "
                        << outcome.alpha_histogram[4];
  std::string detail;
  EXPECT_LT(max_z(p, u, &detail), 5.0) << c.name << "\n" << detail;
}

INSTANTIATE_TEST_SUITE_P(
    Modes, PrepassPipelineTest,
    testing::Values(PrepassCase{"hero", job::IntegratorKind::kHero, false},
                    PrepassCase{"hero_image_scaled", job::IntegratorKind::kHero, true},
                    PrepassCase{"gradient", job::IntegratorKind::kGradient, false}),
    [](const testing::TestParamInfo<PrepassCase>& info) { return std::string(info.param.name); });

// Coats whose index varies with wavelength: hero makes the BSDF at the hero wavelength and
// terminates the other lanes before next-event estimation (pbrt-v4's TerminateSecondary); the
// image must agree with `uniform`, which traces one wavelength per path, per bin. Power, checked
// by hand: without the termination (every lane uses the hero's index) the largest |z| is 7.7.
TEST_F(PipelineStatisticsTest, HeroWithADispersiveCoatAgreesWithUniformPerBin) {
  auto scene = load("tests/testdata/pipeline/spectral_coat.pbrt");
  ASSERT_TRUE(scene.ok()) << scene.status();
  constexpr int kSeeds = 16;
  LocalRenderOptions uniform = base_options(job::IntegratorKind::kUniform, 24, 24, 256);
  LocalRenderOptions hero = uniform;
  hero.render.integrator = job::IntegratorKind::kHero;
  const SeedStats u = over_seeds(*scene, uniform, kSeeds);
  const SeedStats h = over_seeds(*scene, hero, kSeeds);
  std::string detail;
  EXPECT_LT(max_z(h, u, &detail), 5.0) << detail;
}

// A portal changes how the environment is sampled, not the light that reaches a room whose only
// opening is the portal's window: hero and the gradient reconstruction with the portal agree per
// bin with hero on the same room without it.
TEST_F(PipelineStatisticsTest, APortalChangesSamplingNotTheImage) {
  auto with_portal = load("tests/testdata/pipeline/portal_room.pbrt");
  ASSERT_TRUE(with_portal.ok()) << with_portal.status();
  scene::SceneDescription without_portal = *with_portal;
  for (scene::Light& light : without_portal.lights) {
    if (auto* inf = std::get_if<scene::InfiniteLight>(&light.kind)) {
      ASSERT_TRUE(inf->portal.has_value());
      inf->portal.reset();
    }
  }
  constexpr int kSeeds = 12;
  LocalRenderOptions hero = base_options(job::IntegratorKind::kHero, 24, 24, 64);
  LocalRenderOptions gradient = hero;
  gradient.render.integrator = job::IntegratorKind::kGradient;
  const SeedStats plain = over_seeds(without_portal, hero, kSeeds);
  const SeedStats portal_hero = over_seeds(*with_portal, hero, kSeeds);
  const SeedStats portal_gradient = over_seeds(*with_portal, gradient, kSeeds);
  std::string detail;
  EXPECT_LT(max_z(portal_hero, plain, &detail), 5.0) << detail;
  detail.clear();
  EXPECT_LT(max_z(portal_gradient, plain, &detail), 5.0) << detail;
}

// pbrt-v4 renders a non-planar bilinear patch as the curved surface, intersected and sampled as
// an emitter (worker/geometry.h): each pixel agrees with the same surfaces as 48x48 grids of
// triangles on them, hero and the gradient reconstruction alike: the mean of z² over pixels and
// bins is 1.13 (each patch as its two triangles, as Prism had it: 5.0).
TEST_F(PipelineStatisticsTest, CurvedBilinearPatchesAgreeWithFineTriangleGridsPerPixel) {
  auto patches = load("tests/testdata/pipeline/curved_patches.pbrt");
  ASSERT_TRUE(patches.ok()) << patches.status();
  scene::SceneDescription grids = *patches;
  int replaced = 0;
  for (scene::Shape& shape : grids.shapes) {
    auto& mesh = std::get<scene::TriangleMeshShape>(shape.geometry);
    if (mesh.mesh->patches.empty()) continue;
    const auto& m = *mesh.mesh;
    const scene::Triangle& a = m.triangles[0];
    const scene::Float3 c[4] = {m.positions[a[0]], m.positions[a[1]],
                                m.positions[m.triangles[1][2]], m.positions[a[2]]};
    constexpr int kN = 48;
    auto grid = std::make_shared<scene::TriangleMeshData>();
    for (int j = 0; j <= kN; ++j) {
      for (int i = 0; i <= kN; ++i) {
        const double u = double(i) / kN, v = double(j) / kN;
        auto at = [&](float scene::Float3::*k) {
          return float(((1 - u) * (c[0].*k) + u * (c[1].*k)) * (1 - v) +
                       ((1 - u) * (c[2].*k) + u * (c[3].*k)) * v);
        };
        grid->positions.push_back(
            {at(&scene::Float3::x), at(&scene::Float3::y), at(&scene::Float3::z)});
      }
    }
    for (std::uint32_t j = 0; j < kN; ++j) {
      for (std::uint32_t i = 0; i < kN; ++i) {
        const std::uint32_t p = j * (kN + 1) + i, q = p + kN + 1;
        grid->triangles.push_back({p, p + 1, q + 1});
        grid->triangles.push_back({p, q + 1, q});
      }
    }
    grid->positions.reserve(grid->positions.size() + 1);
    mesh.mesh = grid;
    ++replaced;
  }
  ASSERT_EQ(replaced, 2);
  // Per pixel and bin over the seeds: the mean of z² is about 1 where the images agree (at
  // most 1.29, t with 9 degrees of freedom per side).
  auto per_pixel = [&](const scene::SceneDescription& scene, LocalRenderOptions o, int seeds,
                       std::uint64_t first_seed) {
    std::vector<std::vector<double>> runs;
    for (int s = 0; s < seeds; ++s) {
      o.render.seed = first_seed + static_cast<std::uint64_t>(s);
      auto render = LocalRender::create(device_, scene, *library_, o);
      EXPECT_TRUE(render.ok()) << render.status();
      if (!render.ok()) return runs;
      absl::StatusOr<LocalRenderResult> result = (*render)->render();
      EXPECT_TRUE(result.ok()) << result.status();
      if (!result.ok()) return runs;
      const image::SpectralImage& image = result->image;
      std::vector<double> values;
      for (int y = 0; y < image.height(); ++y)
        for (int x = 0; x < image.width(); ++x)
          for (int b = 0; b < image.bins(); ++b) values.push_back(image.value(x, y, b));
      runs.push_back(std::move(values));
    }
    return runs;
  };
  auto mean_z2 = [](const std::vector<std::vector<double>>& a,
                    const std::vector<std::vector<double>>& b) {
    double sum = 0;
    int counted = 0;
    for (std::size_t i = 0; i < a.front().size(); ++i) {
      double ma = 0, mb = 0, va = 0, vb = 0;
      for (const auto& r : a) ma += r[i] / a.size();
      for (const auto& r : b) mb += r[i] / b.size();
      for (const auto& r : a) va += (r[i] - ma) * (r[i] - ma) / (a.size() - 1) / a.size();
      for (const auto& r : b) vb += (r[i] - mb) * (r[i] - mb) / (b.size() - 1) / b.size();
      if (!(va + vb > 0)) continue;
      sum += (ma - mb) * (ma - mb) / (va + vb);
      ++counted;
    }
    return counted > 0 ? sum / counted : 0.0;
  };
  constexpr int kSeeds = 10;
  for (job::IntegratorKind kind : {job::IntegratorKind::kHero, job::IntegratorKind::kGradient}) {
    const LocalRenderOptions o = base_options(kind, 24, 18, 256);
    // Independent seeds: the same streams would correlate the two and shrink z.
    const auto a = per_pixel(*patches, o, kSeeds, 2000);
    const auto b = per_pixel(grids, o, kSeeds, 3000);
    ASSERT_EQ(a.size(), std::size_t(kSeeds));
    ASSERT_EQ(b.size(), std::size_t(kSeeds));
    EXPECT_LT(mean_z2(a, b), 1.6) << job::name(kind);
  }
}

}  // namespace
}  // namespace prism
