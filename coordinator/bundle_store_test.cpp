#include "coordinator/bundle_store.h"

#include <gtest/gtest.h>
#include <spdlog/sinks/null_sink.h>

#include <filesystem>
#include <fstream>

#include "services/base/sha256.h"
#include "services/scene/bundle.h"
#include "tests/testing/child_process.h"

namespace prism::coordinator {
namespace {

namespace fs = std::filesystem;

constexpr char kScene[] = R"(WorldBegin
LightSource "infinite" "spectrum L" [360 1 830 1]
Shape "sphere"
)";

class BundleStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = prism::testing::fresh_dir();
    for (const char* sub : {"bundles", "scenes", "tmp"}) fs::create_directories(root_ / sub);
    library_ =
        std::make_unique<spectral::SpectrumLibrary>(*spectral::SpectrumLibrary::load_builtin());
    store_ = std::make_unique<BundleStore>(
        root_, 1 << 20, *library_,
        std::make_shared<spdlog::logger>("test", std::make_shared<spdlog::sinks::null_sink_mt>()));
  }

  // The packed bundle of `text` as scene.pbrt (its files written under root_/src/<name>).
  std::string pack(const std::string& name, const std::string& text) {
    const fs::path dir = root_ / "src" / name;
    fs::create_directories(dir);
    std::ofstream(dir / "scene.pbrt", std::ios::binary) << text;
    auto bundle = scene::make_bundle(dir, "scene.pbrt", {});
    EXPECT_TRUE(bundle.ok()) << bundle.status();
    return bundle.ok() ? scene::pack(*bundle) : std::string();
  }

  bool tmp_is_empty() const { return fs::is_empty(root_ / "tmp"); }

  fs::path root_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<BundleStore> store_;
};

TEST_F(BundleStoreTest, AnUploadIsStoredUnderItsContentHashAndLoadsAgain) {
  const std::string bytes = pack("good", kScene);
  auto hash = store_->upload("", bytes);
  ASSERT_TRUE(hash.ok()) << hash.status();
  EXPECT_TRUE(base::is_sha256_hex(*hash));
  EXPECT_TRUE(store_->has(*hash));
  EXPECT_EQ(*store_->bytes(*hash), bytes);
  EXPECT_EQ(*store_->scene_path(*hash), "scene.pbrt");
  auto loaded = store_->load_scene(false, *hash, "scene.pbrt");
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->description.lights.size(), 1u);
  // The same bytes again, with the right claimed hash: the same bundle.
  EXPECT_EQ(*store_->upload(*hash, bytes), *hash);
  EXPECT_TRUE(tmp_is_empty());
}

TEST_F(BundleStoreTest, BadUploadsAreRefusedAndLeaveNothing) {
  const std::string bytes = pack("good", kScene);
  auto mismatch = store_->upload(std::string(64, 'a'), bytes);
  EXPECT_EQ(mismatch.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(mismatch.status().message().find("bundle hash mismatch"), std::string::npos);

  auto broken = store_->upload("", pack("broken", "WorldBegin\nShape \"sphere\" \"float radius\""));
  EXPECT_EQ(broken.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(broken.status().message().find("the bundle's scene does not load"), std::string::npos)
      << broken.status();

  auto garbage = store_->upload("", std::string(200, 'x'));
  EXPECT_FALSE(garbage.ok());

  BundleStore small(
      root_, 64, *library_,
      std::make_shared<spdlog::logger>("small", std::make_shared<spdlog::sinks::null_sink_mt>()));
  EXPECT_EQ(small.upload("", bytes).status().code(), absl::StatusCode::kResourceExhausted);

  EXPECT_TRUE(fs::is_empty(root_ / "bundles"));
  EXPECT_TRUE(fs::is_empty(root_ / "scenes"));
  EXPECT_TRUE(tmp_is_empty());
}

TEST_F(BundleStoreTest, UnknownHashesAreNotFound) {
  EXPECT_FALSE(store_->has("not-a-hash"));
  EXPECT_FALSE(store_->has(std::string(64, 'b')));
  EXPECT_EQ(store_->bytes(std::string(64, 'b')).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->scene_path(std::string(64, 'b')).status().code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace prism::coordinator
