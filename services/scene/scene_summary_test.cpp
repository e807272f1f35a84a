#include "services/scene/scene_summary.h"

#include <gtest/gtest.h>

#include "services/scene/parser.h"
#include "services/scene/wavelength_dependence.h"

namespace prism::scene {
namespace {

constexpr char kScene[] =
    R"(Film "spectral" "integer xresolution" 64 "integer yresolution" 32 "integer nbuckets" 16
Sampler "independent" "integer pixelsamples" 8
WorldBegin
MakeNamedMedium "smoke" "string type" "homogeneous" "float sigma_a" 0.5
LightSource "point" "blackbody I" 3000
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" "stdillum-F11" "float scale" 3
  Shape "sphere"
AttributeEnd
MakeNamedMaterial "glass" "string type" "dielectric" "spectrum eta" "glass-BK7"
NamedMaterial "glass"
MediumInterface "smoke" ""
Shape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0]
)";

TEST(SceneSummary, ListsWhatTheRendererNeeds) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(kScene, "s.pbrt");
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_EQ(format_scene_summary(*s),
            "resolution: 64x32\n"
            "film: spectral \"pbrt.exr\"\n"
            "samples per pixel: 8\n"
            "spectral bins: 16\n"
            "integrator: volpath, max depth 5\n"
            "shapes: 2 (1 triangle meshes, 1 spheres)\n"
            "triangles: 1\n"
            "emitters: 2 (2 distinct spectra)\n"
            "  area light at s.pbrt:8:3: L named \"stdillum-F11\", scale 3\n"
            "  point light: I blackbody 3000 K, scale 1 (s.pbrt:5:1)\n"
            "dispersive materials: 1\n"
            "  \"glass\" (s.pbrt:10:1): dielectric eta named \"glass-BK7\"\n"
            "media: 1\n"
            "  \"smoke\" (s.pbrt:4:1): homogeneous sigma_a constant 0.5, sigma_s constant 1, scale "
            "1, g 0\n"
            "warnings: 0\n");
  WavelengthDependence d = analyze_wavelength_dependence(*s);
  EXPECT_TRUE(d.needs_spectral_transport());
  EXPECT_EQ(d.media, (std::vector<int>{0}));
}

TEST(SceneSummary, ConstantIorAndOneEmitterSpectrumNeedNoSpectralTransport) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "WorldBegin\nLightSource \"point\"\nLightSource \"spot\"\nMaterial \"dielectric\" \"float "
      "eta\" 1.5\n"
      "Shape \"sphere\"\n",
      "s.pbrt");
  ASSERT_TRUE(s.ok()) << s.status();
  WavelengthDependence d = analyze_wavelength_dependence(*s);
  EXPECT_TRUE(d.dispersive_materials.empty());
  EXPECT_EQ(d.emitter_spectra.size(), 1u);
  EXPECT_FALSE(d.needs_spectral_transport());
}

// A coat whose index varies with wavelength disperses (the job's spectral machinery and hero's
// lane handling follow it); a constant coat does not.
TEST(SceneSummary, ACoatOfVaryingIndexIsDispersive) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(R"(WorldBegin
LightSource "point"
Material "coateddiffuse" "spectrum eta" "glass-BK7"
Shape "sphere"
Material "coatedconductor" "spectrum interface.eta" [360 1.4 830 1.6]
Shape "sphere"
Material "coateddiffuse" "float eta" 1.7
Shape "sphere"
)",
                                                          "s.pbrt");
  ASSERT_TRUE(s.ok()) << s.status();
  WavelengthDependence d = analyze_wavelength_dependence(*s);
  EXPECT_EQ(d.dispersive_materials, (std::vector<int>{0, 1}));
  EXPECT_TRUE(d.needs_spectral_transport());
}

}  // namespace
}  // namespace prism::scene
