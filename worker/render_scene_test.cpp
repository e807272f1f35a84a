#include "worker/render_scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "absl/strings/match.h"
#include "services/scene/parser.h"
#include "services/scene/scene_loader.h"

namespace prism::worker {
namespace {

class RenderSceneTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    library_ = new spectral::SpectrumLibrary(*spectral::SpectrumLibrary::load_builtin());
    cmf_ = new spectral::ColorMatching(spectral::ColorMatching::cie1931());
    device_ = new EmbreeDevice("threads=1");
  }
  static void TearDownTestSuite() {
    delete device_;
    delete cmf_;
    delete library_;
  }

  static scene::LoadOptions load_options() {
    scene::LoadOptions o = scene::with_library_names(*library_);
    return o;
  }
  static scene::SceneDescription load(const std::string& relpath) {
    auto loaded =
        scene::load_scene(std::filesystem::path(PRISM_SOURCE_DIR) / relpath, load_options());
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    return loaded.ok() ? std::move(loaded->description) : scene::SceneDescription{};
  }
  static absl::StatusOr<scene::SceneDescription> parse(const std::string& text) {
    scene::SceneFiles files;
    files.read = [](const std::string& path, std::uint64_t) -> absl::StatusOr<std::string> {
      return absl::NotFoundError(path);
    };
    files.load_mesh = [](const std::string& path, scene::MeshFormat,
                         const scene::MeshLimits&) -> absl::StatusOr<scene::TriangleMeshData> {
      return absl::NotFoundError(path);
    };
    return scene::parse_scene(text, "inline.pbrt", load_options(), files);
  }
  static absl::StatusOr<std::unique_ptr<RenderScene>> build(const scene::SceneDescription& s,
                                                            job::RenderOptions options = {}) {
    return RenderScene::build(*device_, s, *library_, options, 32, 24);
  }

  // ∫ p(λ) dλ over Λ by a fine midpoint rule (the pdf is piecewise constant on 1 nm cells).
  static double integral(const spectral::WavelengthDistribution& p) {
    double sum = 0;
    for (int i = 0; i < 47000; ++i) sum += p.pdf(360.0f + (i + 0.5f) * 0.01f) * 0.01;
    return sum;
  }
  // Every 1 nm cell over which some emitter emits (a positive integral) has positive density.
  static void expect_positive_where_emitting(const spectral::WavelengthDistribution& pdf,
                                             std::vector<const spectral::Spectrum*> spectra) {
    int emitting = 0;
    for (int c = 0; c < 470; ++c) {
      bool emits = false;
      for (const spectral::Spectrum* s : spectra)
        emits |= spectral::integrate(*s, 360 + c, 361 + c) > 0;
      if (!emits) continue;
      ++emitting;
      EXPECT_GT(pdf.pdf(360.5f + c), 0.0f) << "cell at " << 360 + c << " nm";
    }
    EXPECT_GE(emitting, 400);  // F11 and A cover 380..780 nm at least
  }
  // pbrt-v4's normalisation: the light's final scale times the photometric sum of its
  // spectrum (the illuminant alone for RGB emission) is the scene's `scale`.
  static double photometric_scale(const Light& light) {
    const spectral::Spectrum& s = light_spectrum(light);
    double sum = std::holds_alternative<spectral::RgbIlluminantSpectrum>(s)
                     ? cmf_->photometric_sum(spectral::Spectrum(
                           *std::get<spectral::RgbIlluminantSpectrum>(s).illuminant))
                     : cmf_->photometric_sum(s);
    return light_scale(light) * sum;
  }

  static spectral::SpectrumLibrary* library_;
  static spectral::ColorMatching* cmf_;
  static EmbreeDevice* device_;
};
spectral::SpectrumLibrary* RenderSceneTest::library_ = nullptr;
spectral::ColorMatching* RenderSceneTest::cmf_ = nullptr;
EmbreeDevice* RenderSceneTest::device_ = nullptr;

// pbrt-v4's metals, named as its scenes name them, load through the same name checks every
// caller uses (scene::with_library_names) and build: metal-*-k is a spectrum and no IOR, so a
// loader that checked a conductor's k as an IOR refused every such scene. Names of the wrong
// kind are refused where they stand.
TEST_F(RenderSceneTest, ConductorsTakeTheLibrarysMetalSpectra) {
  auto gold = parse(R"(Camera "perspective"
WorldBegin
LightSource "point" "spectrum I" "stdillum-D65"
Material "conductor" "spectrum eta" "metal-Au-eta" "spectrum k" "metal-Au-k"
Shape "sphere" "float radius" 1
)");
  ASSERT_TRUE(gold.ok()) << gold.status();
  auto rs = build(*gold);
  ASSERT_TRUE(rs.ok()) << rs.status();
  ASSERT_EQ((*rs)->materials().size(), 1u);
  const auto& au = std::get<ConductorMaterial>((*rs)->materials()[0]);
  for (float lambda : {450.0f, 550.0f, 650.0f}) {
    EXPECT_EQ(spectral::eval(au.k, lambda),
              spectral::eval(*library_->find_spectrum("metal-Au-k"), lambda));
    EXPECT_EQ(spectral::eval(au.eta, lambda),
              spectral::eval(*library_->find_spectrum("metal-Au-eta"), lambda));
  }
  // A metal the library does not have is refused where it stands.
  auto platinum = parse(R"(WorldBegin
Material "conductor" "spectrum k" "metal-Pt-k"
Shape "sphere"
)");
  ASSERT_FALSE(platinum.ok());
  EXPECT_EQ(std::string(platinum.status().message()),
            "inline.pbrt:2:35: unknown named spectrum \"metal-Pt-k\"");
  // metal-Au-k is a spectrum, not an index of refraction for a dielectric.
  auto k_as_eta = parse(R"(WorldBegin
Material "dielectric" "spectrum eta" "metal-Au-k"
Shape "sphere"
)");
  ASSERT_FALSE(k_as_eta.ok());
  EXPECT_NE(k_as_eta.status().message().find("inline.pbrt:2:"), std::string_view::npos)
      << k_as_eta.status();
  EXPECT_NE(k_as_eta.status().message().find("metal-Au-k"), std::string_view::npos)
      << k_as_eta.status();
}

TEST_F(RenderSceneTest, PrismScene) {
  scene::SceneDescription desc = load("scenes/prism.pbrt");
  auto rs = build(desc);
  ASSERT_TRUE(rs.ok()) << rs.status();
  const RenderScene& s = **rs;
  EXPECT_EQ(s.camera().width(), 32);
  EXPECT_EQ(s.camera().height(), 24);
  ASSERT_EQ(s.materials().size(), desc.materials.size());
  ASSERT_EQ(s.lights().size(), 2u);  // the lamp and the dim sky
  EXPECT_TRUE(std::holds_alternative<AreaLight>(s.lights()[0]));
  ASSERT_EQ(s.infinite_light(), 1);
  EXPECT_TRUE(std::holds_alternative<InfiniteLight>(s.lights()[1]));
  int emitters = 0, dispersive = 0;
  for (size_t i = 0; i < desc.shapes.size(); ++i) {
    const ShapeInfo& info = s.shape(int(i));
    EXPECT_EQ(info.material, desc.shapes[i].material);
    EXPECT_EQ(info.area_light >= 0, desc.shapes[i].area_light.has_value()) << i;
    if (info.area_light >= 0) {
      ++emitters;
      EXPECT_EQ(std::get<AreaLight>(s.lights()[info.area_light]).shape(), int(i));
    }
    dispersive += is_dispersive(s.materials()[info.material]) ? 1 : 0;
    EXPECT_FALSE(info.medium_transition);
  }
  EXPECT_EQ(emitters, 1);
  EXPECT_EQ(dispersive, 1);  // the SF11 prism
  EXPECT_EQ(s.camera_medium(), -1);
  EXPECT_TRUE(s.media().empty());
  EXPECT_NEAR(photometric_scale(s.lights()[0]), 20, 20 * 1e-6);
  EXPECT_NEAR(photometric_scale(s.lights()[1]), 0.05, 0.05 * 1e-6);
  EXPECT_EQ(s.grid().bins(), 64);

  // The wavelength pdf integrates to 1 and is positive wherever F11 emits.
  const auto& pdf = s.wavelength_pdf();
  EXPECT_NEAR(integral(pdf), 1.0, 1e-5);
  const spectral::Spectrum& f11 = *library_->find_spectrum("stdillum-F11");
  expect_positive_where_emitting(pdf, {&f11});
  // F11's narrow lines are where the emitter term puts its mass: the 611 nm line is far more
  // likely than its neighbourhood.
  EXPECT_GT(pdf.pdf(611.5f), 5 * pdf.pdf(650.0f));
}

TEST_F(RenderSceneTest, CornellTwoLights) {
  scene::SceneDescription desc = load("scenes/cornell-two-lights.pbrt");
  job::RenderOptions options;
  options.bins = 32;
  options.spectral_pdf = job::SpectralPdfKind::kVisible;
  auto rs = build(desc, options);
  ASSERT_TRUE(rs.ok()) << rs.status();
  const RenderScene& s = **rs;
  ASSERT_EQ(s.lights().size(), 2u);
  EXPECT_EQ(s.infinite_light(), -1);
  ASSERT_EQ(s.materials().size(), desc.materials.size());
  std::vector<int> light_shapes;
  for (size_t i = 0; i < desc.shapes.size(); ++i) {
    if (s.shape(int(i)).area_light >= 0) {
      EXPECT_EQ(s.shape(int(i)).area_light, int(light_shapes.size()));
      light_shapes.push_back(int(i));
    }
    // Measured tables vary with wavelength.
    if (i < 7) {
      EXPECT_TRUE(depends_on_wavelength(s.materials()[s.shape(int(i)).material])) << i;
    }
  }
  ASSERT_EQ(light_shapes.size(), 2u);
  EXPECT_TRUE(std::holds_alternative<scene::SphereShape>(desc.shapes[light_shapes[1]].geometry));
  EXPECT_NEAR(photometric_scale(s.lights()[0]), 15, 15 * 1e-6);
  EXPECT_NEAR(photometric_scale(s.lights()[1]), 10, 10 * 1e-6);
  EXPECT_EQ(s.grid().bins(), 32);

  const auto& pdf = s.wavelength_pdf();
  EXPECT_NEAR(integral(pdf), 1.0, 1e-5);
  expect_positive_where_emitting(
      pdf, {library_->find_spectrum("stdillum-F11"), library_->find_spectrum("stdillum-A")});
}

// The wavelength pdf follows the options: p_s · p_e, then ε of uniform-over-the-emission mixed
// in (docs/estimators.md §1).
TEST_F(RenderSceneTest, WavelengthPdfFollowsTheOptions) {
  auto desc = parse(R"(WorldBegin
LightSource "point" "spectrum I" "stdillum-F11" "point3 from" [0 1 0]
Shape "sphere")");
  ASSERT_TRUE(desc.ok()) << desc.status();
  const spectral::Spectrum& f11 = *library_->find_spectrum("stdillum-F11");
  auto emitters =
      *spectral::WavelengthDistribution::emitters(std::span<const spectral::Spectrum>(&f11, 1));
  auto flat = *spectral::WavelengthDistribution::flat();
  auto visible = *spectral::WavelengthDistribution::visible();
  for (auto sensor : {job::SpectralPdfKind::kFlat, job::SpectralPdfKind::kVisible}) {
    for (auto emitter : {job::EmitterPdfKind::kUniform, job::EmitterPdfKind::kEmitters}) {
      job::RenderOptions o;
      o.spectral_pdf = sensor;
      o.emitter_pdf = emitter;
      o.defensive_epsilon = 0.1;
      auto rs = build(*desc, o);
      ASSERT_TRUE(rs.ok()) << rs.status();
      const auto& ps = sensor == job::SpectralPdfKind::kFlat ? flat : visible;
      auto expected = emitter == job::EmitterPdfKind::kEmitters
                          ? *spectral::WavelengthDistribution::product(ps, emitters)
                          : ps;
      expected = *expected.mix_defensive(0.1, emitters);
      const auto& got = (*rs)->wavelength_pdf();
      ASSERT_EQ(got.cells(), expected.cells());
      for (int c = 0; c < got.cells(); ++c) {
        ASSERT_NEAR(got.cell_mass(c), expected.cell_mass(c), 1e-12) << c;
      }
    }
  }
}

// The coordinator's prepass inputs: the job's default distribution, bit for bit the one the
// workers' RenderScene samples, and the sensor term over the bins, null for `flat`; a scene
// without emitters has nothing to learn from.
TEST_F(RenderSceneTest, PrepassDistributionsAreTheJobDefaultAndSensorTerm) {
  auto desc = parse(R"(WorldBegin
LightSource "point" "spectrum I" "stdillum-F11" "point3 from" [0 1 0]
LightSource "point" "spectrum I" "stdillum-F11" "point3 from" [0 2 0]
AttributeBegin
  AreaLightSource "diffuse" "blackbody L" 3000
  Shape "sphere"
AttributeEnd)");
  ASSERT_TRUE(desc.ok()) << desc.status();
  for (int bins : {16, 64}) {
    for (auto sensor : {job::SpectralPdfKind::kFlat, job::SpectralPdfKind::kVisible}) {
      job::RenderOptions o;
      o.bins = bins;
      o.spectral_pdf = sensor;
      auto got = job::prepass_distributions(*desc, o, *library_, bins);
      ASSERT_TRUE(got.ok()) << got.status();
      // The job's default distribution, exactly as the scene the workers build has it.
      auto scene = RenderScene::build(*device_, *desc, *library_, o, 8, 8);
      ASSERT_TRUE(scene.ok()) << scene.status();
      const spectral::WavelengthDistribution& want = (*scene)->wavelength_pdf();
      ASSERT_EQ(got->job_default.cells(), want.cells());
      for (int c = 0; c < want.cells(); ++c) {
        ASSERT_EQ(got->job_default.cell_mass(c), want.cell_mass(c)) << c;
      }
      EXPECT_EQ(got->sensor.has_value(), sensor == job::SpectralPdfKind::kVisible);
      if (got->sensor) {
        const auto visible = *spectral::WavelengthDistribution::visible(bins);
        ASSERT_EQ(got->sensor->cells(), bins);
        for (int c = 0; c < bins; ++c) {
          EXPECT_EQ(got->sensor->cell_mass(c), visible.cell_mass(c)) << c;
        }
      }
    }
  }
  auto dark = parse(R"(WorldBegin
Shape "sphere")");
  ASSERT_TRUE(dark.ok()) << dark.status();
  EXPECT_EQ(job::prepass_distributions(*dark, {}, *library_, 16).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(job::prepass_distributions(*desc, {}, *library_, 0).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// `power` and `illuminance` follow pbrt-v4: with the spectrum normalised to unit photometric
// sum, scale · k_e equals the scene's scale times the target, where k_e is the light's
// geometric factor (4π for a point, the cone integral for a spot, π·area·sides for an area
// light, π for a uniform sky's illuminance).
TEST_F(RenderSceneTest, PowerAndIlluminanceTargets) {
  auto desc = parse(R"(WorldBegin
LightSource "point" "blackbody I" 2700 "float scale" 2 "point3 from" [ 1 2 3 ] "float power" 30
LightSource "spot" "spectrum I" "stdillum-F11" "point3 from" [ 0 5 0 ] "point3 to" [ 0 0 0 ]
  "float coneangle" 20 "float conedeltaangle" 4 "float power" 100
LightSource "infinite" "rgb L" [ 0.1 0.2 0.3 ] "float scale" 0.5 "float illuminance" 7
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" "stdillum-A" "float scale" 4 "bool twosided" true
    "float power" 50
  Translate 0 0 3
  Scale 2 2 2
  Shape "sphere" "float radius" 0.1
AttributeEnd
LightSource "point" "float scale" 3
)");
  ASSERT_TRUE(desc.ok()) << desc.status();
  auto rs = build(*desc);
  ASSERT_TRUE(rs.ok()) << rs.status();
  const auto& lights = (*rs)->lights();
  ASSERT_EQ(lights.size(), 5u);
  const double pi = 3.14159265358979323846;
  const auto& area = std::get<AreaLight>(lights[0]);
  EXPECT_NEAR(area.area(), 4 * pi * 0.2 * 0.2, 1e-6);
  EXPECT_NEAR(photometric_scale(lights[0]) * pi * area.area() * 2, 4 * 50, 200 * 1e-5);
  EXPECT_NEAR(photometric_scale(lights[1]) * 4 * pi, 2 * 30, 60 * 1e-5);
  double cos_end = std::cos(20 * pi / 180), cos_start = std::cos(16 * pi / 180);
  double k_spot = 2 * pi * ((1 - cos_start) + (cos_start - cos_end) / 2);
  EXPECT_NEAR(photometric_scale(lights[2]) * k_spot, 100, 100 * 1e-5);
  EXPECT_NEAR(photometric_scale(lights[3]) * pi, 0.5 * 7, 3.5 * 1e-5);
  EXPECT_EQ((*rs)->infinite_light(), 3);
  // No `L`: pbrt-v4's default illuminant (D65), normalised like any other.
  EXPECT_NEAR(photometric_scale(lights[4]), 3, 3 * 1e-6);
  // For the RGB sky only D65's photometric sum divides the scale; the colour stays in.
  EXPECT_TRUE(std::holds_alternative<spectral::RgbIlluminantSpectrum>(light_spectrum(lights[3])));
}

TEST_F(RenderSceneTest, MediaAndShapeInterfaces) {
  auto desc =
      parse(R"(MakeNamedMedium "fog" "string type" "homogeneous" "rgb sigma_a" [ 0.01 0.02 0.03 ]
  "spectrum sigma_s" [ 400 0.1 700 0.2 ] "float scale" 2 "float g" 0.3
MediumInterface "" "fog"
LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective"
WorldBegin
LightSource "point" "point3 from" [ 0 3 0 ]
AttributeBegin
  MediumInterface "fog" "fog"
  Shape "sphere" "float radius" 0.5
AttributeEnd
AttributeBegin
  Material "interface"
  MediumInterface "fog" ""
  Shape "sphere" "float radius" 2
AttributeEnd
)");
  ASSERT_TRUE(desc.ok()) << desc.status();
  auto rs = build(*desc);
  ASSERT_TRUE(rs.ok()) << rs.status();
  const RenderScene& s = **rs;
  ASSERT_EQ(s.media().size(), 1u);
  EXPECT_TRUE(s.media()[0].chromatic());
  EXPECT_TRUE(s.media()[0].scattering());
  EXPECT_EQ(s.camera_medium(), 0);
  EXPECT_EQ(s.shape(0).medium_inside, 0);
  EXPECT_EQ(s.shape(0).medium_outside, 0);
  EXPECT_FALSE(s.shape(0).medium_transition);
  EXPECT_EQ(s.shape(1).medium_inside, 0);
  EXPECT_EQ(s.shape(1).medium_outside, -1);
  EXPECT_TRUE(s.shape(1).medium_transition);
  EXPECT_TRUE(std::holds_alternative<InterfaceMaterial>(s.materials()[s.shape(1).material]));
}

TEST_F(RenderSceneTest, SceneWithoutLightsIsBlackNotAnError) {
  auto desc = parse("WorldBegin\nShape \"sphere\"\n");
  ASSERT_TRUE(desc.ok()) << desc.status();
  auto rs = build(*desc);
  ASSERT_TRUE(rs.ok()) << rs.status();
  EXPECT_TRUE((*rs)->lights().empty());
  EXPECT_EQ((*rs)->infinite_light(), -1);
  EXPECT_EQ((*rs)->shape(0).area_light, -1);
  const auto& pdf = (*rs)->wavelength_pdf();
  EXPECT_FLOAT_EQ(pdf.pdf(400), 1.0f / 470);
  EXPECT_FLOAT_EQ(pdf.pdf(800), 1.0f / 470);
}

// What the parser accepts but the tracer cannot render is refused with the scene position.
TEST_F(RenderSceneTest, TracerRefusalsCarryTheirLocation) {
  struct Case {
    std::string text, location, words;
  };
  std::vector<Case> cases = {
      {"WorldBegin\nAttributeBegin\n  AreaLightSource \"diffuse\"\n  Scale 1 2 1\n"
       "  Shape \"sphere\"\nAttributeEnd\n",
       "inline.pbrt:5:3:", "similarity"},
      {"WorldBegin\nLightSource \"infinite\"\nLightSource \"infinite\" \"float scale\" 2\n",
       "inline.pbrt:3:1:", "infinite light"},
      {"WorldBegin\nMaterial \"diffuse\" \"spectrum reflectance\" [ 400 0.5 700 1.5 ]\n"
       "Shape \"sphere\"\n",
       "inline.pbrt:2:1:", "reflectance"},
      {"WorldBegin\nMaterial \"conductor\" \"float reflectance\" 1.2\nShape \"sphere\"\n",
       "inline.pbrt:2:1:", "reflectance"},
      {"WorldBegin\nLightSource \"point\" \"spectrum I\" [ 300 1 350 1 ]\n",
       "inline.pbrt:2:1:", "no visible power"},
      // An emitter too bright for floats was said to emit nothing; a spot light's default
      // conedeltaangle over a narrow coneangle was named 'conedelta', which no scene can set.
      {"WorldBegin\nAttributeBegin\nAreaLightSource \"diffuse\" \"rgb L\" [1e38 1e38 1e38]\n"
       "Shape \"sphere\"\nAttributeEnd\n",
       "inline.pbrt:3:1:", "too large to render"},
      {"WorldBegin\nAttributeBegin\nAreaLightSource \"diffuse\" \"float power\" 10\n"
       "Shape \"sphere\" \"float radius\" 1e-20\nAttributeEnd\nShape \"sphere\"\n",
       "inline.pbrt:4:1:", "is too small to sample"},
      {"WorldBegin\nLightSource \"spot\" \"float coneangle\" 0.001\n", "inline.pbrt:2:1:",
       "'float conedeltaangle' (5; 5 is the default where the scene gives none) <= 'float "
       "coneangle' (0.001)"},
  };
  for (const Case& c : cases) {
    auto desc = parse(c.text);
    if (!desc.ok()) {
      ADD_FAILURE() << "the parser already refuses: " << desc.status() << "\n" << c.text;
      continue;
    }
    auto rs = build(*desc);
    ASSERT_FALSE(rs.ok()) << c.text;
    EXPECT_EQ(rs.status().code(), absl::StatusCode::kInvalidArgument) << rs.status();
    EXPECT_TRUE(absl::StartsWith(rs.status().message(), c.location)) << rs.status();
    EXPECT_TRUE(absl::StrContains(rs.status().message(), c.words)) << rs.status();
  }
}

}  // namespace
}  // namespace prism::worker
