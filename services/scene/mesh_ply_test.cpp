#include "services/scene/mesh_ply.h"

#include <gtest/gtest.h>

#include <bit>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace prism::scene {
namespace {

enum class PlyFormat { kAscii, kLittleEndian, kBigEndian };

// Writes PLY files for tests: header lines as given, body values in the chosen encoding.
class PlyWriter {
 public:
  explicit PlyWriter(PlyFormat format) : format_(format) {
    static constexpr const char* kNames[] = {"ascii", "binary_little_endian", "binary_big_endian"};
    header_ = std::string("ply\nformat ") + kNames[static_cast<int>(format)] + " 1.0\n";
  }

  PlyWriter& line(std::string_view text) {
    header_.append(text);
    header_.push_back('\n');
    return *this;
  }

  template <typename T>
  PlyWriter& put(T value) {
    if (format_ == PlyFormat::kAscii) {
      char text[64];
      if constexpr (std::is_floating_point_v<T>) {
        std::snprintf(text, sizeof text, "%.17g ", static_cast<double>(value));
      } else {
        std::snprintf(text, sizeof text, "%lld ", static_cast<long long>(value));
      }
      body_ += text;
      return *this;
    }
    unsigned char raw[sizeof(T)];
    std::memcpy(raw, &value, sizeof(T));
    bool big = format_ == PlyFormat::kBigEndian;
    if (big != (std::endian::native == std::endian::big)) std::reverse(raw, raw + sizeof(T));
    body_.append(reinterpret_cast<const char*>(raw), sizeof(T));
    return *this;
  }

  PlyWriter& end_item() {
    if (format_ == PlyFormat::kAscii) body_ += "\n";
    return *this;
  }

  std::string str() const { return header_ + "end_header\n" + body_; }
  std::size_t header_size() const { return header_.size() + std::strlen("end_header\n"); }

 private:
  PlyFormat format_;
  std::string header_;
  std::string body_;
};

// Five vertices with normals, uvs and properties to skip; an element to skip between vertices
// and faces; a quad and a triangle with properties to skip around the index list.
PlyWriter sample_ply(PlyFormat format) {
  PlyWriter w(format);
  w.line("comment written by mesh_ply_test")
      .line("obj_info nothing to see")
      .line("element vertex 5")
      .line("property float x")
      .line("property float y")
      .line("property float z")
      .line("property double confidence")
      .line("property float nx")
      .line("property float ny")
      .line("property float nz")
      .line("property uchar red")
      .line("property list uchar int extra_list")
      .line("property float u")
      .line("property float v")
      .line("element edge 2")
      .line("property int vertex1")
      .line("property int32 vertex2")
      .line("property list ushort float64 weights")
      .line("element face 2")
      .line("property uint8 flags")
      .line("property list uchar int vertex_indices")
      .line("property list int double junk")
      .line("element material 1")
      .line("property int16 id")
      .line("property char tag");
  const float p[5][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {2, 0.5f, -0.25f}};
  for (int i = 0; i < 5; ++i) {
    w.put(p[i][0]).put(p[i][1]).put(p[i][2]).put(0.75 * i);
    w.put(0.0f).put(0.0f).put(i % 2 ? 1.0f : -1.0f);
    w.put(std::uint8_t(200 + i));
    w.put(std::uint8_t(i % 3));
    for (int k = 0; k < i % 3; ++k) w.put(std::int32_t(-k));
    w.put(0.125f * i).put(1.0f - 0.25f * i);
    w.end_item();
  }
  w.put(std::int32_t(0)).put(std::int32_t(1)).put(std::uint16_t(2)).put(0.5).put(0.25).end_item();
  w.put(std::int32_t(1)).put(std::int32_t(2)).put(std::uint16_t(0)).end_item();
  w.put(std::uint8_t(7)).put(std::uint8_t(4));
  for (std::int32_t i : {0, 1, 2, 3}) w.put(i);
  w.put(std::int32_t(1)).put(3.5).end_item();
  w.put(std::uint8_t(9)).put(std::uint8_t(3));
  for (std::int32_t i : {1, 4, 2}) w.put(i);
  w.put(std::int32_t(0)).end_item();
  w.put(std::int16_t(-3)).put(std::int8_t(-100)).end_item();
  return w;
}

TriangleMeshData expected_sample() {
  TriangleMeshData mesh;
  mesh.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {2, 0.5f, -0.25f}};
  mesh.normals = {{0, 0, -1}, {0, 0, 1}, {0, 0, -1}, {0, 0, 1}, {0, 0, -1}};
  mesh.uvs = {{0, 1}, {0.125f, 0.75f}, {0.25f, 0.5f}, {0.375f, 0.25f}, {0.5f, 0}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}, {1, 4, 2}};
  mesh.patches = {0};  // the quad (0, 1, 2, 3)
  return mesh;
}

bool contains(absl::string_view haystack, std::string_view needle) {
  return haystack.find(absl::string_view(needle.data(), needle.size())) != absl::string_view::npos;
}

// Expects INVALID_ARGUMENT mentioning `needle`.
void expect_invalid(const std::string& bytes, std::string_view needle,
                    const MeshLimits& limits = {}) {
  auto mesh = parse_ply(bytes, "test.ply", limits);
  ASSERT_FALSE(mesh.ok()) << "accepted:\n" << bytes.substr(0, 400);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument) << mesh.status();
  EXPECT_TRUE(contains(mesh.status().message(), needle)) << mesh.status() << "\nwanted: " << needle;
  EXPECT_TRUE(contains(mesh.status().message(), "test.ply")) << mesh.status();
}

std::string header_only(std::string_view body_of_header) {
  return "ply\nformat ascii 1.0\n" + std::string(body_of_header) + "end_header\n";
}

TEST(PlyTest, AsciiAndBothBinaryEncodingsGiveTheSameMesh) {
  for (PlyFormat format : {PlyFormat::kAscii, PlyFormat::kLittleEndian, PlyFormat::kBigEndian}) {
    auto mesh = parse_ply(sample_ply(format).str(), "sample.ply");
    ASSERT_TRUE(mesh.ok()) << static_cast<int>(format) << ": " << mesh.status();
    EXPECT_EQ(*mesh, expected_sample()) << static_cast<int>(format);
  }
}

// A quad (c0, c1, c2, c3) is pbrt-v4's bilinear patch p00 = c0, p10 = c1, p11 = c2, p01 = c3:
// two triangles listed as a patch (scene::TriangleMeshData::patches).
TEST(PlyTest, QuadsAreSplitIntoTwoTrianglesListedAsAPatch) {
  PlyWriter w(PlyFormat::kLittleEndian);
  w.line("element vertex 4").line("property float x").line("property float y");
  w.line("property float z").line("element face 1").line("property list uchar uint vertex_indices");
  for (int i = 0; i < 4; ++i) w.put(float(i & 1)).put(float(i >> 1)).put(0.0f);
  w.put(std::uint8_t(4)).put(std::uint32_t(0)).put(std::uint32_t(1)).put(std::uint32_t(3));
  w.put(std::uint32_t(2));
  auto mesh = parse_ply(w.str(), "quad.ply");
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_EQ(mesh->triangles, (std::vector<Triangle>{{0, 1, 3}, {0, 3, 2}}));
  EXPECT_EQ(mesh->patches, (std::vector<std::uint32_t>{0}));
  EXPECT_TRUE(mesh->normals.empty());
  EXPECT_TRUE(mesh->uvs.empty());
}

TEST(PlyTest, RecognisesTextureCoordinateNames) {
  for (auto [u, v] : {std::pair{"s", "t"}, std::pair{"texture_u", "texture_v"},
                      std::pair{"texture_s", "texture_t"}}) {
    PlyWriter w(PlyFormat::kAscii);
    w.line("element vertex 3").line("property float x").line("property float y");
    w.line("property float z").line(std::string("property float ") + u);
    w.line(std::string("property float ") + v);
    w.line("element face 1").line("property list uchar int vertex_index");
    for (int i = 0; i < 3; ++i)
      w.put(float(i)).put(0.0f).put(0.0f).put(0.5f * i).put(0.25f).end_item();
    w.put(3).put(0).put(1).put(2).end_item();
    auto mesh = parse_ply(w.str(), "uv.ply");
    ASSERT_TRUE(mesh.ok()) << u << ": " << mesh.status();
    EXPECT_EQ(mesh->uvs, (std::vector<Float2>{{0, 0.25f}, {0.5f, 0.25f}, {1, 0.25f}})) << u;
  }
}

TEST(PlyTest, IncompleteNormalsAreIgnored) {
  PlyWriter w(PlyFormat::kAscii);
  w.line("element vertex 3").line("property float x").line("property float y");
  w.line("property float z").line("property float nx").line("property float ny");
  w.line("element face 1").line("property list uchar int vertex_indices");
  for (int i = 0; i < 3; ++i)
    w.put(float(i)).put(float(i * i)).put(0.0f).put(1.0f).put(0.0f).end_item();
  w.put(3).put(0).put(1).put(2).end_item();
  auto mesh = parse_ply(w.str(), "n.ply");
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_TRUE(mesh->normals.empty());
  EXPECT_EQ(mesh->positions[2], (Float3{2, 4, 0}));
}

template <typename Count, typename Index>
std::string faces_with_types(PlyFormat format, std::string_view count_name,
                             std::string_view index_name) {
  PlyWriter w(format);
  w.line("element vertex 4").line("property double x").line("property short y");
  w.line("property uchar z").line("element face 2");
  w.line("property list " + std::string(count_name) + " " + std::string(index_name) +
         " vertex_indices");
  for (int i = 0; i < 4; ++i)
    w.put(double(i)).put(std::int16_t(-i)).put(std::uint8_t(i)).end_item();
  w.put(Count(3)).put(Index(0)).put(Index(1)).put(Index(2)).end_item();
  w.put(Count(3)).put(Index(3)).put(Index(2)).put(Index(1)).end_item();
  return w.str();
}

TEST(PlyTest, AcceptsEveryIntegerTypeForFaceLists) {
  for (PlyFormat format : {PlyFormat::kAscii, PlyFormat::kLittleEndian, PlyFormat::kBigEndian}) {
    std::vector<std::string> files = {
        faces_with_types<std::uint8_t, std::int8_t>(format, "uchar", "char"),
        faces_with_types<std::int8_t, std::uint8_t>(format, "int8", "uint8"),
        faces_with_types<std::uint16_t, std::int16_t>(format, "ushort", "short"),
        faces_with_types<std::int16_t, std::uint16_t>(format, "int16", "uint16"),
        faces_with_types<std::uint32_t, std::int32_t>(format, "uint", "int"),
        faces_with_types<std::int32_t, std::uint32_t>(format, "int32", "uint32"),
    };
    for (const std::string& file : files) {
      auto mesh = parse_ply(file, "types.ply");
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      EXPECT_EQ(mesh->triangles, (std::vector<Triangle>{{0, 1, 2}, {3, 2, 1}}));
      EXPECT_EQ(mesh->positions[3], (Float3{3, -3, 3}));
    }
  }
}

TEST(PlyTest, ReadsTheLowResolutionBunny) {
  auto mesh = load_ply(PRISM_SOURCE_DIR "/services/scene/testdata/io/stanford_bunny_lowres.ply");
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_EQ(mesh->positions.size(), 453u);
  EXPECT_EQ(mesh->triangles.size(), 948u);
  EXPECT_TRUE(mesh->normals.empty());
  EXPECT_NEAR(mesh->positions[0].x, -0.0312216f, 1e-7f);
}

TEST(PlyTest, LoadReportsMissingFile) {
  auto mesh = load_ply("/nonexistent/prism/mesh.ply");
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kNotFound);
}

TEST(PlyTest, LoadRefusesFilesOverTheSizeLimit) {
  MeshLimits limits;
  limits.max_file_bytes = 1000;
  auto mesh =
      load_ply(PRISM_SOURCE_DIR "/services/scene/testdata/io/stanford_bunny_lowres.ply", limits);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kResourceExhausted) << mesh.status();
}

TEST(PlyTest, RefusesMalformedHeaders) {
  expect_invalid("", "not a PLY file");
  expect_invalid("PLY\nformat ascii 1.0\nend_header\n", "not a PLY file");
  expect_invalid("ply\nformat binary_middle_endian 1.0\nend_header\n",
                 "unknown PLY format 'binary_middle_endian'");
  expect_invalid("ply\nformat ascii 2.0\nend_header\n", "unsupported PLY version");
  expect_invalid("ply\nformat ascii 1.0\nelement vertex 3\n", "without 'end_header'");
  expect_invalid("ply\nelement vertex 0\nend_header\n", "no 'format' line");
  expect_invalid(header_only("property float x\n"), ":3: 'property' before any 'element'");
  expect_invalid(header_only("element vertex 1\nproperty float3 x\n"),
                 "unknown property type 'float3'");
  expect_invalid(header_only("element vertex 1\nproperty list float int x\n"),
                 "list count type must be an integer");
  expect_invalid(header_only("element vertex -5\n"), "bad element count '-5'");
  expect_invalid(header_only("element vertex 12abc\n"), "bad element count");
  expect_invalid(header_only("element vertex 99999999999999999999999\n"), "bad element count");
  expect_invalid(header_only("element vertex 1\nelement vertex 2\n"), "declared twice");
  expect_invalid(header_only("element vertex 1\nproperty float x\nproperty float x\n"),
                 "declared twice");
  expect_invalid(header_only("element vertex 1 2 3 4 5 6 7\n"),
                 "expected 'element <name> <count>'");
  std::string long_line = "element vertex 1\nproperty float x";
  for (int i = 0; i < 200000; ++i) long_line += " y";
  expect_invalid(header_only(long_line + "\n"), "expected 'property <type> <name>'");
  expect_invalid(header_only("elephant vertex 1\n"), ":3: unknown header keyword 'elephant'");
  expect_invalid(header_only("element vertex 1\nproperty float x\n"),
                 "needs scalar properties x, y and z");
  expect_invalid(header_only("element vertex 1\nproperty float x\nproperty float y\n"
                             "property float z\n"),
                 "no 'face' element");
  expect_invalid(header_only("element face 1\nproperty list uchar int vertex_indices\n"),
                 "no 'vertex' element");
  expect_invalid(header_only("element vertex 0\nproperty float x\nproperty float y\n"
                             "property float z\nelement face 0\nproperty list uchar float "
                             "vertex_indices\n"),
                 "integer type");
  expect_invalid(header_only("element vertex 0\nproperty float x\nproperty float y\n"
                             "property float z\nelement face 0\nproperty int vertex_indices\n"),
                 "must be a list");
  expect_invalid(header_only("element vertex 0\nproperty float x\nproperty float y\n"
                             "property float z\nelement face 0\nproperty int flags\n"),
                 "no 'vertex_indices'");
}

TEST(PlyTest, TruncatedBinaryIsRefusedAtEveryLength) {
  for (PlyFormat format : {PlyFormat::kLittleEndian, PlyFormat::kBigEndian}) {
    PlyWriter w = sample_ply(format);
    std::string full = w.str();
    for (std::size_t length = 0; length < full.size(); ++length) {
      auto mesh = parse_ply(std::string_view(full).substr(0, length), "cut.ply");
      ASSERT_FALSE(mesh.ok()) << length;
      EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument) << mesh.status();
      if (length > w.header_size()) {
        EXPECT_TRUE(contains(mesh.status().message(), "byte offset") ||
                    contains(mesh.status().message(), "bytes follow the header"))
            << mesh.status();
      }
    }
  }
}

TEST(PlyTest, TruncatedAsciiIsRefused) {
  std::string full = sample_ply(PlyFormat::kAscii).str();
  // Cutting inside the last number can leave a valid shorter number, so stop before it.
  std::size_t last_token = full.find_last_of(" \n", full.find_last_not_of(" \n")) + 1;
  for (std::size_t length = 0; length <= last_token; ++length) {
    auto mesh = parse_ply(std::string_view(full).substr(0, length), "cut.ply");
    ASSERT_FALSE(mesh.ok()) << length;
    EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument) << mesh.status();
  }
}

TEST(PlyTest, HugeCountsAreRefusedBeforeAllocating) {
  std::string header =
      "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
      "property float y\nproperty float z\nelement face 1\n"
      "property list uchar int vertex_indices\nend_header\n";
  std::string file = header + std::string(1024, '\0');
  MeshLimits generous;
  generous.max_vertices = std::uint64_t{1} << 40;
  expect_invalid(file, "4000000000 'vertex' items of at least 12 bytes each, but only 1024",
                 generous);
  auto limited = parse_ply(file, "test.ply");
  EXPECT_EQ(limited.status().code(), absl::StatusCode::kResourceExhausted) << limited.status();

  std::string faces =
      "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float x\n"
      "property float y\nproperty float z\nelement face 4294967295\n"
      "property list uchar int vertex_indices\nend_header\n" +
      std::string(1024, '\0');
  MeshLimits many_triangles;
  many_triangles.max_triangles = std::uint64_t{1} << 40;
  expect_invalid(faces, "'face' items", many_triangles);

  std::string other =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
      "element junk 18446744073709551615\nproperty list uint double values\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  expect_invalid(other, "'junk' items");

  // An element without properties occupies no bytes; it is skipped without a loop.
  std::string empty_element =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement nothing 18446744073709551615\nelement face 1\n"
      "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  EXPECT_TRUE(parse_ply(empty_element, "empty.ply").ok());
}

TEST(PlyTest, HugeListLengthsAreRefused) {
  PlyWriter w(PlyFormat::kLittleEndian);
  w.line("element vertex 3").line("property float x").line("property float y");
  w.line("property float z").line("property list uint double extra");
  w.line("element face 1").line("property list uchar int vertex_indices");
  w.put(0.0f).put(0.0f).put(0.0f).put(std::uint32_t(4000000000u));
  w.put(0.0f).put(0.0f).put(0.0f).put(std::uint32_t(0));
  w.put(0.0f).put(0.0f).put(0.0f).put(std::uint32_t(0));
  w.put(std::uint8_t(3)).put(0).put(1).put(2);
  expect_invalid(w.str(), "a list needs 32000000000 bytes");
}

std::string single_triangle(PlyFormat format, std::int32_t a, std::int32_t b, std::int32_t c) {
  PlyWriter w(format);
  w.line("element vertex 3").line("property float x").line("property float y");
  w.line("property float z").line("element face 1").line("property list uchar int vertex_indices");
  for (int i = 0; i < 3; ++i) w.put(float(i)).put(float(i == 2)).put(0.0f).end_item();
  w.put(std::uint8_t(3)).put(a).put(b).put(c).end_item();
  return w.str();
}

std::size_t body_offset(const std::string& file) {
  return file.find("end_header\n") + 11;
}

TEST(PlyTest, RefusesIndicesOutOfRange) {
  // Byte offsets count from the start of the file; the face starts after 3 * 12 vertex bytes.
  std::string file = single_triangle(PlyFormat::kLittleEndian, 0, 7, 1);
  expect_invalid(file, "byte offset " + std::to_string(body_offset(file) + 36) +
                           ": 'face' item 0: vertex index 7 is out of range (3 vertices)");
  expect_invalid(single_triangle(PlyFormat::kBigEndian, 0, 1, -1),
                 "vertex index -1 is out of range");
  expect_invalid(single_triangle(PlyFormat::kAscii, 3, 1, 2),
                 "test.ply:13: 'face' item 0: vertex index 3 is out of range");
}

TEST(PlyTest, RefusesPolygonsWithMoreThanFourCorners) {
  PlyWriter w(PlyFormat::kAscii);
  w.line("element vertex 5").line("property float x").line("property float y");
  w.line("property float z").line("element face 1").line("property list uchar int vertex_indices");
  for (int i = 0; i < 5; ++i) w.put(float(i)).put(float(i * i)).put(0.0f).end_item();
  w.put(5).put(0).put(1).put(2).put(3).put(4).end_item();
  expect_invalid(w.str(), "face has 5 vertices; only triangles and quads are supported");
  std::string degenerate = single_triangle(PlyFormat::kAscii, 0, 1, 2);
  degenerate.replace(degenerate.rfind("3 0 1 2"), 7, "2 0 1");
  expect_invalid(degenerate, "face has 2 vertices");
}

TEST(PlyTest, RefusesNegativeListLengths) {
  PlyWriter w(PlyFormat::kLittleEndian);
  w.line("element vertex 3").line("property float x").line("property float y");
  w.line("property float z").line("property list char float extra");
  w.line("element face 1").line("property list uchar int vertex_indices");
  for (int i = 0; i < 3; ++i) w.put(float(i)).put(float(i == 2)).put(0.0f).put(std::int8_t(-3));
  w.put(std::uint8_t(3)).put(0).put(1).put(2);
  expect_invalid(w.str(), "list 'extra' has negative length -3");
}

TEST(PlyTest, RefusesNonFiniteAndOutOfRangeCoordinates) {
  std::string ascii = single_triangle(PlyFormat::kAscii, 0, 1, 2);
  ascii.replace(ascii.find("end_header\n") + 11, 1, "nan");
  expect_invalid(ascii, "test.ply:10: 'vertex' item 0: 'x' is nan, not a finite float");

  PlyWriter w(PlyFormat::kBigEndian);
  w.line("element vertex 3").line("property double x").line("property float y");
  w.line("property float z").line("element face 1").line("property list uchar int vertex_indices");
  w.put(0.0).put(0.0f).put(0.0f).put(1e300).put(0.0f).put(0.0f);
  w.put(0.0).put(std::numeric_limits<float>::infinity()).put(0.0f);
  w.put(std::uint8_t(3)).put(0).put(1).put(2);
  expect_invalid(w.str(), "'vertex' item 1: 'x' is 1e+300, not a finite float");
}

TEST(PlyTest, AsciiErrorsNameTheLine) {
  std::string file = single_triangle(PlyFormat::kAscii, 0, 1, 2);
  std::string bad = file;
  bad.replace(bad.find("end_header\n") + 11, 1, "zero");
  expect_invalid(bad, "test.ply:10: 'vertex' item 0: 'zero' is not a number");
  bad = file;
  bad.replace(bad.rfind("3 0 1 2"), 1, "300");
  expect_invalid(bad, "test.ply:13: 'face' item 0: '300' is out of range for its property type");
  bad = file;
  bad.replace(bad.rfind("3 0 1 2"), 7, "3 0 1.5 2");
  expect_invalid(bad, "'1.5' is not an integer");
}

TEST(PlyTest, RefusesDataAfterTheLastElement) {
  std::string file = single_triangle(PlyFormat::kLittleEndian, 0, 1, 2);
  expect_invalid(file + "x", "byte offset " + std::to_string(body_offset(file) + 49) +
                                 ": 1 unexpected bytes after the last element");
  expect_invalid(single_triangle(PlyFormat::kAscii, 0, 1, 2) + "\n7\n",
                 "test.ply:15: unexpected data after the last element");
  EXPECT_TRUE(parse_ply(single_triangle(PlyFormat::kAscii, 0, 1, 2) + " \r\n\n", "x.ply").ok());
}

TEST(PlyTest, TriangleLimitIsResourceExhausted) {
  MeshLimits limits;
  limits.max_triangles = 2;  // two faces pass the header check, the quad makes three triangles
  auto mesh = parse_ply(sample_ply(PlyFormat::kLittleEndian).str(), "sample.ply", limits);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kResourceExhausted) << mesh.status();
  limits.max_triangles = 1;
  mesh = parse_ply(sample_ply(PlyFormat::kAscii).str(), "sample.ply", limits);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kResourceExhausted) << mesh.status();
  limits = MeshLimits{};
  limits.max_vertices = 4;
  mesh = parse_ply(sample_ply(PlyFormat::kAscii).str(), "sample.ply", limits);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kResourceExhausted) << mesh.status();
  limits = MeshLimits{};
  limits.max_file_bytes = 100;
  mesh = parse_ply(sample_ply(PlyFormat::kAscii).str(), "sample.ply", limits);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kResourceExhausted) << mesh.status();
}

TEST(PlyTest, RandomCorruptionNeverCrashes) {
  std::mt19937 rng(1234);
  for (PlyFormat format : {PlyFormat::kAscii, PlyFormat::kLittleEndian, PlyFormat::kBigEndian}) {
    const std::string original = sample_ply(format).str();
    for (int round = 0; round < 3000; ++round) {
      std::string bytes = original;
      int edits = 1 + static_cast<int>(rng() % 4);
      for (int e = 0; e < edits; ++e) {
        std::size_t at = rng() % bytes.size();
        switch (rng() % 4) {
          case 0:
            bytes[at] = static_cast<char>(rng());
            break;
          case 1:
            bytes[at] = static_cast<char>(bytes[at] ^ (1 << (rng() % 8)));
            break;
          case 2:
            bytes.erase(at, 1 + rng() % 8);
            break;
          default:
            bytes.insert(at, 1 + rng() % 8, static_cast<char>(rng()));
            break;
        }
        if (bytes.empty()) bytes.push_back('p');
      }
      auto mesh = parse_ply(bytes, "fuzz.ply");
      if (mesh.ok()) {
        EXPECT_TRUE(mesh->validate().ok());
      } else {
        EXPECT_TRUE(mesh.status().code() == absl::StatusCode::kInvalidArgument ||
                    mesh.status().code() == absl::StatusCode::kResourceExhausted)
            << mesh.status();
      }
    }
  }
}

}  // namespace
}  // namespace prism::scene
