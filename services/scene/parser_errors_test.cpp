// Malformed scenes under testdata/parser/bad/: each must fail with exactly this message,
// including its file:line:column.
#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <ostream>
#include <set>
#include <string>

#include "services/scene/scene_loader.h"

namespace prism::scene {
namespace {

struct BadCase {
  const char* file;
  absl::StatusCode code;
  const char* message;
};

// gtest prints the parameter of a failing or listed test; name the file instead of dumping bytes.
void PrintTo(const BadCase& c, std::ostream* os) {
  *os << c.file;
}

const BadCase kBadCases[] = {
    {"unknown_directive.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_directive.pbrt:3:3: unknown directive 'Frobnicate'"},
    {"unknown_shape.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_shape.pbrt:2:7: unknown shape type \"cone\" (pbrt-v4's: bilinearmesh, curve, "
     "cylinder, disk, loopsubdiv, plymesh, sphere, trianglemesh; Prism renders bilinearmesh, "
     "cylinder, disk, loopsubdiv, objmesh, plymesh, sphere, trianglemesh)"},
    {"unused_parameter.pbrt", absl::StatusCode::kInvalidArgument,
     "unused_parameter.pbrt:3:3: unused parameter 'float radiu'"},
    {"wrong_type_value.pbrt", absl::StatusCode::kInvalidArgument,
     "wrong_type_value.pbrt:1:34: expected a number for 'float fov', found string \"abc\""},
    {"wrong_count.pbrt", absl::StatusCode::kInvalidArgument,
     "wrong_count.pbrt:2:35: 'rgb L' needs 3 values, got 2 values"},
    {"wrong_declared_type.pbrt", absl::StatusCode::kInvalidArgument,
     "wrong_declared_type.pbrt:1:22: parameter 'fov' has type 'string', expected 'float'"},
    {"non_finite.pbrt", absl::StatusCode::kInvalidArgument,
     "non_finite.pbrt:2:31: value '1e999' of 'float radius' is not a finite number"},
    {"non_finite_nan.pbrt", absl::StatusCode::kInvalidArgument,
     "non_finite_nan.pbrt:2:13: value 'nan' of 'Translate' is not a finite number"},
    {"missing_mesh.pbrt", absl::StatusCode::kNotFound,
     "missing_mesh.pbrt:2:17: file \"missing.ply\" does not exist"},
    {"include_depth.pbrt", absl::StatusCode::kInvalidArgument,
     "include_depth.pbrt:1:1: 'Include' of \"include_depth.pbrt\" makes a cycle: "
     "include_depth.pbrt -> include_depth.pbrt"},
    {"include_escape.pbrt", absl::StatusCode::kInvalidArgument,
     "include_escape.pbrt:2:9: path \"../outside.pbrt\" escapes the scene directory"},
    {"absolute_path.pbrt", absl::StatusCode::kInvalidArgument,
     "absolute_path.pbrt:2:17: absolute path \"/etc/passwd\" refused: files must be named relative "
     "to the scene "
     "file"},
    {"unterminated_string.pbrt", absl::StatusCode::kInvalidArgument,
     "unterminated_string.pbrt:2:35: unterminated string"},
    {"unbalanced_attribute_end.pbrt", absl::StatusCode::kInvalidArgument,
     "unbalanced_attribute_end.pbrt:4:1: unmatched 'AttributeEnd' (no AttributeBegin is open)"},
    {"undefined_named_material.pbrt", absl::StatusCode::kInvalidArgument,
     "undefined_named_material.pbrt:2:15: named material \"nope\" is not defined anywhere in "
     "the scene"},
    {"lambdamin.pbrt", absl::StatusCode::kInvalidArgument,
     "lambdamin.pbrt:1:17: 'float lambdamin' must be 360 (Prism's spectral range is 360-830 nm), "
     "got 380"},
    {"resolution_too_large.pbrt", absl::StatusCode::kInvalidArgument,
     "resolution_too_large.pbrt:1:12: 'integer xresolution' must be between 1 and 16384, got "
     "20000"},
    {"unknown_named_spectrum.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_named_spectrum.pbrt:2:34: unknown named spectrum \"stdillum-F99\""},
    {"unknown_named_ior.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_named_ior.pbrt:2:38: unknown named spectrum \"glass-XYZ\""},
    {"unknown_filter.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_filter.pbrt:1:13: unsupported pixel filter type \"sinc\" (supported: box, gaussian, "
     "triangle, mitchell, lanczos)"},
    {"filter_parameter.pbrt", absl::StatusCode::kInvalidArgument,
     "filter_parameter.pbrt:1:24: unused parameter 'float radius'"},
    {"filter_radius.pbrt", absl::StatusCode::kInvalidArgument,
     "filter_radius.pbrt:1:24: 'float xradius' must be between 0.01 and 16 pixels, got 0"},
    {"unknown_material.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_material.pbrt:2:10: unknown material type \"plastic\" (pbrt-v4's: "
     "coatedconductor, coateddiffuse, conductor, dielectric, diffuse, diffusetransmission, hair, "
     "interface, measured, mix, subsurface, thindielectric; Prism renders coatedconductor, "
     "coateddiffuse, conductor, dielectric, diffuse, diffusetransmission, interface, mix, "
     "thindielectric)"},
    {"unknown_light.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_light.pbrt:2:13: unknown light type \"portal\" (pbrt-v4's: distant, goniometric, "
     "infinite, point, projection, spot; Prism renders distant, goniometric, infinite, point, "
     "projection, spot)"},
    {"unknown_camera.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_camera.pbrt:1:8: unsupported camera type \"realistic\" (supported: orthographic, "
     "perspective, spherical)"},
    {"unknown_medium.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_medium.pbrt:1:25: unknown medium type \"grid\" (pbrt-v4's: cloud, homogeneous, "
     "nanovdb, rgbgrid, uniformgrid; Prism renders homogeneous)"},
    {"undefined_medium.pbrt", absl::StatusCode::kInvalidArgument,
     "undefined_medium.pbrt:2:17: medium \"smoke\" is not defined"},
    {"partial_sphere.pbrt", absl::StatusCode::kInvalidArgument,
     "partial_sphere.pbrt:2:16: 'float zmin' is not supported (only full spheres: zmin <= "
     "-radius)"},
    {"infinite_image.pbrt", absl::StatusCode::kInvalidArgument,
     "infinite_image.pbrt:2:24: 'string filename' \"wide.png\" is 2x1; an equal-area "
     "environment map must be square"},
    {"shape_before_world.pbrt", absl::StatusCode::kInvalidArgument,
     "shape_before_world.pbrt:1:1: 'Shape' is only allowed after WorldBegin"},
    {"camera_after_world.pbrt", absl::StatusCode::kInvalidArgument,
     "camera_after_world.pbrt:2:1: 'Camera' is not allowed after WorldBegin"},
    {"missing_world.pbrt", absl::StatusCode::kInvalidArgument,
     "missing_world.pbrt:2:1: end of file before WorldBegin"},
    {"missing_spectrum_file.pbrt", absl::StatusCode::kNotFound,
     "missing_spectrum_file.pbrt:2:43: file \"spectra/missing.csv\" does not exist"},
    {"bad_spectrum_table.pbrt", absl::StatusCode::kInvalidArgument,
     "bad_table.csv:3:1: wavelengths must be positive and strictly increasing"},
    {"too_few_bins.pbrt", absl::StatusCode::kInvalidArgument,
     "too_few_bins.pbrt:1:17: 'integer nbuckets' must be between 4 and 256, got 2"},
    {"bad_index.pbrt", absl::StatusCode::kInvalidArgument,
     "bad_index.pbrt:2:53: 'integer indices' refers to vertex 3 but 'P' has 3 vertices"},
    {"film_sensor.pbrt", absl::StatusCode::kInvalidArgument,
     "film_sensor.pbrt:1:12: 'string sensor' \"canon_eos_5d\" is not supported (supported: "
     "cie1931)"},
    {"two_iors.pbrt", absl::StatusCode::kInvalidArgument,
     "two_iors.pbrt:2:39: 'float sellmeier' conflicts with another index of refraction (give one "
     "of eta, cauchy, "
     "sellmeier)"},
    {"portal_not_rectangle.pbrt", absl::StatusCode::kInvalidArgument,
     "portal_not_rectangle.pbrt:2:52: 'point3 portal' is not a rectangle (its corners p0, p1, p2, "
     "p3 must go around one, with p2 = p1 + p3 - p0 and a right angle at p0)"},
    {"portal_three_corners.pbrt", absl::StatusCode::kInvalidArgument,
     "portal_three_corners.pbrt:2:52: 'point3 portal' needs 4 points (the corners of a "
     "rectangle), got 3"},
    {"portal_constant.pbrt", absl::StatusCode::kInvalidArgument,
     "portal_constant.pbrt:2:40: 'point3 portal' needs an image 'filename' (pbrt-v4 has no "
     "portal for a constant 'L')"},
    {"texture.pbrt", absl::StatusCode::kInvalidArgument,
     "texture.pbrt:3:20: spectrum texture \"cheks\" is not defined anywhere in the scene"},
    {"texture_wrong_kind.pbrt", absl::StatusCode::kInvalidArgument,
     "texture_wrong_kind.pbrt:3:20: texture \"amount\" is a float texture; 'texture reflectance' "
     "needs a spectrum texture"},
    {"texture_coat_eta.pbrt", absl::StatusCode::kInvalidArgument,
     "texture_coat_eta.pbrt:3:26: 'texture eta': a coat's eta is a float or a spectrum, not a "
     "texture (pbrt-v4 rejects it too, as an unused parameter)"},
    {"texture_mapping.pbrt", absl::StatusCode::kInvalidArgument,
     "texture_mapping.pbrt:2:44: 'string mapping' \"spherical\" is not supported (supported: uv)"},
    {"texture_redefined.pbrt", absl::StatusCode::kInvalidArgument,
     "texture_redefined.pbrt:3:9: spectrum texture \"checks\" redefined (first at "
     "texture_redefined.pbrt:2:1)"},
    {"texture_missing_image.pbrt", absl::StatusCode::kNotFound,
     "texture_missing_image.pbrt:2:38: file \"wood.png\" does not exist"},
    {"texture_not_an_image.pbrt", absl::StatusCode::kInvalidArgument,
     "texture_not_an_image.pbrt:2:38: image \"not_an_image.png\": is neither a PNG nor an "
     "OpenEXR file (Prism reads those two formats)"},
    {"coat_rgb_eta.pbrt", absl::StatusCode::kInvalidArgument,
     "coat_rgb_eta.pbrt:2:26: 'rgb eta' cannot be an rgb value; use a float or a spectrum"},
    {"unterminated_bracket.pbrt", absl::StatusCode::kInvalidArgument,
     "unterminated_bracket.pbrt:2:38: unterminated '[' in the values of 'rgb reflectance'"},
    {"unknown_param_type.pbrt", absl::StatusCode::kInvalidArgument,
     "unknown_param_type.pbrt:2:16: unknown parameter type 'flaot' in \"flaot radius\""},
};

class BadSceneTest : public ::testing::TestWithParam<BadCase> {};

TEST_P(BadSceneTest, FailsWithExactMessage) {
  const BadCase& c = GetParam();
  std::filesystem::path dir =
      std::filesystem::path(PRISM_SOURCE_DIR) / "services/scene/testdata/parser/bad";
  LoadOptions options;
  // As the built-in library has them: metal η tables are spectra and IORs, k tables spectra only.
  std::set<std::string, std::less<>> spectra = {"stdillum-A", "stdillum-D65", "stdillum-F11",
                                                "metal-Cu-eta", "metal-Cu-k"};
  std::set<std::string, std::less<>> iors = {"glass-BK7", "glass-SF11", "metal-Cu-eta"};
  options.is_known_spectrum = [&](std::string_view n) { return spectra.contains(n); };
  options.is_known_ior = [&](std::string_view n) { return iors.contains(n); };
  absl::StatusOr<LoadedScene> scene = load_scene(dir / c.file, options);
  ASSERT_FALSE(scene.ok()) << c.file;
  EXPECT_EQ(scene.status().code(), c.code) << scene.status();
  EXPECT_EQ(std::string(scene.status().message()), c.message);
}

INSTANTIATE_TEST_SUITE_P(Corpus, BadSceneTest, ::testing::ValuesIn(kBadCases),
                         [](const ::testing::TestParamInfo<BadCase>& info) {
                           std::string name = info.param.file;
                           name = name.substr(0, name.find('.'));
                           return name;
                         });

TEST(BadSceneCorpus, EveryFileHasACase) {
  std::filesystem::path dir =
      std::filesystem::path(PRISM_SOURCE_DIR) / "services/scene/testdata/parser/bad";
  std::set<std::string> listed;
  for (const BadCase& c : kBadCases) listed.insert(c.file);
  for (const auto& e : std::filesystem::directory_iterator(dir))
    if (e.path().extension() == ".pbrt") {
      EXPECT_TRUE(listed.contains(e.path().filename().string())) << e.path();
    }
}

struct MemoryCase {
  const char* scene;
  const char* message;
};

// Directive-level errors, parsed from memory ("m.pbrt"; "a.pbrt" includes itself).
const MemoryCase kMemoryCases[] = {
    // A type pbrt-v4 does not know is a mistake even under --allow-unsupported; a float bound
    // and an empty list say what they are.
    {"MakeNamedMedium \"m\" \"string type\" \"wibble\"\n",
     "m.pbrt:1:21: unknown medium type \"wibble\" (pbrt-v4's: cloud, homogeneous, nanovdb, "
     "rgbgrid, uniformgrid; Prism renders homogeneous)"},
    {"Integrator \"wibble\"\n",
     "m.pbrt:1:12: unknown integrator type \"wibble\" (pbrt-v4's: ambientocclusion, aov, bdpt, "
     "function, lightpath, mlt, path, randomwalk, simplepath, simplevolpath, sppm, volpath; "
     "Prism renders bdpt, lightpath, mlt, path, randomwalk, simplepath, simplevolpath, sppm, "
     "volpath)"},
    {"Film \"wibble\"\n",
     "m.pbrt:1:6: unknown film type \"wibble\" (pbrt-v4's: gbuffer, rgb, spectral; Prism renders "
     "rgb, spectral)"},
    {"ColorSpace \"wibble\"\n",
     "m.pbrt:1:12: unknown colour space \"wibble\" (pbrt-v4's: srgb, rec2020, aces2065-1, dci-p3; "
     "Prism reads srgb)"},
    {"Accelerator \"wibble\"\n",
     "m.pbrt:1:13: unknown accelerator \"wibble\" (pbrt-v4's: bvh, kdtree; Prism always builds "
     "Embree's BVH)"},
    {"WorldBegin\nTexture \"t\" \"float\" \"wibble\"\n",
     "m.pbrt:2:21: unknown float texture type \"wibble\" (pbrt-v4's: bilerp, checkerboard, "
     "constant, directionmix, dots, fbm, imagemap, mix, ptex, scale, windy, wrinkled; Prism "
     "renders checkerboard, constant, directionmix, imagemap, mix, scale)"},
    {"WorldBegin\nShape \"sphere\" \"float radius\" [1e39]\n",
     "m.pbrt:2:16: 'float radius' must be at most 1e+30 (Prism computes in single precision), "
     "got 1e+39"},
    {"WorldBegin\nShape \"trianglemesh\" \"point3 P\" [] \"integer indices\" []\n",
     "m.pbrt:2:33: 'point3 P' needs at least one triple (3 values), got 0 values"},
    {"WorldBegin\nInclude \"a0.pbrt\"\n",
     "a15.pbrt:1:1: 'Include' nesting is deeper than 16 levels"},
    {"WorldBegin\nInclude \"a.pbrt\"\n",
     "b.pbrt:1:1: 'Include' of \"a.pbrt\" makes a cycle: a.pbrt -> b.pbrt -> a.pbrt"},
    {"Camera \"perspective\"\nCamera \"perspective\"\nWorldBegin\n",
     "m.pbrt:2:1: 'Camera' given twice (first at m.pbrt:1:1)"},
    {"WorldBegin\nWorldBegin\n", "m.pbrt:2:1: 'WorldBegin' given twice (first at m.pbrt:1:1)"},
    {"WorldBegin\nMakeNamedMaterial \"m\" \"string type\" \"diffuse\"\nMakeNamedMaterial \"m\" "
     "\"string type\" "
     "\"diffuse\"\n",
     "m.pbrt:3:19: named material \"m\" redefined (first at m.pbrt:2:1)"},
    {"WorldBegin\nMakeNamedMaterial \"m\" \"rgb reflectance\" [1 1 1]\n",
     "m.pbrt:2:1: 'MakeNamedMaterial' needs a 'string type' parameter"},
    {"WorldBegin\nObjectBegin \"o\"\nAreaLightSource \"diffuse\"\nShape \"sphere\"\n",
     "m.pbrt:4:1: area lights inside ObjectBegin/ObjectEnd are not supported"},
    {"WorldBegin\nObjectBegin \"o\"\nShape \"sphere\"\n",
     "m.pbrt:2:1: ObjectBegin \"o\" is never closed by ObjectEnd"},
    {"WorldBegin\nObjectEnd\n", "m.pbrt:2:1: unmatched 'ObjectEnd'"},
    {"WorldBegin\nObjectInstance \"o\"\n",
     "m.pbrt:2:16: object \"o\" is not defined anywhere in the scene"},
    {"WorldBegin\nObjectBegin \"o\"\nTransformEnd\n",
     "m.pbrt:3:1: 'TransformEnd' closes the ObjectBegin at m.pbrt:2:1"},
    {"WorldBegin\nMaterial \"diffuse\" \"rgb reflectance\" [0.5 1.5 0]\n",
     "m.pbrt:2:38: 'rgb reflectance' is a reflectance and has a component > 1"},
    {"WorldBegin\nMaterial \"conductor\" \"rgb reflectance\" [0.5 0.5 0] \"spectrum eta\" "
     "\"metal-Ag-eta\"\n",
     "m.pbrt:2:22: 'rgb reflectance' cannot be combined with eta or k"},
    {"WorldBegin\nShape \"trianglemesh\" \"integer indices\" [0 1 2]\n",
     "m.pbrt:2:7: \"trianglemesh\" needs 'point3 P'"},
    {"WorldBegin\nShape \"trianglemesh\" \"point3 P\" [0 0 0 1 0 0 0 1 0 1 1 1]\n",
     "m.pbrt:2:7: \"trianglemesh\" needs 'integer indices' (only a single triangle of 3 vertices "
     "may omit them)"},
    {"WorldBegin\nRotate 30 0 0 0\n", "m.pbrt:2:1: 'Rotate' needs a non-zero axis"},
    {"Transform [1 0 0 0 0 1 0 0 0 0 0 0 0 0 0 1]\nWorldBegin\n",
     "m.pbrt:1:1: 'Transform' matrix is singular"},
    {"WorldBegin\n\"oops\"\n", "m.pbrt:2:1: expected a directive, found string \"oops\""},
    {"LookAt 0 0 0 0 0 1 0 1\nWorldBegin\n",
     "m.pbrt:2:1: expected a number for 'LookAt', found 'WorldBegin'"},
    {"WorldBegin\nShape \"sphere\" \"float phimax\" 180\n",
     "m.pbrt:2:16: 'float phimax' is not supported (only full spheres: phimax >= 360)"},
    {"WorldBegin\nCoordSysTransform \"lamp\"\n",
     "m.pbrt:2:19: coordinate system \"lamp\" is not defined"},
    {"WorldBegin\nMaterial \"dielectric\" \"rgb eta\" [1.5 1.5 1.5]\n",
     "m.pbrt:2:23: 'rgb eta' cannot be an rgb value; use a float or a spectrum"},
    {"WorldBegin\nMaterial \"dielectric\" \"float sellmeier\" [1 2 3]\n",
     "m.pbrt:2:23: 'float sellmeier' needs 6 coefficients [B1 B2 B3 C1 C2 C3] (C in um^2), got 3"},
    {"WorldBegin\nMaterial \"diffuse\" \"texture reflectance\" \"checks\"\n",
     "m.pbrt:2:20: spectrum texture \"checks\" is not defined anywhere in the scene"},
    {"WorldBegin\nActiveTransform EndTime\nTranslate 0 0 1\nShape \"sphere\"\n",
     "m.pbrt:4:1: 'Shape' moves: its StartTime and EndTime transforms differ (ActiveTransform), "
     "and Prism does not render motion blur"},
    {"WorldBegin\nLightSource \"spot\" \"float coneangle\" 10 \"float conedeltaangle\" 20\n",
     "m.pbrt:2:41: 'float conedeltaangle' must be between 0 and coneangle, got 20"},
    {"MakeNamedMedium \"m\" \"string type\" \"homogeneous\" \"float g\" 1\nWorldBegin\n",
     "m.pbrt:1:49: 'float g' must be in (-1, 1), got 1"},
    {"WorldBegin\nAttributeBegin\n  ReverseOrientation\nAttributeEnd\nShape \"sphere\" \"float "
     "radius\" -1\n",
     "m.pbrt:5:16: 'float radius' must be > 0, got -1"},
    {"WorldBegin\nLightSource \"point\" \"float scale\" -1\n",
     "m.pbrt:2:21: 'float scale' must be >= 0, got -1"},
    {"WorldBegin\nAreaLightSource \"diffuse\" \"float scale\" -2\nShape \"sphere\"\n",
     "m.pbrt:2:27: 'float scale' must be >= 0, got -2"},
    {"Sampler \"stratified\" \"bool jitter\" false\nWorldBegin\n",
     "m.pbrt:1:22: 'bool jitter' false samples fixed positions in each pixel, which changes the "
     "image; Prism jitters every sample"},
    {"MakeNamedMedium \"m\" \"string type\" \"homogeneous\" \"rgb Le\" [0 0 1]\nWorldBegin\n",
     "m.pbrt:1:49: 'rgb Le': emissive media are not supported"},
    // Image formats pbrt-v4 reads and Prism does not are a refusal, not "not a PNG".
    {"WorldBegin\nTexture \"t\" \"spectrum\" \"imagemap\" \"string filename\" \"wood.JPG\"\n",
     "m.pbrt:2:35: image \"wood.JPG\": Prism reads PNG and OpenEXR textures, not jpg (convert it "
     "to PNG or EXR)"},
    // pbrt-v4 scales its image by the shutter interval's length (the exposure time).
    {"Camera \"perspective\" \"float shutteropen\" 0 \"float shutterclose\" 0.5\nWorldBegin\n",
     "m.pbrt:1:44: 'float shutterclose' makes an exposure time of 0.5, by which pbrt-v4 scales "
     "the image; Prism renders an exposure of 1"},
    {"Camera \"perspective\" \"float shutteropen\" 2 \"float shutterclose\" 2\nWorldBegin\n",
     "m.pbrt:1:44: 'float shutterclose' gives an empty shutter interval (2 to 2): pbrt-v4's "
     "exposure time would be 0"},
    // Coordinates Embree's rays cannot carry (services/scene/coordinate_range.h): a shape far
    // away, a shape scaled down so far that the scene lands there in its own space, the camera.
    {"WorldBegin\nShape \"sphere\"\nTranslate 1e30 0 0\nShape \"sphere\"\n",
     "m.pbrt:4:1: the shape reaches coordinates of 1e+30, beyond the 1e+16 that Prism's ray "
     "tracer (Embree) can carry: move it closer or scale the scene down"},
    {"WorldBegin\nLightSource \"point\" \"point3 from\" [0 3 0]\nScale 1e-30 1e-30 1e-30\n"
     "Shape \"sphere\"\n",
     "m.pbrt:4:1: the shape's transform maps the scene (within 3 of the origin) to coordinates of "
     "3e+30 in the shape's own space, beyond the 1e+16 that Prism's ray tracer (Embree) can "
     "carry: is the shape scaled down by a huge factor?"},
    {"LookAt 1e30 0 0  0 0 0  0 1 0\nCamera \"perspective\"\nWorldBegin\n",
     "m.pbrt:2:8: the camera reaches coordinates of 1e+30, beyond the 1e+16 that Prism's ray "
     "tracer (Embree) can carry: move it closer or scale the scene down"},
    {"WorldBegin\nTranslate 0 -1e20 0\nLightSource \"point\"\n",
     "m.pbrt:3:1: the light reaches coordinates of 1e+20, beyond the 1e+16 that Prism's ray "
     "tracer (Embree) can carry: move it closer or scale the scene down"},
};

TEST(MemoryErrors, ExactMessages) {
  // A chain of 20 distinct files (the depth limit), and a cycle through two.
  std::map<std::string, std::string> files = {{"a.pbrt", "Include \"b.pbrt\"\n"},
                                              {"b.pbrt", "Include \"a.pbrt\"\n"}};
  for (int i = 0; i < 20; ++i) {
    files["a" + std::to_string(i) + ".pbrt"] = "Include \"a" + std::to_string(i + 1) + ".pbrt\"\n";
  }
  for (const MemoryCase& c : kMemoryCases) {
    absl::StatusOr<SceneDescription> s = parse_scene_string(c.scene, "m.pbrt", {}, files);
    ASSERT_FALSE(s.ok()) << c.scene;
    EXPECT_EQ(std::string(s.status().message()), c.message) << c.scene;
  }
}

// Just inside the range: a shape 1e15 away, and one scaled by 1e-15 in a scene of a few units;
// and a shutter interval of length 1, reversed (pbrt-v4 swaps it), which is Prism's exposure.
TEST(MemoryErrors, ScenesWithinTheCoordinateRangeLoad) {
  for (const char* scene :
       {"Camera \"perspective\" \"float shutteropen\" 1.5 \"float shutterclose\" 0.5\n"
        "WorldBegin\n",
        "WorldBegin\nShape \"sphere\"\nTranslate 1e15 0 0\nShape \"sphere\"\n",
        "WorldBegin\nLightSource \"point\" \"point3 from\" [0 3 0]\nScale 1e-15 1e-15 1e-15\n"
        "Shape \"sphere\"\n",
        // Inputs that cannot change the image: a medium's zero emission (an exporter's default),
        // a stratified sampler's default jitter.
        "MakeNamedMedium \"m\" \"string type\" \"homogeneous\" \"rgb Le\" [0 0 0] "
        "\"float Lescale\" 2\nSampler \"stratified\" \"bool jitter\" true\nWorldBegin\n"}) {
    absl::StatusOr<SceneDescription> s = parse_scene_string(scene, "m.pbrt", {}, {});
    EXPECT_TRUE(s.ok()) << scene << ": " << s.status();
  }
}

}  // namespace
}  // namespace prism::scene
