#include "worker/material.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "absl/strings/match.h"
#include "worker/fresnel.h"

namespace prism::worker {
namespace {

class MaterialTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    library_ = new spectral::SpectrumLibrary(*spectral::SpectrumLibrary::load_builtin());
    cmf_ = new spectral::ColorMatching(spectral::ColorMatching::cie1931());
    uplift_ = new spectral::RgbUplift(*cmf_);
  }
  static void TearDownTestSuite() {
    delete uplift_;
    delete cmf_;
    delete library_;
  }

  static scene::Material material(scene::MaterialKind kind, std::string name = "m") {
    return scene::Material{std::move(name), std::move(kind), {"scene.pbrt", 7, 3}};
  }
  static absl::StatusOr<Material> resolve(scene::MaterialKind kind) {
    return resolve_material(material(std::move(kind)), *library_, *uplift_, {});
  }
  static spectral::SampledWavelengths lanes(std::initializer_list<float> nm) {
    spectral::SampledWavelengths w(int(nm.size()));
    int i = 0;
    for (float l : nm) w.set(i++, l, 1.0f / 470);
    return w;
  }

  // A texture of two cells: `a` where u < 0.5, `b` where u >= 0.5 (a checkerboard of 2 x 1).
  static TexturePtr two_cells(texture_nodes::Input a, texture_nodes::Input b, bool spectrum) {
    scene::UvMapping mapping;
    mapping.su = 2;
    mapping.sv = 0;  // t = 0 everywhere: the cell is floor(2u)
    return std::make_shared<const Texture>(
        texture_nodes::Checkerboard{mapping, std::move(a), std::move(b)}, spectrum);
  }
  // A layered material's f at u (v = 0.5) for one fixed pair of directions, at 450 and 600 nm.
  static SampledSpectrum layered_f(const Material& m, float u) {
    const Vec3f wo = normalize(Vec3f{0.3f, 0.1f, 0.9f}), wi = normalize(Vec3f{-0.5f, 0.2f, 0.7f});
    auto bsdf = make_bsdf(m, lanes({450, 600}), TextureContext{{u, 0.5f}, {0, 0, 1}});
    EXPECT_TRUE(bsdf.has_value());
    return bsdf ? std::get<LayeredBsdf>(*bsdf).eval(wo, wi) : SampledSpectrum();
  }

  static spectral::SpectrumLibrary* library_;
  static spectral::ColorMatching* cmf_;
  static spectral::RgbUplift* uplift_;
};
spectral::SpectrumLibrary* MaterialTest::library_ = nullptr;
spectral::ColorMatching* MaterialTest::cmf_ = nullptr;
spectral::RgbUplift* MaterialTest::uplift_ = nullptr;

TEST_F(MaterialTest, EveryKindResolves) {
  auto diffuse = [&](scene::SpectrumParam p) {
    return resolve(scene::DiffuseMaterial{std::move(p)});
  };
  auto c = diffuse(scene::SpectrumConstant{0.25});
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_FLOAT_EQ(spectral::eval(std::get<DiffuseMaterial>(*c).reflectance.constant, 500), 0.25f);
  auto rgb = diffuse(scene::SpectrumRgb{0.8, 0.2, 0.1});
  ASSERT_TRUE(rgb.ok()) << rgb.status();
  EXPECT_TRUE(std::holds_alternative<spectral::RgbAlbedoSpectrum>(
      std::get<DiffuseMaterial>(*rgb).reflectance.constant));
  auto table = diffuse(scene::SpectrumTabulated{{400, 700}, {0.2, 0.6}, "inline"});
  ASSERT_TRUE(table.ok()) << table.status();
  EXPECT_NEAR(spectral::eval(std::get<DiffuseMaterial>(*table).reflectance.constant, 550), 0.4f,
              1e-6f);
  auto named = diffuse(scene::SpectrumNamed{"colorchecker-dark-skin"});
  ASSERT_TRUE(named.ok()) << named.status();
  EXPECT_EQ(spectral::eval(std::get<DiffuseMaterial>(*named).reflectance.constant, 600),
            spectral::eval(*library_->find_spectrum("colorchecker-dark-skin"), 600));
  auto bb = diffuse(scene::SpectrumBlackbody{5000});
  ASSERT_TRUE(bb.ok()) << bb.status();
  EXPECT_TRUE(std::holds_alternative<spectral::BlackbodySpectrum>(
      std::get<DiffuseMaterial>(*bb).reflectance.constant));

  auto dielectric = [&](scene::IorParam eta) {
    return resolve(scene::DielectricMaterial{std::move(eta), {}});
  };
  auto constant = dielectric(scene::IorConstant{1.33});
  ASSERT_TRUE(constant.ok()) << constant.status();
  EXPECT_FALSE(std::get<DielectricMaterial>(*constant).dispersive);
  EXPECT_DOUBLE_EQ(spectral::eta(std::get<DielectricMaterial>(*constant).eta, 400), 1.33);
  auto tab = dielectric(scene::IorTabulated{{{400, 700}, {1.6, 1.5}, "inline"}});
  ASSERT_TRUE(tab.ok()) << tab.status();
  EXPECT_TRUE(std::get<DielectricMaterial>(*tab).dispersive);
  EXPECT_NEAR(spectral::eta(std::get<DielectricMaterial>(*tab).eta, 550), 1.55, 1e-6);
  auto cauchy = dielectric(scene::IorCauchy{{1.5046, 0.0042}});
  ASSERT_TRUE(cauchy.ok()) << cauchy.status();
  EXPECT_NEAR(spectral::eta(std::get<DielectricMaterial>(*cauchy).eta, 500), 1.5046 + 0.0042 / 0.25,
              1e-9);
  auto named_glass = dielectric(scene::IorNamed{"glass-SF11"});
  ASSERT_TRUE(named_glass.ok()) << named_glass.status();
  EXPECT_TRUE(std::get<DielectricMaterial>(*named_glass).dispersive);

  auto copper = resolve(scene::ConductorMaterial{});
  ASSERT_TRUE(copper.ok()) << copper.status();
  const auto& cu = std::get<ConductorMaterial>(*copper);
  EXPECT_FALSE(cu.reflectance.has_value());
  EXPECT_EQ(spectral::eval(cu.k, 550), spectral::eval(*library_->find_spectrum("metal-Cu-k"), 550));
  EXPECT_TRUE(std::holds_alternative<InterfaceMaterial>(*resolve(scene::InterfaceMaterial{})));
}

// N-BK7 (pbrt-v4's glass-BK7) at the helium d line: n_d = 1.5168, in every lane that carries it;
// the catalogue Sellmeier form gives the same value.
TEST_F(MaterialTest, Bk7IndexReachesTheBsdfLanes) {
  scene::IorSellmeier sellmeier{{1.03961212, 0.231792344, 1.01046945},
                                {0.00600069867, 0.0200179144, 103.560653}};
  for (scene::IorParam eta :
       {scene::IorParam(scene::IorNamed{"glass-BK7"}), scene::IorParam(sellmeier)}) {
    auto m = resolve(scene::DielectricMaterial{eta, {}});
    ASSERT_TRUE(m.ok()) << m.status();
    auto w = lanes({587.6f, 450.0f, 587.6f, 700.0f});
    auto bsdf = make_bsdf(*m, w, TextureContext{});
    ASSERT_TRUE(bsdf.has_value());
    const auto& d = std::get<DielectricBsdf>(*bsdf);
    EXPECT_NEAR(d.eta(0), 1.5168f, 1e-4f);
    EXPECT_NEAR(d.eta(2), 1.5168f, 1e-4f);
    EXPECT_GT(d.eta(1), d.eta(0));  // normal dispersion: bluer is denser
    EXPECT_LT(d.eta(3), d.eta(0));
    for (int lane = 4; lane < spectral::kMaxLanes; ++lane) EXPECT_EQ(d.eta(lane), 0.0f);
    EXPECT_TRUE(d.dispersive());
    EXPECT_TRUE(d.specular());
  }
}

TEST_F(MaterialTest, ReflectanceAboveOneIsRefusedWithItsLocation) {
  std::vector<scene::MaterialKind> bad = {
      scene::DiffuseMaterial{scene::SpectrumConstant{1.2}},
      scene::DiffuseMaterial{scene::SpectrumRgb{1.1, 0.2, 0.2}},
      scene::DiffuseMaterial{scene::SpectrumTabulated{{400, 700}, {0.5, 1.5}, "refl.csv"}},
      scene::DiffuseMaterial{scene::SpectrumNamed{"stdillum-D65"}},
      scene::ConductorMaterial{scene::SpectrumNamed{"metal-Cu-eta"},
                               scene::SpectrumNamed{"metal-Cu-k"},
                               scene::SpectrumConstant{1.3},
                               {}},
  };
  for (const auto& kind : bad) {
    auto r = resolve_material(material(kind, "paint"), *library_, *uplift_, {});
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_TRUE(absl::StartsWith(r.status().message(), "scene.pbrt:7:3: material \"paint\""))
        << r.status();
    EXPECT_TRUE(absl::StrContains(r.status().message(), "reflect")) << r.status();
  }
  // Other values a material cannot take, with the same location.
  for (const auto& kind : std::vector<scene::MaterialKind>{
           scene::DiffuseMaterial{scene::SpectrumConstant{-0.1}},
           scene::DielectricMaterial{scene::IorNamed{"glass-unobtainium"}, {}},
           scene::DielectricMaterial{scene::IorConstant{0}, {}},
           scene::DielectricMaterial{scene::IorConstant{1.5}, {-0.1, 0, true}},
       }) {
    auto r = resolve_material(material(kind), *library_, *uplift_, {});
    ASSERT_FALSE(r.ok());
    EXPECT_TRUE(absl::StartsWith(r.status().message(), "scene.pbrt:7:3: ")) << r.status();
  }
}

// pbrt-v4's reflectance → (η = 1, k) mapping: normal-incidence Fresnel reflectance equals r.
TEST_F(MaterialTest, ConductorReflectanceMapsToNormalIncidenceFresnel) {
  scene::ConductorMaterial c;
  c.reflectance = scene::SpectrumTabulated{{360, 830}, {0.1, 0.95}, "inline"};
  auto m = resolve(c);
  ASSERT_TRUE(m.ok()) << m.status();
  auto w = lanes({400, 550, 700});
  auto bsdf = make_bsdf(*m, w, TextureContext{});
  ASSERT_TRUE(bsdf.has_value());
  ASSERT_TRUE(std::holds_alternative<ConductorBsdf>(*bsdf));
  // A smooth conductor's reflection sample reports Fresnel as f·cos (its specular weight).
  auto s = worker::sample(*bsdf, {0, 0, 1}, 0.5f, {0.5f, 0.5f});
  ASSERT_TRUE(s.has_value());
  for (int lane = 0; lane < 3; ++lane) {
    float r = 0.1f + (w.lambda(lane) - 360) / 470 * 0.85f;
    EXPECT_NEAR(s->f[lane] * abs_cos_theta(s->wi), r, 1e-4f) << lane;
  }
  EXPECT_EQ(s->f[3], 0.0f);
  // The tabulated k of the material agrees with the exact mapping.
  const auto& cm = std::get<ConductorMaterial>(*m);
  float r = 0.1f + (550.0f - 360) / 470 * 0.85f;
  EXPECT_NEAR(spectral::eval(cm.k, 550), 2 * std::sqrt(r) / std::sqrt(1 - r), 1e-4f);
  EXPECT_EQ(spectral::eval(cm.eta, 550), 1.0f);
}

TEST_F(MaterialTest, RoughnessRemapping) {
  auto remapped = resolve(scene::DielectricMaterial{scene::IorConstant{1.5}, {0.25, 0.04, true}});
  ASSERT_TRUE(remapped.ok());
  EXPECT_FLOAT_EQ(std::get<DielectricMaterial>(*remapped).alpha_x, 0.5f);
  EXPECT_FLOAT_EQ(std::get<DielectricMaterial>(*remapped).alpha_y, 0.2f);
  auto raw = resolve(scene::ConductorMaterial{
      scene::SpectrumConstant{0.2}, scene::SpectrumConstant{3}, std::nullopt, {0.25, 0.04, false}});
  ASSERT_TRUE(raw.ok()) << raw.status();
  EXPECT_FLOAT_EQ(std::get<ConductorMaterial>(*raw).alpha_x, 0.25f);
  EXPECT_FLOAT_EQ(std::get<ConductorMaterial>(*raw).alpha_y, 0.04f);
  auto bsdf = make_bsdf(*raw, lanes({500, 600}), TextureContext{});
  ASSERT_TRUE(bsdf.has_value());
  EXPECT_FALSE(is_specular(*bsdf));
}

TEST_F(MaterialTest, BsdfLanesBeyondTheCountAreZero) {
  auto m = resolve(scene::DiffuseMaterial{scene::SpectrumConstant{0.5}});
  ASSERT_TRUE(m.ok());
  auto bsdf = make_bsdf(*m, lanes({400, 500}), TextureContext{});
  ASSERT_TRUE(bsdf.has_value());
  SampledSpectrum f = worker::eval(*bsdf, {0, 0, 1}, normalize(Vec3f(0.3f, 0, 1)));
  EXPECT_FLOAT_EQ(f[0], 0.5f * kInvPi);
  EXPECT_FLOAT_EQ(f[1], 0.5f * kInvPi);
  for (int lane = 2; lane < spectral::kMaxLanes; ++lane) EXPECT_EQ(f[lane], 0.0f);
}

TEST_F(MaterialTest, InterfaceHasNoBsdf) {
  EXPECT_FALSE(
      make_bsdf(Material(InterfaceMaterial{}), lanes({500}), TextureContext{}).has_value());
}

TEST_F(MaterialTest, WavelengthDependenceTruthTable) {
  struct Row {
    scene::MaterialKind kind;
    bool dispersive, depends;
  };
  std::vector<Row> rows = {
      {scene::DiffuseMaterial{scene::SpectrumConstant{0.5}}, false, false},
      {scene::DiffuseMaterial{scene::SpectrumRgb{0.5, 0.5, 0.5}}, false, false},
      {scene::DiffuseMaterial{scene::SpectrumRgb{0.8, 0.2, 0.1}}, false, true},
      {scene::DiffuseMaterial{scene::SpectrumNamed{"colorchecker-red"}}, false, true},
      {scene::DielectricMaterial{scene::IorConstant{1.5}, {}}, false, false},
      {scene::DielectricMaterial{scene::IorConstant{1.5}, {0.3, 0.3, true}}, false, false},
      {scene::DielectricMaterial{scene::IorNamed{"glass-BK7"}, {}}, true, true},
      {scene::DielectricMaterial{scene::IorCauchy{{1.5, 0.004}}, {0.2, 0.2, true}}, true, true},
      {scene::ConductorMaterial{}, false, true},
      {scene::ConductorMaterial{
           scene::SpectrumConstant{0.2}, scene::SpectrumConstant{3}, std::nullopt, {}},
       false, false},
      {scene::ConductorMaterial{{}, {}, scene::SpectrumConstant{0.7}, {}}, false, false},
      {scene::ConductorMaterial{{}, {}, scene::SpectrumRgb{0.9, 0.7, 0.3}, {}}, false, true},
      {scene::InterfaceMaterial{}, false, false},
  };
  for (size_t i = 0; i < rows.size(); ++i) {
    auto m = resolve(rows[i].kind);
    ASSERT_TRUE(m.ok()) << i << ": " << m.status();
    EXPECT_EQ(is_dispersive(*m), rows[i].dispersive) << "row " << i;
    EXPECT_EQ(depends_on_wavelength(*m), rows[i].depends) << "row " << i;
    auto bsdf = make_bsdf(*m, lanes({450, 550, 650, 750}), TextureContext{});
    if (bsdf) {
      EXPECT_EQ(worker::is_dispersive(*bsdf), rows[i].dispersive) << "row " << i;
    }
  }
}

// A float texture in a roughness slot sets that axis's alpha per hit, remapped like a constant
// (pbrt-v4's sqrt), while the other axis keeps its constant; the texture is evaluated at the
// hit's uv, so two hits get two distributions.
TEST_F(MaterialTest, TexturedRoughnessIsEvaluatedAtTheHit) {
  // A 2-cell checkerboard of roughness 0.25 (u < 0.5) and 0.64 (u >= 0.5).
  using texture_nodes::Checkerboard;
  using texture_nodes::Input;
  scene::UvMapping mapping;
  mapping.su = 2;
  mapping.sv = 0;  // t = 0 everywhere: the cell is floor(2u)
  auto checks = std::make_shared<const Texture>(
      Checkerboard{mapping, Input{nullptr, 0.25f, {}}, Input{nullptr, 0.64f, {}}}, false);
  scene::DielectricMaterial glass;
  glass.roughness.u_texture = 0;
  glass.roughness.v = 0.09;
  auto m = resolve_material(material(glass), *library_, *uplift_, {checks});
  ASSERT_TRUE(m.ok()) << m.status();
  for (auto [u, alpha] : {std::pair{0.2f, 0.5f}, std::pair{0.7f, 0.8f}}) {
    auto bsdf = make_bsdf(*m, lanes({550}), TextureContext{{u, 0.5f}, {0, 0, 1}});
    ASSERT_TRUE(bsdf.has_value());
    const auto& d = std::get<DielectricBsdf>(*bsdf).distribution();
    EXPECT_FLOAT_EQ(d.alpha_x(), alpha) << u;
    EXPECT_FLOAT_EQ(d.alpha_y(), 0.3f) << u;
  }
}

// A textured slab albedo (pbrt-v4's `texture albedo` on coated materials) is looked up at the
// hit: each cell of a checkerboard gives exactly the BSDF of the constant albedo it holds.
TEST_F(MaterialTest, TexturedLayerAlbedoIsEvaluatedAtTheHit) {
  using texture_nodes::Input;
  auto checks = two_cells(Input{nullptr, 0, spectral::ConstantSpectrum{0.2f}},
                          Input{nullptr, 0, spectral::ConstantSpectrum{0.9f}}, true);
  scene::CoatedDiffuseMaterial coated;
  coated.roughness.u = coated.roughness.v = 0.3;
  coated.layer.thickness = 0.5;
  coated.layer.albedo_texture = 0;
  auto textured = resolve_material(material(coated), *library_, *uplift_, {checks});
  ASSERT_TRUE(textured.ok()) << textured.status();
  for (auto [u, albedo] : {std::pair{0.2f, 0.2}, std::pair{0.7f, 0.9}}) {
    scene::CoatedDiffuseMaterial plain = coated;
    plain.layer.albedo_texture = -1;
    plain.layer.albedo = scene::SpectrumConstant{albedo};
    auto constant = resolve(plain);
    ASSERT_TRUE(constant.ok());
    const SampledSpectrum fa = layered_f(*textured, u), fb = layered_f(*constant, u);
    EXPECT_GT(fa[0], 0.0f) << u;
    for (int k = 0; k < 2; ++k) EXPECT_EQ(fa[k], fb[k]) << u << " lane " << k;
  }
}

// Textured slab thickness and g (pbrt-v4 takes float textures there) are looked up at the hit:
// each checkerboard cell gives exactly the BSDF of the constants it holds.
TEST_F(MaterialTest, TexturedLayerThicknessAndGAreEvaluatedAtTheHit) {
  using texture_nodes::Input;
  auto checker = [](float a, float b) {
    return two_cells(Input{nullptr, a, {}}, Input{nullptr, b, {}}, false);
  };
  scene::CoatedDiffuseMaterial coated;
  coated.roughness.u = coated.roughness.v = 0.3;
  coated.layer.albedo = scene::SpectrumConstant{0.8};
  coated.layer.thickness_texture = 0;
  coated.layer.g_texture = 1;
  auto textured = resolve_material(material(coated), *library_, *uplift_,
                                   {checker(0.02f, 2.0f), checker(0.6f, -0.4f)});
  ASSERT_TRUE(textured.ok()) << textured.status();
  std::vector<float> seen;
  for (auto [u, thickness, g] : {std::tuple{0.2f, 0.02, 0.6}, std::tuple{0.7f, 2.0, -0.4}}) {
    scene::CoatedDiffuseMaterial plain = coated;
    plain.layer.thickness_texture = plain.layer.g_texture = -1;
    plain.layer.thickness = thickness;
    plain.layer.g = g;
    auto constant = resolve(plain);
    ASSERT_TRUE(constant.ok());
    const SampledSpectrum fa = layered_f(*textured, u), fb = layered_f(*constant, u);
    for (int k = 0; k < 2; ++k) EXPECT_EQ(fa[k], fb[k]) << u << " lane " << k;
    seen.push_back(fa[0]);
  }
  EXPECT_NE(seen[0], seen[1]);  // the slab's parameters matter here
}

TEST_F(MaterialTest, SpectrumRolesPickTheUplift) {
  scene::SpectrumParam rgb = scene::SpectrumRgb{2.0, 1.0, 0.5};
  EXPECT_FALSE(
      job::resolve_spectrum(rgb, job::SpectrumRole::kReflectance, *library_, *uplift_).ok());
  auto unbounded = job::resolve_spectrum(rgb, job::SpectrumRole::kUnbounded, *library_, *uplift_);
  ASSERT_TRUE(unbounded.ok()) << unbounded.status();
  EXPECT_TRUE(std::holds_alternative<spectral::RgbUnboundedSpectrum>(*unbounded));
  auto illum = job::resolve_spectrum(rgb, job::SpectrumRole::kIlluminant, *library_, *uplift_);
  ASSERT_TRUE(illum.ok()) << illum.status();
  EXPECT_TRUE(std::holds_alternative<spectral::RgbIlluminantSpectrum>(*illum));
  EXPECT_FALSE(job::resolve_spectrum(scene::SpectrumConstant{-1}, job::SpectrumRole::kUnbounded,
                                     *library_, *uplift_)
                   .ok());
  auto unknown = job::resolve_spectrum(scene::SpectrumNamed{"stdillum-Z9"},
                                       job::SpectrumRole::kIlluminant, *library_, *uplift_);
  ASSERT_FALSE(unknown.ok());
  EXPECT_TRUE(absl::StrContains(unknown.status().message(), "stdillum-Z9"));
}

}  // namespace
}  // namespace prism::worker
