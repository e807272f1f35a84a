#include "services/store/blob_store.h"

#include <gtest/gtest.h>

#include <fstream>
#include <iterator>

#include "services/base/sha256.h"
#include "tests/testing/test_dir.h"

namespace prism::store {
namespace {

namespace fs = std::filesystem;
using prism::testing::fresh_dir;

TEST(BlobStoreTest, PutGetByHash) {
  auto dir = fresh_dir("putget");
  auto store = BlobStore::open(dir);
  ASSERT_TRUE(store.ok()) << store.status();
  auto hash = store->put("scene bytes");
  ASSERT_TRUE(hash.ok());
  EXPECT_EQ(*hash, base::sha256_hex("scene bytes"));
  EXPECT_TRUE(store->contains(*hash));
  EXPECT_EQ(*store->get(*hash), "scene bytes");
  EXPECT_EQ(*store->size(*hash), 11u);
  // Same bytes again: same name, still one file.
  EXPECT_EQ(*store->put("scene bytes"), *hash);
  // Deleting is idempotent.
  ASSERT_TRUE(store->remove(*hash).ok());
  EXPECT_FALSE(store->contains(*hash));
  EXPECT_EQ(store->get(*hash).status().code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(store->remove(*hash).ok());
  EXPECT_EQ(store->remove("../x").code(), absl::StatusCode::kInvalidArgument);
  fs::remove_all(dir);
}

TEST(BlobStoreTest, DiscardMovesTheBlobOutAndAFreshPutWritesItAgain) {
  auto dir = fresh_dir("discard");
  auto store = BlobStore::open(dir / "blobs");
  ASSERT_TRUE(store.ok()) << store.status();
  fs::create_directories(dir / "trash");
  auto hash = store->put("tile result");
  ASSERT_TRUE(hash.ok());
  ASSERT_TRUE(store->discard(*hash, dir / "trash").ok());
  EXPECT_FALSE(store->contains(*hash));
  std::ifstream moved(dir / "trash" / *hash);
  std::string bytes((std::istreambuf_iterator<char>(moved)), std::istreambuf_iterator<char>());
  EXPECT_EQ(bytes, "tile result");
  EXPECT_TRUE(store->discard(*hash, dir / "trash").ok()) << "discarding twice is harmless";
  EXPECT_EQ(*store->put("tile result"), *hash);
  EXPECT_EQ(*store->get(*hash), "tile result");
  EXPECT_EQ(store->discard("../x", dir / "trash").code(), absl::StatusCode::kInvalidArgument);
  fs::remove_all(dir);
}

TEST(BlobStoreTest, RefusesBadHashesAndMismatchedContent) {
  auto dir = fresh_dir("bad");
  auto store = BlobStore::open(dir);
  ASSERT_TRUE(store.ok());
  EXPECT_EQ(store->get("../../etc/passwd").status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store->get(base::sha256_hex("absent")).status().code(), absl::StatusCode::kNotFound);
  auto status = store->put_verified(base::sha256_hex("one"), "two");
  EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(store->contains(base::sha256_hex("one")));
  fs::remove_all(dir);
}

TEST(BlobStoreTest, CorruptionOnDiskIsReportedNotServed) {
  auto dir = fresh_dir("corrupt");
  auto store = BlobStore::open(dir);
  ASSERT_TRUE(store.ok());
  std::string hash = *store->put("original");
  {
    std::ofstream out(dir / hash.substr(0, 2) / hash, std::ios::trunc);
    out << "tampered";
  }
  EXPECT_EQ(store->get(hash).status().code(), absl::StatusCode::kDataLoss);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace prism::store
