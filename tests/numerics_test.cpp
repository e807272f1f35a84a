// The numerical stability suite (`ctest -L numerics`): hard cases through the whole embedded
// pipeline and the reconstruction and prepass stages. Every case asserts that no output holds a
// NaN or an Inf (the spectral image, its RGB and standard errors, the bin statistics, the
// gradient's primal and G) and, where a closed form exists, agrees with it:
//   - scene scales 1e-4 and 1e5: a floor under a distant light shows ρ/π·E·cos θ at any scale;
//   - η → 1: an emitter seen through a slab of η = 1 + 1e-7 (constant and dispersive) is the
//     emitter;
//   - line-only emitters (sodium's 589 nm line) at B = 4 and B = 256: the floor's bin averages
//     are the line's share of the bin, zero in every other bin;
//   - zero albedo: a black floor is exactly black, by every integrator and with the prepass (an
//     all-black prepass);
//   - degenerate and sliver triangles in a mesh and an emitter: finite, and the emitter lights
//     the floor as its one proper triangle does;
//   - δ wrapping the spectrum (k = B/2 and B − 1): the gradient reconstruction of a coloured
//     floor is exact;
//   - the Poisson screening weight α at its bounds (1e-6 and 1e6) and a pixel whose every sample
//     is zero but one: consistent inputs reconstruct exactly, any input keeps its spectral sum;
//   - the prepass's tables from a pixel with one non-zero sample among zeros;
//   - grazing dispersive refraction, total internal reflection of offsets, a 1 nm line and an
//     emitter 10^9/50 ≈ 10^7 times brighter than its neighbour
//     (tests/testdata/pipeline/stress.pbrt).
// Malformed input of each kind (non-finite numbers, degenerate lights, out-of-range weights) is
// refused with a message naming what and where.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"
#include "coordinator/poisson.h"
#include "coordinator/prepass.h"
#include "tests/render_fixture.h"

namespace prism::coordinator {
namespace {

class NumericsTest : public RenderFixture {
 protected:
  // Every value of every output is finite.
  static void expect_finite(const LocalRenderResult& r, const std::string& what) {
    auto finite = [](std::span<const float> values) {
      return std::all_of(values.begin(), values.end(), [](float v) { return std::isfinite(v); });
    };
    EXPECT_TRUE(finite(r.image.data())) << what << ": spectral image";
    EXPECT_TRUE(finite(r.rgb.data())) << what << ": RGB";
    EXPECT_TRUE(finite(r.rgb_standard_error.data())) << what << ": RGB standard error";
    for (const std::vector<double>* v : {&r.statistics.mean, &r.statistics.variance_of_mean}) {
      for (double x : *v) EXPECT_TRUE(std::isfinite(x)) << what << ": bin statistics";
    }
    if (r.primal.has_value()) {
      EXPECT_TRUE(finite(r.primal->data())) << what << ": primal";
    }
    if (r.gradient.has_value()) {
      EXPECT_TRUE(finite(r.gradient->data())) << what << ": gradient";
    }
  }

  // Every integrator's image, finite, per bin against expected(lower, upper) within 4 standard
  // errors of the pixel mean plus `relative` of the largest bin's answer (float round-off in a
  // reconstruction leaves ~1e-17 of the brightest bin in bins whose answer is 0).
  static void expect_answer(const scene::SceneDescription& scene, std::uint64_t spp, int max_depth,
                            double relative, const std::function<double(double, double)>& expected,
                            const std::function<void(LocalRenderOptions&)>& adjust = nullptr,
                            std::span<const job::IntegratorKind> integrators = kIntegrators) {
    for (job::IntegratorKind integrator : integrators) {
      SCOPED_TRACE(job::name(integrator));
      auto result = render(scene, integrator, spp, 11, max_depth, adjust);
      ASSERT_TRUE(result.ok()) << result.status();
      expect_finite(*result, job::name(integrator));
      const spectral::WavelengthGrid grid = *spectral::WavelengthGrid::create(result->image.bins());
      double largest = 0;
      for (int b = 0; b < grid.bins(); ++b) {
        largest = std::max(largest, std::abs(expected(grid.lower(b), grid.upper(b))));
      }
      for (int b = 0; b < grid.bins(); ++b) {
        const double want = expected(grid.lower(b), grid.upper(b));
        const Mean got = pixel_mean(result->image, b);
        EXPECT_NEAR(got.mean, want, 4 * got.standard_error + relative * largest)
            << "bin " << b << " (" << grid.lower(b) << "-" << grid.upper(b) << " nm)";
      }
    }
  }

  // A grey (ρ = 0.5, or `reflectance`) floor seen from above at scale s, under a distant light
  // of illuminance 3 at 30° from the zenith with spectrum `light`.
  static std::string floor_scene(double s, const std::string& light,
                                 const std::string& reflectance = "[360 0.5 830 0.5]",
                                 int bins = 16) {
    return absl::StrCat("LookAt 0 ", 5 * s, " 0  0 0 0  0 0 1\n",
                        "Camera \"perspective\" \"float fov\" 20\n",
                        "Film \"spectral\" \"integer xresolution\" 8 \"integer yresolution\" 8 "
                        "\"integer nbuckets\" ",
                        bins, "\nWorldBegin\nLightSource \"distant\" \"spectrum L\" ", light,
                        " \"point3 from\" [1 1.7320508 0] \"point3 to\" [0 0 0] "
                        "\"float illuminance\" 3\n",
                        "Material \"diffuse\" \"spectrum reflectance\" ", reflectance, "\n",
                        "Shape \"trianglemesh\" \"point3 P\" [", -10 * s, " 0 ", -10 * s, "  ",
                        10 * s, " 0 ", -10 * s, "  ", 10 * s, " 0 ", 10 * s, "  ", -10 * s, " 0 ",
                        10 * s, "] \"integer indices\" [0 1 2 0 2 3]\n");
  }
};

TEST_F(NumericsTest, AFloorUnderADistantLightIsTheSameAtEveryScale) {
  const double expected = 0.5 / M_PI * 3.0 * unit_flat_emission() * std::cos(M_PI / 6);
  for (double s : {1e-4, 1.0, 1e5}) {
    SCOPED_TRACE(absl::StrCat("scale ", s));
    auto scene = load("scale.pbrt", floor_scene(s, "[360 1 830 1]"));
    ASSERT_TRUE(scene.ok()) << scene.status();
    expect_answer(*scene, 16, 3, 1e-5, [&](double, double) { return expected; });
  }
}

// A glass prism on a floor under a sky, every coordinate (the camera's too) scaled: the same seed
// gives the same image at any scale up to float round-off. A 1e-4 scene came out 4 % darker (the
// prism 20-28 %): the ray offset had a floor of 1e-5, absolute, bigger than the prism's sides.
TEST_F(NumericsTest, AGlassPrismIsTheSameAtEveryScale) {
  auto prism_scene = [](double s) {
    auto v = [s](double x) { return absl::StrCat(x * s); };
    auto points = [&](std::initializer_list<double> xs) {
      std::string out;
      for (double x : xs) absl::StrAppend(&out, out.empty() ? "" : " ", v(x));
      return out;
    };
    return absl::StrCat(
        "LookAt ", points({1, 4.2, -2.6, 1, 0.2, 0.1}), "  0 1 0\n",
        "Camera \"perspective\" \"float fov\" 40\n",
        "Film \"spectral\" \"integer xresolution\" 32 \"integer yresolution\" 24 "
        "\"integer nbuckets\" 16\nWorldBegin\n",
        "LightSource \"infinite\" \"spectrum L\" \"stdillum-D65\" \"float scale\" 0.08\n",
        "AttributeBegin\nMaterial \"diffuse\" \"rgb reflectance\" [0.7 0.7 0.7]\n",
        "Shape \"trianglemesh\" \"point3 P\" [",
        points({-10, 0, -10, 10, 0, -10, 10, 0, 10, -10, 0, 10}),
        "] \"integer indices\" [0 2 1 0 3 2]\n", "AttributeEnd\nAttributeBegin\nTranslate 0 ", v(2),
        " 0\nRotate -33 0 0 1\n", "Material \"dielectric\" \"spectrum eta\" \"glass-F11\"\n",
        "Shape \"trianglemesh\" \"point3 P\" [",
        points({-0.3, -0.1732, -1.5, 0.3, -0.1732, -1.5, 0, 0.3464, -1.5, -0.3, -0.1732, 1.5, 0.3,
                -0.1732, 1.5, 0, 0.3464, 1.5}),
        "]\n  \"integer indices\" [0 2 1 3 4 5 0 3 2 3 5 2 1 2 4 2 5 4 0 1 3 1 4 3]\n",
        "AttributeEnd\n");
  };
  auto unit = load("prism_1.pbrt", prism_scene(1));
  ASSERT_TRUE(unit.ok()) << unit.status();
  auto reference = render(*unit, job::IntegratorKind::kHero, 64, 5, 8);
  ASSERT_TRUE(reference.ok()) << reference.status();
  for (double s : {1e-4, 1e5}) {
    SCOPED_TRACE(absl::StrCat("scale ", s));
    auto scaled = load("prism_s.pbrt", prism_scene(s));
    ASSERT_TRUE(scaled.ok()) << scaled.status();
    auto result = render(*scaled, job::IntegratorKind::kHero, 64, 5, 8);
    ASSERT_TRUE(result.ok()) << result.status();
    expect_finite(*result, "scaled");
    for (int b = 0; b < result->image.bins(); ++b) {
      const double want = pixel_mean(reference->image, b).mean;
      EXPECT_NEAR(pixel_mean(result->image, b).mean, want, 2e-3 * want) << "bin " << b;
    }
  }
}

// An emitter (flat, one unit of radiance after pbrt-v4's normalisation) behind a slab whose η is
// within 1e-7 of 1, constant or dispersive: R ≈ 6e-16, so the image is the emitter.
TEST_F(NumericsTest, ASlabOfEtaNearOneIsTransparent) {
  for (const char* eta : {"\"float eta\" 1.0000001", "\"float cauchy\" [1.0000001 1e-9]"}) {
    SCOPED_TRACE(eta);
    auto scene = load("eta_one.pbrt", absl::StrCat(R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 10
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
WorldBegin
AttributeBegin
  Material "dielectric" )",
                                                   eta, R"(
  Shape "trianglemesh" "point3 P" [-3 -3 -1  3 -3 -1  3 3 -1  -3 3 -1] "integer indices" [0 1 2 0 2 3]
  Shape "trianglemesh" "point3 P" [-3 -3 -0.5  -3 3 -0.5  3 3 -0.5  3 -3 -0.5] "integer indices" [0 1 2 0 2 3]
AttributeEnd
AttributeBegin
  Material "diffuse" "spectrum reflectance" [360 0 830 0]
  AreaLightSource "diffuse" "spectrum L" [360 1 830 1]
  Shape "trianglemesh" "point3 P" [-9 -9 3  -9 9 3  9 9 3  9 -9 3] "integer indices" [0 1 2 0 2 3]
AttributeEnd
)"));
    ASSERT_TRUE(scene.ok()) << scene.status();
    const double le = unit_flat_emission();
    expect_answer(*scene, 16, 6, 1e-5, [&](double, double) { return le; });
  }
}

// Sodium's D line as a 0.2 nm triangle at 589 nm: under a distant light of illuminance E the
// floor's bin b averages ρ/π·E·cos θ·∫_b S / (Σ ȳ S · w_b); every other bin is exactly 0. The
// line falls inside one bin at B = 4 and at B = 256. (`uniform` draws one wavelength uniformly
// and would need ~10^4 samples per pixel to meet a 0.2 nm line: hero and gradient sample the
// emitter's spectrum.)
TEST_F(NumericsTest, ALineOnlyEmitterFillsOneBinAtFourAndAt256Bins) {
  const std::string line = "[360 0 588.9 0 589 1 589.1 0 830 0]";
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  const std::vector<double> line_nm = {360, 588.9, 589, 589.1, 830}, line_v = {0, 0, 1, 0, 0};
  const spectral::PiecewiseLinearSpectrum sodium =
      *spectral::PiecewiseLinearSpectrum::create(line_nm, line_v, "sodium");
  const double y_sum = cmf.photometric_sum(spectral::Spectrum(sodium));
  constexpr job::IntegratorKind kSpectral[] = {job::IntegratorKind::kHero,
                                               job::IntegratorKind::kGradient};
  for (int bins : {4, 256}) {
    SCOPED_TRACE(absl::StrCat(bins, " bins"));
    auto scene = load("sodium.pbrt", floor_scene(1, line, "[360 0.5 830 0.5]", bins));
    ASSERT_TRUE(scene.ok()) << scene.status();
    expect_answer(
        *scene, 16, 3, 1e-4,
        [&](double lo, double hi) {
          const double in_bin = sodium.integral(lo, hi);
          return 0.5 / M_PI * 3.0 * std::cos(M_PI / 6) * in_bin / y_sum / (hi - lo);
        },
        nullptr, kSpectral);
  }
}

// A black floor under a lamp it cannot see past: exactly zero everywhere, by every integrator
// and with the prepass, whose every pass then sees an all-black image.
TEST_F(NumericsTest, ZeroAlbedoIsExactlyBlackWithAndWithoutThePrepass) {
  auto scene = load("black.pbrt", R"(LookAt 0 5 0  0 0 0  0 0 1
Camera "perspective" "float fov" 20
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
WorldBegin
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" "stdillum-F11" "float scale" 1e6
  Shape "trianglemesh" "point3 P" [-1 8 -1  1 8 -1  1 8 1  -1 8 1] "integer indices" [0 2 1 0 3 2]
AttributeEnd
Material "diffuse" "spectrum reflectance" [360 0 830 0]
Shape "trianglemesh" "point3 P" [-10 0 -10  10 0 -10  10 0 10  -10 0 10] "integer indices" [0 1 2 0 2 3]
)");
  ASSERT_TRUE(scene.ok()) << scene.status();
  for (bool prepass : {false, true}) {
    SCOPED_TRACE(prepass ? "with the prepass" : "no prepass");
    expect_answer(
        *scene, 64, 5, 0, [](double, double) { return 0.0; },
        [&](LocalRenderOptions& o) {
          if (prepass && o.render.integrator == job::IntegratorKind::kHero) {
            job::PrepassParameters p;
            p.spp = 16;
            o.prepass = p;
          }
        });
  }
  auto result = render(*scene, job::IntegratorKind::kHero, 64, 3, 5, [](LocalRenderOptions& o) {
    job::PrepassParameters p;
    p.spp = 16;
    o.prepass = p;
  });
  ASSERT_TRUE(result.ok()) << result.status();
  ASSERT_TRUE(result->stats.prepass.has_value());
  for (float v : result->image.data()) EXPECT_EQ(v, 0.0f);
}

// Zero-area triangles (a repeated vertex, three collinear points) and a 1e-7-wide sliver, in
// the floor and in the emitter: the image is finite and the emitter lights the floor as its one
// proper triangle does (the sliver adds a relative 1e-7).
TEST_F(NumericsTest, DegenerateAndSliverTrianglesAreHarmless) {
  const std::string head = R"(LookAt 0 5 0  0 0 0  0 0 1
Camera "perspective" "float fov" 40
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
WorldBegin
Material "diffuse" "spectrum reflectance" [360 0.5 830 0.5]
Shape "trianglemesh" "point3 P" [-10 0 -10  10 0 -10  10 0 10  -10 0 10  0 0 0  1 0 1  2 0 2]
  "integer indices" [0 1 2 0 2 3  4 5 6  4 4 5  0 0 0]
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" [360 1 830 1]
)";
  auto clean =
      load("clean.pbrt", head + R"(  Shape "trianglemesh" "point3 P" [-1 3 -1  1 3 -1  0 3 1]
    "integer indices" [0 2 1]
AttributeEnd
)");
  auto broken = load("broken.pbrt", head + R"(  Shape "trianglemesh"
    "point3 P" [-1 3 -1  1 3 -1  0 3 1  0 3 0  0.5 3 0  1 3 0  -1 3 0.5  1 3 0.5000001]
    "integer indices" [0 2 1  3 4 5  3 3 4  6 7 6  6 7 1]
AttributeEnd
)");
  ASSERT_TRUE(clean.ok()) << clean.status();
  ASSERT_TRUE(broken.ok()) << broken.status();
  for (job::IntegratorKind integrator : kIntegrators) {
    SCOPED_TRACE(job::name(integrator));
    auto a = render(*clean, integrator, 256, 21, 3);
    auto b = render(*broken, integrator, 256, 22, 3);
    ASSERT_TRUE(a.ok()) << a.status();
    ASSERT_TRUE(b.ok()) << b.status();
    expect_finite(*b, "broken");
    for (int bin = 0; bin < a->image.bins(); ++bin) {
      const Mean ma = pixel_mean(a->image, bin), mb = pixel_mean(b->image, bin);
      ASSERT_GT(ma.mean, 0);
      EXPECT_NEAR(mb.mean, ma.mean, 4 * std::hypot(ma.standard_error, mb.standard_error))
          << "bin " << bin;
    }
  }
}

// A floor whose reflectance changes across the spectrum, under a flat distant light: the
// gradient reconstruction is exact (every estimate is deterministic) also when the offset wraps
// the spectrum: k = B/2, where +δ and −δ meet, and k = B − 1.
TEST_F(NumericsTest, GradientOffsetsThatWrapTheSpectrumReconstructExactly) {
  auto scene = load("coloured.pbrt",
                    floor_scene(1, "[360 1 830 1]", "[360 0.1 500 0.9 600 0.2 700 0.7 830 0.3]"));
  ASSERT_TRUE(scene.ok()) << scene.status();
  const std::vector<double> rho_nm = {360, 500, 600, 700, 830}, rho_v = {0.1, 0.9, 0.2, 0.7, 0.3};
  const spectral::PiecewiseLinearSpectrum rho =
      *spectral::PiecewiseLinearSpectrum::create(rho_nm, rho_v, "rho");
  const double scale = 3.0 * unit_flat_emission() * std::cos(M_PI / 6) / M_PI;
  for (int k : {8, 15}) {
    SCOPED_TRACE(absl::StrCat("k ", k));
    constexpr job::IntegratorKind kGradient[] = {job::IntegratorKind::kGradient};
    expect_answer(
        *scene, 16, 3, 2e-4, [&](double lo, double hi) { return scale * rho.bin_average(lo, hi); },
        [&](LocalRenderOptions& o) {
          o.render.gradient_offset_bins = k;
          o.keep_primal_and_gradients = true;
        },
        kGradient);
  }
}

// The screened Poisson solve at α = 1e-6 and 1e6 (its bounds), for a pixel whose spectrum is a
// single spike (every sample zero but one): gradients consistent with the primal reconstruct it
// exactly whatever α; any gradients keep the spectrum's sum (each cyclic difference adds as much
// to one bin as it takes from another) and stay finite; at α = 1e6 the result is the primal.
TEST_F(NumericsTest, PoissonAtItsAlphaBoundsOnASpike) {
  constexpr int kBins = 32;
  std::vector<float> primal(kBins, 0.0f);
  primal[7] = 4096.0f;  // one sample of 262144 among 63 zeros, averaged
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0.0f, 50.0f);
  for (int k : {1, 5, 16}) {
    std::vector<float> consistent(kBins), random(kBins);
    for (int b = 0; b < kBins; ++b) {
      consistent[b] = primal[(b + k) % kBins] - primal[b];
      random[b] = noise(rng);
    }
    for (double alpha : {job::kMinPoissonAlpha, 1.0, job::kMaxPoissonAlpha}) {
      SCOPED_TRACE(absl::StrCat("k ", k, " alpha ", alpha));
      auto solver = PoissonSolver::create(kBins, k, alpha);
      ASSERT_TRUE(solver.ok()) << solver.status();
      std::vector<float> out(kBins);
      for (bool l1 : {false, true}) {
        ASSERT_TRUE((l1 ? solver->solve_l1(primal, consistent, out)
                        : solver->solve_l2(primal, consistent, out))
                        .ok());
        for (int b = 0; b < kBins; ++b) EXPECT_NEAR(out[b], primal[b], 2e-3f) << "bin " << b;
      }
      ASSERT_TRUE(solver->solve_l2(primal, random, out).ok());
      double sum = 0;
      for (int b = 0; b < kBins; ++b) {
        ASSERT_TRUE(std::isfinite(out[b]));
        sum += out[b];
      }
      EXPECT_NEAR(sum, 4096.0, 0.05);
      if (alpha == job::kMaxPoissonAlpha) {
        for (int b = 0; b < kBins; ++b) EXPECT_NEAR(out[b], primal[b], 0.05f) << "bin " << b;
      }
    }
  }
  for (double bad : {0.0, -1.0, 1e7, std::nan("")}) {
    auto solver = PoissonSolver::create(kBins, 1, bad);
    ASSERT_FALSE(solver.ok()) << bad;
    EXPECT_NE(solver.status().message().find("lpha"), std::string_view::npos) << solver.status();
  }
}

// The prepass's tables where one pixel's samples are all zero but one (its moments a spike in
// one bin) among black neighbours: finite predictions and a valid table for every pixel.
TEST_F(NumericsTest, PrepassTablesFromOneNonZeroSampleAmongZeros) {
  constexpr int kBins = 16, kW = 8, kH = 8;
  image::SpectralImage moments = *image::SpectralImage::create(kW, kH, 2 * kBins);
  const double n = 64, value = 1e6;
  moments.value(3, 4, 5) = float(value * value / n);  // K_b = E[Y²]
  moments.value(3, 4, kBins + 5) = float(value / n);  // U_b = E[Y]
  GuideImage guides = *GuideImage::create(kW, kH);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) guides.set(x, y, {0.5f, 0, 1, 0, 0.5f});
  const std::vector<double> d(kBins, 1.0 / kBins);
  auto tables = build_tables(moments, guides, {}, d, {}, VarianceModel{4, 4, false});
  ASSERT_TRUE(tables.ok()) << tables.status();
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      EXPECT_TRUE(std::isfinite(tables->predicted_variance(x, y)));
      EXPECT_TRUE(std::isfinite(tables->predicted_default_variance(x, y)));
      const auto cdf = tables->cdf(x, y);
      EXPECT_TRUE(std::is_sorted(cdf.begin(), cdf.end())) << x << "," << y;
    }
  }
}

// Grazing dispersive refraction, offsets meeting total internal reflection, η barely above 1,
// a 1 nm line and a very bright emitter (stress.pbrt): every output of the gradient pipeline
// (every norm, τ 0 and 1) and of the prepass is finite, and the offsets did meet the corners.
TEST_F(NumericsTest, StressSceneGivesFiniteOutputsEverywhere) {
  auto loaded = scene::load_scene(
      std::filesystem::path(PRISM_SOURCE_DIR) / "tests/testdata/pipeline/stress.pbrt",
      scene::with_library_names(*library_));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const scene::SceneDescription& scene = loaded->description;
  for (float tau : {0.0f, 1.0f}) {
    for (auto norm : {job::PoissonNorm::kL2, job::PoissonNorm::kL1, job::PoissonNorm::kWeighted}) {
      auto result =
          render(scene, job::IntegratorKind::kGradient, 64, 7, 8, [&](LocalRenderOptions& o) {
            o.render.gradient_offset_bins = *job::gradient_offset_bins(0.15, o.render.bins);
            o.render.gradient_tau = tau;
            o.keep_primal_and_gradients = true;
            o.poisson_norm = norm;
          });
      ASSERT_TRUE(result.ok()) << result.status();
      expect_finite(*result, absl::StrCat("gradient tau ", tau));
      EXPECT_GT(result->stats.counters.gradient_shifts_failed, 0u);
    }
  }
  for (job::IntegratorKind integrator : kIntegrators) {
    auto result = render(scene, integrator, 64, 8, 8, [&](LocalRenderOptions& o) {
      if (integrator == job::IntegratorKind::kHero) {
        job::PrepassParameters p;
        p.spp = 32;
        o.prepass = p;
      }
    });
    ASSERT_TRUE(result.ok()) << result.status();
    expect_finite(*result, job::name(integrator));
  }
}

// Malformed numbers are refused with the place they were written.
TEST_F(NumericsTest, MalformedNumbersAreRefusedWithTheirPlace) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"WorldBegin\nMaterial \"dielectric\" \"float eta\" [nan]\n", "bad.pbrt:2:"},
      {"WorldBegin\nShape \"sphere\" \"float radius\" [inf]\n", "bad.pbrt:2:"},
      {"WorldBegin\nMaterial \"dielectric\" \"float eta\" [-1.5]\n", "bad.pbrt:2:"},
      {"WorldBegin\nAreaLightSource \"diffuse\" \"float scale\" [-2]\n"
       "Shape \"sphere\"\n",
       "bad.pbrt:2:"},
      {"WorldBegin\nLightSource \"point\" \"blackbody I\" [-5]\n", "bad.pbrt:2:"},
  };
  for (const auto& [text, where] : cases) {
    auto scene = load("bad.pbrt", text);
    if (scene.ok()) {
      // Some are caught when the render is built (the worker's own checks).
      auto result = render(*scene, job::IntegratorKind::kHero, 1, 1, 1);
      ASSERT_FALSE(result.ok()) << text;
      EXPECT_NE(result.status().message().find(where), std::string_view::npos)
          << text << ": " << result.status();
    } else {
      EXPECT_NE(scene.status().message().find(where), std::string_view::npos)
          << text << ": " << scene.status();
    }
  }
}

}  // namespace
}  // namespace prism::coordinator
