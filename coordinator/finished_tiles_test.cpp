#include "coordinator/finished_tiles.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <fstream>
#include <random>

#include "services/base/sha256.h"
#include "services/image/tile_codec.h"

namespace prism::coordinator {
namespace {

namespace fs = std::filesystem;

constexpr int kWidth = 23, kHeight = 17, kBins = 8, kTile = 8;

class FinishedTilesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("prism_finished_tiles_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    plan_ = *plan_tiles({kWidth, kHeight, kTile, 4, 0});
  }
  void TearDown() override { fs::remove_all(dir_); }

  image::TileResult merged(int tile) const {
    const image::TileRect& rect = plan_.tiles[tile];
    auto result = image::TileResult::create(rect, {0, 4}, kBins).value();
    std::mt19937_64 rng(tile);
    std::uniform_real_distribution<double> u(0.0, 10.0);
    std::vector<double> spectrum(kBins);
    for (int y = rect.y0; y < rect.y1; ++y) {
      for (int x = rect.x0; x < rect.x1; ++x) {
        for (int s = 0; s < 4; ++s) {
          for (double& v : spectrum) v = u(rng);
          result.add_sample(x, y, spectrum);
        }
      }
    }
    return result;
  }

  fs::path dir_;
  TilePlan plan_;
};

TEST_F(FinishedTilesTest, StreamedRowsEqualTheImageAssembledInMemory) {
  auto tiles = FinishedTiles::open(dir_ / "job" / "tiles", plan_, kWidth, kBins);
  ASSERT_TRUE(tiles.ok()) << tiles.status();
  auto whole = image::SpectralImage::create(kWidth, kHeight, kBins).value();
  for (std::size_t t = 0; t < plan_.tiles.size(); ++t) {
    EXPECT_FALSE(tiles->has(int(t)));
    const image::TileResult m = merged(int(t));
    ASSERT_TRUE(tiles->put(int(t), m).ok());
    EXPECT_TRUE(tiles->has(int(t)));
    ASSERT_TRUE(image::paste_tile(image::finalise(m), m.rect(), whole).ok());
    // What comes back is the same result, byte for byte.
    EXPECT_EQ(image::serialise_tile(*tiles->get(int(t))), image::serialise_tile(m));
  }
  std::vector<float> buffer;
  image::SpectralRows rows = tiles->rows(
      [](const image::TileResult& r) -> absl::StatusOr<image::SpectralImage> {
        return image::finalise(r);
      },
      &buffer);
  EXPECT_EQ(tiles->band_rows(), kTile);
  for (int y0 = 0; y0 < kHeight; y0 += kTile) {
    const int n = std::min(kTile, kHeight - y0);
    auto band = rows(y0, n);
    ASSERT_TRUE(band.ok()) << band.status();
    const auto expected = whole.crop({0, y0, kWidth, y0 + n}).value();
    EXPECT_EQ(std::memcmp(*band, expected.data().data(), expected.data().size_bytes()), 0) << y0;
  }
  EXPECT_EQ(rows(3, 8).status().code(), absl::StatusCode::kInternal);
  ASSERT_TRUE(tiles->remove().ok());
  EXPECT_FALSE(fs::exists(dir_ / "job" / "tiles"));
}

TEST_F(FinishedTilesTest, RefusesForeignTilesAndReportsDamagedRecords) {
  {
    auto tiles = FinishedTiles::open(dir_, plan_, kWidth, kBins);
    ASSERT_TRUE(tiles.ok());
    EXPECT_EQ(tiles->put(1, merged(0)).code(), absl::StatusCode::kInvalidArgument);
    EXPECT_EQ(tiles->put(-1, merged(0)).code(), absl::StatusCode::kInvalidArgument);
    absl::Status missing = tiles->get(2).status();
    EXPECT_EQ(missing.code(), absl::StatusCode::kDataLoss);
    EXPECT_NE(missing.message().find("finished tile 2 in"), std::string::npos) << missing;
    EXPECT_NE(missing.message().find("tiles.pack"), std::string::npos) << missing;
    for (int tile : {0, 1, 2}) ASSERT_TRUE(tiles->put(tile, merged(tile)).ok());
    // A rewrite supersedes the first record.
    ASSERT_TRUE(tiles->put(1, merged(1)).ok());
    EXPECT_TRUE(tiles->get(1).ok());
  }
  const fs::path pack = dir_ / "tiles.pack";
  const std::uintmax_t whole = fs::file_size(pack);
  {
    // A flipped byte inside tile 0's record (the first; its header is 48 bytes): its hash no
    // longer matches.
    std::fstream file(pack, std::ios::in | std::ios::out | std::ios::binary);
    file.seekp(200);
    const char flipped = static_cast<char>(file.peek() ^ 0x5a);
    file.seekp(200);
    file.put(flipped);
  }
  {
    // The last record torn (a crash while appending): tile 1 falls back to its first record.
    fs::resize_file(pack, whole - 40);
    auto tiles = FinishedTiles::open(dir_, plan_, kWidth, kBins);
    ASSERT_TRUE(tiles.ok());
    absl::Status damaged = tiles->get(0).status();
    EXPECT_EQ(damaged.code(), absl::StatusCode::kDataLoss);
    EXPECT_NE(damaged.message().find("do not match their hash"), std::string::npos) << damaged;
    EXPECT_TRUE(tiles->get(1).ok());
    EXPECT_TRUE(tiles->get(2).ok());
    EXPECT_FALSE(tiles->has(3));
    // Appends go over the torn record.
    ASSERT_TRUE(tiles->put(3, merged(3)).ok());
    EXPECT_TRUE(tiles->get(3).ok());
    std::vector<float> buffer;
    auto rows = tiles->rows(
        [](const image::TileResult& r) -> absl::StatusOr<image::SpectralImage> {
          return image::finalise(r);
        },
        &buffer);
    EXPECT_EQ(rows(0, kTile).status().code(), absl::StatusCode::kDataLoss);
  }
  auto reopened = FinishedTiles::open(dir_, plan_, kWidth, kBins);
  ASSERT_TRUE(reopened.ok());
  EXPECT_TRUE(reopened->get(3).ok());
  EXPECT_TRUE(reopened->get(1).ok());
  EXPECT_EQ(reopened->get(0).status().code(), absl::StatusCode::kDataLoss);
}

// A linked tile is read from the result pack, survives a reopen, is refused without a pack,
// and is DATA_LOSS when its range there is damaged; mixed with ordinary records in one pack.
TEST_F(FinishedTilesTest, ALinkedTileIsReadFromTheResultPack) {
  fs::create_directories(dir_ / "job");
  auto pack = ResultPack::open(dir_ / "job" / "results.pack");
  ASSERT_TRUE(pack.ok()) << pack.status();
  image::TileResult one = merged(1);
  one.round_to_float32();
  const std::string bytes = image::serialise_tile(one);
  const std::uint64_t offset = (*pack)->reserve(bytes.size());
  ASSERT_TRUE((*pack)->write(offset, bytes).ok());
  base::Sha256 hasher;
  hasher.update(bytes);
  const std::array<std::uint8_t, 32> sha = hasher.digest();
  {
    auto tiles = FinishedTiles::open(dir_ / "job" / "tiles", plan_, kWidth, kBins, *pack);
    ASSERT_TRUE(tiles.ok()) << tiles.status();
    ASSERT_TRUE(tiles->put(0, merged(0)).ok());
    ASSERT_TRUE(tiles->put_link(1, offset, bytes.size(), sha).ok());
    EXPECT_TRUE(tiles->linked(1));
    EXPECT_FALSE(tiles->linked(0));
    EXPECT_EQ(tiles->put_link(int(plan_.tiles.size()), offset, bytes.size(), sha).code(),
              absl::StatusCode::kInvalidArgument);
    // The link is 56 bytes: the tile's bytes are not written again.
    EXPECT_EQ(fs::file_size(tiles->pack_path()), 48 + image::serialise_tile(merged(0)).size() + 56);
  }
  auto reopened = FinishedTiles::open(dir_ / "job" / "tiles", plan_, kWidth, kBins, *pack);
  ASSERT_TRUE(reopened.ok()) << reopened.status();
  EXPECT_TRUE(reopened->linked(1));
  auto got = reopened->get(1);
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_TRUE(*got == one);
  auto first = reopened->get(0);
  ASSERT_TRUE(first.ok()) << first.status();
  EXPECT_TRUE(*first == merged(0));

  // Without the result pack: links cannot be made, and a linked tile cannot be read.
  auto alone = FinishedTiles::open(dir_ / "job" / "tiles", plan_, kWidth, kBins);
  ASSERT_TRUE(alone.ok()) << alone.status();
  EXPECT_EQ(alone->put_link(2, offset, bytes.size(), sha).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(alone->get(1).status().code(), absl::StatusCode::kDataLoss);

  // A damaged range in the result pack: DATA_LOSS naming the tile.
  ASSERT_TRUE((*pack)->write(offset + 100, "damage").ok());
  const absl::Status damaged = reopened->get(1).status();
  EXPECT_EQ(damaged.code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(damaged.message().find("finished tile 1"), std::string::npos) << damaged;

  // A torn link (the last record cut short) is forgotten, and the tile is not finished.
  fs::resize_file(reopened->pack_path(), fs::file_size(reopened->pack_path()) - 3);
  auto torn = FinishedTiles::open(dir_ / "job" / "tiles", plan_, kWidth, kBins, *pack);
  ASSERT_TRUE(torn.ok()) << torn.status();
  EXPECT_FALSE(torn->has(1));
  EXPECT_TRUE(torn->has(0));
}

}  // namespace
}  // namespace prism::coordinator
