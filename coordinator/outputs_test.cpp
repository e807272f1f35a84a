#include "coordinator/outputs.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "services/base/atomic_file.h"
#include "services/base/check.h"
#include "services/image/exr_spectral.h"
#include "services/image/png.h"
#include "services/spectral/wavelength_grid.h"
#include "tests/testing/test_dir.h"

namespace prism::coordinator {
namespace {
namespace fs = std::filesystem;
using prism::testing::fresh_dir;

std::vector<fs::path> listing(const fs::path& dir) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(dir)) files.push_back(entry.path().filename());
  std::sort(files.begin(), files.end());
  return files;
}

TEST(OutputPathsTest, NamesFollowTheSpectralOutput) {
  auto paths = output_paths(fs::path("renders/out.exr"), std::nullopt, "ignored.exr");
  ASSERT_TRUE(paths.ok()) << paths.status();
  EXPECT_EQ(paths->spectral_exr, fs::path("renders/out.exr"));
  EXPECT_EQ(paths->rgb_exr, fs::path("renders/out.rgb.exr"));
  EXPECT_EQ(paths->png, fs::path("renders/out.png"));
  EXPECT_EQ(paths->json, fs::path("renders/out.json"));

  auto no_extension = output_paths(fs::path("out"), fs::path("r/report.json"), "x.exr");
  ASSERT_TRUE(no_extension.ok()) << no_extension.status();
  EXPECT_EQ(no_extension->spectral_exr, fs::path("out.exr"));
  EXPECT_EQ(no_extension->json, fs::path("r/report.json"));
}

TEST(OutputPathsTest, DefaultIsTheFilmFilenameStemInTheCurrentDirectory) {
  auto paths = output_paths(std::nullopt, std::nullopt, "images/cornell-two-lights.exr");
  ASSERT_TRUE(paths.ok()) << paths.status();
  EXPECT_EQ(paths->spectral_exr, fs::path("cornell-two-lights.exr"));
  EXPECT_EQ(paths->rgb_exr, fs::path("cornell-two-lights.rgb.exr"));
  EXPECT_EQ(paths->png, fs::path("cornell-two-lights.png"));
  EXPECT_EQ(paths->json, fs::path("cornell-two-lights.json"));
  auto png_film = output_paths(std::nullopt, std::nullopt, "killeroo.png");
  ASSERT_TRUE(png_film.ok());
  EXPECT_EQ(png_film->spectral_exr, fs::path("killeroo.exr"));
}

// A directory, existing or written with a trailing '/', gets the default name inside it (the
// helper's `prism fetch -o fdir` wrote fdir.exr beside it).
TEST(OutputPathsTest, ADirectoryGetsTheDefaultNameInsideIt) {
  const fs::path dir = fresh_dir("into-dir");
  auto existing = output_paths(dir, std::nullopt, "scenes/killeroo.exr");
  ASSERT_TRUE(existing.ok()) << existing.status();
  EXPECT_EQ(existing->spectral_exr, dir / "killeroo.exr");
  EXPECT_EQ(existing->json, dir / "killeroo.json");
  auto slash = output_paths(fs::path("out/"), std::nullopt, "x.exr");
  ASSERT_TRUE(slash.ok());
  EXPECT_EQ(slash->spectral_exr, fs::path("out/x.exr"));
  EXPECT_EQ(output_paths(fs::path("out"), std::nullopt, "x.exr")->spectral_exr,
            fs::path("out.exr"));  // not a directory: a stem
}

TEST(OutputPathsTest, RefusesBadNames) {
  auto png = output_paths(fs::path("out.png"), std::nullopt, "x.exr");
  EXPECT_EQ(png.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(png.status().message().find("out.png"), std::string::npos);
  EXPECT_FALSE(output_paths(fs::path(""), std::nullopt, "x.exr").ok());
  for (const char* nameless : {".exr", "out/.exr", ".EXR"}) {
    auto n = output_paths(fs::path(nameless), std::nullopt, "x.exr");
    EXPECT_EQ(n.status().code(), absl::StatusCode::kInvalidArgument) << nameless;
  }
  auto clash = output_paths(fs::path("out.exr"), fs::path("./out.png"), "x.exr");
  EXPECT_EQ(clash.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(clash.status().message().find("out.png"), std::string::npos) << clash.status();
  EXPECT_FALSE(output_paths(fs::path("out.exr"), fs::path("out.exr"), "x.exr").ok());
}

TEST(OutputPathsTest, LocationsAreCheckedBeforeRendering) {
  const fs::path dir = fresh_dir("locations");
  auto ok = output_paths(dir / "a.exr", std::nullopt, "x.exr");
  ASSERT_TRUE(ok.ok());
  EXPECT_TRUE(check_output_locations(*ok).ok());
  auto missing = output_paths(dir / "no" / "a.exr", std::nullopt, "x.exr");
  ASSERT_TRUE(missing.ok());
  absl::Status status = check_output_locations(*missing);
  EXPECT_EQ(status.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(status.message().find("does not exist"), std::string::npos) << status;
  fs::create_directories(dir / "a.png");
  absl::Status is_dir = check_output_locations(*ok);
  EXPECT_EQ(is_dir.code(), absl::StatusCode::kInvalidArgument) << is_dir;
  EXPECT_TRUE(listing(dir) == std::vector<fs::path>{"a.png"});
  // A name that leaves no room for its temporary name (".NAME.tmp.PID.N" within 255 bytes) is
  // refused here, not after the render.
  auto long_name = output_paths(dir / (std::string(230, 'n') + ".exr"), std::nullopt, "x.exr");
  ASSERT_TRUE(long_name.ok());
  absl::Status too_long = check_output_locations(*long_name);
  EXPECT_EQ(too_long.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(too_long.message().find("bytes, over the 220"), std::string::npos) << too_long;
}

// The helper's finding: `prism render victim.pbrt --json victim.pbrt` replaced the scene with
// its report, and `-o texin.exr` the scene's own texture.
TEST(OutputPathsTest, NoOutputReplacesOneOfTheScenesFiles) {
  const fs::path dir = fresh_dir("scene-files");
  fs::create_directories(dir / "textures");
  for (const char* name : {"scene.pbrt", "textures/wood.exr"}) {
    std::ofstream(dir / name) << "x";
  }
  const std::vector<std::string> files = {"scene.pbrt", "textures/wood.exr"};
  auto json_on_scene =
      output_paths(dir / "out.exr", dir / "textures" / ".." / "scene.pbrt", "x.exr");
  ASSERT_TRUE(json_on_scene.ok());
  absl::Status status = check_outputs_spare_scene(*json_on_scene, dir, files);
  EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << status;
  EXPECT_NE(status.message().find("the scene's own file 'scene.pbrt'"), std::string::npos)
      << status;
  auto exr_on_texture = output_paths(dir / "textures" / "wood.exr", std::nullopt, "x.exr");
  ASSERT_TRUE(exr_on_texture.ok());
  EXPECT_EQ(check_outputs_spare_scene(*exr_on_texture, dir, files).code(),
            absl::StatusCode::kInvalidArgument);
  // Through a link too.
  fs::create_symlink(dir / "scene.pbrt", dir / "link.json");
  auto linked = output_paths(dir / "out.exr", dir / "link.json", "x.exr");
  ASSERT_TRUE(linked.ok());
  EXPECT_EQ(check_outputs_spare_scene(*linked, dir, files).code(),
            absl::StatusCode::kInvalidArgument);
  // Names beside them, existing or not, are fine.
  std::ofstream(dir / "old.exr") << "an earlier render";
  auto beside = output_paths(dir / "old.exr", std::nullopt, "x.exr");
  ASSERT_TRUE(beside.ok());
  EXPECT_TRUE(check_outputs_spare_scene(*beside, dir, files).ok());
  EXPECT_TRUE(check_not_a_scene_file(dir / "new.bundle", dir, files).ok());
  EXPECT_FALSE(check_not_a_scene_file(dir / "scene.pbrt", dir, files).ok());
}

image::TileResult result_with(const image::TileRect& rect, int bins,
                              const std::vector<std::vector<double>>& samples_per_pixel_bin0) {
  auto r = image::TileResult::create(rect, {0, 3}, bins);
  EXPECT_TRUE(r.ok());
  int p = 0;
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x, ++p) {
      for (double v : samples_per_pixel_bin0[p]) {
        std::vector<double> spectrum(bins, 0.0);
        spectrum[0] = v;
        spectrum[1] = 2 * v;
        r->add_sample(x, y, spectrum);
      }
    }
  }
  return *std::move(r);
}

TEST(BinStatisticsTest, MeansAndStandardErrorsMatchTheFormulas) {
  // Two tiles of two pixels. Pixel samples (bin 0; bin 1 is twice as much):
  //  {1,2,3}: mean 2, s^2 = 1, se = sqrt(1/3);  {5}: one sample, no error estimate;
  //  {4,4}:   mean 4, se 0;                      {0,10}: mean 5, s^2 = 50, se = 5.
  BinStatisticsAccumulator acc(2, 4);
  acc.add_tile(1, result_with({2, 0, 4, 1}, 4, {{4, 4}, {0, 10}}));
  acc.add_tile(0, result_with({0, 0, 2, 1}, 4, {{1, 2, 3}, {5}}));
  BinStatistics s = acc.finish();
  ASSERT_EQ(s.mean.size(), 4u);
  EXPECT_DOUBLE_EQ(s.mean[0], (2.0 + 5.0 + 4.0 + 5.0) / 4);
  EXPECT_DOUBLE_EQ(s.mean[1], 2 * (2.0 + 5.0 + 4.0 + 5.0) / 4);
  EXPECT_EQ(s.mean[2], 0.0);
  EXPECT_EQ(s.pixels_with_error, 3u);
  EXPECT_NEAR(s.standard_error[0], (std::sqrt(1.0 / 3) + 0.0 + 5.0) / 3, 1e-12);
  EXPECT_NEAR(s.standard_error[1], 2 * (std::sqrt(1.0 / 3) + 0.0 + 5.0) / 3, 1e-12);
  EXPECT_EQ(s.standard_error[3], 0.0);
  EXPECT_NEAR(s.variance_of_mean[0], (1.0 / 3 + 0.0 + 25.0) / 3, 1e-12);
  EXPECT_NEAR(s.variance_of_mean[1], 4 * (1.0 / 3 + 0.0 + 25.0) / 3, 1e-12);
}

// pbrt-v4's sensor: a D65 spectrum with ∫ ȳ·S dλ = 1 is linear sRGB (1, 1, 1).
TEST(ColourTest, BinnedD65AtUnitLuminanceIsSrgbWhite) {
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  const spectral::PiecewiseLinearSpectrum d65 = spectral::cie_d65();
  // Bins of 15 nm and finer: coarser bins blur the CMFs by more than 1 %.
  for (int bins : {32, 64, 256}) {
    auto grid = spectral::WavelengthGrid::create(bins);
    ASSERT_TRUE(grid.ok());
    std::vector<float> spectrum(bins);
    for (int b = 0; b < bins; ++b)
      spectrum[b] = static_cast<float>(d65.bin_average(grid->lower(b), grid->upper(b)));
    const double y = cmf.bin_weights(*grid).to_xyz(spectrum).y;
    for (float& v : spectrum) v = static_cast<float>(v / (y * spectral::kCieYIntegral));
    auto image = image::SpectralImage::create(3, 2, bins);
    ASSERT_TRUE(image.ok());
    for (int py = 0; py < 2; ++py)
      for (int px = 0; px < 3; ++px)
        for (int b = 0; b < bins; ++b) image->value(px, py, b) = spectrum[b] * (1 + px + 3 * py);
    auto rgb = to_linear_srgb(*image, cmf);
    ASSERT_TRUE(rgb.ok()) << rgb.status();
    for (int py = 0; py < 2; ++py)
      for (int px = 0; px < 3; ++px)
        for (int c = 0; c < 3; ++c)
          EXPECT_NEAR(rgb->value(px, py, c), 1 + px + 3 * py, 0.01 * (1 + px + 3 * py))
              << bins << " bins, channel " << c;
  }
  auto too_few = image::SpectralImage::create(1, 1, 3);
  ASSERT_TRUE(too_few.ok());
  EXPECT_EQ(to_linear_srgb(*too_few, cmf).status().code(), absl::StatusCode::kInvalidArgument);
}

// A black 2x2 image of 8 bins.
image::SpectralImage blank_image() {
  auto image = image::SpectralImage::create(2, 2, 8);
  PRISM_CHECK(image.ok());
  return *std::move(image);
}

RenderReport sample_report() {
  RenderReport r;
  r.scene = "scenes/box.pbrt";
  r.width = 4;
  r.height = 3;
  r.spp = 8;
  r.bins = 8;
  r.integrator = "hero";
  r.spectral_pdf = "flat";
  r.emitter_pdf = "emitters";
  r.light_selection = "power";
  r.max_depth = 5;
  r.threads = 2;
  r.tile_size = 32;
  r.seed = 7;
  r.wall_seconds = 2.0;
  r.render_seconds = 1.0;
  r.samples = 96;
  r.rays = 1000;
  r.counters = {{"rays", 1000}, {"non_finite", 0}};
  r.peak_memory_bytes = 1 << 20;
  r.statistics.mean.assign(8, 0.5);
  r.statistics.standard_error.assign(8, std::nan(""));
  return r;
}

TEST(WriteOutputsTest, WritesFourFilesThatReadBack) {
  const fs::path dir = fresh_dir("write");
  auto image = image::SpectralImage::create(4, 3, 8);
  ASSERT_TRUE(image.ok());
  for (std::size_t i = 0; i < image->data().size(); ++i)
    image->data()[i] = 0.001f * float(i) + 1e-7f;
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  auto paths = output_paths(dir / "render.exr", std::nullopt, "x.exr");
  ASSERT_TRUE(paths.ok());
  const RenderReport report = sample_report();
  ASSERT_TRUE(write_outputs(*image, cmf, report, *paths, {1.0f, {}}).ok());
  EXPECT_TRUE((listing(dir) ==
               std::vector<fs::path>{"render.exr", "render.json", "render.png", "render.rgb.exr"}));

  auto spectral = image::read_spectral_exr(paths->spectral_exr);
  ASSERT_TRUE(spectral.ok()) << spectral.status();
  ASSERT_EQ(spectral->spectral.data().size(), image->data().size());
  EXPECT_EQ(std::memcmp(spectral->spectral.data().data(), image->data().data(),
                        image->data().size() * sizeof(float)),
            0);
  EXPECT_EQ(spectral->metadata.at("spp"), "8");
  EXPECT_EQ(spectral->metadata.at("integrator"), "hero");
  EXPECT_EQ(spectral->metadata.at("seed"), "7");
  EXPECT_EQ(spectral->metadata.at("bins"), "8");
  EXPECT_EQ(spectral->metadata.at("scene"), "scenes/box.pbrt");
  EXPECT_EQ(spectral->metadata.at("version"), prism_version());

  auto expected_rgb = to_linear_srgb(*image, cmf);
  ASSERT_TRUE(expected_rgb.ok());
  auto rgb = image::read_rgb_exr(paths->rgb_exr);
  ASSERT_TRUE(rgb.ok()) << rgb.status();
  ASSERT_TRUE(spectral->rgb.has_value());
  for (std::size_t i = 0; i < expected_rgb->data().size(); ++i) {
    EXPECT_EQ(rgb->rgb.data()[i], expected_rgb->data()[i]);
    EXPECT_EQ(spectral->rgb->data()[i], expected_rgb->data()[i]);
  }
  auto png = image::read_png(paths->png);
  ASSERT_TRUE(png.ok()) << png.status();
  EXPECT_EQ(png->width, 4);
  EXPECT_EQ(png->height, 3);
  EXPECT_EQ(png->bytes[5 * 3 + 1], image::preview_byte(expected_rgb->value(1, 1, 1), 1.0f));

  auto text = base::read_file(paths->json);
  ASSERT_TRUE(text.ok());
  nlohmann::json j = nlohmann::json::parse(*text);
  EXPECT_EQ(j["scene"], "scenes/box.pbrt");
  EXPECT_EQ(j["spp"], 8);
  EXPECT_DOUBLE_EQ(j["samples_per_second"].get<double>(), 96.0);
  EXPECT_DOUBLE_EQ(j["samples_per_second_per_core"].get<double>(), 48.0);
  EXPECT_DOUBLE_EQ(j["rays_per_second"].get<double>(), 1000.0);
  EXPECT_EQ(j["counters"]["rays"], 1000);
  EXPECT_EQ(j["bin_centres_nm"].size(), 8u);
  EXPECT_TRUE(j["bin_standard_error"][0].is_null());
  EXPECT_EQ(j["outputs"]["png"], paths->png.string());
  EXPECT_EQ(j["peak_memory_bytes"], 1 << 20);
}

TEST(WriteOutputsTest, AFailedWriteNamesTheFileAndLeavesNothingPartial) {
  const fs::path dir = fresh_dir("fail");
  const image::SpectralImage image = blank_image();
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  // The PNG's name is taken by a directory: that one write fails, the others succeed.
  auto paths = output_paths(dir / "r.exr", std::nullopt, "x.exr");
  ASSERT_TRUE(paths.ok());
  fs::create_directories(paths->png);
  absl::Status status = write_outputs(image, cmf, sample_report(), *paths, {});
  EXPECT_FALSE(status.ok());
  EXPECT_NE(status.message().find("could not write '" + paths->png.string() + "'"),
            std::string::npos)
      << status;
  EXPECT_EQ(status.message().find("r.json'"), std::string::npos) << status;
  EXPECT_TRUE(fs::is_directory(paths->png));
  // No temporary files are left behind.
  EXPECT_TRUE((listing(dir) == std::vector<fs::path>{"r.exr", "r.json", "r.png", "r.rgb.exr"}));
}

// A gradient job's τ says where it came from, and the pilot's figures come with it.
TEST(WriteOutputsTest, TheJsonSaysHowTauWasChosen) {
  const fs::path dir = fresh_dir("tau");
  const image::SpectralImage image = blank_image();
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  auto paths = output_paths(dir / "render.exr", std::nullopt, "x.exr");
  ASSERT_TRUE(paths.ok());
  RenderReport report = sample_report();
  report.gradient = GradientReport{};
  report.gradient->tau = 0.25f;
  ASSERT_TRUE(write_outputs(image, cmf, report, *paths, {0.0f, {}}).ok());
  nlohmann::json given = nlohmann::json::parse(*base::read_file(paths->json));
  EXPECT_EQ(given["gradient"]["tau"], 0.25);
  EXPECT_EQ(given["gradient"]["tau_source"], "given");
  EXPECT_FALSE(given["gradient"].contains("tau_pilot"));

  report.gradient->tau_pilot =
      job::TauPilotReport{0.1f, 1200, 8, 5000, 0.25f, 0.5f, 0.0625f, 0.125f, 0.75f, 0.02};
  ASSERT_TRUE(write_outputs(image, cmf, report, *paths, {0.0f, {}}).ok());
  nlohmann::json pilot = nlohmann::json::parse(*base::read_file(paths->json));
  EXPECT_EQ(pilot["gradient"]["tau_source"], "pilot");
  const nlohmann::json& t = pilot["gradient"]["tau_pilot"];
  EXPECT_EQ(t["epsilon"], 0.1);
  EXPECT_EQ(t["pixels"], 1200);
  EXPECT_EQ(t["spp"], 8);
  EXPECT_EQ(t["events"], 5000);
  EXPECT_EQ(t["shifted_event_fraction"], 0.25);
  EXPECT_EQ(t["shifted_square_fraction"], 0.5);
  EXPECT_EQ(t["lost_benefit_fraction"], 0.0625);
  EXPECT_EQ(t["predicted_offset_work_fraction"], 0.125);
  EXPECT_EQ(t["predicted_second_moment_rise"], 0.75);
  EXPECT_EQ(t["seconds"], 0.02);
}

// A finished tile's RGB: the mean of the samples' own RGB when the result has them, plus the
// reconstruction's change of the bins' RGB for a reconstructed tile; the bins' RGB otherwise.
TEST(TileRgbTest, ComesFromTheSamplesRgbPlusTheReconstructionsChange) {
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  image::TileBuffers buffers;
  buffers.rgb = true;
  auto merged = image::TileResult::create({4, 2, 6, 3}, {0, 4}, 8, buffers);
  ASSERT_TRUE(merged.ok());
  for (int p = 0; p < 2; ++p) {
    merged->mutable_counts()[p] = 4;
    for (int b = 0; b < 8; ++b) merged->mutable_sums()[p * 8 + b] = 0.4 * (b + 1 + p);
  }
  const double sums[2][3] = {{0.8, 1.2, 0.4}, {2.0, 1.6, 3.2}};
  for (int p = 0; p < 2; ++p) {
    for (int c = 0; c < 3; ++c) merged->mutable_rgb_sums()[p * 3 + c] = sums[p][c];
  }
  const image::SpectralImage plain = image::finalise(*merged);
  image::SpectralImage reconstructed = plain;
  for (float& v : reconstructed.data()) v *= 1.25f;

  auto exact = tile_rgb(*merged, plain, false, cmf);
  ASSERT_TRUE(exact.ok()) << exact.status();
  auto corrected = tile_rgb(*merged, reconstructed, true, cmf);
  ASSERT_TRUE(corrected.ok()) << corrected.status();
  auto plain_rgb = to_linear_srgb(plain, cmf);
  auto reconstructed_rgb = to_linear_srgb(reconstructed, cmf);
  ASSERT_TRUE(plain_rgb.ok() && reconstructed_rgb.ok());
  for (int p = 0; p < 2; ++p) {
    const double w[3] = {sums[p][0] / 4, sums[p][1] / 4, sums[p][2] / 4};
    for (int c = 0; c < 3; ++c) {
      EXPECT_FLOAT_EQ(exact->value(p, 0, c), float(w[c]));
      EXPECT_FLOAT_EQ(corrected->value(p, 0, c),
                      float(w[c] + reconstructed_rgb->value(p, 0, c) - plain_rgb->value(p, 0, c)));
    }
  }
  // Without RGB buffers (a result from before them): the bins' RGB.
  auto bins_only = image::TileResult::create({4, 2, 6, 3}, {0, 4}, 8);
  ASSERT_TRUE(bins_only.ok());
  auto fallback = tile_rgb(*bins_only, reconstructed, true, cmf);
  ASSERT_TRUE(fallback.ok());
  EXPECT_TRUE(std::ranges::equal(fallback->data(), reconstructed_rgb->data()));
  // The finished tile must be the result's size.
  auto small = image::SpectralImage::create(1, 1, 8);
  EXPECT_EQ(tile_rgb(*merged, *small, false, cmf).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(PeakMemoryTest, IsAtLeastWhatWeTouch) {
  std::vector<char> block(64 << 20);
  for (std::size_t i = 0; i < block.size(); i += 4096) block[i] = char(i);
  EXPECT_GE(peak_memory_bytes(), std::uint64_t{64} << 20);
  EXPECT_GT(block[4096], -200);
}

}  // namespace
}  // namespace prism::coordinator
