#include "services/scene/path_guard.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <string_view>

namespace prism::scene {
namespace {

namespace fs = std::filesystem;

bool contains(absl::string_view haystack, std::string_view needle) {
  return haystack.find(absl::string_view(needle.data(), needle.size())) != absl::string_view::npos;
}

// base/root/{scene.pbrt, meshes/a.ply, link_in -> meshes/a.ply, link_out -> ../outside/secret,
//            dir_out -> ../outside, meshes_link -> meshes}
// base/outside/secret
class PathGuardTest : public ::testing::Test {
 protected:
  void SetUp() override {
    base_ =
        fs::temp_directory_path() /
        ("prism_path_guard_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
         "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(base_);
    root_ = base_ / "root";
    fs::create_directories(root_ / "meshes");
    fs::create_directories(base_ / "outside");
    std::ofstream(root_ / "scene.pbrt") << "Shape \"plymesh\"\n";
    std::ofstream(root_ / "meshes" / "a.ply") << "ply\n";
    std::ofstream(base_ / "outside" / "secret") << "secret\n";
    fs::create_symlink("meshes/a.ply", root_ / "link_in");
    fs::create_symlink("../outside/secret", root_ / "link_out");
    fs::create_directory_symlink("../outside", root_ / "dir_out");
    fs::create_directory_symlink("meshes", root_ / "meshes_link");
    auto guard = PathGuard::create(root_);
    ASSERT_TRUE(guard.ok()) << guard.status();
    guard_.emplace(*std::move(guard));
  }
  void TearDown() override { fs::remove_all(base_); }

  // Most references are refused as malformed or escaping: INVALID_ARGUMENT.
  void expect_invalid(std::string_view reference, std::string_view needle) {
    expect_refused(reference, absl::StatusCode::kInvalidArgument, needle);
  }
  void expect_refused(std::string_view reference, absl::StatusCode code, std::string_view needle) {
    auto resolved = guard_->resolve(reference);
    ASSERT_FALSE(resolved.ok()) << reference << " resolved to " << *resolved;
    EXPECT_EQ(resolved.status().code(), code) << resolved.status();
    EXPECT_TRUE(contains(resolved.status().message(), needle))
        << resolved.status() << "\nwanted: " << needle;
  }

  fs::path base_;
  fs::path root_;
  std::optional<PathGuard> guard_;
};

TEST_F(PathGuardTest, ResolvesFilesInsideTheRoot) {
  auto resolved = guard_->resolve_reference("meshes/a.ply");
  ASSERT_TRUE(resolved.ok()) << resolved.status();
  EXPECT_EQ(resolved->real_path, fs::canonical(root_ / "meshes" / "a.ply"));
  EXPECT_EQ(resolved->relative_path, "meshes/a.ply");
  resolved = guard_->resolve_reference("./meshes//../meshes/./a.ply");
  ASSERT_TRUE(resolved.ok()) << resolved.status();
  EXPECT_EQ(resolved->relative_path, "meshes/a.ply");
  EXPECT_EQ(guard_->root(), fs::canonical(root_));
}

TEST_F(PathGuardTest, FollowsSymbolicLinksThatStayInside) {
  auto resolved = guard_->resolve_reference("link_in");
  ASSERT_TRUE(resolved.ok()) << resolved.status();
  EXPECT_EQ(resolved->real_path, fs::canonical(root_ / "meshes" / "a.ply"));
  EXPECT_EQ(resolved->relative_path, "link_in");
  auto through_dir = guard_->resolve("meshes_link/a.ply");
  ASSERT_TRUE(through_dir.ok()) << through_dir.status();
  EXPECT_EQ(*through_dir, fs::canonical(root_ / "meshes" / "a.ply"));
}

TEST_F(PathGuardTest, RefusesLexicalEscapes) {
  expect_invalid("../x", "escapes the scene directory");
  expect_invalid("a/../../x", "escapes the scene directory");
  expect_invalid("../outside/secret", "escapes");
  expect_invalid("meshes/../..", "escapes");
}

TEST_F(PathGuardTest, RefusesAbsolutePaths) {
  expect_invalid("/etc/passwd", "is absolute");
  expect_invalid((root_ / "scene.pbrt").string(), "absolute");
}

TEST_F(PathGuardTest, RefusesSymbolicLinksOutOfTheRoot) {
  expect_invalid("link_out", "outside the scene directory");
  expect_invalid("dir_out/secret", "outside the scene directory");
}

TEST_F(PathGuardTest, RefusesEmptyAndMalformedNames) {
  expect_invalid("", "empty file name");
  expect_invalid(std::string_view("scene.pbrt\0.png", 15), "NUL byte");
  expect_invalid("a\nb", "control character");
  expect_invalid("meshes\\a.ply", "backslash");
  expect_invalid(".", "does not name a file");
  expect_invalid("meshes/..", "does not name a file");
}

TEST_F(PathGuardTest, RefusesMissingFilesAndDirectories) {
  expect_refused("meshes/b.ply", absl::StatusCode::kNotFound, "not found");
  expect_refused("scene.pbrt/x", absl::StatusCode::kNotFound, "not found");
  expect_invalid("meshes", "not a regular file");
  expect_invalid("meshes_link", "not a regular file");
}

TEST_F(PathGuardTest, CreateNeedsAnExistingDirectory) {
  EXPECT_EQ(PathGuard::create(base_ / "missing").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(PathGuard::create(root_ / "scene.pbrt").status().code(),
            absl::StatusCode::kInvalidArgument);
  // A root reached through a symbolic link works like the real directory.
  fs::create_directory_symlink(root_, base_ / "root_link");
  auto guard = PathGuard::create(base_ / "root_link");
  ASSERT_TRUE(guard.ok()) << guard.status();
  EXPECT_TRUE(guard->resolve("meshes/a.ply").ok());
}

TEST(NormalizeReferenceTest, NormalisesLexically) {
  EXPECT_EQ(*normalize_reference("a.ply"), "a.ply");
  EXPECT_EQ(*normalize_reference("./a//b/../c.ply"), "a/c.ply");
  EXPECT_EQ(*normalize_reference("a/b/"), "a/b");
  EXPECT_FALSE(normalize_reference("..").ok());
  EXPECT_FALSE(normalize_reference("/a").ok());
  EXPECT_FALSE(normalize_reference("").ok());
}

TEST(PlainRelativePathTest, AcceptsOnlyNormalisedPaths) {
  EXPECT_TRUE(check_plain_relative_path("scene.pbrt").ok());
  EXPECT_TRUE(check_plain_relative_path("meshes/bunny 2.ply").ok());
  for (std::string_view bad :
       {"", "/etc/passwd", "../x", "a/../b", "a/./b", "./a", "a//b", "a/", "a\\b", "..", "."}) {
    absl::Status status = check_plain_relative_path(bad);
    EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << "'" << bad << "'";
  }
  EXPECT_FALSE(check_plain_relative_path(std::string_view("a\0b", 3)).ok());
  EXPECT_TRUE(contains(check_plain_relative_path("a/../b").message(), "'..' component"));
}

TEST(IsWithinTest, ComparesWholeComponents) {
  EXPECT_TRUE(is_within("/a/b/c", "/a/b"));
  EXPECT_TRUE(is_within("/a/b", "/a/b"));
  EXPECT_FALSE(is_within("/a/bc", "/a/b"));
  EXPECT_FALSE(is_within("/a", "/a/b"));
  EXPECT_TRUE(is_within("/etc", "/"));
}

}  // namespace
}  // namespace prism::scene
