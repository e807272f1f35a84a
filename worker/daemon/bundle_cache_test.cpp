#include "worker/daemon/bundle_cache.h"

#include <gtest/gtest.h>

#include <filesystem>

#include "services/base/atomic_file.h"
#include "services/scene/bundle.h"
#include "tests/testing/test_dir.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;
using prism::testing::fresh_dir;

std::string furnace_blob(scene::Bundle* out = nullptr) {
  auto bundle =
      scene::make_bundle(fs::path(PRISM_SOURCE_DIR) / "worker/testdata", "furnace.pbrt", {});
  EXPECT_TRUE(bundle.ok()) << bundle.status();
  if (out != nullptr) *out = *bundle;
  return scene::pack(*bundle);
}

// Entries of `dir` (none when it does not exist).
int entries(const fs::path& dir) {
  if (!fs::exists(dir)) return 0;
  return static_cast<int>(std::distance(fs::directory_iterator(dir), fs::directory_iterator()));
}

TEST(BundleCache, InstallsUnderItsHashWithTheSceneBytes) {
  scene::Bundle bundle;
  const std::string blob = furnace_blob(&bundle);
  BundleCache cache(fresh_dir("install"));
  auto before = cache.find(bundle.content_hash);
  ASSERT_TRUE(before.ok());
  EXPECT_FALSE(before->has_value());

  auto dir = cache.install(bundle.content_hash, blob);
  ASSERT_TRUE(dir.ok()) << dir.status();
  EXPECT_EQ(*dir, cache.dir() / bundle.content_hash);
  auto scene_text = base::read_file(*dir / "furnace.pbrt");
  ASSERT_TRUE(scene_text.ok());
  EXPECT_EQ(*scene_text, bundle.find("furnace.pbrt")->contents);
  auto after = cache.find(bundle.content_hash);
  ASSERT_TRUE(after.ok());
  EXPECT_EQ(after->value_or(fs::path()), *dir);
  // Only the bundle's directory: the temporary one was renamed, not copied.
  EXPECT_EQ(entries(cache.dir()), 1);
  // A second install of the same hash is a no-op that finds the same directory.
  auto again = cache.install(bundle.content_hash, blob);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(*again, *dir);
}

TEST(BundleCache, RefusesABlobWhoseHashIsNotTheOneAskedFor) {
  scene::Bundle bundle;
  const std::string blob = furnace_blob(&bundle);
  BundleCache cache(fresh_dir("wrong_hash"));
  const std::string other(64, 'a');
  auto dir = cache.install(other, blob);
  ASSERT_FALSE(dir.ok());
  EXPECT_EQ(dir.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(dir.status().message().find(bundle.content_hash), absl::string_view::npos)
      << dir.status();
  EXPECT_EQ(entries(cache.dir()), 0);
}

TEST(BundleCache, RefusesATamperedBlobAndAMalformedHash) {
  scene::Bundle bundle;
  std::string blob = furnace_blob(&bundle);
  blob.back() ^= 0x20;  // a byte of the scene file's contents
  BundleCache cache(fresh_dir("tampered"));
  auto dir = cache.install(bundle.content_hash, blob);
  ASSERT_FALSE(dir.ok());
  EXPECT_EQ(dir.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(entries(cache.dir()), 0);

  auto escape = cache.find("../etc");
  ASSERT_FALSE(escape.ok());
  EXPECT_EQ(escape.status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace prism::worker
