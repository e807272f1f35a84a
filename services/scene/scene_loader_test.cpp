// Loading from disk: the example scenes, root confinement, and in-memory parsing.
#include "services/scene/scene_loader.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "services/scene/bundle.h"
#include "services/scene/wavelength_dependence.h"

namespace prism::scene {
namespace {

namespace fs = std::filesystem;

fs::path scenes_dir() { return fs::path(PRISM_SOURCE_DIR) / "scenes"; }

TEST(ExampleScenes, PrismLoads) {
  absl::StatusOr<LoadedScene> loaded = load_scene(scenes_dir() / "prism.pbrt", LoadOptions{});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const SceneDescription& s = loaded->description;
  EXPECT_EQ(loaded->scene_relpath, "prism.pbrt");
  EXPECT_EQ(s.film.type, FilmType::kSpectral);
  EXPECT_EQ(s.film.x_resolution, 320);
  EXPECT_EQ(s.film.y_resolution, 240);
  EXPECT_EQ(s.sampler.samples_per_pixel, 128);
  EXPECT_EQ(s.files, (std::vector<std::string>{"prism.pbrt", "prism/prism.obj"}));
  WavelengthDependence d = analyze_wavelength_dependence(s);
  ASSERT_EQ(d.dispersive_materials.size(), 1u);
  EXPECT_EQ(std::get<DielectricMaterial>(s.materials[static_cast<size_t>(d.dispersive_materials[0])].kind).eta,
            IorParam(IorNamed{"glass-SF11"}));
  EXPECT_EQ(d.emitter_spectra, (std::vector<SpectrumParam>{SpectrumNamed{"stdillum-F11"}, SpectrumNamed{"stdillum-D65"}}));
  EXPECT_EQ(s.area_light_count(), 1u);
  EXPECT_EQ(s.triangle_count(), 2u + 8u + 2u);  // floor, prism, lamp
  EXPECT_TRUE(s.warnings.empty()) << s.warnings.size();
  // The sampler note is the scene's only departure from pbrt-v4.
  EXPECT_EQ(feature_warnings(s.features).size(), 1u);
  EXPECT_EQ(count_features(s.features, FeatureStatus::kIgnored), 1);
  EXPECT_EQ(count_features(s.features, FeatureStatus::kRefused), 0);
}

TEST(ExampleScenes, CornellTwoLightsLoads) {
  absl::StatusOr<LoadedScene> loaded = load_scene(scenes_dir() / "cornell-two-lights.pbrt", LoadOptions{});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const SceneDescription& s = loaded->description;
  EXPECT_EQ(s.shapes.size(), 9u);
  EXPECT_EQ(s.area_light_count(), 2u);
  WavelengthDependence d = analyze_wavelength_dependence(s);
  EXPECT_EQ(d.emitter_spectra, (std::vector<SpectrumParam>{SpectrumNamed{"stdillum-A"}, SpectrumNamed{"stdillum-F11"}}));
  EXPECT_TRUE(d.dispersive_materials.empty());
  // Mirrored camera: raster x runs along world -x, so the red wall (x = 556) is on the left.
  const Transform& w = s.camera.world_from_camera;
  Vec3 right = w.apply_vector({1, 0, 0});
  EXPECT_NEAR(right[0], -1.0, 1e-12);
  Vec3 eye = w.apply_point({0, 0, 0});
  EXPECT_NEAR(eye[0], 278, 1e-9);
  EXPECT_NEAR(eye[2], -800, 1e-9);
  EXPECT_DOUBLE_EQ(s.camera.fov_deg, 39.3077);
  // The luminaire's triangles face down (pbrt's cross(p0 - p2, p1 - p2)).
  const Shape& luminaire = s.shapes[7];
  ASSERT_TRUE(luminaire.area_light.has_value());
  const TriangleMeshData& m = *std::get<TriangleMeshShape>(luminaire.geometry).mesh;
  for (const Triangle& t : m.triangles) {
    const Float3& p0 = m.positions[t[0]];
    const Float3& p1 = m.positions[t[1]];
    const Float3& p2 = m.positions[t[2]];
    double ax = p0.x - p2.x, az = p0.z - p2.z, bx = p1.x - p2.x, bz = p1.z - p2.z;
    EXPECT_LT(az * bx - ax * bz, 0.0);  // y component of the cross product
  }
  EXPECT_EQ(s.files.size(), 1u + 3u + 8u);
  EXPECT_EQ(s.files[1], "cornell-two-lights/spectra/white.csv");
  const auto& white = std::get<SpectrumTabulated>(std::get<DiffuseMaterial>(s.materials[0].kind).reflectance);
  EXPECT_EQ(white.wavelengths_nm.size(), 76u);
  EXPECT_EQ(white.wavelengths_nm.front(), 400);
  EXPECT_EQ(white.values.front(), 0.343);
}

TEST(ExampleScenes, OpenedFilesMakeABundle) {
  absl::StatusOr<LoadedScene> loaded = load_scene(scenes_dir() / "cornell-two-lights.pbrt", LoadOptions{});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const std::vector<std::string>& files = loaded->description.files;
  absl::StatusOr<Bundle> bundle = make_bundle(loaded->root, loaded->scene_relpath, files);
  ASSERT_TRUE(bundle.ok()) << bundle.status();
  EXPECT_EQ(bundle->entries.size(), files.size());
  EXPECT_EQ(bundle->scene_path, "cornell-two-lights.pbrt");
  EXPECT_EQ(bundle->content_hash.size(), 64u);
}

TEST(ExampleScenes, NamesAreValidatedWhenAsked) {
  LoadOptions options;
  options.is_known_spectrum = [](std::string_view n) { return n == "stdillum-A" || n == "stdillum-D65"; };
  absl::StatusOr<LoadedScene> loaded = load_scene(scenes_dir() / "cornell-two-lights.pbrt", options);
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(std::string(loaded.status().message()), "cornell-two-lights.pbrt:48:42: unknown named spectrum \"stdillum-F11\"");
}

class LoaderFiles : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("prism_scene_loader_" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "root");
  }
  void TearDown() override { fs::remove_all(dir_); }
  void write(const fs::path& p, const std::string& text) {
    fs::create_directories(p.parent_path());
    std::ofstream(p) << text;
  }
  fs::path dir_;
};

TEST_F(LoaderFiles, SymlinkOutOfTheRootIsRefused) {
  write(dir_ / "secret.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  fs::create_symlink(dir_ / "secret.obj", dir_ / "root/link.obj");
  write(dir_ / "root/s.pbrt", "WorldBegin\nShape \"objmesh\" \"string filename\" \"link.obj\"\n");
  absl::StatusOr<LoadedScene> loaded = load_scene(dir_ / "root/s.pbrt", LoadOptions{});
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(std::string(loaded.status().message()).starts_with("s.pbrt:2:17: ")) << loaded.status();
}

TEST_F(LoaderFiles, MeshLimitsReachTheMeshLoaders) {
  write(dir_ / "root/m.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n");
  write(dir_ / "root/s.pbrt", "WorldBegin\nShape \"objmesh\" \"string filename\" \"m.obj\"\n");
  LoadOptions options;
  options.mesh_limits.max_triangles = 1;
  absl::StatusOr<LoadedScene> loaded = load_scene(dir_ / "root/s.pbrt", options);
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_TRUE(std::string(loaded.status().message()).starts_with("s.pbrt:2:17: ")) << loaded.status();
  options.mesh_limits.max_triangles = 2;
  options.max_total_triangles = 1;
  loaded = load_scene(dir_ / "root/s.pbrt", options);
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(std::string(loaded.status().message()), "s.pbrt:2:1: the scene has more than 1 triangles");
}

TEST(ParseFromMemory, FilesComeFromTheGivenMap) {
  std::map<std::string, std::string> files = {
      // Names are relative to the main scene's directory, as in pbrt-v4.
      {"a/inc.pbrt", "Include \"a/b.pbrt\"\n"},
      {"a/b.pbrt", "Shape \"objmesh\" \"string filename\" \"m.obj\"\n"},
      {"m.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"},
  };
  absl::StatusOr<SceneDescription> s = parse_scene_string("WorldBegin\nInclude \"a/inc.pbrt\"\n", "mem.pbrt", {}, files);
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_EQ(s->files, (std::vector<std::string>{"mem.pbrt", "a/inc.pbrt", "a/b.pbrt", "m.obj"}));
  absl::StatusOr<SceneDescription> missing = parse_scene_string("WorldBegin\nInclude \"x.pbrt\"\n", "mem.pbrt");
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(std::string(missing.status().message()), "mem.pbrt:2:9: file \"x.pbrt\" does not exist");
}

}  // namespace
}  // namespace prism::scene
