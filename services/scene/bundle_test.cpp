#include "services/scene/bundle.h"

#include "services/base/sha256.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <string>
#include <string_view>
#include <vector>

namespace prism::scene {
namespace {

namespace fs = std::filesystem;

bool contains(absl::string_view haystack, std::string_view needle) {
  return haystack.find(absl::string_view(needle.data(), needle.size())) != absl::string_view::npos;
}

void write(const fs::path& path, std::string_view bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << bytes;
}

// Every regular file under dir, by '/'-separated relative path.
std::map<std::string, std::string> list_files(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (!entry.is_regular_file()) continue;
    std::ifstream in(entry.path(), std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    files[fs::relative(entry.path(), dir).generic_string()] = bytes;
  }
  return files;
}

void put_le(std::string& out, std::uint64_t value, int bytes) {
  for (int i = 0; i < bytes; ++i) out.push_back(static_cast<char>((value >> (8 * i)) & 0xff));
}

// A blob in the documented packed layout, written independently of pack(), with a correct
// content hash unless `hash` is given: what an attacker who knows the format can produce.
std::string handmade_blob(std::string_view manifest, std::string_view data, std::string hash = {}) {
  if (hash.empty()) hash = base::sha256_hex(manifest);
  std::string blob = "PRISMBDL";
  put_le(blob, 1, 4);
  put_le(blob, 0, 4);
  blob += hash;
  put_le(blob, manifest.size(), 8);
  blob.append(manifest);
  blob.append(data);
  return blob;
}

std::string file_line(std::string_view contents, std::string_view path) {
  return "file " + base::sha256_hex(contents) + " " + std::to_string(contents.size()) + " " +
         std::string(path) + "\n";
}

class BundleTest : public ::testing::Test {
 protected:
  void SetUp() override {
    base_ = fs::temp_directory_path() /
            ("prism_bundle_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
             "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(base_);
    make_scene(base_ / "one");
    make_scene(base_ / "elsewhere" / "two");
  }
  void TearDown() override { fs::remove_all(base_); }

  static void make_scene(const fs::path& dir) {
    write(dir / "scene.pbrt", "Shape \"plymesh\" \"string filename\" \"meshes/bunny.ply\"\n");
    write(dir / "meshes" / "bunny.ply", std::string("ply\0binary", 10));
    write(dir / "textures" / "wood.png", "PNG");
    write(dir / "textures" / "empty.txt", "");
    write(dir / "unrelated.txt", "not referenced");
  }

  Bundle make(const fs::path& dir, const std::vector<std::string>& refs) {
    auto bundle = make_bundle(dir, "scene.pbrt", refs);
    EXPECT_TRUE(bundle.ok()) << bundle.status();
    return bundle.ok() ? *std::move(bundle) : Bundle{};
  }

  void expect_unpack_fails(const std::string& blob, absl::StatusCode code, std::string_view needle,
                           const BundleLimits& limits = {}) {
    auto unpacked = unpack(blob, limits);
    ASSERT_FALSE(unpacked.ok()) << "accepted, wanted: " << needle;
    EXPECT_EQ(unpacked.status().code(), code) << unpacked.status();
    EXPECT_TRUE(contains(unpacked.status().message(), needle))
        << unpacked.status() << "\nwanted: " << needle;
  }

  fs::path base_;
  const std::vector<std::string> refs_ = {"textures/wood.png", "meshes/bunny.ply",
                                          "textures/empty.txt"};
};

TEST_F(BundleTest, ListsSortedUniqueEntriesAndHashesTheCanonicalManifest) {
  Bundle bundle =
      make(base_ / "one", {"textures/wood.png", "./meshes/bunny.ply",
                           "textures/../textures/wood.png", "scene.pbrt", "textures/empty.txt"});
  ASSERT_EQ(bundle.entries.size(), 4u);
  EXPECT_EQ(bundle.entries[0].path, "meshes/bunny.ply");
  EXPECT_EQ(bundle.entries[1].path, "scene.pbrt");
  EXPECT_EQ(bundle.entries[2].path, "textures/empty.txt");
  EXPECT_EQ(bundle.entries[3].path, "textures/wood.png");
  EXPECT_EQ(bundle.scene_path, "scene.pbrt");
  EXPECT_EQ(bundle.entries[0].size, 10u);
  EXPECT_EQ(bundle.entries[0].contents, std::string("ply\0binary", 10));
  EXPECT_EQ(bundle.entries[3].sha256, base::sha256_hex("PNG"));
  std::string manifest = canonical_manifest(bundle);
  EXPECT_TRUE(manifest.starts_with("prism-bundle 1\nscene scene.pbrt\nfile "));
  EXPECT_TRUE(contains(manifest, file_line("PNG", "textures/wood.png")));
  EXPECT_EQ(bundle.content_hash, base::sha256_hex(manifest));
  ASSERT_NE(bundle.find("textures/wood.png"), nullptr);
  EXPECT_EQ(bundle.find("unrelated.txt"), nullptr);
}

TEST_F(BundleTest, HashIgnoresLocationAndOrder) {
  Bundle one = make(base_ / "one", refs_);
  std::vector<std::string> reordered = {"textures/empty.txt", "meshes/bunny.ply",
                                        "textures/wood.png", "meshes/bunny.ply"};
  Bundle two = make(base_ / "elsewhere" / "two", reordered);
  EXPECT_EQ(one.content_hash, two.content_hash);
  EXPECT_EQ(pack(one), pack(two));
  write(base_ / "elsewhere" / "two" / "textures" / "wood.png", "PNG!");
  EXPECT_NE(make(base_ / "elsewhere" / "two", refs_).content_hash, one.content_hash);
}

TEST_F(BundleTest, RefusesReferencesOutsideTheRoot) {
  auto bundle = make_bundle(base_ / "one", "scene.pbrt",
                            std::vector<std::string>{"../elsewhere/two/scene.pbrt"});
  EXPECT_EQ(bundle.status().code(), absl::StatusCode::kInvalidArgument) << bundle.status();
  bundle = make_bundle(base_ / "one", "missing.pbrt", {});
  EXPECT_EQ(bundle.status().code(), absl::StatusCode::kNotFound) << bundle.status();
  BundleLimits limits;
  limits.max_files = 2;
  bundle = make_bundle(base_ / "one", "scene.pbrt", refs_, limits);
  EXPECT_EQ(bundle.status().code(), absl::StatusCode::kResourceExhausted) << bundle.status();
}

TEST_F(BundleTest, PackUnpackRoundTrips) {
  Bundle bundle = make(base_ / "one", refs_);
  std::string blob = pack(bundle);
  EXPECT_TRUE(blob.starts_with("PRISMBDL"));
  auto unpacked = unpack(blob);
  ASSERT_TRUE(unpacked.ok()) << unpacked.status();
  EXPECT_EQ(unpacked->content_hash, bundle.content_hash);
  EXPECT_EQ(unpacked->scene_path, bundle.scene_path);
  ASSERT_EQ(unpacked->entries.size(), bundle.entries.size());
  for (std::size_t i = 0; i < bundle.entries.size(); ++i) {
    EXPECT_EQ(unpacked->entries[i].path, bundle.entries[i].path);
    EXPECT_EQ(unpacked->entries[i].size, bundle.entries[i].size);
    EXPECT_EQ(unpacked->entries[i].sha256, bundle.entries[i].sha256);
    EXPECT_EQ(unpacked->entries[i].contents, bundle.entries[i].contents);
  }
  EXPECT_EQ(pack(*unpacked), blob);
}

TEST_F(BundleTest, RefusesChangedContent) {
  std::string blob = pack(make(base_ / "one", refs_));
  blob[blob.size() - 2] ^= 0x20;  // inside textures/wood.png, the last file
  expect_unpack_fails(blob, absl::StatusCode::kInvalidArgument,
                      "file 'textures/wood.png' does not match its SHA-256");
}

TEST_F(BundleTest, RefusesChangedManifest) {
  Bundle bundle = make(base_ / "one", refs_);
  std::string blob = pack(bundle);
  std::size_t at = blob.find("textures/wood.png");
  ASSERT_NE(at, std::string::npos);
  blob[at] = 'T';
  expect_unpack_fails(blob, absl::StatusCode::kInvalidArgument, "content hash mismatch");
  blob = pack(bundle);
  blob[20] = blob[20] == 'a' ? 'b' : 'a';  // the claimed hash
  expect_unpack_fails(blob, absl::StatusCode::kInvalidArgument, "content hash mismatch");
}

TEST_F(BundleTest, RefusesTruncatedBlobsAtEveryLength) {
  std::string blob = pack(make(base_ / "one", refs_));
  for (std::size_t length = 0; length < blob.size(); ++length) {
    auto unpacked = unpack(std::string_view(blob).substr(0, length));
    ASSERT_FALSE(unpacked.ok()) << length;
    EXPECT_EQ(unpacked.status().code(), absl::StatusCode::kInvalidArgument) << unpacked.status();
  }
  expect_unpack_fails(blob.substr(0, blob.size() - 1), absl::StatusCode::kInvalidArgument,
                      "truncated: the manifest lists");
  expect_unpack_fails(blob.substr(0, 40), absl::StatusCode::kInvalidArgument,
                      "truncated: 40 bytes");
  expect_unpack_fails(blob + "x", absl::StatusCode::kInvalidArgument,
                      "1 unexpected bytes after the last file");
}

TEST_F(BundleTest, RefusesBadHeaders) {
  std::string blob = pack(make(base_ / "one", refs_));
  std::string bad = blob;
  bad[0] = 'X';
  expect_unpack_fails(bad, absl::StatusCode::kInvalidArgument, "bad magic");
  bad = blob;
  bad[8] = 2;
  expect_unpack_fails(bad, absl::StatusCode::kInvalidArgument, "unsupported format version 2");
  bad = blob;
  bad[12] = 1;
  expect_unpack_fails(bad, absl::StatusCode::kInvalidArgument, "unknown flags");
  bad = blob;
  bad[16] = 'Z';
  expect_unpack_fails(bad, absl::StatusCode::kInvalidArgument, "malformed content hash");
  bad = blob;
  bad[87] = 0x7f;  // manifest length far beyond the blob
  expect_unpack_fails(bad, absl::StatusCode::kResourceExhausted, "manifest is");
  BundleLimits generous;
  generous.max_manifest_bytes = ~std::uint64_t{0};
  expect_unpack_fails(bad, absl::StatusCode::kInvalidArgument, "truncated: the manifest is",
                      generous);
}

TEST_F(BundleTest, RefusesUnsafeAndDuplicatePaths) {
  std::string scene = "scene";
  std::string head = "prism-bundle 1\nscene scene.pbrt\n";
  std::string ok_scene = file_line(scene, "scene.pbrt");
  expect_unpack_fails(handmade_blob(head + file_line("x", "../evil") + ok_scene, "x" + scene),
                      absl::StatusCode::kInvalidArgument, "path '../evil' has a '..' component");
  expect_unpack_fails(handmade_blob(head + file_line("x", "a/../../evil") + ok_scene, "x" + scene),
                      absl::StatusCode::kInvalidArgument, "'..' component");
  expect_unpack_fails(
      handmade_blob(head + file_line("x", "/etc/cron.d/evil") + ok_scene, "x" + scene),
      absl::StatusCode::kInvalidArgument, "is absolute");
  expect_unpack_fails(
      handmade_blob(head + file_line("x", "a") + file_line("x", "a") + ok_scene, "xx" + scene),
      absl::StatusCode::kInvalidArgument, "duplicate path 'a'");
  expect_unpack_fails(handmade_blob(head + ok_scene + file_line("x", "a"), scene + "x"),
                      absl::StatusCode::kInvalidArgument, "manifest is not sorted");
  expect_unpack_fails(
      handmade_blob(head + file_line("x", "a") + file_line("y", "a/b") + ok_scene, "xy" + scene),
      absl::StatusCode::kInvalidArgument, "'a' is both a file and the directory");
  expect_unpack_fails(handmade_blob(head + file_line("x", "a"), "x"),
                      absl::StatusCode::kInvalidArgument, "scene file 'scene.pbrt' is not in");
  std::string padded = "file " + base::sha256_hex(scene) + " 05 scene.pbrt\n";
  expect_unpack_fails(handmade_blob(head + padded, scene), absl::StatusCode::kInvalidArgument,
                      "not in canonical form");
  expect_unpack_fails(handmade_blob("prism-bundle 2\nscene scene.pbrt\n" + ok_scene, scene),
                      absl::StatusCode::kInvalidArgument, "does not start with");
  expect_unpack_fails(handmade_blob(head + "file abc 5 scene.pbrt\n", scene),
                      absl::StatusCode::kInvalidArgument, "malformed SHA-256");
  // A well-formed hand-made blob is accepted: the checks above are not artefacts of the helper.
  EXPECT_TRUE(unpack(handmade_blob(head + file_line("x", "a") + ok_scene, "x" + scene)).ok());
}

TEST_F(BundleTest, EnforcesLimits) {
  std::string blob = pack(make(base_ / "one", refs_));
  BundleLimits limits;
  limits.max_file_bytes = 9;
  expect_unpack_fails(blob, absl::StatusCode::kResourceExhausted,
                      "file 'meshes/bunny.ply' is 10 bytes, over the limit of 9", limits);
  limits = BundleLimits{};
  limits.max_total_bytes = 20;
  expect_unpack_fails(blob, absl::StatusCode::kResourceExhausted, "files total more than 20",
                      limits);
  limits = BundleLimits{};
  limits.max_files = 3;
  expect_unpack_fails(blob, absl::StatusCode::kResourceExhausted, "4 files, over the limit of 3",
                      limits);
  limits = BundleLimits{};
  limits.max_path_bytes = 10;
  expect_unpack_fails(blob, absl::StatusCode::kResourceExhausted, "over the limit of 10", limits);
  limits = BundleLimits{};
  limits.max_manifest_bytes = 100;
  expect_unpack_fails(blob, absl::StatusCode::kResourceExhausted, "manifest is", limits);
  // A size claim beyond every limit is refused before anything is allocated.
  std::string head = "prism-bundle 1\nscene scene.pbrt\n";
  expect_unpack_fails(
      handmade_blob(head + "file " + base::sha256_hex("") + " 18446744073709551615 scene.pbrt\n", ""),
      absl::StatusCode::kResourceExhausted, "over the limit");
}

TEST_F(BundleTest, RefusesManifestsWithTooManyLines) {
  BundleLimits limits;
  limits.max_files = 10;
  std::string manifest = "prism-bundle 1\nscene s\n" + std::string(100000, '\n');
  expect_unpack_fails(handmade_blob(manifest, ""), absl::StatusCode::kResourceExhausted,
                      "100000 files, over the limit of 10", limits);
}

TEST_F(BundleTest, RandomCorruptionIsAlwaysRefused) {
  const std::string blob = pack(make(base_ / "one", refs_));
  std::mt19937 rng(99);
  for (int round = 0; round < 3000; ++round) {
    std::string bad = blob;
    std::size_t at = rng() % bad.size();
    if (round % 3 == 0) {
      bad.erase(at, 1 + rng() % 16);
    } else {
      bad[at] = static_cast<char>(bad[at] ^ (1 + rng() % 255));
    }
    auto unpacked = unpack(bad);
    ASSERT_FALSE(unpacked.ok()) << "accepted a blob changed at byte " << at;
    EXPECT_TRUE(unpacked.status().code() == absl::StatusCode::kInvalidArgument ||
                unpacked.status().code() == absl::StatusCode::kResourceExhausted)
        << unpacked.status();
  }
}

TEST_F(BundleTest, ExtractWritesExactlyTheFiles) {
  Bundle bundle = make(base_ / "one", refs_);
  auto unpacked = unpack(pack(bundle));
  ASSERT_TRUE(unpacked.ok()) << unpacked.status();
  fs::path out = base_ / "out" / "job7";
  ASSERT_TRUE(extract_to(*unpacked, out).ok());
  std::map<std::string, std::string> expected;
  for (const BundleEntry& e : bundle.entries) expected[e.path] = e.contents;
  EXPECT_EQ(list_files(out), expected);
  // Extracting again overwrites in place.
  EXPECT_TRUE(extract_to(*unpacked, out).ok());
  EXPECT_EQ(list_files(out), expected);
  // The extracted scene bundles to the same hash.
  EXPECT_EQ(make(out, refs_).content_hash, bundle.content_hash);
}

TEST_F(BundleTest, ExtractNeverWritesOutsideTheDirectory) {
  Bundle bundle = make(base_ / "one", refs_);
  fs::path out = base_ / "out";
  fs::create_directories(out);
  fs::create_directories(base_ / "victim");
  fs::create_directory_symlink(base_ / "victim", out / "textures");
  absl::Status status = extract_to(bundle, out);
  EXPECT_EQ(status.code(), absl::StatusCode::kFailedPrecondition) << status;
  EXPECT_TRUE(fs::is_empty(base_ / "victim"));

  Bundle evil = bundle;
  evil.entries.insert(evil.entries.begin(), BundleEntry{"../escaped", 1, base::sha256_hex("x"), "x"});
  status = extract_to(evil, base_ / "out2");
  EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << status;
  EXPECT_FALSE(fs::exists(base_ / "escaped"));
  EXPECT_TRUE(list_files(base_ / "out2").empty());
}

}  // namespace
}  // namespace prism::scene
