#include "services/scene/mesh_obj.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

namespace prism::scene {
namespace {

namespace fs = std::filesystem;

bool contains(absl::string_view haystack, std::string_view needle) {
  return haystack.find(absl::string_view(needle.data(), needle.size())) != absl::string_view::npos;
}

void expect_invalid(const std::string& text, std::string_view needle) {
  auto mesh = parse_obj(text, "test.obj");
  ASSERT_FALSE(mesh.ok()) << "accepted:\n" << text;
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument) << mesh.status();
  EXPECT_TRUE(contains(mesh.status().message(), needle)) << mesh.status() << "\nwanted: " << needle;
  EXPECT_TRUE(contains(mesh.status().message(), "test.obj")) << mesh.status();
}

// The mesh of a well-formed file (the test fails, and the mesh is empty, when it does not parse).
TriangleMeshData parsed(std::string_view text, std::string_view name) {
  auto mesh = parse_obj(text, name);
  EXPECT_TRUE(mesh.ok()) << mesh.status();
  return mesh.ok() ? *std::move(mesh) : TriangleMeshData();
}

// A unit cube: 8 positions, 6 face normals, 4 texture coordinates, 6 quads indexed per corner.
constexpr std::string_view kCube = R"(# cube
mtllib cube.mtl
o cube
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
vn 0 0 -1
vn 0 0 1
vn 0 -1 0
vn 0 1 0
vn -1 0 0
vn 1 0 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl white
f 1/1/1 4/2/1 3/3/1 2/4/1
f 5/1/2 6/2/2 7/3/2 8/4/2
f 1/1/3 2/2/3 6/3/3 5/4/3
g top
f 4/1/4 8/2/4 7/3/4 3/4/4
f 1/1/5 5/2/5 8/3/5 4/4/5
f 2/1/6 3/2/6 7/3/6 6/4/6
)";

TEST(ObjTest, SplitsQuadsAndBuildsOneVertexPerCornerTriple) {
  const TriangleMeshData mesh = parsed(std::string(kCube), "cube.obj");
  // Each cube corner appears on 3 faces with 3 different normals: 24 distinct triples.
  ASSERT_EQ(mesh.positions.size(), 24u);
  ASSERT_EQ(mesh.normals.size(), 24u);
  ASSERT_EQ(mesh.uvs.size(), 24u);
  ASSERT_EQ(mesh.triangles.size(), 12u);
  // First quad 1 4 3 2 -> (1 4 3) and (1 3 2), as new vertices 0..3.
  EXPECT_EQ(mesh.triangles[0], (Triangle{0, 1, 2}));
  EXPECT_EQ(mesh.triangles[1], (Triangle{0, 2, 3}));
  EXPECT_EQ(mesh.positions[1], (Float3{0, 1, 0}));
  EXPECT_EQ(mesh.uvs[2], (Float2{1, 1}));
  for (const Triangle& t : mesh.triangles) {
    // All three corners of a triangle share their face's normal.
    EXPECT_EQ(mesh.normals[t[0]], mesh.normals[t[1]]);
    EXPECT_EQ(mesh.normals[t[0]], mesh.normals[t[2]]);
  }
}

TEST(ObjTest, SharesVerticesUsedByMoreThanOneFace) {
  const TriangleMeshData mesh =
      parsed("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n", "two.obj");
  EXPECT_EQ(mesh.positions.size(), 4u);
  EXPECT_EQ(mesh.triangles, (std::vector<Triangle>{{0, 1, 2}, {0, 2, 3}}));
  EXPECT_TRUE(mesh.normals.empty());
  EXPECT_TRUE(mesh.uvs.empty());
}

TEST(ObjTest, FanTriangulatesLargerPolygonsAndResolvesRelativeIndices) {
  const TriangleMeshData mesh =
      parsed("v 0 0 0\nv 2 0 0\nv 3 1 0\nv 1 2 0\nv -1 1 0\nf -5 -4 -3 -2 -1\n", "pentagon.obj");
  EXPECT_EQ(mesh.triangles, (std::vector<Triangle>{{0, 1, 2}, {0, 2, 3}, {0, 3, 4}}));
  ASSERT_EQ(mesh.positions.size(), 5u);
  EXPECT_EQ(mesh.positions[4], (Float3{-1, 1, 0}));
}

TEST(ObjTest, DropsNormalsAndUvsUnlessEveryCornerHasThem) {
  const TriangleMeshData mesh = parsed(
      "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvt 0 0\n"
      "f 1/1/1 2/1/1 3/1/1\nf 2 4 3\n",
      "mixed.obj");
  EXPECT_TRUE(mesh.normals.empty());
  EXPECT_TRUE(mesh.uvs.empty());
  EXPECT_EQ(mesh.positions.size(), 4u);
}

TEST(ObjTest, IgnoresMaterialLibraries) {
  // The .mtl files are never opened, wherever they point.
  const TriangleMeshData mesh = parsed(
      "mtllib ../../../../etc/passwd /etc/shadow\nusemtl x\n"
      "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
      "mtl.obj");
  EXPECT_EQ(mesh.triangles.size(), 1u);
}

TEST(ObjTest, ReadsThePrismTestFile) {
  auto mesh = load_obj(PRISM_SOURCE_DIR "/services/scene/testdata/io/prism.obj");
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_EQ(mesh->positions.size(), 6u);
  EXPECT_EQ(mesh->triangles.size(), 8u);
  EXPECT_EQ(mesh->triangles[0], (Triangle{0, 1, 2}));
  EXPECT_EQ(mesh->positions[1], (Float3{0, 1.7320508075689f, -1}));
}

TEST(ObjTest, RefusesFilesWithoutFaces) {
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces");
  expect_invalid("v 0 0 0\nv 1 0 0\nl 1 2\n", "no faces");
  expect_invalid("", "no faces");
}

TEST(ObjTest, RefusesIndicesOutOfRange) {
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
                 "refers to a missing position (3 positions; its corner 3 names position 4)");
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n",
                 "missing position (3 positions; its corner 3 counts back past the first)");
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//2\n", "missing normal");
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n",
                 "missing texture coordinate");
}

TEST(ObjTest, RefusesDegenerateFaces) {
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\n", "fewer than 3 corners");
}

TEST(ObjTest, RefusesNonFiniteCoordinates) {
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1e39 0\nf 1 2 3\n", "non-finite position");
  // Values tinyobjloader would read as 0 without a word are refused with their line.
  expect_invalid("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n",
                 "line 3: 'nan' in a 'v' line is not a finite number");
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1e999 0\nf 1 2 3\n", "line 3: '1e999' in a 'v' line");
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1,5 0\nf 1 2 3\n", "line 3: '1,5' in a 'v' line");
  expect_invalid("# x\n\n  v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 inf\nf 1//1 2//1 3//1\n",
                 "line 6: 'inf' in a 'vn' line");
  expect_invalid("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 x\nf 1/1 2/1 3/1\n",
                 "line 4: 'x' in a 'vt' line");
  // Signs, exponents, vertex colours and CRLF line ends are numbers as usual.
  const TriangleMeshData mesh =
      parsed("v +0 -0.0 0\r\nv 1e0 0 0 0.5 0.5 0.5\r\nv 0 1.0E+0 0\r\nf 1 2 3\r\n", "ok.obj");
  ASSERT_EQ(mesh.positions.size(), 3u);
  EXPECT_EQ(mesh.positions[2], (Float3{0, 1, 0}));
}

TEST(ObjTest, LimitsAreResourceExhausted) {
  MeshLimits limits;
  limits.max_triangles = 11;
  auto mesh = parse_obj(std::string(kCube), "cube.obj", limits);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kResourceExhausted) << mesh.status();
  limits = MeshLimits{};
  limits.max_vertices = 23;
  mesh = parse_obj(std::string(kCube), "cube.obj", limits);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kResourceExhausted) << mesh.status();
  limits = MeshLimits{};
  limits.max_file_bytes = 10;
  mesh = parse_obj(std::string(kCube), "cube.obj", limits);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kResourceExhausted) << mesh.status();
}

TEST(ObjTest, LoadNamesTheFileInErrors) {
  fs::path dir = fs::temp_directory_path() /
                 ("prism_obj_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()));
  fs::create_directories(dir);
  fs::path file = dir / "broken.obj";
  std::ofstream(file) << "v 0 0 0\nf 1 1 2\n";
  auto mesh = load_obj(file);
  ASSERT_FALSE(mesh.ok());
  EXPECT_TRUE(contains(mesh.status().message(), file.string())) << mesh.status();
  EXPECT_EQ(load_obj(dir / "missing.obj").status().code(), absl::StatusCode::kNotFound);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace prism::scene
