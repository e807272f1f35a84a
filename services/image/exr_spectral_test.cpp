#include "services/image/exr_spectral.h"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <ImfStringAttribute.h>
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>

#include "absl/strings/str_format.h"

namespace prism::image {
namespace {

namespace fs = std::filesystem;

class ExrTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("prism_exr_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

// Random finite floats over the whole exponent range: denormals, tiny, huge, negative, zero.
std::vector<float> random_floats(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<float> v(n);
  for (float& f : v) {
    do {
      f = std::bit_cast<float>(static_cast<std::uint32_t>(rng()));
    } while (!std::isfinite(f));
  }
  if (n >= 4) {
    v[0] = std::numeric_limits<float>::denorm_min();
    v[1] = std::numeric_limits<float>::max();
    v[2] = -0.0f;
    v[3] = 1e-30f;
  }
  return v;
}

RgbImage random_rgb(int w, int h, std::uint64_t seed) {
  return RgbImage::from_data(w, h, random_floats(std::size_t(w) * h * 3, seed)).value();
}

TEST_F(ExrTest, SpectralRoundTripIsBitExact) {
  for (int bins : {4, 64, 100, 256}) {
    int w = 7, h = 5;
    auto spectral =
        SpectralImage::from_data(w, h, bins, random_floats(std::size_t(w) * h * bins, bins));
    ASSERT_TRUE(spectral.ok());
    RgbImage rgb = random_rgb(w, h, 1000 + bins);
    ExrMetadata metadata{{"spp", "1024"},
                         {"integrator", "hero"},
                         {"seed", "42"},
                         {"job_id", "job-7"},
                         {"note", "free text, with spaces"}};
    fs::path path = dir_ / absl::StrFormat("b%d.exr", bins);
    ASSERT_TRUE(write_spectral_exr(path, *spectral, rgb, metadata).ok());
    auto read = read_spectral_exr(path);
    ASSERT_TRUE(read.ok()) << read.status();
    ASSERT_EQ(read->spectral.bins(), bins);
    ASSERT_EQ(read->spectral.width(), w);
    ASSERT_EQ(read->spectral.height(), h);
    EXPECT_EQ(std::memcmp(read->spectral.data().data(), spectral->data().data(),
                          spectral->data().size_bytes()),
              0)
        << bins << " bins";
    ASSERT_TRUE(read->rgb.has_value());
    EXPECT_EQ(std::memcmp(read->rgb->data().data(), rgb.data().data(), rgb.data().size_bytes()), 0);
    EXPECT_EQ(read->wavelengths_nm, bin_centres_nm(bins));
    EXPECT_EQ(read->metadata, metadata);
  }
}

TEST_F(ExrTest, StreamedBandsWriteTheSameFileAsTheWholeImage) {
  const int w = 13, h = 11, bins = 16;
  auto spectral =
      SpectralImage::from_data(w, h, bins, random_floats(std::size_t(w) * h * bins, 77)).value();
  RgbImage rgb = random_rgb(w, h, 78);
  ExrMetadata metadata{{"spp", "8"}};
  ASSERT_TRUE(write_spectral_exr(dir_ / "whole.exr", spectral, rgb, metadata).ok());
  for (int band_rows : {1, 4, 11, 64}) {
    // Each band is served from a fresh buffer, as the coordinator's tile reader does.
    std::vector<float> buffer;
    std::vector<int> asked;
    auto rows = [&](int y0, int n) -> absl::StatusOr<const float*> {
      asked.push_back(y0);
      EXPECT_EQ(n, std::min(band_rows, h - y0));
      auto band = spectral.crop({0, y0, w, y0 + n}).value();
      buffer.assign(band.data().begin(), band.data().end());
      return buffer.data();
    };
    const fs::path path = dir_ / absl::StrFormat("bands%d.exr", band_rows);
    ASSERT_TRUE(
        write_spectral_exr_rows(path, bin_centres_nm(bins), w, h, band_rows, rows, rgb, metadata)
            .ok());
    EXPECT_EQ(asked.size(), std::size_t((h + band_rows - 1) / band_rows));
    auto read = read_spectral_exr(path);
    ASSERT_TRUE(read.ok()) << read.status();
    EXPECT_EQ(std::memcmp(read->spectral.data().data(), spectral.data().data(),
                          spectral.data().size_bytes()),
              0)
        << band_rows << " rows per band";
    EXPECT_EQ(std::memcmp(read->rgb->data().data(), rgb.data().data(), rgb.data().size_bytes()), 0);
  }
  // A failing source abandons the file.
  auto failing = [&](int y0, int) -> absl::StatusOr<const float*> {
    if (y0 > 0) return absl::DataLossError("tile 3 is unreadable");
    return spectral.data().data();
  };
  absl::Status status = write_spectral_exr_rows(dir_ / "failed.exr", bin_centres_nm(bins), w, h, 4,
                                                failing, rgb, metadata);
  EXPECT_EQ(status.code(), absl::StatusCode::kDataLoss) << status;
  EXPECT_FALSE(fs::exists(dir_ / "failed.exr"));
}

std::string file_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// A stream fed band by band, with its metadata given only at the end, writes the bytes
// write_spectral_exr_rows writes, at every compression and thread count; the file appears only
// at write(), and the stream's own file has no name.
TEST_F(ExrTest, StreamedWhileRenderingWritesTheSameBytes) {
  const int w = 37, h = 70, bins = 24;
  auto spectral =
      SpectralImage::from_data(w, h, bins, random_floats(std::size_t(w) * h * bins, 9)).value();
  RgbImage rgb = random_rgb(w, h, 10);
  const ExrMetadata metadata{{"spp", "8"}, {"integrator", "hero"}};
  const fs::path work = dir_ / "work";
  fs::create_directories(work);
  for (ExrCompression compression : all_exr_compressions()) {
    for (int threads : {1, 2}) {
      const ExrWriteOptions options{compression, threads};
      const std::string label = absl::StrFormat("%s-%d", name(compression), threads);
      const fs::path direct = dir_ / (label + ".direct.exr");
      ASSERT_TRUE(write_spectral_exr(direct, spectral, rgb, metadata, options).ok());
      auto stream = SpectralExrStream::create(work, bin_centres_nm(bins), w, h, options);
      ASSERT_TRUE(stream.ok()) << stream.status();
      const fs::path streamed = dir_ / (label + ".streamed.exr");
      EXPECT_EQ((*stream)->write(streamed, metadata).code(), absl::StatusCode::kFailedPrecondition);
      for (int y0 = 0, band = 0; y0 < h; ++band) {
        const int rows = std::min(h - y0, 5 + band % 7);  // uneven bands
        auto cut = spectral.crop({0, y0, w, y0 + rows}).value();
        ASSERT_TRUE(
            (*stream)
                ->write_rows(rows, cut.data().data(), rgb.data().data() + std::size_t(y0) * w * 3)
                .ok());
        y0 += rows;
      }
      EXPECT_TRUE(fs::is_empty(work)) << "the stream's file has no name";
      EXPECT_FALSE(fs::exists(streamed));
      EXPECT_EQ((*stream)->write_rows(1, spectral.data().data(), rgb.data().data()).code(),
                absl::StatusCode::kInvalidArgument);
      ASSERT_TRUE((*stream)->write(streamed, metadata).ok());
      EXPECT_TRUE(file_bytes(streamed) == file_bytes(direct)) << label;
    }
  }
  EXPECT_EQ(SpectralExrStream::create(work, {500.0, 400.0}, w, h).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(SpectralExrStream::create(dir_ / "missing", bin_centres_nm(bins), w, h).status().code(),
            absl::StatusCode::kInternal);
}

// Every offered compression is lossless, is the one the header records, and writes the same
// bytes whatever the thread count (a job's outputs are bytes-identical on any machine).
TEST_F(ExrTest, EveryCompressionIsLosslessAndThreadCountFree) {
  // Taller than several line blocks (PIZ: 32 rows) so the threads have blocks to share.
  const int w = 37, h = 101, bins = 24;
  auto spectral =
      SpectralImage::from_data(w, h, bins, random_floats(std::size_t(w) * h * bins, 5)).value();
  RgbImage rgb = random_rgb(w, h, 6);
  ASSERT_EQ(all_exr_compressions().size(), 5u);
  for (ExrCompression compression : all_exr_compressions()) {
    const std::string label(name(compression));
    EXPECT_EQ(parse_exr_compression(label), compression);
    std::string first_bytes;
    for (int threads : {1, 2, 5}) {
      const fs::path path = dir_ / absl::StrFormat("%s-%d.exr", label, threads);
      ASSERT_TRUE(write_spectral_exr(path, spectral, rgb, {}, {compression, threads}).ok());
      Imf::InputFile file(path.c_str());
      EXPECT_EQ(static_cast<int>(file.header().compression()),
                static_cast<int>(compression == ExrCompression::kNone   ? Imf::NO_COMPRESSION
                                 : compression == ExrCompression::kRle  ? Imf::RLE_COMPRESSION
                                 : compression == ExrCompression::kZips ? Imf::ZIPS_COMPRESSION
                                 : compression == ExrCompression::kZip  ? Imf::ZIP_COMPRESSION
                                                                        : Imf::PIZ_COMPRESSION))
          << label;
      auto read = read_spectral_exr(path);
      ASSERT_TRUE(read.ok()) << read.status();
      EXPECT_EQ(std::memcmp(read->spectral.data().data(), spectral.data().data(),
                            spectral.data().size_bytes()),
                0)
          << label << ", " << threads << " threads";
      EXPECT_EQ(std::memcmp(read->rgb->data().data(), rgb.data().data(), rgb.data().size_bytes()),
                0);
      std::ifstream in(path, std::ios::binary);
      const std::string bytes((std::istreambuf_iterator<char>(in)),
                              std::istreambuf_iterator<char>());
      if (threads == 1) {
        first_bytes = bytes;
      } else {
        EXPECT_TRUE(bytes == first_bytes) << label << ": " << threads << " threads differ";
      }
    }
  }
  for (const char* bad : {"", "ZIP", "dwaa", "pxr24", "b44"}) {
    EXPECT_FALSE(parse_exr_compression(bad).has_value()) << bad;
  }
}

TEST_F(ExrTest, ChannelNamesAndAttributesFollowTheSpectralLayout) {
  auto spectral = SpectralImage::create(2, 2, 64);
  fs::path path = dir_ / "names.exr";
  ASSERT_TRUE(write_spectral_exr(path, *spectral, *RgbImage::create(2, 2), {{"spp", "16"}}).ok());

  Imf::InputFile file(path.c_str());
  const Imf::ChannelList& channels = file.header().channels();
  for (const char* name : {"S0.363,671875nm", "S0.371,015625nm", "S0.598,671875nm",
                           "S0.826,328125nm", "R", "G", "B"}) {
    const Imf::Channel* channel = channels.findChannel(name);
    ASSERT_NE(channel, nullptr) << name;
    EXPECT_EQ(channel->type, Imf::FLOAT) << name;
  }
  int count = 0;
  for (auto it = channels.begin(); it != channels.end(); ++it) ++count;
  EXPECT_EQ(count, 64 + 3);
  const auto* version =
      file.header().findTypedAttribute<Imf::StringAttribute>("spectralLayoutVersion");
  ASSERT_NE(version, nullptr);
  EXPECT_EQ(version->value(), "1.0");
  const auto* units = file.header().findTypedAttribute<Imf::StringAttribute>("emissiveUnits");
  ASSERT_NE(units, nullptr);
  EXPECT_EQ(units->value(), "W.m^-2.sr^-1");
  const auto* spp = file.header().findTypedAttribute<Imf::StringAttribute>("prism:spp");
  ASSERT_NE(spp, nullptr);
  EXPECT_EQ(spp->value(), "16");
}

TEST(SpectralChannelName, FormatsAndParses) {
  EXPECT_EQ(bin_centre_nm(0, 64), 363.671875);
  EXPECT_EQ(spectral_channel_name(bin_centre_nm(0, 64)), "S0.363,671875nm");
  EXPECT_EQ(spectral_channel_name(bin_centre_nm(63, 64)), "S0.826,328125nm");
  EXPECT_EQ(spectral_channel_name(bin_centre_nm(0, 100)), "S0.362,35nm");
  EXPECT_EQ(spectral_channel_name(bin_centre_nm(0, 47)), "S0.365nm");
  EXPECT_EQ(spectral_channel_name(bin_centre_nm(0, 4)), "S0.418,75nm");
  EXPECT_EQ(parse_spectral_channel_name("S0.363,671875nm"), 363.671875);
  EXPECT_EQ(parse_spectral_channel_name("S0.400.000nm"), 400.0);
  EXPECT_EQ(parse_spectral_channel_name("S0.550nm"), 550.0);
  EXPECT_FALSE(parse_spectral_channel_name("S0.550Hz").has_value());
  EXPECT_FALSE(parse_spectral_channel_name("S0.5,5,0nm").has_value());
  EXPECT_FALSE(parse_spectral_channel_name("S0.nm").has_value());
  EXPECT_FALSE(parse_spectral_channel_name("S1.550nm").has_value());
  EXPECT_FALSE(parse_spectral_channel_name("S0.-5nm").has_value());
  for (int bins : {4, 64, 100, 256}) {
    for (int b = 0; b < bins; ++b) {
      double lambda = bin_centre_nm(b, bins);
      EXPECT_EQ(parse_spectral_channel_name(spectral_channel_name(lambda)), lambda);
    }
  }
}

// Writes a file the way another renderer would: the given channel names, FLOAT, value
// (channel index + 1) * 0.5 + pixel index, channels in the given order.
void write_foreign(const fs::path& path, const std::vector<std::string>& names, int w, int h,
                   bool with_rgb, const std::vector<std::pair<std::string, std::string>>& attrs) {
  Imf::Header header(w, h);
  for (const auto& [k, v] : attrs) header.insert(k, Imf::StringAttribute(v));
  std::vector<std::string> all = names;
  if (with_rgb) all.insert(all.end(), {"R", "G", "B"});
  std::vector<std::vector<float>> planes(all.size(), std::vector<float>(std::size_t(w) * h));
  Imf::FrameBuffer frame;
  for (std::size_t c = 0; c < all.size(); ++c) {
    header.channels().insert(all[c], Imf::Channel(Imf::FLOAT));
    for (int p = 0; p < w * h; ++p) planes[c][p] = float(c + 1) * 0.5f + float(p);
    frame.insert(all[c], Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(planes[c].data()),
                                    sizeof(float), sizeof(float) * w));
  }
  Imf::OutputFile file(path.c_str(), header);
  file.setFrameBuffer(frame);
  file.writePixels(h);
}

TEST_F(ExrTest, ReadsThreeDecimalChannelsWithDotsOrCommas) {
  for (char separator : {'.', ','}) {
    // Deliberately not in wavelength order (names sort as strings in the file anyway).
    std::vector<std::string> names;
    for (const char* lambda : {"600.500", "400.000", "1000.250", "450.125"}) {
      std::string s = lambda;
      s[s.find('.')] = separator;
      names.push_back("S0." + s + "nm");
    }
    fs::path path = dir_ / (separator == '.' ? "dots.exr" : "commas.exr");
    write_foreign(path, names, 3, 2, false,
                  {{"spectralLayoutVersion", "1.0"}, {"emissiveUnits", "W.m^-2.sr^-1"}});
    auto read = read_spectral_exr(path);
    ASSERT_TRUE(read.ok()) << read.status();
    EXPECT_EQ(read->wavelengths_nm, (std::vector<double>{400.0, 450.125, 600.5, 1000.25}));
    EXPECT_FALSE(read->rgb.has_value());
    // Bin order follows wavelength: 400 was written as channel 1, 450.125 as 3, 600.5 as 0.
    EXPECT_EQ(read->spectral.value(0, 0, 0), 1.0f);
    EXPECT_EQ(read->spectral.value(0, 0, 1), 2.0f);
    EXPECT_EQ(read->spectral.value(0, 0, 2), 0.5f);
    EXPECT_EQ(read->spectral.value(2, 1, 3), 1.5f + 5.0f);
  }
}

TEST_F(ExrTest, RefusesRgbOnlyPolarisedReflectiveAndDuplicateFiles) {
  auto expect_refused = [&](const std::string& file, const std::vector<std::string>& names,
                            bool rgb, const std::string& needle) {
    fs::path path = dir_ / file;
    write_foreign(path, names, 2, 2, rgb, {});
    auto read = read_spectral_exr(path);
    ASSERT_FALSE(read.ok()) << file;
    EXPECT_EQ(read.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(read.status().message().find(needle), std::string::npos) << read.status();
    EXPECT_NE(read.status().message().find(path.string()), std::string::npos) << read.status();
  };
  expect_refused("rgb.exr", {}, true, "no spectral channels");
  expect_refused("polarised.exr", {"S0.500nm", "S1.500nm", "S2.500nm", "S3.500nm"}, false,
                 "polarised");
  expect_refused("reflective.exr", {"T.500nm"}, false, "reflective");
  expect_refused("duplicate.exr", {"S0.500nm", "S0.500,000nm"}, false, "same wavelength");
  expect_refused("units.exr", {"S0.5,5e14Hz"}, false, "S0.<wavelength>nm");

  fs::path garbage = dir_ / "garbage.exr";
  std::FILE* f = std::fopen(garbage.c_str(), "wb");
  std::fputs("not an exr file at all", f);
  std::fclose(f);
  EXPECT_EQ(read_spectral_exr(garbage).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(read_spectral_exr(dir_ / "missing.exr").status().code(), absl::StatusCode::kNotFound);
  // A PNG (the preview, given where its EXR belongs) is named as one.
  fs::path png = dir_ / "preview.png";
  std::FILE* p = std::fopen(png.c_str(), "wb");
  std::fputs("\x89PNG\r\n\x1a\n and the rest", p);
  std::fclose(p);
  const absl::Status not_exr = read_spectral_exr(png).status();
  EXPECT_EQ(not_exr.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(not_exr.message().find("preview.png: it is a PNG, and an OpenEXR file is wanted"),
            std::string::npos)
      << not_exr;
}

TEST_F(ExrTest, RgbRoundTripFloatExactAndHalfClose) {
  RgbImage rgb = RgbImage::from_data(4, 3, random_floats(36, 5)).value();
  fs::path path = dir_ / "rgb.exr";
  ASSERT_TRUE(write_rgb_exr(path, rgb, ExrPixelType::kFloat, {{"integrator", "path"}}).ok());
  auto read = read_rgb_exr(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(std::memcmp(read->rgb.data().data(), rgb.data().data(), rgb.data().size_bytes()), 0);
  EXPECT_EQ(read->metadata.at("integrator"), "path");

  std::vector<float> values(36);
  for (int i = 0; i < 36; ++i) values[i] = 0.01f * float(i) + 0.001f;
  values[35] = 1e6f;  // beyond half's range
  RgbImage moderate = RgbImage::from_data(4, 3, values).value();
  fs::path half_path = dir_ / "half.exr";
  absl::Status half_status = write_rgb_exr(half_path, moderate, ExrPixelType::kHalf);
  ASSERT_TRUE(half_status.ok()) << half_status;
  {
    Imf::InputFile file(half_path.c_str());
    EXPECT_EQ(file.header().channels().findChannel("R")->type, Imf::HALF);
  }
  auto half = read_rgb_exr(half_path);
  ASSERT_TRUE(half.ok()) << half.status();
  for (int i = 0; i < 35; ++i) EXPECT_NEAR(half->rgb.data()[i], values[i], values[i] * 1e-3f);
  EXPECT_TRUE(std::isinf(half->rgb.data()[35]));

  // A spectral file read as RGB gives its R, G, B; an RGB file read generically has no bins.
  auto spectral = SpectralImage::create(4, 3, 4);
  ASSERT_TRUE(write_spectral_exr(dir_ / "s.exr", *spectral, rgb).ok());
  auto from_spectral = read_rgb_exr(dir_ / "s.exr");
  ASSERT_TRUE(from_spectral.ok());
  EXPECT_EQ(
      std::memcmp(from_spectral->rgb.data().data(), rgb.data().data(), rgb.data().size_bytes()), 0);
  auto generic = read_exr(path);
  ASSERT_TRUE(generic.ok());
  EXPECT_FALSE(generic->spectral.has_value());
  EXPECT_TRUE(generic->rgb.has_value());
  write_foreign(dir_ / "y.exr", {"Y"}, 2, 2, false, {});
  EXPECT_EQ(read_rgb_exr(dir_ / "y.exr").status().code(), absl::StatusCode::kInvalidArgument);
}

TEST_F(ExrTest, InvalidWritesAndFailedWritesLeaveNoFile) {
  auto spectral = SpectralImage::create(4, 4, 8);
  auto rgb_wrong = RgbImage::create(3, 4);
  fs::path path = dir_ / "out.exr";
  EXPECT_EQ(write_spectral_exr(path, *spectral, *rgb_wrong).code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(fs::exists(path));
  EXPECT_FALSE(write_spectral_exr(path, {500, 400, 600, 700, 710, 720, 730, 740}, *spectral,
                                  *RgbImage::create(4, 4))
                   .ok());
  EXPECT_FALSE(fs::exists(path));

  // The final rename fails (the target is a non-empty directory): no file, no temporary.
  fs::create_directories(dir_ / "taken.exr" / "child");
  absl::Status status = write_spectral_exr(dir_ / "taken.exr", *spectral, *RgbImage::create(4, 4));
  EXPECT_FALSE(status.ok());
  EXPECT_TRUE(fs::is_directory(dir_ / "taken.exr"));
  // A directory that does not exist: OpenEXR cannot create the temporary.
  status = write_rgb_exr(dir_ / "missing" / "x.exr", *RgbImage::create(2, 2));
  EXPECT_FALSE(status.ok());
  EXPECT_NE(status.message().find("x.exr"), std::string::npos) << status;
  int entries = 0;
  for (const auto& entry : fs::directory_iterator(dir_)) {
    (void)entry;
    ++entries;
  }
  EXPECT_EQ(entries, 1);  // only taken.exr
}

}  // namespace
}  // namespace prism::image
