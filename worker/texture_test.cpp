#include "worker/texture.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "services/scene/scene_loader.h"
#include "tests/testing/test_dir.h"

namespace prism::worker {
namespace {

// The parser's texture corpus (services/scene/testdata/parser/good/textures.pbrt): a 2x2 image
// (top row red, green; bottom row blue, sRGB grey 128), a 1x1 grey float image, a checkerboard
// and the arithmetic textures over them.
class TextureTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    library_ = new spectral::SpectrumLibrary(*spectral::SpectrumLibrary::load_builtin());
    cmf_ = new spectral::ColorMatching(spectral::ColorMatching::cie1931());
    uplift_ = new spectral::RgbUplift(*cmf_);
    auto loaded = scene::load_scene(std::filesystem::path(PRISM_SOURCE_DIR) /
                                        "services/scene/testdata/parser/good/textures.pbrt",
                                    scene::with_library_names(*library_));
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    scene_ = new scene::SceneDescription(std::move(loaded->description));
    auto textures = Texture::resolve_all(*scene_, *library_, *uplift_);
    ASSERT_TRUE(textures.ok()) << textures.status();
    textures_ = new std::vector<TexturePtr>(std::move(*textures));
  }
  static void TearDownTestSuite() {
    delete textures_;
    delete scene_;
    delete uplift_;
    delete cmf_;
    delete library_;
  }

  static const Texture& texture(const std::string& name) {
    for (size_t i = 0; i < scene_->textures.size(); ++i) {
      if (scene_->textures[i].name == name) return *(*textures_)[i];
    }
    ADD_FAILURE() << name;
    return *textures_->front();
  }
  static spectral::SampledWavelengths lanes() {
    spectral::SampledWavelengths w(4);
    const float nm[4] = {420, 510, 580, 660};
    for (int i = 0; i < 4; ++i) w.set(i, nm[i], 1.0f / 470);
    return w;
  }
  // The albedo uplift of an RGB at the test lanes.
  static spectral::SampledSpectrum albedo(float r, float g, float b) {
    auto p = uplift_->fit({r, g, b});
    EXPECT_TRUE(p.ok());
    spectral::SampledSpectrum out;
    const auto w = lanes();
    for (int i = 0; i < 4; ++i) out[i] = (*p)(w.lambda(i));
    return out;
  }
  static void expect_spectrum(const spectral::SampledSpectrum& got,
                              const spectral::SampledSpectrum& want, float tol = 1e-6f) {
    for (int i = 0; i < 4; ++i) EXPECT_NEAR(got[i], want[i], tol) << "lane " << i;
  }
  static TextureContext at(float u, float v, Vec3f n = {0, 0, 1}) { return {{u, v}, n}; }

  static spectral::SpectrumLibrary* library_;
  static spectral::ColorMatching* cmf_;
  static spectral::RgbUplift* uplift_;
  static scene::SceneDescription* scene_;
  static std::vector<TexturePtr>* textures_;
};
spectral::SpectrumLibrary* TextureTest::library_ = nullptr;
spectral::ColorMatching* TextureTest::cmf_ = nullptr;
spectral::RgbUplift* TextureTest::uplift_ = nullptr;
scene::SceneDescription* TextureTest::scene_ = nullptr;
std::vector<TexturePtr>* TextureTest::textures_ = nullptr;

TEST_F(TextureTest, CheckerboardPicksByTheParityOfTheScaledCell) {
  const Texture& checks = texture("checks");  // uscale 4, vscale 2
  const auto light = albedo(0.8f, 0.8f, 0.75f), dark = albedo(0.15f, 0.15f, 0.2f);
  expect_spectrum(checks.spectrum(at(0.1f, 0.1f), lanes()), light);  // cell (0, 0)
  expect_spectrum(checks.spectrum(at(0.3f, 0.1f), lanes()), dark);   // cell (1, 0)
  expect_spectrum(checks.spectrum(at(0.3f, 0.6f), lanes()), light);  // cell (1, 1)
  expect_spectrum(checks.spectrum(at(-0.1f, 0.1f), lanes()), dark);  // cell (-1, 0)
  EXPECT_TRUE(checks.varies_with_wavelength());
}

TEST_F(TextureTest, ImagesAreLookedUpBilinearlyWithTheFileTopAtVOne) {
  const Texture& quad = texture("quad-linear");  // linear encoding, repeat
  // Texel centres: (u, v) = (0.25, 0.75) is the file's top-left texel.
  expect_spectrum(quad.spectrum(at(0.25f, 0.75f), lanes()), albedo(1, 0, 0));
  expect_spectrum(quad.spectrum(at(0.75f, 0.75f), lanes()), albedo(0, 1, 0));
  expect_spectrum(quad.spectrum(at(0.25f, 0.25f), lanes()), albedo(0, 0, 1));
  const float g = 128 / 255.0f;
  expect_spectrum(quad.spectrum(at(0.75f, 0.25f), lanes()), albedo(g, g, g));
  // Halfway between two texels: the mean of their spectra (so the mean of their colours).
  expect_spectrum(quad.spectrum(at(0.5f, 0.75f), lanes()),
                  (albedo(1, 0, 0) + albedo(0, 1, 0)) * 0.5f);
  // Repeat wraps: u = 0 is halfway between the last column and the first.
  expect_spectrum(quad.spectrum(at(0.0f, 0.75f), lanes()),
                  (albedo(1, 0, 0) + albedo(0, 1, 0)) * 0.5f);
}

TEST_F(TextureTest, ScaleInvertAndClampFollowPbrtV4) {
  const Texture& quad = texture("quad");  // sRGB, scale 0.5, invert, clamp
  // Red (1, 0, 0) → scaled (0.5, 0, 0) → inverted (0.5, 1, 1).
  expect_spectrum(quad.spectrum(at(0.25f, 0.75f), lanes()), albedo(0.5f, 1, 1));
  // Clamp: far outside the image the edge texel stays.
  expect_spectrum(quad.spectrum(at(-3.0f, 5.0f), lanes()), albedo(0.5f, 1, 1));
  // The scale texture multiplies by the float texture "half" (0.5).
  expect_spectrum(texture("scaled").spectrum(at(0.25f, 0.75f), lanes()), albedo(0.5f, 1, 1) * 0.5f);
}

TEST_F(TextureTest, FloatImagesMixAndDirectionMix) {
  const float grey = float(std::pow(64 / 255.0, 2.0));  // "gamma 2" encoding
  EXPECT_FLOAT_EQ(texture("grey").value(at(0.3f, 0.9f)), grey);
  EXPECT_FALSE(texture("grey").varies_with_wavelength());
  // mix: (1 − a)·checks + a·rgb(0.1, 0.2, 0.3) with a the grey image.
  expect_spectrum(texture("mixed").spectrum(at(0.1f, 0.1f), lanes()),
                  albedo(0.8f, 0.8f, 0.75f) * (1 - grey) + albedo(0.1f, 0.2f, 0.3f) * grey);
  // directionmix towards +z (its dir after the Rotate): a = |n · dir|.
  const Texture& facing = texture("facing");
  expect_spectrum(facing.spectrum(at(0.1f, 0.1f, {0, 0, 1}), lanes()), albedo(0.8f, 0.8f, 0.75f));
  expect_spectrum(facing.spectrum(at(0.1f, 0.1f, {0, 0, -1}), lanes()), albedo(0.8f, 0.8f, 0.75f));
  const auto side = texture("quad").spectrum(at(0.1f, 0.1f), lanes());
  expect_spectrum(facing.spectrum(at(0.1f, 0.1f, {1, 0, 0}), lanes()), side);
  const float c = std::sqrt(0.5f);
  expect_spectrum(facing.spectrum(at(0.1f, 0.1f, {c, 0, c}), lanes()),
                  albedo(0.8f, 0.8f, 0.75f) * c + side * (1 - c), 1e-5f);
}

// pbrt-v4 resolves a material's textures once the whole scene is read, so a material may name a
// texture defined further on. Its slot then comes before the textures it names, which resolve
// first; the result is the texture the scene in its usual order gives.
TEST_F(TextureTest, AMaterialMayNameATextureDefinedFurtherOn) {
  const std::string material =
      "Material \"diffuse\" \"texture reflectance\" \"late\"\nShape \"sphere\"\n";
  const std::string textures =
      "Texture \"a\" \"spectrum\" \"constant\" \"rgb value\" [0.9 0.1 0.1]\n"
      "Texture \"b\" \"spectrum\" \"checkerboard\" \"float uscale\" 4 \"float vscale\" 4\n"
      "Texture \"amount\" \"float\" \"imagemap\" \"string filename\" \"grey.png\"\n"
      "Texture \"late\" \"spectrum\" \"mix\" \"texture tex1\" \"a\" \"texture tex2\" \"b\"\n"
      "  \"texture amount\" \"amount\"\n";
  const std::filesystem::path good =
      std::filesystem::path(PRISM_SOURCE_DIR) / "services/scene/testdata/parser/good";
  auto load = [&](const std::string& text) {
    const std::filesystem::path dir = testing::fresh_dir("texture_forward");
    std::filesystem::copy(good / "textures/grey.png", dir / "grey.png");
    std::ofstream(dir / "s.pbrt") << text;
    auto loaded = scene::load_scene(dir / "s.pbrt", scene::with_library_names(*library_));
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    return loaded.ok() ? std::move(loaded->description) : scene::SceneDescription{};
  };
  const scene::SceneDescription forward = load("WorldBegin\n" + material + textures);
  const scene::SceneDescription ordered = load("WorldBegin\n" + textures + material);
  ASSERT_EQ(forward.textures.size(), 4u);
  ASSERT_EQ(forward.materials.size(), 1u);
  const int slot = std::get<scene::DiffuseMaterial>(forward.materials[0].kind).reflectance_texture;
  ASSERT_EQ(slot, 0);  // reserved by the material, filled by the Texture directive
  EXPECT_EQ(forward.textures[0].name, "late");
  EXPECT_EQ(forward.textures[0].where.line, 7);
  auto a = Texture::resolve_all(forward, *library_, *uplift_);
  auto b = Texture::resolve_all(ordered, *library_, *uplift_);
  ASSERT_TRUE(a.ok()) << a.status();
  ASSERT_TRUE(b.ok()) << b.status();
  const int ordered_slot =
      std::get<scene::DiffuseMaterial>(ordered.materials[0].kind).reflectance_texture;
  for (float u : {0.05f, 0.3f, 0.55f, 0.8f}) {
    for (float v : {0.1f, 0.6f}) {
      const auto got = (*a)[size_t(slot)]->spectrum(at(u, v), lanes());
      const auto want = (*b)[size_t(ordered_slot)]->spectrum(at(u, v), lanes());
      for (int i = 0; i < 4; ++i) EXPECT_EQ(got[i], want[i]) << u << " " << v << " lane " << i;
    }
  }
}

// A float texture of an RGB image reads its first channel, as pbrt-v4's MIPMap::Texel<Float>
// does: quad.png's red texel (1, 0, 0) is 1, where the average of the channels gave 1/3.
TEST_F(TextureTest, AFloatImageOfAnRgbFileReadsItsFirstChannel) {
  const std::filesystem::path dir = testing::fresh_dir("float_of_rgb");
  std::filesystem::copy(std::filesystem::path(PRISM_SOURCE_DIR) /
                            "services/scene/testdata/parser/good/textures/quad.png",
                        dir / "quad.png");
  std::ofstream(dir / "scene.pbrt")
      << "WorldBegin\nTexture \"red\" \"float\" \"imagemap\" \"string filename\" "
         "\"quad.png\" \"string encoding\" \"linear\"\n";
  auto loaded = scene::load_scene(dir / "scene.pbrt", scene::with_library_names(*library_));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  auto textures = Texture::resolve_all(loaded->description, *library_, *uplift_);
  ASSERT_TRUE(textures.ok()) << textures.status();
  ASSERT_EQ(textures->size(), 1u);
  EXPECT_FLOAT_EQ(textures->front()->value(at(0.25f, 0.75f)), 1.0f);
}

}  // namespace
}  // namespace prism::worker
