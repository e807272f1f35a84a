// Scenes with answers known in closed form, rendered through the embedded pipeline (scene
// loader, worker, tile merge, reconstruction) by `uniform`, `hero` and `gradient`: each bin's
// mean over the image's pixels must agree with the answer within 4 standard errors of that
// mean (the pixels are independent estimates). Each scene isolates one feature:
//   - a chromatic absorbing medium behind dispersive glass (Beer–Lambert; where pbrt-v4's
//     volpath is biased, docs/conformance.md),
//   - a distant light with a target illuminance on a diffuse floor,
//   - an environment image with a target illuminance on a diffuse floor (where pbrt-v4's
//     normalisation is off by 2, docs/conformance.md),
//   - a diffuse-transmission sheet in a constant sky,
//   - a thin dielectric sheet in front of an emitter.
// Emitters that the answer does not count as reflectors are black (pbrt's default grey would
// return light the formulas leave out).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>

#include "coordinator/local_render.h"
#include "services/base/status.h"
#include "services/image/png.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/color.h"
#include "services/spectral/named_spectra.h"
#include "tests/render_fixture.h"
#include "tests/testing/test_dir.h"

namespace prism::coordinator {
namespace {

class KnownAnswerTest : public RenderFixture {};

// An 8x8 view straight down +z through a narrow field (box filter), `between` the camera and a
// flat two-sided emitter of unit flat radiance at z = 3 that fills the view.
std::string on_axis_scene(int bins, const std::string& between) {
  return R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 1
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" )" +
         std::to_string(bins) + R"(
PixelFilter "box"
WorldBegin
)" + between +
         R"(AttributeBegin
  Material "diffuse" "rgb reflectance" [0 0 0]
  AreaLightSource "diffuse" "spectrum L" [360 1 830 1] "bool twosided" true
  Shape "trianglemesh" "point3 P" [-4 -4 3  4 -4 3  4 4 3  -4 4 3] "integer indices" [0 1 2 0 2 3]
AttributeEnd
)";
}

// Along the axis of a BK7 slab one unit thick, filled with a dye (piecewise-linear sigma_a,
// scale 1.5), at a flat emitter behind it: at (near) normal incidence every wavelength crosses
// the same length, so L(λ) = Le·(1 − R)²·τ / (1 − R²·τ²), R = ((η − 1)/(η + 1))², τ =
// exp(−1.5·σ_a(λ)), the internal reflections retracing the axis.
TEST_F(KnownAnswerTest, ADyeBehindDispersiveGlassFollowsBeerLambert) {
  auto scene = load("dye_slab.pbrt", on_axis_scene(16, R"(
MakeNamedMedium "dye" "string type" "homogeneous"
  "spectrum sigma_a" [360 5 480 5 540 3 590 0.5 640 0.15 830 0.15]
  "spectrum sigma_s" [360 0 830 0] "float scale" 1.5
AttributeBegin
  MediumInterface "dye" ""
  Material "dielectric" "spectrum eta" "glass-BK7"
  Shape "trianglemesh" "point3 P" [-2 -2 -0.5  2 -2 -0.5  2 2 -0.5  -2 2 -0.5]
    "integer indices" [0 2 1 0 3 2]
  Shape "trianglemesh" "point3 P" [-2 -2 0.5  2 -2 0.5  2 2 0.5  -2 2 0.5]
    "integer indices" [0 1 2 0 2 3]
AttributeEnd
)"));
  ASSERT_TRUE(scene.ok()) << scene.status();
  const spectral::Ior* bk7 = library_->find_ior("glass-BK7");
  ASSERT_NE(bk7, nullptr);
  const double le = unit_flat_emission();
  auto sigma_a = [](double l) {
    const double x[] = {360, 480, 540, 590, 640, 830}, y[] = {5, 5, 3, 0.5, 0.15, 0.15};
    for (int i = 0; i < 5; ++i) {
      if (l <= x[i + 1]) return y[i] + (y[i + 1] - y[i]) * (l - x[i]) / (x[i + 1] - x[i]);
    }
    return 0.15;
  };
  auto radiance = [&](double l) {
    const double n = spectral::eta(*bk7, l);
    const double r = (n - 1) * (n - 1) / ((n + 1) * (n + 1));
    const double tau = std::exp(-1.5 * sigma_a(l));
    return le * (1 - r) * (1 - r) * tau / (1 - r * r * tau * tau);
  };
  expect_every_integrator(*scene, 512, 24, [&](double lo, double hi) {
    constexpr int kSteps = 2000;
    double sum = 0;
    for (int i = 0; i < kSteps; ++i) sum += radiance(lo + (i + 0.5) * (hi - lo) / kSteps);
    return sum / kSteps;
  });
}

// A distant light with `illuminance` 3 on a grey floor at 30° from the light: every pixel's
// radiance is ρ/π·E·cos 30° over the flat spectrum, E the illuminance on a surface facing the
// light (pbrt-v4: the spectrum normalised to one nit, times `illuminance`).
TEST_F(KnownAnswerTest, ADistantLightLightsAFloorAsItsIlluminanceSays) {
  auto scene = load("distant.pbrt", R"(LookAt 0 5 0  0 0 0  0 0 1
Camera "perspective" "float fov" 20
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
WorldBegin
LightSource "distant" "spectrum L" [360 1 830 1] "point3 from" [1 1.7320508 0]
  "point3 to" [0 0 0] "float illuminance" 3
Material "diffuse" "spectrum reflectance" [360 0.5 830 0.5]
Shape "trianglemesh" "point3 P" [-10 0 -10  10 0 -10  10 0 10  -10 0 10]
  "integer indices" [0 1 2 0 2 3]
)");
  ASSERT_TRUE(scene.ok()) << scene.status();
  const double expected = 0.5 / M_PI * 3.0 * unit_flat_emission() * std::cos(M_PI / 6);
  expect_every_integrator(*scene, 256, 3, [&](double, double) { return expected; });

  auto pointless = load("distant.pbrt",
                        "WorldBegin\nLightSource \"distant\" \"point3 from\" "
                        "[1 1 1] \"point3 to\" [1 1 1]\n");
  ASSERT_FALSE(pointless.ok());
  EXPECT_NE(pointless.status().message().find(
                "distant.pbrt:2:13: distant light needs 'from' and 'to' to differ"),
            std::string_view::npos)
      << pointless.status();
}

// An environment image with `illuminance` 2 over a grey floor: a white image is D65 at every
// texel, so the floor's radiance is ρ·E/π · D65(λ)/Y(D65), the same as under a uniform D65 sky
// with that illuminance. pbrt-v4 weighs the texels by 2π/N instead of 4π/N and would light
// this floor twice as brightly as its own uniform sky (docs/conformance.md).
TEST_F(KnownAnswerTest, AnEnvironmentImageLightsAFloorAsItsIlluminanceSays) {
  const std::filesystem::path dir = prism::testing::test_dir();
  auto white = image::RgbImage::create(16, 16);
  ASSERT_TRUE(white.ok());
  for (float& v : white->data()) v = 1.0f;
  ASSERT_TRUE(image::write_png_preview(dir / "white-equalarea.png", *white).ok());
  const std::string floor = R"(Material "diffuse" "spectrum reflectance" [360 0.5 830 0.5]
Shape "trianglemesh" "point3 P" [-10 0 -10  10 0 -10  10 0 10  -10 0 10]
  "integer indices" [0 1 2 0 2 3]
)";
  const std::string camera = R"(LookAt 0 5 0  0 0 0  0 0 1
Camera "perspective" "float fov" 20
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
WorldBegin
Rotate -90 1 0 0
)";
  const spectral::Spectrum& d65 = *library_->find_spectrum("stdillum-D65");
  const double y_d65 = spectral::ColorMatching::cie1931().photometric_sum(spectral::Spectrum(d65));
  auto expected = [&](double lo, double hi) {
    return 0.5 * 2.0 / M_PI * spectral::integrate(d65, lo, hi) / (hi - lo) / y_d65;
  };
  for (const char* light : {"LightSource \"infinite\" \"string filename\" "
                            "\"white-equalarea.png\" \"float illuminance\" 2\n",
                            "LightSource \"infinite\" \"spectrum L\" \"stdillum-D65\" "
                            "\"float illuminance\" 2\n"}) {
    SCOPED_TRACE(light);
    auto scene = load("sky.pbrt", camera + light + "Identity\n" + floor);
    ASSERT_TRUE(scene.ok()) << scene.status();
    expect_every_integrator(*scene, 256, 2, expected);
  }
}

// A thin dielectric sheet (η 1.5) at normal incidence in front of a flat emitter passes
// T' = (1 − R)/(1 + R) of its light at every wavelength, R = 0.04.
TEST_F(KnownAnswerTest, AThinDielectricSheetPassesTheSlabTransmittance) {
  auto scene = load("thin.pbrt", on_axis_scene(8, R"(
AttributeBegin
  Material "thindielectric" "float eta" 1.5
  Shape "trianglemesh" "point3 P" [-2 -2 0  2 -2 0  2 2 0  -2 2 0] "integer indices" [0 1 2 0 2 3]
AttributeEnd
)"));
  ASSERT_TRUE(scene.ok()) << scene.status();
  const double expected = unit_flat_emission() * (1 - 0.04) / (1 + 0.04);
  expect_every_integrator(*scene, 256, 8, [&](double, double) { return expected; });
}

// Diverged gradient offsets (after a dispersive ball) crossing a thin dielectric sheet: nothing
// non-finite.
TEST_F(KnownAnswerTest, GradientOffsetsCrossAThinSheetFinitely) {
  auto scene = load("thin_mixed.pbrt", R"(LookAt 0 1 -4  0 0 0  0 1 0
Camera "perspective" "float fov" 40
Film "spectral" "integer xresolution" 16 "integer yresolution" 16 "integer nbuckets" 16
WorldBegin
LightSource "infinite" "spectrum L" [360 1 830 1]
AttributeBegin
  Material "dielectric" "spectrum eta" "glass-SF11"
  Translate 0 0 -1
  Shape "sphere" "float radius" 0.7
AttributeEnd
Material "thindielectric" "spectrum eta" "glass-BK7"
Shape "trianglemesh" "point3 P" [-2 -2 0  2 -2 0  2 2 0  -2 2 0] "integer indices" [0 1 2 0 2 3]
Material "diffuse" "rgb reflectance" [0.5 0.5 0.5]
Shape "trianglemesh" "point3 P" [-5 -1 -5  5 -1 -5  5 -1 5  -5 -1 5] "integer indices" [0 1 2 0 2 3]
)");
  ASSERT_TRUE(scene.ok()) << scene.status();
  auto result = render(*scene, job::IntegratorKind::kGradient, 64, 1, 8);
  ASSERT_TRUE(result.ok()) << result.status();
  for (float v : result->image.data()) ASSERT_TRUE(std::isfinite(v));
  EXPECT_EQ(result->stats.counters.non_finite, 0u);
  EXPECT_GT(result->stats.counters.gradient_divergences, 0u);
}

// A diffuse-transmission sheet (R 0.3, T 0.5) in a constant sky, lit from both sides, shows
// (R + T) times the sky's radiance (no interreflection to count): the sheet's pixels against the
// sky's.
TEST_F(KnownAnswerTest, ADiffuseTransmissionSheetShowsReflectancePlusTransmittance) {
  auto scene = load("sheet.pbrt", sky_scene(R"(
Material "diffusetransmission" "spectrum reflectance" [360 0.3 830 0.3]
  "spectrum transmittance" [360 0.5 830 0.5]
Shape "trianglemesh" "point3 P" [-1 -1 0  1 -1 0  1 1 0  -1 1 0] "integer indices" [0 1 2 0 2 3]
)"));
  ASSERT_TRUE(scene.ok()) << scene.status();
  expect_sheet_over_sky(*scene, 0.8, 2);
}

// pbrt-v4's alpha cut-outs on a black sheet in a constant sky: the sheet shows (1 − α) of the
// sky, for a constant α = 0.3 and for a checkerboard of α 0.2 / 0.6 (four equal cells about the
// image centre: 0.6). A black sphere of α 0.5 seen through its middle is crossed twice, each
// crossing deciding on its own: 0.25 of the sky; a disk of α 0.4, 0.6.
TEST_F(KnownAnswerTest, AlphaCutOutsLetTheSkyThroughInProportion) {
  for (auto [shape, expected] :
       {std::pair{std::string(R"(Shape "trianglemesh" "point3 P" [-1 -1 0  1 -1 0  1 1 0  -1 1 0]
  "integer indices" [0 1 2 0 2 3] "float alpha" 0.3)"),
                  0.7},
        std::pair{std::string(R"(Texture "holes" "float" "checkerboard" "float uscale" 2
  "float vscale" 2 "float tex1" 0.2 "float tex2" 0.6
Shape "trianglemesh" "point3 P" [-1 -1 0  1 -1 0  1 1 0  -1 1 0]
  "integer indices" [0 1 2 0 2 3] "point2 uv" [0 0 1 0 1 1 0 1] "texture alpha" "holes")"),
                  0.6},
        std::pair{std::string(R"(Shape "sphere" "float radius" 0.9 "float alpha" 0.5)"), 0.25},
        std::pair{std::string(R"(Shape "disk" "float radius" 1 "float alpha" 0.4)"), 0.6}}) {
    SCOPED_TRACE(shape);
    auto scene = load("alpha.pbrt", sky_scene(R"(
Material "diffuse" "spectrum reflectance" [360 0 830 0]
)" + shape + "\n"));
    ASSERT_TRUE(scene.ok()) << scene.status();
    expect_sheet_over_sky(*scene, expected, 5);
  }
}

// A `mix` of a black and a white diffuse material (amount 0.3: the white one at 30 % of the
// vertices, chosen by a hash of the hit) on a sheet in a constant sky shows 0.3 times the sky,
// like the sheet the diffuse-transmission test uses; nested inside another mix with a second
// white, amount 0.5, 0.65; with a float checkerboard of amounts 0.1 and 0.5 over four equal
// cells symmetric about the image centre, their mean, 0.3.
TEST_F(KnownAnswerTest, AMixPicksItsComponentsInProportion) {
  for (auto [outer, expected] :
       {std::pair{std::string("speckled"), 0.3}, std::pair{std::string("nested"), 0.65},
        std::pair{std::string("textured"), 0.3}}) {
    SCOPED_TRACE(outer);
    auto scene = load("mix.pbrt", sky_scene(R"(
MakeNamedMaterial "black" "string type" "diffuse" "spectrum reflectance" [360 0 830 0]
MakeNamedMaterial "white" "string type" "diffuse" "spectrum reflectance" [360 1 830 1]
MakeNamedMaterial "speckled" "string type" "mix" "string materials" ["black" "white"]
  "float amount" 0.3
MakeNamedMaterial "nested" "string type" "mix" "string materials" ["speckled" "white"]
  "float amount" 0.5
Texture "amounts" "float" "checkerboard" "float uscale" 2 "float vscale" 2
  "float tex1" 0.1 "float tex2" 0.5
MakeNamedMaterial "textured" "string type" "mix" "string materials" ["black" "white"]
  "texture amount" "amounts"
NamedMaterial ")" + outer + R"("
Shape "trianglemesh" "point3 P" [-1 -1 0  1 -1 0  1 1 0  -1 1 0] "integer indices" [0 1 2 0 2 3]
  "point2 uv" [0 0 1 0 1 1 0 1]
)"));
    ASSERT_TRUE(scene.ok()) << scene.status();
    expect_sheet_over_sky(*scene, expected, 3);
  }
  // A mix names materials defined before it, and takes a float amount.
  auto undefined =
      load("mix_bad.pbrt", "WorldBegin\nMaterial \"mix\" \"string materials\" [\"a\" \"b\"]\n");
  ASSERT_FALSE(undefined.ok());
  EXPECT_NE(undefined.status().message().find("mix_bad.pbrt:2:16: mix: named material \"a\" is not "
                                              "defined"),
            std::string_view::npos)
      << undefined.status();
}

}  // namespace
}  // namespace prism::coordinator
