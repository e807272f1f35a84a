// The good-scene corpus under testdata/parser/good/: each scene's parsed values.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "absl/strings/match.h"
#include "services/scene/scene_loader.h"

namespace prism::scene {
namespace {

namespace fs = std::filesystem;

SceneDescription load_good(const std::string& name) {
  fs::path path = fs::path(PRISM_SOURCE_DIR) / "services/scene/testdata/parser/good" / name;
  absl::StatusOr<LoadedScene> scene = load_scene(path, LoadOptions{});
  EXPECT_TRUE(scene.ok()) << scene.status();
  if (!scene.ok()) return {};
  return std::move(scene->description);
}

void expect_near(const Vec3& a, const Vec3& b, double tol = 1e-9) {
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(a[i], b[i], tol) << "component " << i;
}

TEST(GoodScenes, CameraLookingDownPlusZIsTheWorldFrame) {
  SceneDescription s = load_good("camera.pbrt");
  const Camera& c = s.camera;
  EXPECT_EQ(c.type, "perspective");
  EXPECT_DOUBLE_EQ(c.fov_deg, 45.0);
  EXPECT_DOUBLE_EQ(c.lens_radius, 0.25);
  EXPECT_DOUBLE_EQ(c.focal_distance, 3.0);
  EXPECT_EQ(c.frame_aspect_ratio, 1.5);
  ASSERT_TRUE(c.screen_window.has_value());
  EXPECT_EQ(*c.screen_window, (std::array<double, 4>{-1.5, 1.5, -1, 1}));
  // pbrt-v4 LookAt (0,0,0)->(0,0,1), up +y: camera space == world space, so raster x (camera
  // +x) is world +x: the image's right side shows world +x (left-handed convention).
  EXPECT_TRUE(c.world_from_camera.is_identity());
  expect_near(c.world_from_camera.apply_vector({1, 0, 0}), {1, 0, 0});
  expect_near(c.world_from_camera.apply_vector({0, 1, 0}), {0, 1, 0});
  expect_near(c.world_from_camera.apply_vector({0, 0, 1}), {0, 0, 1});
  EXPECT_FALSE(c.world_from_camera.swaps_handedness());
  EXPECT_EQ(c.medium, -1);
  EXPECT_EQ(s.film.type, FilmType::kSpectral);
  EXPECT_EQ(s.film.x_resolution, 320);
  EXPECT_EQ(s.film.y_resolution, 240);
  EXPECT_EQ(s.film.filename, "out.exr");
  EXPECT_EQ(s.film.bins, 32);
  EXPECT_EQ(s.sampler.name, "halton");
  EXPECT_EQ(s.sampler.samples_per_pixel, 64);
  EXPECT_EQ(s.integrator.name, "volpath");
  EXPECT_EQ(s.integrator.max_depth, 12);
  ASSERT_EQ(s.shapes.size(), 1u);
  EXPECT_EQ(std::get<SphereShape>(s.shapes[0].geometry).radius, 1.0);
  // No light: pbrt-v4 warns that the image is black, so does Prism.
  EXPECT_EQ(s.warnings, (std::vector<std::string>{
                            "camera.pbrt: warning: the scene has no light that emits (LightSource "
                            "or AreaLightSource): the image is black"}));
  ASSERT_EQ(feature_warnings(s.features).size(), 1u);
  EXPECT_EQ(feature_warnings(s.features)[0],
            "camera.pbrt:8:9: warning: Sampler \"halton\" ignored: Prism uses its own sample "
            "sequence; 64 "
            "samples per "
            "pixel become the default spp");
  EXPECT_EQ(s.files, (std::vector<std::string>{"camera.pbrt"}));
}

TEST(GoodScenes, MirroredLookAtCameraAndCameraCoordinateSystem) {
  SceneDescription s = load_good("camera_moved.pbrt");
  const Transform& w = s.camera.world_from_camera;
  expect_near(w.apply_point({0, 0, 0}), {1, 2, 3});
  double l14 = std::sqrt(14.0);
  expect_near(w.apply_vector({0, 0, 1}), {-1 / l14, -2 / l14, -3 / l14});
  // right = normalize(cross(up, dir)) = (-3, 0, 1)/sqrt(10); `Scale -1 1 1` before LookAt
  // mirrors camera x, so raster x runs along world (3, 0, -1)/sqrt(10).
  double l10 = std::sqrt(10.0);
  expect_near(w.apply_vector({1, 0, 0}), {3 / l10, 0, -1 / l10});
  EXPECT_TRUE(w.swaps_handedness());
  ASSERT_EQ(s.shapes.size(), 1u);
  // CoordSysTransform "camera": the shape sits in camera space.
  expect_near(s.shapes[0].object_to_world.apply_point({0, 0, 0}), {1, 2, 3});
  EXPECT_TRUE(s.shapes[0].transform_swaps_handedness);
}

TEST(GoodScenes, TransformsComposeLikePbrt) {
  SceneDescription s = load_good("transforms.pbrt");
  ASSERT_EQ(s.shapes.size(), 8u);
  // Translate * Rotate * Scale: the scale applies first.
  expect_near(s.shapes[0].object_to_world.apply_point({1, 0, 0}), {1, 4, 3});
  EXPECT_TRUE(s.shapes[1].object_to_world.is_identity());
  expect_near(s.shapes[2].object_to_world.apply_point({1, 1, 1}), {7, 8, 9});
  EXPECT_FALSE(s.shapes[2].transform_swaps_handedness);
  EXPECT_TRUE(s.shapes[3].transform_swaps_handedness);
  EXPECT_TRUE(s.shapes[3].reverse_orientation);
  EXPECT_FALSE(s.shapes[4].reverse_orientation);
  EXPECT_EQ(s.shapes[4].object_to_world, s.shapes[2].object_to_world);
  EXPECT_TRUE(s.shapes[5].object_to_world.is_identity());
  expect_near(s.shapes[6].object_to_world.apply_point({0, 0, 0}), {0, 0, -1});
  EXPECT_TRUE(s.shapes[7].object_to_world.is_identity());
  // Normals use the inverse transpose.
  expect_near(s.shapes[2].object_to_world.apply_normal({0, 0, 1}), {0, 0, 0.5});
}

TEST(GoodScenes, Materials) {
  SceneDescription s = load_good("materials.pbrt");
  ASSERT_EQ(s.shapes.size(), 7u);
  ASSERT_EQ(s.materials.size(), 11u);
  auto material_of = [&](size_t shape) -> const Material& {
    return s.materials[static_cast<size_t>(s.shapes[shape].material)];
  };
  EXPECT_EQ(std::get<DiffuseMaterial>(material_of(0).kind).reflectance,
            SpectrumParam(SpectrumConstant{0.5}));
  EXPECT_EQ(std::get<DiffuseMaterial>(material_of(1).kind).reflectance,
            SpectrumParam(SpectrumRgb{0.1, 0.2, 0.3}));
  const auto& inline_table =
      std::get<SpectrumTabulated>(std::get<DiffuseMaterial>(material_of(2).kind).reflectance);
  EXPECT_EQ(inline_table.wavelengths_nm, (std::vector<double>{400, 500, 700}));
  EXPECT_EQ(inline_table.values, (std::vector<double>{0.1, 0.5, 0.9}));
  EXPECT_EQ(inline_table.source, "inline");
  const auto& file_table =
      std::get<SpectrumTabulated>(std::get<DiffuseMaterial>(material_of(3).kind).reflectance);
  EXPECT_EQ(file_table.source, "spectra/white.csv");
  EXPECT_EQ(file_table.wavelengths_nm, (std::vector<double>{400, 550, 700}));
  EXPECT_EQ(file_table.values, (std::vector<double>{0.5, 0.6, 0.7}));

  EXPECT_EQ(material_of(4).name, "glass");
  EXPECT_EQ(std::get<DielectricMaterial>(material_of(4).kind).eta, IorParam(IorNamed{"glass-BK7"}));
  EXPECT_EQ(material_of(5).name, "flint");
  const auto& flint = std::get<IorSellmeier>(std::get<DielectricMaterial>(material_of(5).kind).eta);
  EXPECT_EQ(flint.b, (std::array<double, 3>{1.73759695, 0.313747346, 1.89878101}));
  EXPECT_EQ(flint.c, (std::array<double, 3>{0.013188707, 0.0623068142, 155.23629}));
  const auto& copper = std::get<ConductorMaterial>(material_of(6).kind);
  EXPECT_EQ(copper.eta, SpectrumParam(SpectrumNamed{"metal-Cu-eta"}));
  EXPECT_EQ(copper.k, SpectrumParam(SpectrumNamed{"metal-Cu-k"}));
  EXPECT_FALSE(copper.reflectance.has_value());
  EXPECT_DOUBLE_EQ(copper.roughness.u, 0.05);

  auto named = [&](const std::string& name) -> const Material& {
    for (const Material& m : s.materials)
      if (m.name == name) return m;
    ADD_FAILURE() << name;
    return s.materials[0];
  };
  const auto& cauchy = std::get<DielectricMaterial>(named("cauchy").kind);
  EXPECT_EQ(cauchy.eta, IorParam(IorCauchy{{1.5046, 0.0042}}));
  EXPECT_DOUBLE_EQ(cauchy.roughness.u, 0.1);
  EXPECT_DOUBLE_EQ(cauchy.roughness.v, 0.1);
  EXPECT_FALSE(cauchy.roughness.remap);
  const auto& water = std::get<DielectricMaterial>(named("water").kind);
  EXPECT_EQ(water.eta, IorParam(IorConstant{1.33}));
  EXPECT_FALSE(is_dispersive(water.eta));
  EXPECT_TRUE(is_dispersive(cauchy.eta));
  EXPECT_DOUBLE_EQ(water.roughness.u, 0.2);
  EXPECT_DOUBLE_EQ(water.roughness.v, 0.3);
  EXPECT_TRUE(water.roughness.remap);
  EXPECT_EQ(std::get<ConductorMaterial>(named("gold-ish").kind).reflectance,
            std::optional<SpectrumParam>(SpectrumRgb{0.9, 0.7, 0.3}));
  EXPECT_TRUE(std::holds_alternative<InterfaceMaterial>(named("boundary").kind));
  EXPECT_EQ(s.files, (std::vector<std::string>{"materials.pbrt", "spectra/white.csv"}));
}

TEST(GoodScenes, TexturesCoatedMaterialsAndDisks) {
  SceneDescription s = load_good("textures.pbrt");
  ASSERT_EQ(s.textures.size(), 8u);
  auto texture = [&](const std::string& name) -> const Texture& {
    for (const Texture& t : s.textures)
      if (t.name == name) return t;
    ADD_FAILURE() << name;
    return s.textures[0];
  };
  const auto& checks = std::get<CheckerboardTexture>(texture("checks").kind);
  EXPECT_TRUE(texture("checks").spectrum);
  EXPECT_DOUBLE_EQ(checks.mapping.su, 4);
  EXPECT_DOUBLE_EQ(checks.mapping.sv, 2);
  EXPECT_EQ(checks.tex1.spectrum, SpectrumParam(SpectrumRgb{0.8, 0.8, 0.75}));
  EXPECT_EQ(checks.tex2.texture, -1);

  // 8-bit images are decoded by their encoding: sRGB by default, exactly pbrt-v4's curve.
  const auto& quad = std::get<ImageTexture>(texture("quad").kind);
  EXPECT_EQ(quad.filename, "textures/quad.png");
  EXPECT_EQ(quad.wrap, TextureWrap::kClamp);
  EXPECT_TRUE(quad.invert);
  EXPECT_DOUBLE_EQ(quad.scale, 0.5);
  ASSERT_EQ(quad.image->width, 2);
  ASSERT_EQ(quad.image->height, 2);
  ASSERT_EQ(quad.image->channels, 3);
  EXPECT_FLOAT_EQ(quad.image->values[0], 1.0f);  // top-left red
  EXPECT_FLOAT_EQ(quad.image->values[1], 0.0f);
  EXPECT_FLOAT_EQ(quad.image->values[9], float(std::pow((128 / 255.0 + 0.055) / 1.055, 2.4)));
  const auto& linear = std::get<ImageTexture>(texture("quad-linear").kind);
  EXPECT_FLOAT_EQ(linear.image->values[9], 128 / 255.0f);
  const auto& grey = std::get<ImageTexture>(texture("grey").kind);
  EXPECT_FALSE(texture("grey").spectrum);
  ASSERT_EQ(grey.image->channels, 1);
  EXPECT_FLOAT_EQ(grey.image->values[0], float(std::pow(64 / 255.0, 2.0)));

  const auto& scaled = std::get<ScaleTexture>(texture("scaled").kind);
  EXPECT_EQ(s.textures[size_t(scaled.tex.texture)].name, "quad");
  EXPECT_EQ(s.textures[size_t(scaled.scale.texture)].name, "half");
  const auto& mixed = std::get<MixTexture>(texture("mixed").kind);
  EXPECT_EQ(mixed.tex2.spectrum, SpectrumParam(SpectrumRgb{0.1, 0.2, 0.3}));
  EXPECT_EQ(s.textures[size_t(mixed.amount.texture)].name, "grey");
  // directionmix's dir is in the space current at the directive: Rotate 90 about x takes +y
  // to +z.
  expect_near(std::get<DirectionMixTexture>(texture("facing").kind).direction_world, {0, 0, 1});

  ASSERT_EQ(s.shapes.size(), 6u);
  // loopsubdiv: 8 · 4² triangles; its normals follow pbrt-v4, against the winding's side (the
  // octahedron's outside), so the geometric normals turn inwards as in pbrt-v4.
  const auto& subdivided = std::get<TriangleMeshShape>(s.shapes[5].geometry);
  EXPECT_EQ(subdivided.source, "loopsubdiv");
  EXPECT_EQ(subdivided.mesh->triangles.size(), 128u);
  ASSERT_EQ(subdivided.mesh->normals.size(), subdivided.mesh->positions.size());
  for (size_t i = 0; i < subdivided.mesh->positions.size(); ++i) {
    const Float3& p = subdivided.mesh->positions[i];
    const Float3& n = subdivided.mesh->normals[i];
    EXPECT_LT(p.x * n.x + p.y * n.y + p.z * n.z, 0.0f) << i;
  }
  // pbrt-v4 orders a cylinder's zmin and zmax.
  const auto& cylinder = std::get<CylinderShape>(s.shapes[4].geometry);
  EXPECT_DOUBLE_EQ(cylinder.radius, 0.5);
  EXPECT_DOUBLE_EQ(cylinder.z_min, -2);
  EXPECT_DOUBLE_EQ(cylinder.z_max, 1);
  const auto& disk = std::get<DiskShape>(s.shapes[0].geometry);
  EXPECT_DOUBLE_EQ(disk.radius, 2);
  EXPECT_DOUBLE_EQ(disk.inner_radius, 0.5);
  EXPECT_DOUBLE_EQ(disk.height, 0.25);
  const auto& diffuse = std::get<DiffuseMaterial>(s.materials[size_t(s.shapes[0].material)].kind);
  EXPECT_EQ(s.textures[size_t(diffuse.reflectance_texture)].name, "mixed");

  const auto& coated =
      std::get<CoatedDiffuseMaterial>(s.materials[size_t(s.shapes[1].material)].kind);
  EXPECT_EQ(s.textures[size_t(coated.reflectance_texture)].name, "facing");
  EXPECT_EQ(coated.eta, IorParam(IorConstant{1.5}));
  EXPECT_DOUBLE_EQ(coated.roughness.u, 0.1);
  EXPECT_DOUBLE_EQ(coated.layer.thickness, 0.02);
  EXPECT_EQ(coated.layer.albedo, SpectrumParam(SpectrumRgb{0.5, 0.4, 0.3}));
  EXPECT_DOUBLE_EQ(coated.layer.g, 0.2);
  EXPECT_EQ(coated.layer.max_depth, 5);
  EXPECT_EQ(coated.layer.samples, 2);
  const auto& metal =
      std::get<CoatedConductorMaterial>(s.materials[size_t(s.shapes[2].material)].kind);
  EXPECT_EQ(metal.interface_eta, IorParam(IorConstant{1.4}));
  EXPECT_DOUBLE_EQ(metal.interface_roughness.u, 0.05);
  EXPECT_EQ(metal.conductor_eta, SpectrumParam(SpectrumNamed{"metal-Au-eta"}));
  EXPECT_EQ(metal.k, SpectrumParam(SpectrumNamed{"metal-Au-k"}));
  EXPECT_DOUBLE_EQ(metal.conductor_roughness.u, 0.3);
  EXPECT_DOUBLE_EQ(metal.conductor_roughness.v, 0.2);
  EXPECT_EQ(metal.layer.max_depth, 10);  // pbrt-v4's defaults
  EXPECT_EQ(metal.layer.samples, 1);
  EXPECT_DOUBLE_EQ(metal.layer.thickness, 0.01);
  // Float textures in float slots: a textured roughness on one axis (the other given as a
  // number), a textured mix amount.
  const Material* textured = nullptr;
  for (const Material& m : s.materials) {
    if (const auto* c = std::get_if<ConductorMaterial>(&m.kind); c && m.name.empty()) {
      textured = &m;
    }
  }
  ASSERT_NE(textured, nullptr);
  const auto& conductor = std::get<ConductorMaterial>(textured->kind);
  EXPECT_EQ(s.textures[size_t(conductor.roughness.u_texture)].name, "grey");
  EXPECT_EQ(conductor.roughness.v_texture, -1);
  EXPECT_DOUBLE_EQ(conductor.roughness.v, 0.3);
  const auto& mix = std::get<MixMaterial>(s.materials[size_t(s.shapes[3].material)].kind);
  EXPECT_EQ(s.textures[size_t(mix.amount_texture)].name, "half");
  // A goniometric light is a point light with a grey image (8-bit sRGB decoded).
  ASSERT_EQ(s.lights.size(), 1u);
  const auto& gonio = std::get<PointLight>(s.lights[0].kind);
  ASSERT_NE(gonio.goniometric, nullptr);
  EXPECT_EQ(gonio.filename, "textures/grey.png");
  EXPECT_FLOAT_EQ(gonio.goniometric->values[0], float(std::pow((64 / 255.0 + 0.055) / 1.055, 2.4)));
  EXPECT_EQ(gonio.power, std::optional<double>(10));
  // Images are scene files: a bundle must carry them.
  EXPECT_EQ(s.files,
            (std::vector<std::string>{"textures.pbrt", "textures/quad.png", "textures/grey.png"}));
}

TEST(GoodScenes, LightsAreaLightsAndMedia) {
  SceneDescription s = load_good("lights.pbrt");
  ASSERT_EQ(s.lights.size(), 4u);
  const auto& point = std::get<PointLight>(s.lights[0].kind);
  EXPECT_EQ(point.intensity, SpectrumParam(SpectrumBlackbody{2700}));
  EXPECT_DOUBLE_EQ(point.scale, 2.0);
  expect_near(point.position_world, {1, 2, 3});
  const auto& spot = std::get<SpotLight>(s.lights[1].kind);
  EXPECT_EQ(spot.intensity, SpectrumParam(SpectrumNamed{"stdillum-F11"}));
  expect_near(spot.position_world, {10, 5, 0});
  expect_near(spot.direction_world, {0, -1, 0});
  EXPECT_DOUBLE_EQ(spot.cone_angle_deg, 20.0);
  EXPECT_DOUBLE_EQ(spot.cone_delta_angle_deg, 4.0);
  EXPECT_EQ(spot.power, 100.0);
  const auto& env = std::get<InfiniteLight>(s.lights[2].kind);
  EXPECT_EQ(env.radiance, SpectrumParam(SpectrumRgb{0.1, 0.2, 0.3}));
  EXPECT_DOUBLE_EQ(env.scale, 0.5);
  const auto& last = std::get<PointLight>(s.lights[3].kind);
  EXPECT_EQ(last.intensity, SpectrumParam(SpectrumNamed{"stdillum-D65"}));
  EXPECT_EQ(s.lights[3].medium, 0);
  EXPECT_EQ(s.lights[0].medium, -1);

  ASSERT_EQ(s.media.size(), 1u);
  EXPECT_EQ(s.media[0].name, "fog");
  const auto& fog = std::get<HomogeneousMedium>(s.media[0].kind);
  EXPECT_EQ(fog.sigma_a, SpectrumParam(SpectrumRgb{0.01, 0.02, 0.03}));
  EXPECT_EQ(std::get<SpectrumTabulated>(fog.sigma_s).values, (std::vector<double>{0.1, 0.2}));
  EXPECT_DOUBLE_EQ(fog.scale, 2.0);
  EXPECT_DOUBLE_EQ(fog.g, 0.3);

  ASSERT_EQ(s.shapes.size(), 2u);
  ASSERT_TRUE(s.shapes[0].area_light.has_value());
  const AreaLight& area = *s.shapes[0].area_light;
  EXPECT_EQ(area.radiance, SpectrumParam(SpectrumNamed{"stdillum-A"}));
  EXPECT_DOUBLE_EQ(area.scale, 4.0);
  EXPECT_TRUE(area.two_sided);
  EXPECT_EQ(area.power, 50.0);
  EXPECT_EQ(s.shapes[0].media.inside, 0);
  EXPECT_EQ(s.shapes[0].media.outside, -1);
  EXPECT_TRUE(s.shapes[0].media.is_transition());
  // AttributeEnd ended the area light and the medium interface.
  EXPECT_FALSE(s.shapes[1].area_light.has_value());
  EXPECT_EQ(s.shapes[1].media.inside, -1);
  EXPECT_EQ(s.shapes[1].media.outside, -1);
}

// pbrt-v4's geometric normal of triangle (p0, p1, p2): cross(p0 - p2, p1 - p2).
Vec3 triangle_normal(const TriangleMeshData& m, size_t t) {
  auto p = [&](size_t k) {
    const Float3& v = m.positions[m.triangles[t][k]];
    return Vec3{v.x, v.y, v.z};
  };
  Vec3 a = p(0), b = p(1), c = p(2);
  Vec3 e0{a[0] - c[0], a[1] - c[1], a[2] - c[2]};
  Vec3 e1{b[0] - c[0], b[1] - c[1], b[2] - c[2]};
  return {e0[1] * e1[2] - e0[2] * e1[1], e0[2] * e1[0] - e0[0] * e1[2],
          e0[0] * e1[1] - e0[1] * e1[0]};
}

TEST(GoodScenes, MeshesIncludesAndFiles) {
  SceneDescription s = load_good("meshes.pbrt");
  ASSERT_EQ(s.shapes.size(), 8u);
  auto mesh = [&](size_t i) -> const TriangleMeshShape& {
    return std::get<TriangleMeshShape>(s.shapes[i].geometry);
  };
  EXPECT_EQ(mesh(0).source, "trianglemesh");
  EXPECT_EQ(mesh(0).mesh->positions.size(), 4u);
  EXPECT_EQ(mesh(0).mesh->triangles.size(), 2u);
  EXPECT_EQ(mesh(0).mesh->normals.size(), 4u);
  EXPECT_EQ(mesh(0).mesh->uvs.size(), 4u);
  EXPECT_EQ(mesh(0).mesh->uvs[2], (Float2{1, 1}));
  EXPECT_EQ(mesh(1).mesh->triangles, (std::vector<Triangle>{{0, 1, 2}}));
  // Bilinear patch (p00, p10, p01, p11): two triangles facing like the patch normal (+z).
  EXPECT_EQ(mesh(2).source, "bilinearmesh");
  EXPECT_EQ(mesh(2).mesh->triangles, (std::vector<Triangle>{{0, 1, 3}, {0, 3, 2}}));
  EXPECT_EQ(mesh(2).mesh->patches, (std::vector<std::uint32_t>{0}));  // the two are one patch
  expect_near(triangle_normal(*mesh(2).mesh, 0), {0, 0, 1});
  expect_near(triangle_normal(*mesh(2).mesh, 1), {0, 0, 1});
  // Without uv, the patch's own (u, v) at its corners, as pbrt-v4 gives a bilinear patch (each
  // triangle's default (0,0) (1,0) (1,1) put a seam across a textured quad).
  EXPECT_EQ(mesh(2).mesh->uvs,
            (std::vector<Float2>{Float2{0, 0}, Float2{1, 0}, Float2{0, 1}, Float2{1, 1}}));
  EXPECT_EQ(mesh(3).source, "meshes/tri.obj");
  EXPECT_EQ(mesh(4).source, "meshes/quad.ply");
  EXPECT_EQ(mesh(4).mesh->triangles.size(), 2u);
  // From sub/part.pbrt: "meshes/tri.obj" (relative to the main file, as in pbrt-v4) is the same
  // file, loaded once.
  EXPECT_EQ(mesh(5).source, "meshes/tri.obj");
  EXPECT_EQ(mesh(5).mesh, mesh(3).mesh);
  expect_near(s.shapes[5].object_to_world.apply_point({0, 0, 0}), {0, 0, 5});
  EXPECT_EQ(mesh(6).source, "sub/local.obj");
  EXPECT_EQ(s.shapes[6].where.file, "sub/part.pbrt");
  EXPECT_EQ(s.shapes[6].where.line, 6);
  EXPECT_TRUE(s.shapes[7].object_to_world.is_identity());
  EXPECT_EQ(s.triangle_count(), 11u);
  EXPECT_EQ(s.files, (std::vector<std::string>{"meshes.pbrt", "meshes/tri.obj", "meshes/quad.ply",
                                               "sub/part.pbrt", "sub/local.obj"}));
}

// pbrt-v4 resolves every file name against the main scene file's directory (its search
// directory), whichever file names it: sub/a.inc's "b.inc" is the root's b.inc, not sub/b.inc.
TEST(GoodScenes, NestedIncludesNameFilesFromTheMainScenesDirectory) {
  const std::map<std::string, std::string> files = {
      {"sub/a.inc", "Include \"b.inc\"\nInclude \"sub/c.inc\"\n"},
      {"b.inc", "Shape \"sphere\" \"float radius\" 0.2\n"},
      {"sub/b.inc", "Shape \"sphere\" \"float radius\" 0.9\n"},
      {"sub/c.inc", "Shape \"sphere\" \"float radius\" 0.5\n"},
  };
  absl::StatusOr<SceneDescription> s =
      parse_scene_string("WorldBegin\nInclude \"sub/a.inc\"\n", "main.pbrt", {}, files);
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->shapes.size(), 2u);
  EXPECT_EQ(std::get<SphereShape>(s->shapes[0].geometry).radius, 0.2);
  EXPECT_EQ(std::get<SphereShape>(s->shapes[1].geometry).radius, 0.5);
  EXPECT_EQ(s->files, (std::vector<std::string>{"main.pbrt", "sub/a.inc", "b.inc", "sub/c.inc"}));
}

// Lights switched off (a zero radiance, intensity or scale) render black in pbrt-v4: they are
// left out, each recorded as ignored, and an area light's shape stays as plain geometry.
TEST(GoodScenes, LightsThatEmitNothingAreLeftOut) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "WorldBegin\n"
      "LightSource \"point\" \"rgb I\" [0 0 0]\n"
      "LightSource \"spot\" \"float scale\" 0\n"
      "LightSource \"distant\" \"float L\" 0\n"
      "LightSource \"point\" \"rgb I\" [0 0 1e-9]\n"
      "AttributeBegin\n"
      "  AreaLightSource \"diffuse\" \"rgb L\" [0 0 0]\n"
      "  Shape \"sphere\"\n"
      "AttributeEnd\n",
      "m.pbrt", {}, {});
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->lights.size(), 1u);  // the dim but lit point light
  EXPECT_EQ(s->lights[0].where.line, 5);
  ASSERT_EQ(s->shapes.size(), 1u);
  EXPECT_FALSE(s->shapes[0].area_light.has_value());
  int ignored = 0;
  for (const FeatureUse& f : s->features) {
    if (f.feature.find("emitting nothing") == std::string::npos) continue;
    EXPECT_EQ(f.status, FeatureStatus::kIgnored);
    ignored += f.uses;
  }
  EXPECT_EQ(ignored, 4);
}

// pbrt-v4 reads the deprecated TransformBegin/End as AttributeBegin/End: a material, reverse
// orientation or area light set inside is undone at TransformEnd (Prism restored only the
// transform, so every pbrt --upgrade'd v3 scene kept the inner material), and either end closes
// either begin.
TEST(GoodScenes, TransformBeginIsAttributeBeginAsInPbrtV4) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "WorldBegin\n"
      "Material \"diffuse\" \"rgb reflectance\" [0.1 0.1 0.9]\n"
      "TransformBegin\n"
      "  Material \"diffuse\" \"rgb reflectance\" [0.9 0.1 0.1]\n"
      "  ReverseOrientation\n"
      "  AreaLightSource \"diffuse\"\n"
      "  Translate 1 0 0\n"
      "  Shape \"sphere\"\n"
      "TransformEnd\n"
      "Shape \"sphere\"\n"
      "TransformBegin\n"
      "AttributeEnd\n"
      "AttributeBegin\n"
      "TransformEnd\n",
      "m.pbrt", {}, {});
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->shapes.size(), 2u);
  EXPECT_NE(s->shapes[0].material, s->shapes[1].material);
  EXPECT_EQ(s->shapes[1].material, 0);  // the blue one, set before the block
  EXPECT_TRUE(s->shapes[0].reverse_orientation);
  EXPECT_FALSE(s->shapes[1].reverse_orientation);
  EXPECT_TRUE(s->shapes[0].area_light.has_value());
  EXPECT_FALSE(s->shapes[1].area_light.has_value());
  // An unclosed one is named as written.
  absl::StatusOr<SceneDescription> open_block =
      parse_scene_string("WorldBegin\nLightSource \"point\"\nTransformBegin\n", "m.pbrt", {}, {});
  ASSERT_TRUE(open_block.ok()) << open_block.status();
  EXPECT_EQ(open_block->warnings,
            (std::vector<std::string>{"m.pbrt:3:1: warning: TransformBegin is never closed"}));
}

// pbrt-v4 resolves ObjectInstance after the whole scene is read: an instance may come before
// its ObjectBegin, and is placed by the transform where it stands.
TEST(GoodScenes, AnObjectMayBeInstancedBeforeItIsDefined) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "WorldBegin\n"
      "AttributeBegin\n"
      "  Translate 0 0 5\n"
      "  ObjectInstance \"later\"\n"
      "AttributeEnd\n"
      "ObjectBegin \"later\"\n"
      "  Shape \"sphere\"\n"
      "ObjectEnd\n"
      "ObjectInstance \"later\"\n",
      "m.pbrt", {}, {});
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->shapes.size(), 2u);
  std::vector<double> z;
  for (const Shape& shape : s->shapes) z.push_back(shape.object_to_world.apply_point({0, 0, 0})[2]);
  std::sort(z.begin(), z.end());
  EXPECT_EQ(z, (std::vector<double>{0, 5}));
}

// pbrt-v4 keeps two current transforms, at the shutter's open and close; ActiveTransform picks
// the ones transform directives change. What does not move renders, what moves is refused.
TEST(GoodScenes, ActiveTransformWithoutMotionRenders) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "ActiveTransform StartTime\n"
      "LookAt 0 0 -5  0 0 0  0 1 0\n"
      "ActiveTransform EndTime\n"
      "LookAt 0 0 -5  0 0 0  0 1 0\n"
      "ActiveTransform StartTime\n"  // WorldBegin makes both active again
      "Camera \"perspective\"\n"
      "WorldBegin\n"
      "Translate 1 0 0\n"  // both
      "AttributeBegin\n"
      "  ActiveTransform EndTime\n"
      "  Translate 0 2 0\n"
      "  ActiveTransform StartTime\n"
      "  Translate 0 2 0\n"
      "  ActiveTransform All\n"
      "  Shape \"sphere\"\n"
      "  CoordinateSystem \"here\"\n"
      "AttributeEnd\n"
      "Translate 0 0 3\n"
      "Shape \"sphere\"\n"
      "AttributeBegin\n"
      "  ActiveTransform EndTime\n"
      "  Translate 0 0 -9\n"  // the end transform only: the light moves
      "  LightSource \"point\"\n"
      "  CoordSysTransform \"here\"\n"  // sets both, whichever is active
      "  Shape \"sphere\"\n"
      "AttributeEnd\n"
      "Shape \"sphere\"\n",  // AttributeEnd restored the active transforms
      "m.pbrt", {}, {});
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->shapes.size(), 4u);
  expect_near(s->shapes[0].object_to_world.apply_point({0, 0, 0}), {1, 2, 0});
  expect_near(s->shapes[1].object_to_world.apply_point({0, 0, 0}), {1, 0, 3});
  expect_near(s->shapes[2].object_to_world.apply_point({0, 0, 0}), {1, 2, 0});
  expect_near(s->shapes[3].object_to_world.apply_point({0, 0, 0}), {1, 0, 3});
  ASSERT_EQ(s->lights.size(), 1u);
  // pbrt-v4 places a moving light by its start transform.
  const FeatureUse* moving = nullptr;
  for (const FeatureUse& f : s->features)
    if (f.feature == "moving LightSource") moving = &f;
  ASSERT_NE(moving, nullptr);
  EXPECT_EQ(moving->status, FeatureStatus::kSupported);
  EXPECT_EQ(moving->where.to_string(), "m.pbrt:23:3");
  EXPECT_EQ(count_features(s->features, FeatureStatus::kRefused), 0);
}

TEST(GoodScenes, MovingShapesInstancesAndCamerasAreRefusedWhereTheyAre) {
  const std::string moves =
      "WorldBegin\n"
      "ActiveTransform StartTime\n"
      "Rotate 10 0 1 0\n"
      "ActiveTransform All\n";
  struct Case {
    std::string text, error;
  } cases[] = {
      {moves + "Shape \"sphere\"\n",
       "m.pbrt:5:1: 'Shape' moves: its StartTime and EndTime transforms differ "
       "(ActiveTransform), and Prism does not render motion blur"},
      {"WorldBegin\nObjectBegin \"o\"\nShape \"sphere\"\nObjectEnd\n" + moves.substr(11) +
           "ObjectInstance \"o\"\n",
       "m.pbrt:8:1: 'ObjectInstance' moves"},
      {"ActiveTransform EndTime\nTranslate 0 0 1\nCamera \"perspective\"\nWorldBegin\n",
       "m.pbrt:3:1: 'Camera' moves"},
  };
  for (const Case& c : cases) {
    absl::StatusOr<SceneDescription> s = parse_scene_string(c.text, "m.pbrt", {}, {});
    ASSERT_FALSE(s.ok()) << c.text;
    EXPECT_TRUE(absl::StartsWith(s.status().message(), c.error)) << s.status();
    LoadOptions allow;
    allow.allow_unsupported = true;
    s = parse_scene_string(c.text, "m.pbrt", allow, {});
    ASSERT_TRUE(s.ok()) << s.status();
    EXPECT_EQ(count_features(s->features, FeatureStatus::kRefused), 1) << c.text;
  }
}

// A material or a shape's alpha may name a texture defined further on (pbrt-v4 resolves them
// once the scene is read); a texture may not (pbrt-v4 creates textures in order), and a name
// never defined, or defined as the other kind, is an error at its first use.
TEST(GoodScenes, TexturesNamedBeforeTheirDefinition) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "WorldBegin\n"
      "Material \"diffuse\" \"texture reflectance\" \"checks\"\n"
      "Shape \"sphere\" \"texture alpha\" \"cut\"\n"
      "Material \"diffuse\" \"texture reflectance\" \"checks\"\n"
      "Texture \"cut\" \"float\" \"constant\" \"float value\" 0.5\n"
      "Texture \"checks\" \"spectrum\" \"checkerboard\" \"texture tex1\" \"earlier\"\n"
      "Texture \"earlier\" \"spectrum\" \"constant\"\n",
      "m.pbrt", {}, {});
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.status().message(), "m.pbrt:6:44: spectrum texture \"earlier\" is not defined");

  s = parse_scene_string(
      "WorldBegin\n"
      "Material \"diffuse\" \"texture reflectance\" \"checks\"\n"
      "Shape \"sphere\" \"texture alpha\" \"cut\"\n"
      "Material \"diffuse\" \"texture reflectance\" \"checks\"\n"
      "Texture \"cut\" \"float\" \"constant\" \"float value\" 0.5\n"
      "Texture \"checks\" \"spectrum\" \"checkerboard\"\n",
      "m.pbrt", {}, {});
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->textures.size(), 2u);
  ASSERT_EQ(s->materials.size(), 2u);
  for (const Material& m : s->materials) {
    const int t = std::get<DiffuseMaterial>(m.kind).reflectance_texture;
    ASSERT_EQ(t, 0);
    EXPECT_TRUE(std::holds_alternative<CheckerboardTexture>(s->textures[size_t(t)].kind));
    EXPECT_EQ(s->textures[size_t(t)].where.line, 6);
  }
  ASSERT_EQ(s->shapes.size(), 1u);
  ASSERT_EQ(s->shapes[0].alpha_texture, 1);
  EXPECT_EQ(s->textures[1].name, "cut");

  s = parse_scene_string(
      "WorldBegin\n"
      "Material \"diffuse\" \"texture reflectance\" \"nowhere\"\n",
      "m.pbrt", {}, {});
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.status().message(),
            "m.pbrt:2:20: spectrum texture \"nowhere\" is not defined anywhere in the scene");
  s = parse_scene_string(
      "WorldBegin\n"
      "Material \"diffuse\" \"texture reflectance\" \"grey\"\n"
      "Texture \"grey\" \"float\" \"constant\"\n",
      "m.pbrt", {}, {});
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.status().message(),
            "m.pbrt:2:20: spectrum texture \"grey\" is not defined anywhere in the scene (the "
            "texture of that name at m.pbrt:3:1 is a float texture)");
}

// Exporters write pbrt-v4's default crop, the whole image, out: that is the image Prism renders,
// and it was refused. Any other crop still is.
TEST(GoodScenes, ACropOfTheWholeImageIsTheImage) {
  auto film = [](const std::string& crop) {
    return parse_scene_string(
        "Film \"rgb\" \"integer xresolution\" 48 \"integer yresolution\" 32 " + crop +
            "\nWorldBegin\n",
        "m.pbrt", {}, {});
  };
  for (const std::string& whole :
       {"\"float cropwindow\" [0 1 0 1]", "\"integer pixelbounds\" [0 48 0 32]",
        "\"float cropwindow\" [1 0 -0.1 1.1]"}) {  // ordered and clamped, as in pbrt-v4
    absl::StatusOr<SceneDescription> s = film(whole);
    ASSERT_TRUE(s.ok()) << whole << ": " << s.status();
    EXPECT_EQ(count_features(s->features, FeatureStatus::kIgnored), 1) << whole;
  }
  for (const std::string& crop :
       {"\"float cropwindow\" [0 0.5 0 1]", "\"integer pixelbounds\" [0 10 0 32]"}) {
    absl::StatusOr<SceneDescription> s = film(crop);
    ASSERT_FALSE(s.ok()) << crop;
    EXPECT_NE(s.status().message().find("a crop is not supported; Prism renders the whole image"),
              std::string::npos)
        << s.status();
  }
  absl::StatusOr<SceneDescription> three = film("\"float cropwindow\" [0 1 0]");
  ASSERT_FALSE(three.ok());
  EXPECT_NE(three.status().message().find("'cropwindow' needs 4 values (x0 x1 y0 y1), got 3"),
            std::string::npos)
      << three.status();
}

// A byte order mark before the first directive (a file saved by a Windows editor) is skipped,
// in the main file and in an included one; columns count from the text after it.
TEST(GoodScenes, AByteOrderMarkIsSkipped) {
  const std::map<std::string, std::string> files = {{"inc.pbrt", "\xEF\xBB\xBFShape \"sphere\"\n"}};
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "\xEF\xBB\xBFLookAt 0 0 -5  0 0 0  0 1 0\nWorldBegin\nInclude \"inc.pbrt\"\n", "m.pbrt", {},
      files);
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->shapes.size(), 1u);
  EXPECT_EQ(s->shapes[0].where.column, 1);
}

// pbrt-v4 reads Material "none" and Material "" as no material, a boundary between media.
TEST(GoodScenes, MaterialNoneIsAnInterface) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "WorldBegin\nMaterial \"none\"\nShape \"sphere\"\nMaterial \"\"\nShape \"sphere\"\n",
      "m.pbrt", {}, {});
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->shapes.size(), 2u);
  for (const Shape& shape : s->shapes) {
    EXPECT_TRUE(
        std::holds_alternative<InterfaceMaterial>(s->materials[std::size_t(shape.material)].kind));
  }
}

// pbrt-v4 resolves NamedMaterial when it builds the scene, so a material may be defined after
// the shapes that name it (an exporter writing geometry first), also through an instance.
TEST(GoodScenes, NamedMaterialsMayBeDefinedAfterTheirShapes) {
  absl::StatusOr<SceneDescription> s = parse_scene_string(
      "WorldBegin\n"
      "NamedMaterial \"late\"\n"
      "Shape \"sphere\"\n"
      "ObjectBegin \"o\"\nShape \"sphere\" \"float radius\" 2\nObjectEnd\n"
      "ObjectInstance \"o\"\n"
      "MakeNamedMaterial \"late\" \"string type\" \"conductor\"\n"
      "Shape \"sphere\" \"float radius\" 3\n",
      "m.pbrt", {}, {});
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ(s->shapes.size(), 3u);
  for (const Shape& shape : s->shapes) {
    ASSERT_GE(shape.material, 0);
    EXPECT_EQ(s->materials[std::size_t(shape.material)].name, "late");
  }
}

TEST(GoodScenes, ObjectInstancesAreFlattenedWithComposedTransforms) {
  SceneDescription s = load_good("instances.pbrt");
  ASSERT_EQ(s.shapes.size(), 4u);
  expect_near(s.shapes[0].object_to_world.apply_point({0, 0, 0}), {0, 10, 0});
  expect_near(s.shapes[1].object_to_world.apply_point({0, 0, 0}), {3, 10, 0});
  expect_near(s.shapes[3].object_to_world.apply_point({0, 0, 0}), {-3, 0, 0});
  EXPECT_FALSE(s.shapes[1].transform_swaps_handedness);
  EXPECT_TRUE(s.shapes[3].transform_swaps_handedness);
  EXPECT_EQ(std::get<TriangleMeshShape>(s.shapes[1].geometry).mesh,
            std::get<TriangleMeshShape>(s.shapes[3].geometry).mesh);
}

TEST(GoodScenes, AcceptedButChangedInputIsReportedAsWarnings) {
  SceneDescription s = load_good("warnings.pbrt");
  EXPECT_EQ(s.sampler.name, "stratified");
  EXPECT_EQ(s.sampler.samples_per_pixel, 15);
  EXPECT_EQ(s.integrator.name, "bdpt");
  EXPECT_EQ(s.integrator.max_depth, 7);
  // The pixel filter is pbrt-v4's, no longer ignored.
  EXPECT_EQ(s.filter.type, PixelFilterType::kGaussian);
  EXPECT_EQ(s.filter.x_radius, 1.5);
  EXPECT_EQ(s.filter.y_radius, 1.25);
  EXPECT_EQ(s.filter.sigma, 0.5);
  EXPECT_EQ(s.warnings,
            (std::vector<std::string>{"warnings.pbrt:7:1: warning: AttributeBegin is never closed",
                                      "warnings.pbrt: warning: the scene has no light that emits "
                                      "(LightSource or AreaLightSource): the image is black"}));
  EXPECT_EQ(feature_warnings(s.features),
            (std::vector<std::string>{
                "warnings.pbrt:1:9: warning: Sampler \"stratified\" ignored: Prism uses its own "
                "sample sequence; 15 samples per pixel become the default spp",
                "warnings.pbrt:2:12: warning: Integrator \"bdpt\" ignored: converges to the same "
                "image; rendered by Prism's spectral path tracer",
                "warnings.pbrt:2:40: warning: Integrator \"bdpt\" 'string lightsampler' ignored: "
                "integrator tuning does not change the converged image",
                "warnings.pbrt:4:8: warning: Option 'bool disablepixeljitter' ignored: false is "
                "pbrt-v4's default",
                "warnings.pbrt:5:1: warning: Accelerator \"bvh\" ignored: Prism always builds "
                "Embree's BVH; the image is the same",
            }));
}

// How pbrt-v4 stores its output does not change the image: accepted, and said.
TEST(GoodScenes, StorageOnlyFilmParametersAreAcceptedWithANote) {
  SceneDescription s = load_good("savefp16.pbrt");
  EXPECT_EQ(s.film.x_resolution, 16);
  EXPECT_EQ(feature_warnings(s.features),
            (std::vector<std::string>{"savefp16.pbrt:1:61: warning: Film \"rgb\" 'bool savefp16' "
                                      "ignored: Prism writes float32 EXRs (the image is the "
                                      "same)"}));
}

}  // namespace
}  // namespace prism::scene
