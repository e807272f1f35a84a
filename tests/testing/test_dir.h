// Test support: a directory of the running test's own. ctest runs every test case as its own
// process, two at a time, and gtest's TempDir() is shared by all of them, so a file written
// there under a fixed name ("scene.pbrt") can be rewritten by another test between one test's
// write and its read. Files a test writes go under test_dir() or fresh_dir() instead: the name
// carries the suite, the test and the process id.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

namespace prism::testing {

namespace detail {
inline std::filesystem::path test_dir_path(const std::string& name) {
  const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string leaf = "prism_test";
  if (info != nullptr) leaf.assign(info->test_suite_name()).append("_").append(info->name());
  if (!name.empty()) leaf.append("_").append(name);
  leaf.append("_").append(std::to_string(::getpid()));
  return std::filesystem::path(::testing::TempDir()) / leaf;
}
}  // namespace detail

// The running test's directory (created if absent; what the test wrote earlier stays).
inline std::filesystem::path test_dir() {
  const std::filesystem::path dir = detail::test_dir_path("");
  std::filesystem::create_directories(dir);
  return dir;
}

// A fresh, empty directory named after the running test, `name` and the process id.
inline std::filesystem::path fresh_dir(const std::string& name = "") {
  const std::filesystem::path dir = detail::test_dir_path(name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

// A fresh directory holding scene/scene.pbrt, a copy of `scene`: a farm job's bundle as the
// process tests submit it.
inline std::filesystem::path fresh_scene_dir(const std::filesystem::path& scene) {
  const std::filesystem::path dir = fresh_dir();
  std::filesystem::create_directories(dir / "scene");
  std::filesystem::copy_file(scene, dir / "scene" / "scene.pbrt");
  return dir;
}

}  // namespace prism::testing
