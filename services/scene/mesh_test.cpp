#include "services/scene/mesh.h"

#include <gtest/gtest.h>

#include <limits>

namespace prism::scene {
namespace {

TriangleMeshData quad() {
  TriangleMeshData mesh;
  mesh.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  return mesh;
}

TEST(TriangleMeshDataTest, ValidMeshPasses) {
  TriangleMeshData mesh = quad();
  EXPECT_TRUE(mesh.validate().ok());
  mesh.normals.assign(4, {0, 0, 1});
  mesh.uvs.assign(4, {0.5f, 0.5f});
  EXPECT_TRUE(mesh.validate().ok());
}

TEST(TriangleMeshDataTest, RefusesIndexOutOfRange) {
  TriangleMeshData mesh = quad();
  mesh.triangles[1][2] = 4;
  absl::Status status = mesh.validate();
  EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(status.message().find("triangle 1 refers to vertex 4"), absl::string_view::npos)
      << status;
}

TEST(TriangleMeshDataTest, RefusesInconsistentSizes) {
  TriangleMeshData mesh = quad();
  mesh.normals.assign(3, {0, 0, 1});
  EXPECT_NE(mesh.validate().message().find("3 normals for 4 vertices"), absl::string_view::npos);
  mesh = quad();
  mesh.uvs.assign(5, {0, 0});
  EXPECT_NE(mesh.validate().message().find("5 uvs for 4 vertices"), absl::string_view::npos);
}

TEST(TriangleMeshDataTest, RefusesNonFiniteValues) {
  TriangleMeshData mesh = quad();
  mesh.positions[2].y = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NE(mesh.validate().message().find("vertex 2 has a non-finite position"),
            absl::string_view::npos);
  mesh = quad();
  mesh.normals.assign(4, {0, 0, 1});
  mesh.normals[3].x = std::numeric_limits<float>::infinity();
  EXPECT_NE(mesh.validate().message().find("vertex 3 has a non-finite normal"),
            absl::string_view::npos);
  mesh = quad();
  mesh.uvs.assign(4, {0, 0});
  mesh.uvs[0].v = -std::numeric_limits<float>::infinity();
  EXPECT_NE(mesh.validate().message().find("vertex 0 has a non-finite uv"),
            absl::string_view::npos);
}

TEST(TriangleMeshDataTest, RefusesEmptyMeshes) {
  TriangleMeshData mesh;
  EXPECT_FALSE(mesh.validate().ok());
  mesh = quad();
  mesh.triangles.clear();
  EXPECT_NE(mesh.validate().message().find("no triangles"), absl::string_view::npos);
}

}  // namespace
}  // namespace prism::scene
