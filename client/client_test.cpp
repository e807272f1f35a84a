#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "client/auto_integrator.h"
#include "client/check_command.h"
#include "client/compare_command.h"
#include "client/render_command.h"
#include "services/image/exr_spectral.h"

namespace prism::client {
namespace {

namespace fs = std::filesystem;
const fs::path kScenes = fs::path(PRISM_SOURCE_DIR) / "scenes";

TEST(CheckCommandTest, ReportsTheDispersivePrismScene) {
  auto checked = run_check({kScenes / "prism.pbrt", false});
  ASSERT_TRUE(checked.ok()) << checked.status();
  const std::string& text = checked->text;
  EXPECT_TRUE(checked->renders);
  EXPECT_NE(text.find("resolution: 320x240"), std::string::npos) << text;
  EXPECT_NE(text.find("stdillum-F11"), std::string::npos);
  EXPECT_NE(text.find("dispersive materials: 1"), std::string::npos);
  EXPECT_NE(text.find("bundle: 2 files, hash "), std::string::npos);

  auto json = run_check({kScenes / "prism.pbrt", true});
  ASSERT_TRUE(json.ok());
  auto j = nlohmann::json::parse(json->text);
  EXPECT_EQ(j["width"], 320);
  EXPECT_EQ(j["dispersive_materials"].size(), 1u);
  EXPECT_EQ(j["bundle_hash"].get<std::string>().size(), 64u);
  EXPECT_TRUE(j["needs_spectral_transport"]);
}

TEST(CheckCommandTest, ReportsTwoEmitterSpectraInTheCornellBox) {
  auto json = run_check({kScenes / "cornell-two-lights.pbrt", true});
  ASSERT_TRUE(json.ok()) << json.status();
  auto j = nlohmann::json::parse(json->text);
  EXPECT_EQ(j["emitter_spectra"].size(), 2u);
  EXPECT_EQ(j["area_lights"], 2);
  EXPECT_TRUE(j["media"].empty());
  // The same scene gives the same bundle hash every time.
  auto again = nlohmann::json::parse(run_check({kScenes / "cornell-two-lights.pbrt", true})->text);
  EXPECT_EQ(j["bundle_hash"], again["bundle_hash"]);
}

TEST(CheckCommandTest, UnknownNamedSpectrumIsAnErrorAtItsPosition) {
  fs::path dir = fs::temp_directory_path() / ("prism_check_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  {
    std::ofstream out(dir / "s.pbrt");
    out << "WorldBegin\nAttributeBegin\n  AreaLightSource \"diffuse\" \"spectrum L\" "
           "\"stdillum-F99\"\n  Shape \"sphere\"\nAttributeEnd\n";
  }
  auto result = run_check({dir / "s.pbrt", false});
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(std::string(result.status().message()).starts_with("s.pbrt:3:")) << result.status();
  EXPECT_NE(result.status().message().find("stdillum-F99"), std::string::npos);
  fs::remove_all(dir);
}

TEST(CompareCommandTest, PrintsMetricsOfTwoImages) {
  fs::path dir = fs::temp_directory_path() / ("prism_compare_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  auto ref = *image::SpectralImage::from_data(2, 1, 4, {1, 1, 1, 1, 2, 2, 2, 2});
  auto test = *image::SpectralImage::from_data(2, 1, 4, {1, 1, 1, 1, 2, 2, 2, 4});
  auto rgb = *image::RgbImage::from_data(2, 1, {0, 0, 0, 0, 0, 0});
  ASSERT_TRUE(image::write_spectral_exr(dir / "ref.exr", ref, rgb).ok());
  ASSERT_TRUE(image::write_spectral_exr(dir / "test.exr", test, rgb).ok());
  auto json = run_compare({dir / "test.exr", dir / "ref.exr", std::nullopt, true});
  ASSERT_TRUE(json.ok()) << json.status();
  auto j = nlohmann::json::parse(*json);
  // One of eight values is off by 2: MSE = 4 / 8; relMSE = (4 / (4 + 0.01)) / 8.
  EXPECT_DOUBLE_EQ(j["spectral"]["mse"].get<double>(), 0.5);
  EXPECT_NEAR(j["spectral"]["rel_mse"].get<double>(), 4.0 / 4.01 / 8, 1e-12);
  // The crop that excludes the differing pixel has no error.
  auto cropped = nlohmann::json::parse(
      *run_compare({dir / "test.exr", dir / "ref.exr", image::Crop{0, 0, 1, 1}, true}));
  EXPECT_EQ(cropped["spectral"]["mse"].get<double>(), 0.0);
  auto outside = run_compare({dir / "test.exr", dir / "ref.exr", image::Crop{1, 0, 2, 1}, false});
  EXPECT_EQ(outside.status().code(), absl::StatusCode::kInvalidArgument);
  fs::remove_all(dir);
}

TEST(CompareCommandTest, CropSyntax) {
  auto crop = parse_crop("3,4,10,20");
  ASSERT_TRUE(crop.ok());
  EXPECT_EQ(crop->x, 3);
  EXPECT_EQ(crop->h, 20);
  for (const char* bad : {"", "1,2,3", "1,2,3,4,5", "a,b,c,d", "-1,0,1,1", "1,2,3,4x"}) {
    EXPECT_EQ(parse_crop(bad).status().code(), absl::StatusCode::kInvalidArgument) << bad;
  }
  // The message names the flag the text came from (prism bench's --inset parses it too).
  EXPECT_EQ(parse_crop("1,2,3").status().message(),
            "--crop '1,2,3': want x,y,w,h as four non-negative integers");
  EXPECT_EQ(parse_crop("1,2,3", "--inset").status().message(),
            "--inset '1,2,3': want x,y,w,h as four non-negative integers");
}

// A target error is 0.01 or 1 %, and a bad one is refused under the flag that gave it (prism
// bench's --reference-error parses it too).
TEST(RenderCommandTest, TargetErrorSyntax) {
  EXPECT_DOUBLE_EQ(*parse_target_error("0.01"), 0.01);
  EXPECT_DOUBLE_EQ(*parse_target_error("1%"), 0.01);
  for (const char* bad : {"", "0", "%", "abc", "-1", "200%", "0.5x"}) {
    EXPECT_EQ(parse_target_error(bad).status().code(), absl::StatusCode::kInvalidArgument) << bad;
  }
  EXPECT_EQ(parse_target_error("0", "--reference-error").status().message().substr(0, 25),
            "--reference-error '0': wa");
  EXPECT_EQ(parse_target_error("0").status().message().substr(0, 22), "--target-error '0': wa");
}

// The filters' widths at their documented limits: 0.1 nm as a double is below the float 0.1f the
// job holds, and was refused with "want nm in 0.1..470".
TEST(RenderCommandTest, FilterWidthsTakeTheirLimits) {
  for (double width : {0.1, 470.0}) {
    RenderCommandOptions splat;
    splat.integrator = "light";
    splat.splat_width = width;
    EXPECT_TRUE(validate_render_flags(splat).ok()) << width << validate_render_flags(splat);
    RenderCommandOptions gather;
    gather.integrator = "hero";
    gather.gather_width = width;
    EXPECT_TRUE(validate_render_flags(gather).ok()) << width << validate_render_flags(gather);
  }
  RenderCommandOptions narrow;
  narrow.integrator = "light";
  narrow.splat_width = 0.09;
  EXPECT_FALSE(validate_render_flags(narrow).ok());
}

// The share of light paths that minimises (eye + light/s)(eye_rays + s·light_rays) for
// hero+caustics's eye and light parts, against the closed form.
CausticSplit make_split(double eye_variance, double light_variance, double eye_rays,
                        double light_rays) {
  return {.eye_variance = eye_variance,
          .light_variance = light_variance,
          .eye_rays = eye_rays,
          .light_rays = light_rays};
}

TEST(AutoIntegratorTest, TheCausticShareMinimisesVarianceTimesRays) {
  // eye 0.03, light 0.0008 per sample at s = 1; eye rays 2, light rays 1.
  const CausticSplit split = make_split(0.03, 0.0008, 2.0, 1.0);
  // sqrt(0.0008·2 / (0.03·1)) = 0.2309, whose nearest power of two (in log2) is 1/4.
  EXPECT_EQ(split.best_share(), 0.25);
  EXPECT_NEAR(split.variance(0.25), 0.0332, 1e-12);
  EXPECT_NEAR(split.rays(0.25), 2.25, 1e-12);
  // The power of two found is the best of all of them.
  for (double s = 1.0; s >= job::kMinCausticPaths; s /= 2) {
    EXPECT_LE(split.variance(0.25) * split.rays(0.25), split.variance(s) * split.rays(s)) << s;
  }
  // Light paths with no variance (they find nothing the eye paths would not): the fewest.
  EXPECT_EQ(make_split(0.03, 0.0, 2.0, 1.0).best_share(), job::kMinCausticPaths);
  // Eye paths with no variance (the light part is all of it): every light path.
  EXPECT_EQ(make_split(0.0, 0.001, 2.0, 1.0).best_share(), 1.0);
}

// Clean caustics: the most light paths within 2 % of hero's rays, taken where at that share they
// render the caustic paths at least 4 times cleaner than the eye tracers. The README demo's
// probe figures (scenes/prism.pbrt at 64 spp): light part 6.92e-7 per sample at one path, 1.873
// rays per light path, the eye tracers' caustic variance 3.405e-4, hero's 2.007 rays.
TEST(AutoIntegratorTest, CleanCausticsTakeTheMostLightPathsTwoPercentOfRaysBuy) {
  const CausticSplit demo = make_split(0.03525 - 6.92e-7, 6.92e-7, 3.871 - 1.873, 1.873);
  // 0.02·2.007/1.873 = 0.0214 light paths at most: 1/64; 6.92e-7·64 = 4.4e-5 <= 3.405e-4/4.
  EXPECT_EQ(clean_caustic_share(demo, 3.405e-4, 2.007), 1.0 / 64);
  // Twice hero's rays allow twice the share.
  EXPECT_EQ(clean_caustic_share(demo, 3.405e-4, 4.014), 1.0 / 32);
  // At 1/64 the light paths are 7.7 times cleaner: not with an eye variance under 4 times theirs.
  EXPECT_EQ(clean_caustic_share(demo, 4.0 * 6.92e-7 * 64 * 0.99, 2.007), std::nullopt);
  EXPECT_EQ(clean_caustic_share(demo, 4.0 * 6.92e-7 * 64 * 1.01, 2.007), 1.0 / 64);
  // Light paths so dear that 2 % of hero's rays buy fewer than 1/256 per pixel: none.
  EXPECT_EQ(clean_caustic_share(make_split(0.03, 1e-9, 100.0, 500.0), 1.0, 2.0), std::nullopt);
  // So cheap that every pixel gets one: the share stops at 1.
  EXPECT_EQ(clean_caustic_share(make_split(0.03, 1e-9, 2.999, 0.001), 1.0, 2.0), 1.0);
  // Nothing to clean: no caustic variance, or light paths that found nothing.
  EXPECT_EQ(clean_caustic_share(demo, 0.0, 2.007), std::nullopt);
  EXPECT_EQ(clean_caustic_share(make_split(0.03525, 0.0, 1.998, 1.873), 3.405e-4, 2.007),
            std::nullopt);
}

}  // namespace
}  // namespace prism::client
