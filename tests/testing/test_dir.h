// Test support: a directory of the running test's own. ctest runs every test case as its own
// process, two at a time, and gtest's TempDir() is shared by all of them, so a file written
// there under a fixed name ("scene.pbrt") can be rewritten by another test between one test's
// write and its read. Files a test writes go under test_dir() or fresh_dir() instead: the name
// carries the suite, the test and the process id. A passing test's directories are removed when
// it ends.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

namespace prism::testing {

namespace detail {

// Removes the directories a passing test made when the test ends (a failing test's stay, for a
// look), so that runs do not pile them up in the temporary directory.
class TestDirCleaner : public ::testing::EmptyTestEventListener {
 public:
  static TestDirCleaner& instance() {
    static TestDirCleaner* cleaner = [] {
      auto* c = new TestDirCleaner;  // owned by gtest's listener list once appended
      ::testing::UnitTest::GetInstance()->listeners().Append(c);
      return c;
    }();
    return *cleaner;
  }
  // Outside a test (a suite's set-up) the directory is left alone: later tests may use it.
  void made(const std::filesystem::path& dir) {
    if (::testing::UnitTest::GetInstance()->current_test_info() == nullptr) return;
    for (const std::filesystem::path& d : dirs_) {
      if (d == dir) return;
    }
    dirs_.push_back(dir);
  }
  void OnTestEnd(const ::testing::TestInfo& info) override {
    if (info.result() != nullptr && !info.result()->Failed()) {
      std::error_code ignored;
      for (const std::filesystem::path& d : dirs_) std::filesystem::remove_all(d, ignored);
    }
    dirs_.clear();
  }

 private:
  std::vector<std::filesystem::path> dirs_;
};

inline std::filesystem::path test_dir_path(const std::string& name) {
  const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string leaf = "prism_test";
  if (info != nullptr) leaf.assign(info->test_suite_name()).append("_").append(info->name());
  if (!name.empty()) leaf.append("_").append(name);
  leaf.append("_").append(std::to_string(::getpid()));
  // Parameterised tests' names hold '/' ("Scenes/LightTracingTest", "Agrees.../Glass"): one
  // directory, not a tree whose parents would outlive the test.
  for (char& c : leaf) {
    if (c == '/') c = '_';
  }
  return std::filesystem::path(::testing::TempDir()) / leaf;
}
}  // namespace detail

// The running test's directory (created if absent; what the test wrote earlier stays).
inline std::filesystem::path test_dir() {
  const std::filesystem::path dir = detail::test_dir_path("");
  std::filesystem::create_directories(dir);
  detail::TestDirCleaner::instance().made(dir);
  return dir;
}

// A fresh, empty directory named after the running test, `name` and the process id.
inline std::filesystem::path fresh_dir(const std::string& name = "") {
  const std::filesystem::path dir = detail::test_dir_path(name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  detail::TestDirCleaner::instance().made(dir);
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
