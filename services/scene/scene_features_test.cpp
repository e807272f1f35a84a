// The policy for input Prism does not render as pbrt-v4 would: refused by name and position,
// or (allow_unsupported) substituted and listed; what cannot change the image is accepted and
// listed as ignored; every use is in SceneDescription::features.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <variant>

#include "services/scene/parser.h"

namespace prism::scene {
namespace {

// One use of each kind of refusal: a whole type, a value, a parameter, a directive, an
// animated transform, an emitter Prism cannot sample, an option that changes the image.
constexpr const char* kUnsupported = R"(Camera "realistic" "string lensfile" "wide.dat"
Film "rgb" "integer xresolution" 8 "integer yresolution" 4 "float iso" 400
Option "bool forcediffuse" true
WorldBegin
Attribute "shape" "float radius" 2
Material "hair" "float eumelanin" 1.3
Shape "sphere" "float zmin" 0
Shape "curve" "point3 P" [0 0 0 1 1 1 2 2 2 3 3 3]
MakeNamedMedium "fog" "string type" "cloud" "float density" 2
Texture "noise" "float" "fbm" "integer octaves" 4
AttributeBegin
  ActiveTransform EndTime
  Translate 0 0 5
  ActiveTransform All
  AreaLightSource "diffuse" "blackbody L" 3000
  Shape "cylinder" "float alpha" 0.5 "float mystery" 1
AttributeEnd
)";

LoadOptions allowing() {
  LoadOptions o;
  o.allow_unsupported = true;
  return o;
}

const FeatureUse* find_feature(const SceneDescription& s, const std::string& feature) {
  for (const FeatureUse& f : s.features)
    if (f.feature == feature) return &f;
  return nullptr;
}

TEST(SceneFeatures, AStrictLoadRefusesTheFirstUnsupportedFeatureByPosition) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(kUnsupported, "u.pbrt");
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.status().message(),
            "u.pbrt:1:8: unsupported camera type \"realistic\" (supported: orthographic, "
            "perspective, spherical)");
}

TEST(SceneFeatures, AllowingUnsupportedInputRendersAListedSubstitutionForEach) {
  absl::StatusOr<SceneDescription> loaded = parse_scene_string(kUnsupported, "u.pbrt", allowing());
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const SceneDescription& s = *loaded;

  // Camera: pbrt-v4's perspective default; the film keeps its size.
  EXPECT_EQ(s.camera.type, "perspective");
  EXPECT_EQ(s.camera.fov_deg, 90.0);
  EXPECT_EQ(s.film.x_resolution, 8);
  // The hair material becomes the default diffuse one, the partial sphere a full sphere, the
  // curve is dropped.
  ASSERT_EQ(s.materials.size(), 1u);
  EXPECT_TRUE(std::holds_alternative<DiffuseMaterial>(s.materials[0].kind));
  ASSERT_EQ(s.shapes.size(), 2u);
  EXPECT_TRUE(std::holds_alternative<SphereShape>(s.shapes[0].geometry));
  EXPECT_TRUE(std::holds_alternative<CylinderShape>(s.shapes[1].geometry));
  EXPECT_TRUE(s.shapes[1].area_light.has_value());
  // The end-time translation is dropped: the shutter-open transform is the identity.
  EXPECT_TRUE(s.shapes[1].object_to_world.is_identity());
  // The cloud medium is a vacuum; the fbm texture a constant 0.5.
  ASSERT_EQ(s.media.size(), 1u);
  const auto& fog = std::get<HomogeneousMedium>(s.media[0].kind);
  EXPECT_EQ(std::get<SpectrumConstant>(fog.sigma_a).value, 0.0);
  EXPECT_EQ(std::get<SpectrumConstant>(fog.sigma_s).value, 0.0);
  ASSERT_EQ(s.textures.size(), 1u);
  EXPECT_EQ(std::get<ConstantTexture>(s.textures[0].kind).value.value, 0.5);

  struct Expected {
    const char* feature;
    const char* where;
    const char* substitution;
  };
  const Expected expected[] = {
      {"Camera \"realistic\"", "u.pbrt:1:8", "a perspective camera with a 90 degree field of view"},
      {"Film \"rgb\" 'float iso'", "u.pbrt:2:60", "iso 100"},
      {"Option 'bool forcediffuse'", "u.pbrt:3:8", "the scene without the option"},
      {"directive Attribute", "u.pbrt:5:1", "the scene without the directive"},
      {"Material \"hair\"", "u.pbrt:6:10", "pbrt-v4's default material (diffuse, reflectance 0.5)"},
      {"Shape \"sphere\" 'float zmin'", "u.pbrt:7:16", "a full sphere"},
      {"Shape \"curve\"", "u.pbrt:8:7", "the scene without this shape"},
      {"MakeNamedMedium \"cloud\"", "u.pbrt:9:23", "a vacuum (no absorption, no scattering)"},
      {"Texture \"fbm\"", "u.pbrt:10:25", "a constant 0.5"},
      {"motion blur", "u.pbrt:16:3", "the shutter-open (StartTime) transform, without motion"},
      {"Shape \"cylinder\" 'float mystery'", "u.pbrt:16:38", "the scene without it"},
  };
  for (const Expected& e : expected) {
    const FeatureUse* f = find_feature(s, e.feature);
    ASSERT_NE(f, nullptr) << e.feature;
    EXPECT_EQ(f->status, FeatureStatus::kRefused) << e.feature;
    EXPECT_EQ(f->where.to_string(), e.where) << e.feature;
    EXPECT_EQ(f->substitution, e.substitution) << e.feature;
    EXPECT_FALSE(f->note.empty()) << e.feature;
  }
  EXPECT_EQ(count_features(s.features, FeatureStatus::kRefused), int(std::size(expected)));
  // Each substitution is also a warning, which renders print.
  const std::vector<std::string> warnings = feature_warnings(s.features);
  EXPECT_TRUE(std::any_of(warnings.begin(), warnings.end(), [](const std::string& w) {
    return w ==
           "u.pbrt:7:16: warning: 'float zmin' is not supported (only full spheres: zmin <= "
           "-radius); rendered as a full sphere";
  }));
}

TEST(SceneFeatures, EverySupportedApproximatedAndIgnoredUseIsListedOnce) {
  constexpr const char* kScene = R"(Sampler "halton" "integer pixelsamples" 4
Accelerator "kdtree"
WorldBegin
Texture "checks" "spectrum" "checkerboard" "float uscale" 4
Material "coateddiffuse" "texture reflectance" "checks" "texture albedo" "checks"
Shape "sphere"
Shape "sphere" "float radius" 2
Shape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0] "integer faceIndices" [0]
)";
  absl::StatusOr<SceneDescription> s = parse_scene_string(kScene, "f.pbrt");
  ASSERT_TRUE(s.ok()) << s.status();
  auto status_of = [&](const std::string& feature) {
    const FeatureUse* f = find_feature(*s, feature);
    EXPECT_NE(f, nullptr) << feature;
    return f == nullptr ? std::string() : std::string(feature_status_name(f->status));
  };
  EXPECT_EQ(status_of("Sampler \"halton\""), "ignored");
  EXPECT_EQ(status_of("Accelerator \"kdtree\""), "ignored");
  EXPECT_EQ(status_of("Texture \"checkerboard\""), "approximated");
  EXPECT_EQ(status_of("Material \"coateddiffuse\""), "supported");
  EXPECT_EQ(status_of("Shape \"trianglemesh\" 'integer faceIndices'"), "ignored");
  EXPECT_EQ(status_of("Shape \"sphere\""), "supported");
  EXPECT_EQ(find_feature(*s, "Shape \"sphere\"")->uses, 2);
  EXPECT_EQ(find_feature(*s, "Shape \"sphere\"")->where.to_string(), "f.pbrt:6:7");
  EXPECT_EQ(count_features(s->features, FeatureStatus::kRefused), 0);
  // The slab's albedo takes a spectrum texture too.
  const auto& coated = std::get<CoatedDiffuseMaterial>(s->materials[0].kind);
  EXPECT_EQ(coated.reflectance_texture, 0);
  EXPECT_EQ(coated.layer.albedo_texture, 0);
}

// Options are sorted by what they do to the image, not accepted wholesale.
TEST(SceneFeatures, OptionsThatChangeTheImageAreRefusedAndTheRestIgnored) {
  absl::StatusOr<SceneDescription> ok = parse_scene_string(
      "Option \"integer seed\" 3\nOption \"bool disablepixeljitter\" false\n"
      "Option \"bool disabletexturefiltering\" true\nWorldBegin\n",
      "o.pbrt");
  ASSERT_TRUE(ok.ok()) << ok.status();
  EXPECT_EQ(count_features(ok->features, FeatureStatus::kIgnored), 2);
  EXPECT_EQ(count_features(ok->features, FeatureStatus::kSupported), 1);
  // pbrt-v4's own form, untyped: the same judgements.
  absl::StatusOr<SceneDescription> untyped = parse_scene_string(
      "Option \"seed\" 3\nOption \"disablepixeljitter\" false\n"
      "Option \"disabletexturefiltering\" true\nOption \"rendercoordsys\" \"world\"\n"
      "WorldBegin\n",
      "o.pbrt");
  ASSERT_TRUE(untyped.ok()) << untyped.status();
  EXPECT_EQ(count_features(untyped->features, FeatureStatus::kIgnored), 3);
  EXPECT_EQ(count_features(untyped->features, FeatureStatus::kSupported), 1);
  // An unknown name, or a value of the wrong kind, is malformed (pbrt-v4 refuses them too).
  for (const auto& [text, message] :
       {std::pair<std::string, std::string>{"Option \"nosuchoption\" false",
                                            "o.pbrt:1:8: unknown option \"nosuchoption\""},
        {"Option \"disablepixeljitter\" maybe",
         "o.pbrt:1:29: Option \"disablepixeljitter\" takes true or false, not 'maybe'"},
        {"Option \"seed\" 1.5", "o.pbrt:1:15: Option \"seed\" takes an integer, not '1.5'"}}) {
    absl::StatusOr<SceneDescription> bad = parse_scene_string(text + "\nWorldBegin\n", "o.pbrt");
    ASSERT_FALSE(bad.ok()) << text;
    EXPECT_EQ(bad.status().message(), message) << text;
  }
  absl::StatusOr<SceneDescription> untyped_bad =
      parse_scene_string("Option \"forcediffuse\" true\nWorldBegin\n", "o.pbrt");
  ASSERT_FALSE(untyped_bad.ok());
  EXPECT_EQ(untyped_bad.status().message(),
            "o.pbrt:1:8: Option 'forcediffuse' changes the image and is not supported by Prism");
  for (const char* changes : {"disablepixeljitter", "disablewavelengthjitter", "forcediffuse"}) {
    absl::StatusOr<SceneDescription> bad = parse_scene_string(
        absl::StrCat("Option \"bool ", changes, "\" true\nWorldBegin\n"), "o.pbrt");
    ASSERT_FALSE(bad.ok()) << changes;
    EXPECT_EQ(bad.status().message(),
              absl::StrCat("o.pbrt:1:8: Option '", changes,
                           "' changes the image and is not supported by Prism"));
  }
}

// An integrator that renders another quantity is refused; one that converges to the same
// image is accepted and listed; settings that bias the image are refused.
TEST(SceneFeatures, IntegratorsAreJudgedByTheImageTheyConvergeTo) {
  absl::StatusOr<SceneDescription> ao =
      parse_scene_string("Integrator \"ambientocclusion\"\nWorldBegin\n", "i.pbrt");
  ASSERT_FALSE(ao.ok());
  EXPECT_EQ(ao.status().message(),
            "i.pbrt:1:12: integrator \"ambientocclusion\" renders something other than the light "
            "transport; Prism renders path, volpath and the integrators that converge to the same "
            "image");
  absl::StatusOr<SceneDescription> reg =
      parse_scene_string("Integrator \"volpath\" \"bool regularize\" true\nWorldBegin\n", "i.pbrt");
  ASSERT_FALSE(reg.ok());
  EXPECT_EQ(reg.status().message(),
            "i.pbrt:1:22: 'bool regularize' changes the image; Prism renders it off");
  absl::StatusOr<SceneDescription> sppm =
      parse_scene_string("Integrator \"sppm\" \"float radius\" 0.1\nWorldBegin\n", "i.pbrt");
  ASSERT_TRUE(sppm.ok()) << sppm.status();
  EXPECT_EQ(feature_status_name(find_feature(*sppm, "Integrator \"sppm\"")->status),
            std::string("ignored"));
}

}  // namespace
}  // namespace prism::scene
