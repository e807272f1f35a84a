// End-to-end tests of `prism render`, running the real binary (PRISM_BINARY) in a fresh
// directory: output bytes do not depend on thread count or tile size, and bad scenes or flags
// fail with a clear message, a non-zero exit and no file written.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "services/base/atomic_file.h"
#include "services/image/exr_spectral.h"
#include "services/image/png.h"
#include "tests/testing/child_process.h"
#include "tests/testing/test_dir.h"

namespace {
namespace fs = std::filesystem;
using prism::testing::fresh_dir;

struct CommandRun {
  int exit_code = -1;
  std::string output;  // stdout and stderr
};

// Runs `prism <args>` with `dir` as the working directory; stdout and stderr in order.
CommandRun run_prism(const fs::path& dir, const std::vector<std::string>& args) {
  std::vector<std::string> argv = {PRISM_BINARY};
  argv.insert(argv.end(), args.begin(), args.end());
  prism::testing::ChildOptions options;
  options.working_dir = dir;
  options.merge_stderr = true;
  const prism::testing::RunResult run = prism::testing::run(std::move(argv), options);
  return CommandRun{run.exit_code, run.out};
}

std::vector<std::string> listing(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& entry : fs::recursive_directory_iterator(dir))
    names.push_back(fs::relative(entry.path(), dir).string());
  std::sort(names.begin(), names.end());
  return names;
}

std::string source(const std::string& relative) {
  return (fs::path(PRISM_SOURCE_DIR) / relative).string();
}

const std::string kCornell = "scenes/cornell-two-lights.pbrt";

std::vector<std::string> cornell_args(const std::string& out, const std::string& threads,
                                      const std::string& tile) {
  return {"render",    source(kCornell), "-o",     out,  "--resolution", "64x64", "--spp",  "4",
          "--threads", threads,          "--tile", tile, "--max-depth",  "5",     "--seed", "3"};
}

std::vector<float> spectral_pixels(const fs::path& path, std::vector<double>* wavelengths) {
  auto exr = prism::image::read_spectral_exr(path);
  EXPECT_TRUE(exr.ok()) << exr.status();
  if (!exr.ok()) return {};
  if (wavelengths != nullptr) *wavelengths = exr->wavelengths_nm;
  return {exr->spectral.data().begin(), exr->spectral.data().end()};
}

// `first`'s arguments followed by `then`'s.
std::vector<std::string> joined(std::vector<std::string> first,
                                const std::vector<std::string>& then) {
  first.insert(first.end(), then.begin(), then.end());
  return first;
}

bool same_bits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

TEST(RenderCliTest, BytesDoNotDependOnThreadsOrTileSize) {
  const fs::path dir = fresh_dir("determinism");
  CommandRun a = run_prism(dir, cornell_args("t1_tile16.exr", "1", "16"));
  ASSERT_EQ(a.exit_code, 0) << a.output;
  CommandRun b = run_prism(dir, cornell_args("t2_tile16.exr", "2", "16"));
  ASSERT_EQ(b.exit_code, 0) << b.output;
  CommandRun c = run_prism(dir, cornell_args("t2_tile64.exr", "2", "64"));
  ASSERT_EQ(c.exit_code, 0) << c.output;
  EXPECT_NE(a.output.find("wrote t1_tile16.exr, t1_tile16.rgb.exr, t1_tile16.png, t1_tile16.json"),
            std::string::npos)
      << a.output;

  std::vector<double> wavelengths;
  const std::vector<float> reference = spectral_pixels(dir / "t1_tile16.exr", &wavelengths);
  ASSERT_EQ(reference.size(), 64u * 64u * 32u);  // the Film's nbuckets
  ASSERT_EQ(wavelengths.size(), 32u);
  EXPECT_TRUE(same_bits(reference, spectral_pixels(dir / "t2_tile16.exr", nullptr)));
  EXPECT_TRUE(same_bits(reference, spectral_pixels(dir / "t2_tile64.exr", nullptr)));
  // The whole files too: nothing in them records threads or tiles.
  EXPECT_EQ(*prism::base::read_file(dir / "t1_tile16.exr"),
            *prism::base::read_file(dir / "t2_tile64.exr"));
  EXPECT_EQ(*prism::base::read_file(dir / "t1_tile16.png"),
            *prism::base::read_file(dir / "t2_tile64.png"));
  // Nor how the scene's path was typed: the outputs name it as the job does, by its path in the
  // bundle, as a farm job's do.
  std::vector<std::string> relative = cornell_args("relative.exr", "1", "16");
  relative[1] = fs::relative(source(kCornell), dir).string();
  ASSERT_NE(relative[1], source(kCornell));
  CommandRun r = run_prism(dir, relative);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(*prism::base::read_file(dir / "t1_tile16.exr"),
            *prism::base::read_file(dir / "relative.exr"));

  // The render is a real image: finite, non-negative, lit.
  double total = 0;
  for (float v : reference) {
    ASSERT_TRUE(std::isfinite(v));
    ASSERT_GE(v, 0.0f);
    total += v;
  }
  EXPECT_GT(total, 0.0);

  // A different seed changes the noise, so the equalities above are not vacuous.
  CommandRun d = run_prism(dir, {"render", source(kCornell), "-o", "seed4.exr", "--resolution",
                                 "64x64", "--spp", "4", "--max-depth", "5", "--seed", "4"});
  ASSERT_EQ(d.exit_code, 0) << d.output;
  EXPECT_FALSE(same_bits(reference, spectral_pixels(dir / "seed4.exr", nullptr)));

  auto text = prism::base::read_file(dir / "t2_tile64.json");
  ASSERT_TRUE(text.ok());
  nlohmann::json j = nlohmann::json::parse(*text);
  EXPECT_EQ(j["width"], 64);
  EXPECT_EQ(j["spp"], 4);
  EXPECT_EQ(j["bins"], 32);
  EXPECT_EQ(j["threads"], 2);
  EXPECT_EQ(j["tile_size"], 64);
  EXPECT_EQ(j["integrator"], "hero");
  EXPECT_EQ(j["max_depth"], 5);
  EXPECT_EQ(j["samples"], 64 * 64 * 4);
  EXPECT_GE(j["rays"].get<std::uint64_t>(), 64u * 64u * 4u);
  EXPECT_EQ(j["counters"]["camera_rays"], 64 * 64 * 4);
  EXPECT_GT(j["peak_memory_bytes"].get<std::uint64_t>(), 0u);
  EXPECT_EQ(j["bin_mean"].size(), 32u);
  EXPECT_EQ(j["outputs"]["spectral_exr"], "t2_tile64.exr");
  auto png = prism::image::read_png(dir / "t2_tile64.png");
  ASSERT_TRUE(png.ok()) << png.status();
  EXPECT_EQ(png->width, 64);
  EXPECT_EQ(png->height, 64);
  auto rgb = prism::image::read_rgb_exr(dir / "t2_tile64.rgb.exr");
  ASSERT_TRUE(rgb.ok()) << rgb.status();
  EXPECT_EQ(rgb->metadata.at("seed"), "3");
  EXPECT_EQ(rgb->metadata.at("scene"), "cornell-two-lights.pbrt");
  EXPECT_EQ(j["scene"], "cornell-two-lights.pbrt");
}

TEST(RenderCliTest, DefaultsComeFromTheScene) {
  // No -o: the Film's filename stem in the working directory; bins from nbuckets, resolution
  // from the Film (overridden here to stay small), spp from the Sampler.
  const fs::path dir = fresh_dir("defaults");
  const fs::path scene = dir / "scene";
  fs::create_directories(scene);
  auto text = prism::base::read_file(source("tests/testdata/render/non_finite.pbrt"));
  ASSERT_TRUE(text.ok());
  std::string fixed = *text;
  const std::string bad = "[ 1e999 ]";
  fixed.replace(fixed.find(bad), bad.size(), "[ 4 ]");
  fixed.replace(fixed.find("non_finite.exr"), std::strlen("non_finite.exr"), "sub/lamp.exr");
  ASSERT_TRUE(prism::base::write_file_atomic(scene / "lamp.pbrt", fixed).ok());
  CommandRun run = run_prism(dir, {"render", "scene/lamp.pbrt", "--threads", "2"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_EQ(listing(dir), (std::vector<std::string>{"lamp.exr", "lamp.json", "lamp.png",
                                                    "lamp.rgb.exr", "scene", "scene/lamp.pbrt"}));
  auto exr = prism::image::read_spectral_exr(dir / "lamp.exr");
  ASSERT_TRUE(exr.ok()) << exr.status();
  EXPECT_EQ(exr->spectral.width(), 16);
  EXPECT_EQ(exr->spectral.bins(), 16);
  EXPECT_EQ(exr->metadata.at("spp"), "4");
  EXPECT_EQ(exr->metadata.at("max_depth"), "5");
}

struct BadCase {
  std::vector<std::string> args;
  std::string message;  // must appear in the output
};

void expect_failure_writes_nothing(const std::string& name, const BadCase& c) {
  const fs::path dir = fresh_dir(name);
  CommandRun run = run_prism(dir, c.args);
  EXPECT_NE(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find(c.message), std::string::npos) << "expected '" << c.message << "' in:\n"
                                                           << run.output;
  EXPECT_TRUE(listing(dir).empty()) << name << " left files behind";
}

TEST(RenderCliTest, BadScenesFailClearlyAndWriteNothing) {
  const std::string bad = "tests/testdata/render/";
  expect_failure_writes_nothing(
      "missing_mesh",
      {{"render", source(bad + "missing_mesh.pbrt")},
       "prism: missing_mesh.pbrt:14:17: file \"meshes/missing.ply\" does not exist"});
  expect_failure_writes_nothing(
      "non_finite", {{"render", source(bad + "non_finite.pbrt")},
                     "prism: non_finite.pbrt:10:68: value '1e999' of 'float scale' is not a "
                     "finite number"});
  expect_failure_writes_nothing(
      "unsupported", {{"render", source(bad + "unsupported.pbrt")},
                      "prism: unsupported.pbrt:3:8: unsupported camera type \"realistic\""});
  expect_failure_writes_nothing("no_scene", {{"render", "no/such/scene.pbrt"}, "does not exist"});
}

// An output that is one of the scene's own files is refused before anything is written: the
// report onto the scene or its mesh, and the bundle of `prism pack` onto the scene.
TEST(RenderCliTest, OutputsNeverReplaceTheScenesOwnFiles) {
  const fs::path dir = fresh_dir("outputs_spare_scene");
  fs::copy(source("scenes/prism.pbrt"), dir / "scene.pbrt");
  fs::copy(source("scenes/prism"), dir / "prism", fs::copy_options::recursive);
  const std::string before = prism::base::read_file(dir / "scene.pbrt", 1 << 20).value();
  const std::string mesh = prism::base::read_file(dir / "prism" / "prism.obj", 1 << 20).value();
  const std::vector<std::string> files_before = listing(dir);
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"render", "scene.pbrt", "--json", "scene.pbrt"},
        std::vector<std::string>{"render", "scene.pbrt", "--json", "prism/../prism/prism.obj"},
        std::vector<std::string>{"pack", "scene.pbrt", "--bundle", "./scene.pbrt"}}) {
    std::vector<std::string> full = args;
    for (const char* extra : {"--spp", "1", "--resolution", "8x8", "--integrator", "hero"}) {
      full.push_back(extra);
    }
    const CommandRun run = run_prism(dir, full);
    EXPECT_NE(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("it is the scene's own file '"), std::string::npos) << run.output;
    EXPECT_EQ(prism::base::read_file(dir / "scene.pbrt", 1 << 20).value(), before);
    EXPECT_EQ(prism::base::read_file(dir / "prism" / "prism.obj", 1 << 20).value(), mesh);
    EXPECT_EQ(listing(dir), files_before);
  }
}

// A render to a target error: rounds of samples until every pixel meets it or max spp is
// reached. Its bytes do not depend on the threads; the report says what was reached; a looser
// target stops earlier with fewer samples, and a target met in round 1 is the plain render.
TEST(RenderCliTest, TargetErrorRendersStopWhereTheErrorIsMetAndDoNotDependOnThreads) {
  const fs::path dir = fresh_dir("target_error");
  auto args = [&](const std::string& out, const std::string& threads, const std::string& target) {
    return std::vector<std::string>{"render",         source(kCornell), "-o",        out,
                                    "--resolution",   "32x32",          "--spp",     "4",
                                    "--target-error", target,           "--max-spp", "128",
                                    "--threads",      threads,          "--tile",    "8"};
  };
  CommandRun a = run_prism(dir, args("a.exr", "1", "20%"));
  ASSERT_EQ(a.exit_code, 0) << a.output;
  CommandRun b = run_prism(dir, args("b.exr", "2", "20%"));
  ASSERT_EQ(b.exit_code, 0) << b.output;
  EXPECT_NE(a.output.find("to 20 % per pixel:"), std::string::npos) << a.output;
  EXPECT_EQ(*prism::base::read_file(dir / "a.exr"), *prism::base::read_file(dir / "b.exr"));
  auto report = [&](const std::string& name) {
    return nlohmann::json::parse(*prism::base::read_file(dir / name))["target_error"];
  };
  const auto t = report("a.json");
  ASSERT_FALSE(t.is_null());
  EXPECT_EQ(t["scope"], "pixel");
  // The target travels as a float; the report gives its shortest decimal, as given.
  EXPECT_EQ(t["target"].get<double>(), 0.2);
  for (const char* k : {"pixel_max", "pixel_mean", "pixel_p99", "image"}) {
    EXPECT_TRUE(std::isfinite(t["reached"][k].get<double>())) << k;
  }
  if (t["met"].get<bool>()) {
    EXPECT_LE(t["reached"]["pixel_max"].get<double>(), 0.2 + 1e-9);
  } else {
    EXPECT_EQ(t["spp"]["max"], 128);
  }
  EXPECT_LE(t["reached"]["pixel_p99"].get<double>(), t["reached"]["pixel_max"].get<double>());
  EXPECT_LE(t["reached"]["pixel_mean"].get<double>(), t["reached"]["pixel_max"].get<double>());
  // A looser target takes no more samples.
  CommandRun loose = run_prism(dir, args("loose.exr", "2", "60%"));
  ASSERT_EQ(loose.exit_code, 0) << loose.output;
  EXPECT_LE(report("loose.json")["spp"]["mean"].get<double>(), t["spp"]["mean"].get<double>());
  // A target the first 4 samples meet (the image's mean to 50 %) stops after round 1: the plain
  // 4-spp render's bytes.
  std::vector<std::string> met_args = args("met.exr", "2", "50%");
  met_args.insert(met_args.end(), {"--target-error-scope", "image"});
  CommandRun met = run_prism(dir, met_args);
  ASSERT_EQ(met.exit_code, 0) << met.output;
  CommandRun plain = run_prism(dir, {"render", source(kCornell), "-o", "plain.exr", "--resolution",
                                     "32x32", "--spp", "4", "--tile", "8"});
  ASSERT_EQ(plain.exit_code, 0) << plain.output;
  const auto m = report("met.json");
  if (m["rounds"] == 1) {
    EXPECT_TRUE(same_bits(spectral_pixels(dir / "met.exr", nullptr),
                          spectral_pixels(dir / "plain.exr", nullptr)));
  } else {
    ADD_FAILURE() << "a 50 % target for the image was not met in round 1: " << m.dump();
  }
}

// `prism reconstruct` of a gradient render's own primal and gradient files gives that render's
// image: the same bins, and the same RGB (the primal's exact RGB plus the reconstruction's
// change; it was the bins' RGB, 1.8 % off in relMSE at 16 bins).
TEST(RenderCliTest, ReconstructOfARendersPairIsThatRender) {
  const fs::path dir = fresh_dir("reconstruct_pair");
  CommandRun render =
      run_prism(dir, {"render", source("scenes/dispersive-caustic.pbrt"), "-o", "g.exr",
                      "--resolution", "24x16", "--spp", "16", "--bins", "16", "--integrator",
                      "gradient", "--primal-and-gradients", "--threads", "2"});
  ASSERT_EQ(render.exit_code, 0) << render.output;
  CommandRun again =
      run_prism(dir, {"reconstruct", "g.primal.exr", "g.gradient.exr", "-o", "r.exr"});
  ASSERT_EQ(again.exit_code, 0) << again.output;
  auto rendered = prism::image::read_spectral_exr(dir / "g.exr");
  auto reconstructed = prism::image::read_spectral_exr(dir / "r.exr");
  ASSERT_TRUE(rendered.ok() && reconstructed.ok());
  ASSERT_TRUE(rendered->rgb.has_value() && reconstructed->rgb.has_value());
  const auto& a = rendered->spectral.data();
  const auto& b = reconstructed->spectral.data();
  ASSERT_EQ(a.size(), b.size());
  double peak = 0;
  for (float v : a) peak = std::max(peak, double(std::abs(v)));
  ASSERT_GT(peak, 0);
  for (std::size_t i = 0; i < a.size(); ++i) ASSERT_NEAR(a[i], b[i], 1e-5 * peak) << i;
  const auto& ra = rendered->rgb->data();
  const auto& rb = reconstructed->rgb->data();
  ASSERT_EQ(ra.size(), rb.size());
  double rgb_peak = 0;
  for (float v : ra) rgb_peak = std::max(rgb_peak, double(std::abs(v)));
  for (std::size_t i = 0; i < ra.size(); ++i) ASSERT_NEAR(ra[i], rb[i], 1e-5 * rgb_peak) << i;
  // A reconstruction says it is one, and is not taken as a primal.
  EXPECT_EQ(reconstructed->metadata["content"], "reconstruction");
  CommandRun twice = run_prism(dir, {"reconstruct", "r.exr", "g.gradient.exr", "-o", "r2.exr"});
  EXPECT_NE(twice.exit_code, 0);
  EXPECT_NE(twice.output.find("holds the reconstruction of its render"), std::string::npos)
      << twice.output;
  // The render's own image is one too.
  EXPECT_EQ(rendered->metadata["content"], "reconstruction");
  CommandRun of_render = run_prism(dir, {"reconstruct", "g.exr", "g.gradient.exr", "-o", "r3.exr"});
  EXPECT_NE(of_render.exit_code, 0);
  EXPECT_NE(of_render.output.find("'g.exr' holds the reconstruction"), std::string::npos)
      << of_render.output;
  // A render with its own alpha and norm: the files record them, and reconstruct uses them (it
  // took 0.4 and l2, 0.4 % off).
  CommandRun tuned = run_prism(
      dir, {"render", source("scenes/dispersive-caustic.pbrt"), "-o", "t.exr", "--resolution",
            "24x16", "--spp", "16", "--bins", "16", "--integrator", "gradient",
            "--primal-and-gradients", "--threads", "2", "--alpha", "2", "--poisson", "l1"});
  ASSERT_EQ(tuned.exit_code, 0) << tuned.output;
  CommandRun retuned =
      run_prism(dir, {"reconstruct", "t.primal.exr", "t.gradient.exr", "-o", "rt.exr"});
  ASSERT_EQ(retuned.exit_code, 0) << retuned.output;
  EXPECT_NE(retuned.output.find(", l1"), std::string::npos) << retuned.output;
  {
    auto t = prism::image::read_spectral_exr(dir / "t.exr");
    auto rt = prism::image::read_spectral_exr(dir / "rt.exr");
    ASSERT_TRUE(t.ok() && rt.ok());
    EXPECT_EQ(t->spectral.data().size(), rt->spectral.data().size());
    for (std::size_t i = 0; i < t->spectral.data().size(); ++i) {
      ASSERT_NEAR(t->spectral.data()[i], rt->spectral.data()[i], 1e-5 * peak) << i;
    }
  }
  // An alpha given to both is held as the job holds it (a float): the same bins, bit for bit.
  CommandRun alpha_render =
      run_prism(dir, {"render", source("scenes/dispersive-caustic.pbrt"), "-o", "a.exr",
                      "--resolution", "24x16", "--spp", "16", "--bins", "16", "--integrator",
                      "gradient", "--primal-and-gradients", "--threads", "2", "--alpha", "0.4"});
  ASSERT_EQ(alpha_render.exit_code, 0) << alpha_render.output;
  CommandRun alpha_again = run_prism(
      dir, {"reconstruct", "a.primal.exr", "a.gradient.exr", "--alpha", "0.4", "-o", "ra.exr"});
  ASSERT_EQ(alpha_again.exit_code, 0) << alpha_again.output;
  {
    auto a = prism::image::read_spectral_exr(dir / "a.exr");
    auto ra = prism::image::read_spectral_exr(dir / "ra.exr");
    ASSERT_TRUE(a.ok() && ra.ok());
    const auto x = a->spectral.data(), y = ra->spectral.data();
    EXPECT_TRUE(std::equal(x.begin(), x.end(), y.begin(), y.end()));
  }
  // Nor is the gradient file a reference image for bench.
  CommandRun bench =
      run_prism(dir, {"bench", source("scenes/dispersive-caustic.pbrt"), "--resolution", "24x16",
                      "--bins", "16", "--methods", "hero", "--spp", "2", "--seeds", "1",
                      "--reference", "g.gradient.exr", "-o", "bench"});
  EXPECT_NE(bench.exit_code, 0);
  EXPECT_NE(bench.output.find("holds the gradient of a gradient render"), std::string::npos)
      << bench.output;
  // Nor a test image for compare (it printed metrics of the differences).
  CommandRun compared = run_prism(dir, {"compare", "g.gradient.exr", "g.exr"});
  EXPECT_NE(compared.exit_code, 0);
  EXPECT_NE(compared.output.find("g.gradient.exr holds the gradient of a gradient render"),
            std::string::npos)
      << compared.output;
}

// A target error with the default integrator on a scene with caustic paths: auto offered
// light-traced caustics, which a target-error job refuses, so the documented way to render a
// reference failed unless --integrator was given. Auto leaves them out there, and says so.
TEST(RenderCliTest, TargetErrorUnderAutoLeavesLightTracedCausticsOut) {
  const fs::path dir = fresh_dir("target_error_auto");
  CommandRun run =
      run_prism(dir, {"render", source("scenes/three-emitters.pbrt"), "-o", "t.exr", "--resolution",
                      "16x12", "--target-error", "50%", "--max-spp", "16", "--threads", "2"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const auto report = nlohmann::json::parse(*prism::base::read_file(dir / "t.json"));
  EXPECT_NE(report["auto"]["reason"].get<std::string>().find(
                "light paths do not combine with --target-error"),
            std::string::npos)
      << report["auto"].dump();
  EXPECT_EQ(report["caustics"], "off");
  EXPECT_FALSE(report["target_error"].is_null());
  // The smallest target the flag takes (0.01 %) renders; it failed in the job's float.
  CommandRun smallest = run_prism(
      dir, {"render", source("scenes/three-emitters.pbrt"), "-o", "s.exr", "--resolution", "8x6",
            "--integrator", "hero", "--spp", "4", "--target-error", "0.01%", "--max-spp", "8"});
  EXPECT_EQ(smallest.exit_code, 0) << smallest.output;
}

// `--integrator auto`: where nothing depends on wavelength it is hero, with no pilot, and the
// same bytes; on a spectral scene the report lists the candidates the pilot measured and the
// image is exactly the chosen method's render.
// --caustic-paths under auto (the default) is the share of light paths should auto choose
// light-traced caustics; where it chooses another method the flag does not apply. It made such
// renders fail with "use it with --caustics light (or --integrator auto)".
TEST(RenderCliTest, CausticPathsUnderAutoRenderWhateverAutoChooses) {
  const fs::path dir = fresh_dir("auto_caustic_paths");
  for (const char* scene : {"scenes/prism.pbrt", "scenes/slit-prism.pbrt"}) {
    const CommandRun run =
        run_prism(dir, {"render", source(scene), "--caustic-paths", "0.5", "--spp", "4",
                        "--resolution", "32x24", "--threads", "1", "-o", "out.exr"});
    EXPECT_EQ(run.exit_code, 0) << scene << ": " << run.output;
    EXPECT_NE(run.output.find("chosen by auto"), std::string::npos) << run.output;
  }
}

// An explicit --prepass that the job's samples leave no budget says so, instead of a summary
// that only reads "hero".
TEST(RenderCliTest, APrepassWithoutABudgetSaysSo) {
  const fs::path dir = fresh_dir("prepass_no_budget");
  const CommandRun run = run_prism(
      dir, {"render", source("scenes/three-emitters.pbrt"), "--integrator", "hero", "--prepass",
            "--spp", "64", "--resolution", "32x24", "--threads", "1", "-o", "out.exr"});
  EXPECT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("hero (no prepass: 64 spp leave it no budget"), std::string::npos)
      << run.output;
}

TEST(RenderCliTest, AutoChoosesAMethodAndRendersExactlyWhatItChose) {
  const fs::path dir = fresh_dir("auto");
  {
    std::ofstream scene(dir / "grey.pbrt");
    scene << R"(LookAt 0 3 -6  0 0.6 0  0 1 0
Camera "perspective" "float fov" 40
Film "spectral" "integer xresolution" 24 "integer yresolution" 16 "integer nbuckets" 16
WorldBegin
LightSource "distant" "blackbody L" 5500 "point3 from" [1 4 -2] "point3 to" [0 0 0]
Material "diffuse" "rgb reflectance" [0.6 0.3 0.2]
Shape "trianglemesh" "point3 P" [-4 0 -4  4 0 -4  4 0 4  -4 0 4] "integer indices" [0 1 2 0 2 3]
Shape "sphere" "float radius" 0.7
)";
  }
  CommandRun grey = run_prism(
      dir, {"render", "grey.pbrt", "--integrator", "auto", "--spp", "8", "-o", "grey_auto.exr"});
  ASSERT_EQ(grey.exit_code, 0) << grey.output;
  EXPECT_NE(grey.output.find("hero (chosen by auto: nothing in the scene depends on wavelength"),
            std::string::npos)
      << grey.output;
  CommandRun grey_hero = run_prism(
      dir, {"render", "grey.pbrt", "--integrator", "hero", "--spp", "8", "-o", "grey_hero.exr"});
  ASSERT_EQ(grey_hero.exit_code, 0) << grey_hero.output;
  EXPECT_EQ(*prism::base::read_file(dir / "grey_auto.exr"),
            *prism::base::read_file(dir / "grey_hero.exr"));
  auto grey_report = nlohmann::json::parse(*prism::base::read_file(dir / "grey_auto.json"));
  EXPECT_EQ(grey_report["auto"]["choice"], "hero");
  EXPECT_TRUE(grey_report["auto"]["candidates"].empty());

  const std::vector<std::string> common = {
      "render", source("scenes/three-emitters.pbrt"), "--resolution", "48x36", "--spp", "32"};
  std::vector<std::string> automatic = common;
  automatic.insert(automatic.end(), {"--integrator", "auto", "-o", "spectral_auto.exr"});
  CommandRun spectral = run_prism(dir, automatic);
  ASSERT_EQ(spectral.exit_code, 0) << spectral.output;
  EXPECT_NE(spectral.output.find("(chosen by auto: "), std::string::npos) << spectral.output;
  auto report = nlohmann::json::parse(*prism::base::read_file(dir / "spectral_auto.json"));
  const auto& a = report["auto"];
  // The scene has a dispersive glass (uniform) and smooth glass the light tracer can aim at
  // (hero+caustics, judged at its fitted share of light paths).
  ASSERT_EQ(a["candidates"].size(), 4u) << a.dump();
  std::set<std::string> methods;
  double chosen_efficiency = -1;
  for (const auto& c : a["candidates"]) {
    methods.insert(c["method"].get<std::string>());
    EXPECT_GT(c["rel_mse_per_sample"].get<double>(), 0) << c.dump();
    EXPECT_GT(c["rays_per_sample"].get<double>(), 0) << c.dump();
    if (c["method"] == "hero") {
      EXPECT_DOUBLE_EQ(c["relative_efficiency"].get<double>(), 1.0);
    }
    if (c["method"] == a["choice"]) chosen_efficiency = c["relative_efficiency"].get<double>();
  }
  EXPECT_EQ(methods, (std::set<std::string>{"hero", "gradient", "uniform", "hero+caustics"}));
  // Each candidate's predicted relMSE at equal time, relative to hero's, is its relMSE per sample
  // times its counted rays per sample times its method's cost of a ray.
  const std::map<std::string, double> ray_cost = {
      {"hero", 1.16}, {"gradient", 1.18}, {"uniform", 1.0}, {"hero+caustics", 1.16}};
  auto efficiency = [&](const nlohmann::json& c) {
    return c["rel_mse_per_sample"].get<double>() * c["rays_per_sample"].get<double>() *
           c["ray_cost"].get<double>();
  };
  const nlohmann::json* hero = nullptr;
  for (const auto& c : a["candidates"]) {
    if (c["method"] == "hero") hero = &c;
  }
  ASSERT_NE(hero, nullptr);
  for (const auto& c : a["candidates"]) {
    EXPECT_DOUBLE_EQ(c["ray_cost"].get<double>(), ray_cost.at(c["method"].get<std::string>()));
    EXPECT_NEAR(c["relative_efficiency"].get<double>(), efficiency(c) / efficiency(*hero), 1e-9)
        << c.dump();
  }
  // The pilot: an eighth of the job's spp (at least 8), and its renders (two per candidate, and
  // two more for hero+caustics's second share) at most about 4 % of the job's samples
  // (48 x 36 x 32): its film is shrunk to fit.
  int pilot_width = 0, pilot_height = 0, pilot_spp = 0;
  const std::string reason = a["reason"].get<std::string>();
  ASSERT_EQ(std::sscanf(reason.c_str() + reason.find("(pilot: "), "(pilot: %dx%d, 2 x %d spp",
                        &pilot_width, &pilot_height, &pilot_spp),
            3)
      << reason;
  EXPECT_EQ(pilot_spp, 8);
  EXPECT_LE(pilot_width, 48 / 4);
  EXPECT_LE(pilot_height, 36 / 4);
  EXPECT_LE(2.0 * 5 * pilot_width * pilot_height * pilot_spp, 0.05 * 48 * 36 * 32) << reason;
  ASSERT_GT(chosen_efficiency, 0) << "the choice is not a candidate: " << a.dump();
  // Another method is chosen when it is predicted 10 % better, or for clean caustics
  // (client/auto_integrator.h), which the reason says.
  if (a["choice"] != "hero" && reason.rfind("clean caustics: ", 0) != 0) {
    EXPECT_LE(chosen_efficiency, 0.9) << a.dump();
  }
  std::vector<std::string> explicit_args = common;
  if (a["choice"] == "hero+caustics") {
    EXPECT_EQ(report["integrator"], "hero");
    EXPECT_EQ(report["caustics"], "light");
    explicit_args.insert(explicit_args.end(),
                         {"--integrator", "hero", "--caustics", "light", "--caustic-paths",
                          absl::StrCat(report["caustic_paths"].get<double>())});
  } else {
    EXPECT_EQ(report["integrator"], a["choice"]);
    explicit_args.insert(explicit_args.end(), {"--integrator", a["choice"].get<std::string>()});
  }
  explicit_args.insert(explicit_args.end(), {"-o", "spectral.exr"});
  CommandRun chosen = run_prism(dir, explicit_args);
  ASSERT_EQ(chosen.exit_code, 0) << chosen.output;
  EXPECT_TRUE(same_bits(spectral_pixels(dir / "spectral_auto.exr", nullptr),
                        spectral_pixels(dir / "spectral.exr", nullptr)));

  // Where the floor sees its lamp only through a prism, the pilot finds light-traced caustics
  // best by far (docs/benchmarks.md), and the choice renders as the explicit options do, with
  // the share of light paths the pilot fitted.
  CommandRun caustic =
      run_prism(dir, {"render", source("scenes/dispersive-caustic.pbrt"), "--resolution", "160x120",
                      "--spp", "32", "-o", "caustic_auto.exr"});
  ASSERT_EQ(caustic.exit_code, 0) << caustic.output;
  EXPECT_NE(caustic.output.find("hero with light-traced caustics (chosen by auto"),
            std::string::npos)
      << caustic.output;
  auto caustic_report = nlohmann::json::parse(*prism::base::read_file(dir / "caustic_auto.json"));
  EXPECT_EQ(caustic_report["auto"]["choice"], "hero+caustics");
  EXPECT_EQ(caustic_report["caustics"], "light");
  ASSERT_TRUE(caustic_report.contains("caustic_paths"));
  const double share = caustic_report["caustic_paths"].get<double>();
  const nlohmann::json& judged = caustic_report["auto"]["candidates"].back();
  EXPECT_EQ(judged["method"], "hero+caustics");
  EXPECT_EQ(judged["caustic_paths"].get<double>(), share);
  CommandRun caustic_explicit =
      run_prism(dir, {"render", source("scenes/dispersive-caustic.pbrt"), "--resolution", "160x120",
                      "--spp", "32", "--integrator", "hero", "--caustics", "light",
                      "--caustic-paths", absl::StrCat(share), "-o", "caustic.exr"});
  ASSERT_EQ(caustic_explicit.exit_code, 0) << caustic_explicit.output;
  EXPECT_TRUE(same_bits(spectral_pixels(dir / "caustic_auto.exr", nullptr),
                        spectral_pixels(dir / "caustic.exr", nullptr)));

  // --caustics light, and --splat (which draws light paths), mean hero with light-traced
  // caustics under auto, without a pilot.
  for (const char* flag : {"--caustics", "--splat"}) {
    std::vector<std::string> args = {"render",
                                     source("scenes/slit-prism.pbrt"),
                                     "--resolution",
                                     "40x30",
                                     "--spp",
                                     "2",
                                     "-o",
                                     "asked.exr",
                                     flag};
    if (std::string(flag) == "--caustics") args.push_back("light");
    CommandRun asked = run_prism(dir, args);
    ASSERT_EQ(asked.exit_code, 0) << asked.output;
    EXPECT_NE(asked.output.find("hero with light-traced caustics (chosen by auto: "),
              std::string::npos)
        << asked.output;
    auto asked_report = nlohmann::json::parse(*prism::base::read_file(dir / "asked.json"));
    EXPECT_EQ(asked_report["auto"]["choice"], "hero+caustics");
  }

  // Asking for the prepass means hero with it, without a pilot.
  CommandRun prepass =
      run_prism(dir, {"render", source("scenes/three-emitters.pbrt"), "--resolution", "48x36",
                      "--spp", "32", "--prepass", "-o", "prepass.exr"});
  ASSERT_EQ(prepass.exit_code, 0) << prepass.output;
  EXPECT_NE(prepass.output.find("hero (chosen by auto: the prepass was asked for"),
            std::string::npos)
      << prepass.output;
}

// Where gradient is a candidate, auto runs its τ pilot on the job itself (its pilot renders trace
// at the job's τ), and a gradient choice reuses it: the job's τ and the pilot's figures are
// `--integrator gradient`'s, as are the bytes, and the τ pilot's seconds are part of auto's. The
// pool (waves and a window, every path through three dispersive interfaces) is where the pilot
// predicts gradient at a fraction of hero's error (docs/benchmarks.md).
TEST(RenderCliTest, AutoChoosingGradientReusesItsTauPilot) {
  const fs::path dir = fresh_dir("auto_gradient_tau");
  const std::vector<std::string> common = {
      "render", source("scenes/pool.pbrt"), "--resolution", "64x48", "--spp", "32", "--seed", "1"};
  CommandRun automatic = run_prism(dir, joined(common, {"-o", "auto.exr"}));
  ASSERT_EQ(automatic.exit_code, 0) << automatic.output;
  CommandRun gradient =
      run_prism(dir, joined(common, {"--integrator", "gradient", "-o", "gradient.exr"}));
  ASSERT_EQ(gradient.exit_code, 0) << gradient.output;
  auto a = nlohmann::json::parse(*prism::base::read_file(dir / "auto.json"));
  auto g = nlohmann::json::parse(*prism::base::read_file(dir / "gradient.json"));
  ASSERT_EQ(a["auto"]["choice"], "gradient") << a["auto"].dump();
  ASSERT_TRUE(a["gradient"].contains("tau_pilot")) << a["gradient"].dump();
  nlohmann::json auto_pilot = a["gradient"]["tau_pilot"], own_pilot = g["gradient"]["tau_pilot"];
  EXPECT_LE(auto_pilot["seconds"].get<double>(), a["auto"]["pilot_seconds"].get<double>());
  auto_pilot.erase("seconds");
  own_pilot.erase("seconds");
  EXPECT_EQ(auto_pilot, own_pilot);
  EXPECT_EQ(a["gradient"]["tau"], g["gradient"]["tau"]);
  EXPECT_EQ(*prism::base::read_file(dir / "auto.exr"),
            *prism::base::read_file(dir / "gradient.exr"));
}

// The Cornell box with two lamps can be light traced but every surface in it is diffuse: no
// caustic path, so no hero+caustics candidate (its pilot runs would be hero's, costed twice); no
// dispersive glass, so no uniform and no gradient (which would render hero's image). Hero is left
// alone, and no pilot runs: the image is `--integrator hero`'s. Rough dispersive glass keeps
// uniform and light-traced caustics (glass, rough or not, is a caustic target) but not gradient,
// which has nothing to shift there.
TEST(RenderCliTest, AutoOffersOnlyCandidatesThatCanDifferFromHero) {
  const fs::path dir = fresh_dir("auto_no_caustics");
  CommandRun run =
      run_prism(dir, {"render", source("scenes/cornell-two-lights.pbrt"), "--resolution", "40x40",
                      "--spp", "16", "--no-prepass", "-o", "auto.exr"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  auto report = nlohmann::json::parse(*prism::base::read_file(dir / "auto.json"));
  EXPECT_TRUE(report["auto"]["candidates"].empty()) << report["auto"].dump();
  EXPECT_EQ(report["auto"]["choice"], "hero");
  const std::string reason = report["auto"]["reason"].get<std::string>();
  EXPECT_NE(reason.find("hero is the only candidate"), std::string::npos) << reason;
  EXPECT_EQ(reason.find("(pilot: "), std::string::npos) << reason;
  CommandRun hero =
      run_prism(dir, {"render", source("scenes/cornell-two-lights.pbrt"), "--resolution", "40x40",
                      "--spp", "16", "--integrator", "hero", "--no-prepass", "-o", "hero.exr"});
  ASSERT_EQ(hero.exit_code, 0) << hero.output;
  EXPECT_TRUE(same_bits(spectral_pixels(dir / "auto.exr", nullptr),
                        spectral_pixels(dir / "hero.exr", nullptr)));

  CommandRun rough =
      run_prism(dir, {"render", source("scenes/rough-glass-caustics.pbrt"), "--resolution", "40x30",
                      "--spp", "16", "--no-prepass", "-o", "rough.exr"});
  ASSERT_EQ(rough.exit_code, 0) << rough.output;
  auto rough_report = nlohmann::json::parse(*prism::base::read_file(dir / "rough.json"));
  std::set<std::string> methods;
  for (const auto& c : rough_report["auto"]["candidates"]) {
    methods.insert(c["method"].get<std::string>());
  }
  EXPECT_EQ(methods, (std::set<std::string>{"hero", "uniform", "hero+caustics"}))
      << rough_report["auto"].dump();
  EXPECT_NE(rough_report["auto"]["reason"].get<std::string>().find(
                "gradient is not a candidate: nothing refracts smooth-dispersively"),
            std::string::npos)
      << rough_report["auto"].dump();

  // A job smaller than its smallest pilot (4x4 pixels, 2 x 8 spp per candidate): hero without a
  // pilot (a 1x1 film paid a 1280-sample pilot for 4 samples).
  CommandRun tiny =
      run_prism(dir, {"render", source("scenes/rough-glass-caustics.pbrt"), "--resolution", "1x1",
                      "--spp", "4", "--no-prepass", "-o", "tiny.exr"});
  ASSERT_EQ(tiny.exit_code, 0) << tiny.output;
  auto tiny_report = nlohmann::json::parse(*prism::base::read_file(dir / "tiny.json"));
  EXPECT_EQ(tiny_report["auto"]["choice"], "hero");
  EXPECT_TRUE(tiny_report["auto"]["candidates"].empty()) << tiny_report["auto"].dump();
  EXPECT_NE(tiny_report["auto"]["reason"].get<std::string>().find("too small for a pilot"),
            std::string::npos)
      << tiny_report["auto"].dump();
}

// scenes/slit-prism.pbrt's floor sees its narrow slit lamp only through the prism: the pilot's eye
// samples almost never find it, so their measured variance alone ranks hero and hero+caustics
// alike. The probe of the caustic paths (client/auto_integrator.h) renders them from the lamp and
// models what the eye samples missed; it is orders of magnitude more than they measured, it goes
// to every eye-traced candidate, and auto light-traces the caustic.
TEST(RenderCliTest, AutoModelsTheCausticPathsItsEyeSamplesMiss) {
  const fs::path dir = fresh_dir("auto_caustic_probe");
  CommandRun run = run_prism(dir, {"render", source("scenes/slit-prism.pbrt"), "--resolution",
                                   "96x72", "--spp", "64", "-o", "slit.exr"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  auto report = nlohmann::json::parse(*prism::base::read_file(dir / "slit.json"));
  const auto& a = report["auto"];
  EXPECT_EQ(a["choice"], "hero+caustics") << a.dump();
  const std::string reason = a["reason"].get<std::string>();
  EXPECT_NE(reason.find("the eye tracers' caustic paths, modelled from light paths, add"),
            std::string::npos)
      << reason;
  std::map<std::string, double> variance;
  for (const auto& c : a["candidates"]) {
    variance[c["method"].get<std::string>()] = c["rel_mse_per_sample"].get<double>();
  }
  ASSERT_EQ(variance.size(), 4u) << a.dump();
  // The same unseen variance is in hero's, uniform's and gradient's figures.
  EXPECT_GT(variance["hero"], 100 * variance["hero+caustics"]) << a.dump();
  EXPECT_GT(variance["uniform"], 100 * variance["hero+caustics"]) << a.dump();
  EXPECT_GT(variance["gradient"], 100 * variance["hero+caustics"]) << a.dump();
}

// The README demo (scenes/prism.pbrt): its caustic paths are about 1 % of hero's relMSE, so the
// pilot ranks hero and hero+caustics alike, but the eye tracers render them as fireflies on the
// dim floor. Clean caustics (client/auto_integrator.h): the probe says 1/64 of a light path per
// pixel and sample, 1.5 % more rays, renders them several times cleaner, so auto takes it, and
// the image is exactly that of hero with --caustics light at that share.
TEST(RenderCliTest, AutoRendersTheDemosCausticByLightTracing) {
  const fs::path dir = fresh_dir("auto_clean_caustics");
  const std::vector<std::string> common = {
      "render", source("scenes/prism.pbrt"), "--resolution", "160x120", "--spp", "64"};
  auto with = [&](const std::vector<std::string>& extra) { return joined(common, extra); };
  CommandRun run = run_prism(dir, with({"-o", "auto.exr"}));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  auto report = nlohmann::json::parse(*prism::base::read_file(dir / "auto.json"));
  const auto& a = report["auto"];
  ASSERT_EQ(a["choice"], "hero+caustics") << a.dump();
  const std::string reason = a["reason"].get<std::string>();
  EXPECT_EQ(reason.rfind("clean caustics: ", 0), 0u) << reason;
  EXPECT_NE(reason.find("light paths render the caustic paths"), std::string::npos) << reason;
  double share = 0, efficiency = 0;
  for (const auto& c : a["candidates"]) {
    if (c["method"] == "hero+caustics") {
      share = c["caustic_paths"].get<double>();
      efficiency = c["relative_efficiency"].get<double>();
    }
  }
  EXPECT_EQ(share, 1.0 / 64) << a.dump();
  // Not what the relMSE alone would have taken: hero+caustics is not 10 % better than hero
  // (client::kAutoMinimumGain).
  EXPECT_GT(efficiency, 0.9) << a.dump();
  CommandRun explicit_run =
      run_prism(dir, with({"--integrator", "hero", "--caustics", "light", "--caustic-paths",
                           "0.015625", "-o", "explicit.exr"}));
  ASSERT_EQ(explicit_run.exit_code, 0) << explicit_run.output;
  EXPECT_TRUE(same_bits(spectral_pixels(dir / "auto.exr", nullptr),
                        spectral_pixels(dir / "explicit.exr", nullptr)));
}

// Hero in a scene of several emitter spectra runs the prepass where the job's spp gives it a
// budget (900 spp and up: its first pass then gets 8 spp); its first pass decides whether
// per-pixel tables pay. boxes (two LED spectra, no dispersion, a dye) is such a scene: its pilot
// finds nothing better than hero. The image is exactly `--integrator hero --prepass`'s;
// --no-prepass keeps the prepass off, and so does a job of 256 spp.
TEST(RenderCliTest, AutoRunsThePrepassForHeroUnderSeveralEmitterSpectra) {
  const fs::path dir = fresh_dir("auto_prepass");
  const std::vector<std::string> common = {
      "render", source("scenes/boxes.pbrt"), "--resolution", "32x18", "--spp", "1024"};
  auto with = [&](const std::vector<std::string>& extra) { return joined(common, extra); };
  CommandRun automatic = run_prism(dir, with({"-o", "auto.exr"}));
  ASSERT_EQ(automatic.exit_code, 0) << automatic.output;
  auto report = nlohmann::json::parse(*prism::base::read_file(dir / "auto.json"));
  EXPECT_EQ(report["auto"]["choice"], "hero+prepass") << report["auto"].dump();
  EXPECT_NE(report["auto"]["reason"].get<std::string>().find("2 emitter spectra: the prepass runs"),
            std::string::npos)
      << report["auto"].dump();
  EXPECT_EQ(report["integrator"], "hero");
  EXPECT_TRUE(report.contains("prepass")) << report.dump();
  CommandRun explicit_run =
      run_prism(dir, with({"--integrator", "hero", "--prepass", "-o", "explicit.exr"}));
  ASSERT_EQ(explicit_run.exit_code, 0) << explicit_run.output;
  EXPECT_TRUE(same_bits(spectral_pixels(dir / "auto.exr", nullptr),
                        spectral_pixels(dir / "explicit.exr", nullptr)));

  CommandRun off = run_prism(dir, with({"--no-prepass", "-o", "off.exr"}));
  ASSERT_EQ(off.exit_code, 0) << off.output;
  auto off_report = nlohmann::json::parse(*prism::base::read_file(dir / "off.json"));
  // Without the prepass, hero's few caustic paths (through the dyed glass blocks onto the walls)
  // are light traced: clean caustics, which are not combined with the prepass above.
  EXPECT_EQ(off_report["auto"]["choice"], "hero+caustics") << off_report["auto"].dump();
  EXPECT_EQ(off_report["auto"]["reason"].get<std::string>().rfind("clean caustics: ", 0), 0u)
      << off_report["auto"].dump();
  EXPECT_FALSE(off_report.contains("prepass")) << off_report.dump();

  CommandRun small = run_prism(dir, {"render", source("scenes/boxes.pbrt"), "--resolution", "32x18",
                                     "--spp", "256", "-o", "small.exr"});
  ASSERT_EQ(small.exit_code, 0) << small.output;
  auto small_report = nlohmann::json::parse(*prism::base::read_file(dir / "small.json"));
  EXPECT_EQ(small_report["auto"]["choice"], "hero+caustics") << small_report["auto"].dump();
  EXPECT_FALSE(small_report.contains("prepass")) << small_report.dump();
}

TEST(RenderCliTest, BadFlagsFailClearlyAndWriteNothing) {
  const std::string scene = source(kCornell);
  const std::vector<BadCase> cases = {
      {{"render", scene, "--bins", "3"}, "prism: --bins 3 is out of range: want 4..256"},
      {{"render", scene, "--bins", "257"}, "--bins 257 is out of range"},
      {{"render", scene, "--resolution", "0x5"}, "prism: --resolution '0x5': want WxH"},
      {{"render", scene, "--resolution", "64"}, "--resolution '64': want WxH"},
      {{"render", scene, "--integrator", "foo"},
       "prism: --integrator 'foo': want uniform, hero, gradient, light or auto"},
      {{"render", scene, "--caustics", "photon"}, "prism: --caustics 'photon': want off or light"},
      {{"render", scene, "--integrator", "gradient", "--caustics", "light"},
       "light-traced caustics (--caustics light, light_caustics) need the hero or the uniform "
       "integrator, not gradient"},
      {{"render", scene, "--integrator", "hero", "--splat"},
       "prism: --splat draws light paths as lines: use it with --integrator light or --caustics "
       "light"},
      {{"render", scene, "--caustics", "off", "--splat-width", "30"},
       "--splat draws light paths as lines"},
      {{"render", scene, "--integrator", "light", "--splat-width", "0"},
       "prism: --splat-width 0 is out of range: want nm in 0.1..470"},
      {{"render", scene, "--integrator", "light", "--gather"},
       "prism: --gather filters eye-traced images: use it with --integrator hero or uniform, "
       "without --caustics light (light paths have --splat)"},
      {{"render", scene, "--integrator", "hero", "--caustics", "light", "--gather"},
       "--gather filters eye-traced images"},
      {{"render", scene, "--integrator", "light", "--splat", "--gather"},
       "prism: --gather and --splat are two filters of the same output: choose one"},
      {{"render", scene, "--caustics", "light", "--caustic-paths", "0"},
       "prism: --caustic-paths 0 is out of range: want light paths per pixel and sample in "
       "0.00390625..1"},
      {{"render", scene, "--integrator", "hero", "--caustic-paths", "0.5"},
       "prism: --caustic-paths is the share of light paths of --caustics light"},
      {{"render", scene, "--gather-width", "900"},
       "prism: --gather-width 900 is out of range: want nm in 0.1..470"},
      {{"render", scene, "--spp", "0"}, "--spp 0 is out of range"},
      {{"render", scene, "--spp", "-3"}, "--spp -3 is out of range"},
      {{"render", scene, "--threads", "-1"}, "--threads -1 is out of range"},
      {{"render", scene, "--samples-per-task", "0"},
       "prism: --samples-per-task 0 is out of range: want 1..16777216"},
      {{"render", scene, "--tile", "2"}, "--tile 2 is out of range: want 4..1024"},
      {{"render", scene, "--max-depth", "-1"}, "--max-depth -1 is out of range"},
      {{"render", scene, "--spectral-pdf", "peaky"},
       "--spectral-pdf 'peaky': want flat or visible"},
      {{"render", scene, "--emitter-pdf", "x"}, "--emitter-pdf 'x': want uniform or emitters"},
      {{"render", scene, "--light-selection", "best"},
       "--light-selection 'best': want uniform, power or spatial"},
      {{"render", scene, "--exposure", "1e9"}, "--exposure 1e+09 is out of range"},
      {{"render", scene, "--exr-compression", "dwaa"},
       "prism: --exr-compression 'dwaa': want none, rle, zips, zip or piz"},
      {{"render", scene, "--spool", "sometimes"},
       "prism: --spool 'sometimes': want auto, always or never"},
      {{"render", scene, "--max-memory", "lots"},
       "prism: --max-memory 'lots' is not a byte count: want e.g. 1073741824, 512M, 12G or 1.5T"},
      {{"render", scene, "--max-memory", "1M", "--resolution", "64x64", "--integrator", "hero"},
       "prism: rendering 64x64 with 32 bins needs about"},
      {{"render", scene, "-o", "out.png"}, "give a name ending in .exr"},
      {{"render", scene, "-o", "/dev/null"},
       "cannot write '/dev/null': it is a device or other special file"},
      {{"render", scene, "-o", "missing/out.exr", "--resolution", "8x8"},
       "cannot write 'missing/out.exr': directory 'missing' does not exist"},
      {{"render", scene, "-o", "a.exr", "--json", "a.png"}, "both be written to 'a.png'"},
      {{"render", scene, "--spp", "many"}, "--spp"},
      {{"render", scene, "--seed", "-1"}, "prism: --seed '-1': want an integer in 0.."},
      {{"render", scene, "--target-error", "0"}, "--target-error '0': want a relative error"},
      {{"render", scene, "--target-error", "150%"}, "--target-error '150%'"},
      {{"render", scene, "--target-error", "lots"}, "--target-error 'lots'"},
      {{"render", scene, "--max-spp", "64"}, "--max-spp and --target-error-scope go with"},
      {{"render", scene, "--target-error", "1%", "--target-error-scope", "tile"},
       "--target-error-scope 'tile': want pixel or image"},
      {{"render", scene, "--target-error", "1%", "--spp", "64", "--max-spp", "32"},
       "--max-spp 32 is below --spp 64"},
      {{"render", scene, "--target-error", "1%", "--spp", "1"},
       "spp 1 is too few for a target error"},
      {{"render", scene, "--json", "/dev/null"},
       "cannot write '/dev/null': it is a device or other special file"},
      {{"pack", scene, "--bundle", "/dev/null"},
       "cannot write '/dev/null': it is a device or other special file"},
      {{"pack", scene, "--bundle", "b.bin", "-o", "named.exr"},
       "prism: pack writes --bundle and prints the request; -o names the outputs"},
  };
  for (std::size_t i = 0; i < cases.size(); ++i) {
    SCOPED_TRACE(i);
    expect_failure_writes_nothing("flag" + std::to_string(i), cases[i]);
  }
}

// The finished bins not held in memory (as --spool auto does for images over 1 GiB of bins:
// streamed into the spectral EXR while rendering, or spooled to disk when rendering to a target
// error) give the same files, byte for byte, as the bins held in memory, at every EXR
// compression; neither leaves a file behind, and a job that keeps other whole images refuses
// them.
TEST(RenderCliTest, SpooledBinsWriteTheSameBytesAsBinsInMemory) {
  const fs::path dir = fresh_dir("render_cli_spool");
  const std::vector<std::pair<std::string, std::vector<std::string>>> variants = {
      {"rle", {}},
      {"zip", {}},
      {"rle", {"--target-error", "20%", "--max-spp", "16"}},
  };
  for (std::size_t v = 0; v < variants.size(); ++v) {
    const auto& [compression, extra] = variants[v];
    const std::string stem = compression + "-" + std::to_string(v);
    for (const std::string spool : {"never", "always"}) {
      std::vector<std::string> args = cornell_args(spool + "-" + stem + ".exr", "2", "16");
      args.insert(args.end(),
                  {"--spool", spool, "--exr-compression", compression, "--integrator", "hero"});
      args.insert(args.end(), extra.begin(), extra.end());
      CommandRun run = run_prism(dir, args);
      ASSERT_EQ(run.exit_code, 0) << run.output;
    }
    for (const std::string suffix : {".exr", ".rgb.exr", ".png"}) {
      EXPECT_EQ(*prism::base::read_file(dir / ("never-" + stem + suffix)),
                *prism::base::read_file(dir / ("always-" + stem + suffix)))
          << stem << suffix;
    }
  }
  EXPECT_EQ(listing(dir).size(), 24u) << "6 renders x 4 files, nothing else left";
  CommandRun refused = run_prism(
      dir, {"render", source(kCornell), "--integrator", "gradient", "--primal-and-gradients",
            "--spool", "always", "--resolution", "8x8", "-o", "g.exr"});
  EXPECT_EQ(refused.exit_code, 1);
  EXPECT_NE(refused.output.find("a spooled render keeps no whole image"), std::string::npos)
      << refused.output;
}

// Issue 18, case 3: just under the image-size limits, a render that cannot fit the process's
// memory died of std::bad_alloc after allocating for a while. With its bins held in memory
// (--spool never) it is refused at once, with the numbers, and writes nothing. (By default
// such a render spools its bins to disk and fits: docs/benchmarks.md, 8K at 64 bins.)
TEST(RenderCliTest, RendersThatCannotFitTheMemoryLimitAreRefusedAtOnce) {
  const fs::path dir = fresh_dir("render_cli_memory");
  struct Case {
    std::vector<std::string> args;
    std::string message;
  };
  const std::vector<Case> cases = {
      {{"--resolution", "8192x8192", "--bins", "63"},
       "prism: rendering 8192x8192 with 63 bins needs about 18 GiB of memory (spectral image 16 "
       "GiB, RGB and standard errors 1.5 GiB"},
      {{"--resolution", "4096x4096", "--bins", "256"},
       "prism: rendering 4096x4096 with 256 bins needs about 17 GiB of memory (spectral image 16 "
       "GiB"},
  };
  for (const Case& c : cases) {
    std::vector<std::string> argv = {PRISM_BINARY, "render", source("scenes/prism.pbrt"),
                                     "--spp",      "1",      "--integrator",
                                     "hero",       "-o",     "big.exr",
                                     "--spool",    "never"};
    argv.insert(argv.end(), c.args.begin(), c.args.end());
    prism::testing::ChildOptions options;
    options.working_dir = dir;
    options.merge_stderr = true;
    options.address_space_limit = std::uint64_t{16} << 30;
    const prism::testing::RunResult run = prism::testing::run(argv, options);
    EXPECT_EQ(run.exit_code, 1) << run.out;
    EXPECT_NE(run.out.find(c.message), std::string::npos) << run.out;
    EXPECT_NE(run.out.find("more than the 16 GiB allowed (RLIMIT_AS); use fewer --bins"),
              std::string::npos)
        << run.out;
    EXPECT_TRUE(listing(dir).empty());
  }
}

// Reads a CSV's rows as fields (a quoted field may hold commas).
std::vector<std::vector<std::string>> csv_rows(const std::string& text) {
  std::vector<std::vector<std::string>> rows;
  std::vector<std::string> fields(1);
  bool quoted = false;
  for (char c : text) {
    if (c == '"') {
      quoted = !quoted;
    } else if (c == ',' && !quoted) {
      fields.emplace_back();
    } else if (c == '\n' && !quoted) {
      rows.push_back(std::move(fields));
      fields.assign(1, "");
    } else {
      fields.back().push_back(c);
    }
  }
  return rows;
}

}  // namespace

// A scene with a refused feature (a realistic camera) renders only when the user allows it, and
// the report lists what was rendered instead; `prism check` lists the refusal either way.
TEST(RenderCliTest, UnsupportedFeaturesRenderOnlyWhenAllowedAndTheReportListsThem) {
  const std::string scene = source("tests/testdata/render/unsupported.pbrt");
  CommandRun check = run_prism(fresh_dir("check_unsupported"), {"check", scene});
  EXPECT_EQ(check.exit_code, 1) << check.output;
  EXPECT_NE(check.output.find("  refused      Camera \"realistic\" (unsupported.pbrt:3:8): "
                              "unsupported camera type \"realistic\" (supported: orthographic, "
                              "perspective, spherical); --allow-unsupported renders a perspective "
                              "camera with a 90 degree field of view"),
            std::string::npos)
      << check.output;
  EXPECT_NE(check.output.find("prism render refuses this scene: 1 features are not supported"),
            std::string::npos)
      << check.output;
  CommandRun allowed_check =
      run_prism(fresh_dir("check_allowed"), {"check", scene, "--allow-unsupported", "--json"});
  ASSERT_EQ(allowed_check.exit_code, 0) << allowed_check.output;
  auto checked = nlohmann::json::parse(allowed_check.output);
  EXPECT_EQ(checked["refused"], 1);
  EXPECT_TRUE(checked["renders"]);

  // A scene that does not load is a JSON answer too with --json (stdout was empty).
  {
    const fs::path bad = fresh_dir("check_bad");
    std::ofstream(bad / "bad.pbrt") << "WorldBegin\nShape \"sphere\" \"float radius\" [\n";
    CommandRun bad_check = run_prism(bad, {"check", "bad.pbrt", "--json"});
    EXPECT_EQ(bad_check.exit_code, 1);
    const auto answer = nlohmann::json::parse(bad_check.output, nullptr, false);
    ASSERT_FALSE(answer.is_discarded()) << bad_check.output;
    EXPECT_FALSE(answer["renders"]);
    EXPECT_EQ(answer["error"].get<std::string>().rfind("bad.pbrt:", 0), 0u) << answer.dump();
  }

  const fs::path dir = fresh_dir("render_allowed");
  CommandRun run =
      run_prism(dir, {"render", scene, "-o", "u.exr", "--allow-unsupported", "--threads", "1"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  // The substitution is said on the terminal and recorded in the report.
  EXPECT_NE(run.output.find("unsupported.pbrt:3:8: warning: unsupported camera type "
                            "\"realistic\" (supported: orthographic, perspective, spherical); "
                            "rendered as a perspective camera with a 90 degree field of view"),
            std::string::npos)
      << run.output;
  auto text = prism::base::read_file(dir / "u.json");
  ASSERT_TRUE(text.ok()) << text.status();
  auto report = nlohmann::json::parse(*text);
  const auto& substituted = report["scene_features"]["substituted"];
  ASSERT_EQ(substituted.size(), 1u) << report["scene_features"].dump(2);
  EXPECT_EQ(substituted[0]["feature"], "Camera \"realistic\"");
  EXPECT_EQ(substituted[0]["where"], "unsupported.pbrt:3:8");
  EXPECT_EQ(substituted[0]["substitution"], "a perspective camera with a 90 degree field of view");
  // The sampler type cannot change the image: accepted, and noted.
  ASSERT_EQ(report["scene_features"]["ignored"].size(), 1u);
  EXPECT_EQ(report["scene_features"]["ignored"][0]["feature"], "Sampler \"zsobol\"");
}

// `prism bench` on a small scene: every method, budget, seed and region has a row with finite
// errors and a known noise floor; the report and both plots are written; a second run against
// the cached reference file finds the same floor; bad flags fail before rendering.
// The light tracer, hero with light-traced caustics and the filtered methods are bench methods
// too.
TEST(RenderCliTest, BenchMeasuresTheLightPathMethods) {
  const fs::path dir = fresh_dir("bench_light");
  CommandRun run =
      run_prism(dir, {"bench", source("scenes/slit-prism.pbrt"), "--resolution", "32x24",
                      "--methods", "hero,light,hero+caustics,light+splat,hero+gather", "--spp", "4",
                      "--seeds", "1", "--reference-spp", "16", "--threads", "2", "-o", "out"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  auto csv = prism::base::read_file(dir / "out" / "results.csv");
  ASSERT_TRUE(csv.ok()) << csv.status();
  const auto rows = csv_rows(*csv);
  ASSERT_EQ(rows.size(), 6u) << *csv;  // a header and one row per method
  const auto method = std::find(rows[0].begin(), rows[0].end(), "method") - rows[0].begin();
  std::set<std::string> methods;
  for (std::size_t i = 1; i < rows.size(); ++i) methods.insert(rows[i][method]);
  EXPECT_EQ(methods, (std::set<std::string>{"hero", "light", "hero+caustics", "light+splat",
                                            "hero+gather"}));
  // The `ran` column names the integrator with its light-traced caustics and its filter: each is
  // the method itself (it said "light" for light+splat, which the report showed as
  // "light+splat (light)", as though the splatting had not run).
  const auto ran = std::find(rows[0].begin(), rows[0].end(), "ran") - rows[0].begin();
  for (std::size_t i = 1; i < rows.size(); ++i) {
    EXPECT_EQ(rows[i][ran], rows[i][method]) << *csv;
  }
}

// --splat (and --gather) write the filtered image beside the unbiased one, which they leave bit
// for bit as it is, and the report says how the image was filtered.
TEST(RenderCliTest, SplattingAndGatheringWriteAFilteredImageAndLeaveTheMainOneAlone) {
  const fs::path dir = fresh_dir("splat");
  const std::vector<std::string> common = {"render",       source("scenes/slit-prism.pbrt"),
                                           "--resolution", "48x36",
                                           "--spp",        "8",
                                           "--integrator", "light"};
  std::vector<std::string> plain_args = common, splat_args = common;
  plain_args.insert(plain_args.end(), {"-o", "plain.exr"});
  splat_args.insert(splat_args.end(), {"--splat-width", "80", "-o", "splat.exr"});
  CommandRun plain = run_prism(dir, plain_args);
  ASSERT_EQ(plain.exit_code, 0) << plain.output;
  EXPECT_FALSE(fs::exists(dir / "plain.filtered.exr"));
  CommandRun splat = run_prism(dir, splat_args);
  ASSERT_EQ(splat.exit_code, 0) << splat.output;
  EXPECT_NE(splat.output.find("splat.filtered.exr, splat.filtered.png"), std::string::npos)
      << splat.output;
  EXPECT_TRUE(same_bits(spectral_pixels(dir / "plain.exr", nullptr),
                        spectral_pixels(dir / "splat.exr", nullptr)));
  std::vector<double> wavelengths;
  const std::vector<float> filtered = spectral_pixels(dir / "splat.filtered.exr", &wavelengths);
  EXPECT_EQ(wavelengths.size(), 32u);
  EXPECT_FALSE(same_bits(filtered, spectral_pixels(dir / "splat.exr", nullptr)));
  EXPECT_TRUE(fs::exists(dir / "splat.filtered.png"));
  auto report = nlohmann::json::parse(*prism::base::read_file(dir / "splat.json"));
  EXPECT_EQ(report["filtered"]["method"], "splat");
  EXPECT_EQ(report["filtered"]["width_nm"], 80.0);
  EXPECT_NEAR(report["filtered"]["last_width_nm"].get<double>(), 80.0 * std::pow(8.0, -0.2), 1e-9);
  EXPECT_GT(report["filtered"]["lines"].get<std::uint64_t>(), 0u);
  EXPECT_EQ(report["outputs"]["filtered_exr"], "splat.filtered.exr");

  // --gather does the same for an eye-traced image.
  const std::vector<std::string> eye = {"render",       source("scenes/crossing-caustics.pbrt"),
                                        "--resolution", "48x36",
                                        "--spp",        "128",
                                        "--integrator", "hero"};
  std::vector<std::string> eye_plain = eye, eye_gather = eye;
  eye_plain.insert(eye_plain.end(), {"-o", "eye.exr"});
  eye_gather.insert(eye_gather.end(), {"--gather", "-o", "gather.exr"});
  ASSERT_EQ(run_prism(dir, eye_plain).exit_code, 0);
  CommandRun gather = run_prism(dir, eye_gather);
  ASSERT_EQ(gather.exit_code, 0) << gather.output;
  EXPECT_TRUE(same_bits(spectral_pixels(dir / "eye.exr", nullptr),
                        spectral_pixels(dir / "gather.exr", nullptr)));
  EXPECT_FALSE(same_bits(spectral_pixels(dir / "gather.filtered.exr", nullptr),
                         spectral_pixels(dir / "gather.exr", nullptr)));
  auto gather_report = nlohmann::json::parse(*prism::base::read_file(dir / "gather.json"));
  EXPECT_EQ(gather_report["filtered"]["method"], "gather");
  EXPECT_EQ(gather_report["filtered"]["width_nm"], 100.0);
  EXPECT_GT(gather_report["filtered"]["pixels_filtered"].get<std::uint64_t>(), 0u);
}

TEST(RenderCliTest, BenchWritesResultsReportAndPlots) {
  const fs::path dir = fresh_dir("bench");
  const std::vector<std::string> common = {"bench",
                                           source("scenes/three-emitters.pbrt"),
                                           "--resolution",
                                           "32x24",
                                           "--seeds",
                                           "2",
                                           "--inset",
                                           "4,4,8,8",
                                           "--reference-spp",
                                           "8",
                                           "--reference-cache",
                                           "cache",
                                           "--threads",
                                           "2"};
  std::vector<std::string> args = common;
  args.insert(args.end(), {"--spp", "2,4", "-o", "out"});
  CommandRun run = run_prism(dir, args);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  auto csv = prism::base::read_file(dir / "out" / "results.csv");
  ASSERT_TRUE(csv.ok()) << csv.status();
  const auto rows = csv_rows(*csv);
  // A header, then 5 methods x 2 budgets x 2 seeds x 2 regions.
  ASSERT_EQ(rows.size(), 41u) << *csv;
  const std::vector<std::string>& header = rows[0];
  auto column = [&](const std::string& name) {
    return std::find(header.begin(), header.end(), name) - header.begin();
  };
  std::set<std::string> methods, regions;
  std::string floor;
  for (std::size_t i = 1; i < rows.size(); ++i) {
    ASSERT_EQ(rows[i].size(), header.size()) << i;
    methods.insert(rows[i][column("method")]);
    regions.insert(rows[i][column("region")]);
    EXPECT_EQ(rows[i][column("floor_known")], "1");
    EXPECT_TRUE(std::isfinite(std::stod(rows[i][column("rel_mse")])));
    EXPECT_GT(std::stod(rows[i][column("seconds")]), 0);
    if (rows[i][column("region")] == "image") floor = rows[i][column("mse_floor")];
  }
  EXPECT_EQ(methods,
            (std::set<std::string>{"uniform", "hero", "hero+prepass", "gradient", "auto"}));
  EXPECT_EQ(regions, (std::set<std::string>{"image", "4,4,8,8"}));
  // The methods take turns: each budget and seed renders every method, in --methods order,
  // before the next seed (so a drifting clock falls on all of them alike).
  const std::vector<std::string> order = {"uniform", "hero", "hero+prepass", "gradient", "auto"};
  std::vector<std::string> ran, expected;
  for (std::size_t i = 1; i < rows.size(); ++i) {
    if (rows[i][column("region")] != "image") continue;
    ran.push_back(absl::StrCat(rows[i][column("budget")], " ", rows[i][column("seed")], " ",
                               rows[i][column("method")]));
  }
  for (const char* budget : {"2spp", "4spp"}) {
    for (const char* seed : {"1", "2"}) {
      for (const std::string& m : order)
        expected.push_back(absl::StrCat(budget, " ", seed, " ", m));
    }
  }
  EXPECT_EQ(ran, expected);
  auto report = prism::base::read_file(dir / "out" / "report.md");
  ASSERT_TRUE(report.ok());
  EXPECT_NE(report->find("## three-emitters: whole image"), std::string::npos) << *report;
  EXPECT_NE(report->find("## three-emitters: 4,4,8,8"), std::string::npos);
  EXPECT_NE(report->find("relMSE ÷ hero at equal time"), std::string::npos);
  auto svg = prism::base::read_file(dir / "out" / "three-emitters.svg");
  ASSERT_TRUE(svg.ok());
  EXPECT_NE(svg->find("<svg"), std::string::npos);
  auto png = prism::image::read_png(dir / "out" / "three-emitters.png");
  ASSERT_TRUE(png.ok()) << png.status();
  EXPECT_EQ(png->width, 1200);

  // Reporting on the CSV without rendering draws the same plot from the same points (to the
  // CSV's nine digits: a point is a mean over the seeds), on the clock the rows were timed with.
  CommandRun replot = run_prism(dir, {"bench", "--results", "out/results.csv", "-o", "replot"});
  ASSERT_EQ(replot.exit_code, 0) << replot.output;
  auto replot_data = prism::base::read_file(dir / "replot" / "three-emitters.dat");
  auto plot_data = prism::base::read_file(dir / "out" / "three-emitters.dat");
  ASSERT_TRUE(replot_data.ok()) << replot_data.status();
  ASSERT_TRUE(plot_data.ok()) << plot_data.status();
  const std::vector<std::string> replotted = absl::StrSplit(*replot_data, absl::ByAnyChar("\n "));
  const std::vector<std::string> plotted = absl::StrSplit(*plot_data, absl::ByAnyChar("\n "));
  ASSERT_EQ(replotted.size(), plotted.size());
  for (std::size_t i = 0; i < plotted.size(); ++i) {
    double a = 0, b = 0;
    if (absl::SimpleAtod(plotted[i], &a) && absl::SimpleAtod(replotted[i], &b)) {
      EXPECT_NEAR(a, b, 1e-7 * std::abs(a)) << i;
    } else {
      EXPECT_EQ(replotted[i], plotted[i]) << i;
    }
  }
  // The same file twice is the same rows once; methods that match no row are an error.
  CommandRun twice = run_prism(dir, {"bench", "--results", "out/results.csv", "--results",
                                     "out/results.csv", "-o", "twice"});
  ASSERT_EQ(twice.exit_code, 0) << twice.output;
  EXPECT_EQ(prism::base::read_file(dir / "twice" / "three-emitters.dat").value(), *replot_data);
  CommandRun none = run_prism(
      dir, {"bench", "--results", "out/results.csv", "--methods", "hero+caustics", "-o", "none"});
  EXPECT_NE(none.exit_code, 0);
  EXPECT_NE(none.output.find("--results: no row of the method(s) hero+caustics"), std::string::npos)
      << none.output;
  auto replot_script = prism::base::read_file(dir / "replot" / "three-emitters.gp");
  ASSERT_TRUE(replot_script.ok());
  EXPECT_NE(replot_script->find("seconds (wall clock)"), std::string::npos) << *replot_script;
  auto replot_png = prism::image::read_png(dir / "replot" / "three-emitters.png");
  ASSERT_TRUE(replot_png.ok()) << replot_png.status();
  EXPECT_EQ(replot_png->width, 1200);

  // gnuplot exits 0 when it cannot write a plot (a full disk): a cut-off plot is an error, not
  // "wrote". A gnuplot that writes half a PNG and SVG stands in for it.
  fs::create_directories(dir / "fakebin");
  {
    std::ofstream fake(dir / "fakebin" / "gnuplot");
    fake << "#!/bin/sh\nprintf '\\211PNG\\r\\n' > three-emitters.png.tmp\n"
         << "printf '<svg>' > three-emitters.svg.tmp\nexit 0\n";
  }
  fs::permissions(dir / "fakebin" / "gnuplot", fs::perms::owner_all);
  prism::testing::ChildOptions cut_off;
  cut_off.working_dir = dir;
  cut_off.merge_stderr = true;
  cut_off.env = {"PATH=" + (dir / "fakebin").string() + ":/usr/bin:/bin"};
  const prism::testing::RunResult truncated = prism::testing::run(
      {PRISM_BINARY, "bench", "--results", "out/results.csv", "-o", "cut"}, cut_off);
  EXPECT_NE(truncated.exit_code, 0) << truncated.out;
  EXPECT_NE(truncated.out.find("incomplete"), std::string::npos) << truncated.out;
  EXPECT_FALSE(fs::exists(dir / "cut" / "three-emitters.png"));
  EXPECT_FALSE(fs::exists(dir / "cut" / "three-emitters.png.tmp"));

  // The cached reference, given explicitly, brings its half along: the same floor.
  fs::path cached;
  for (const auto& entry : fs::directory_iterator(dir / "cache")) {
    const std::string name = entry.path().filename().string();
    if (name.ends_with(".exr") && !name.ends_with(".half.exr")) cached = entry.path();
  }
  ASSERT_FALSE(cached.empty());
  CommandRun again = run_prism(
      dir, {"bench", source("scenes/three-emitters.pbrt"), "--resolution", "32x24", "--methods",
            "hero", "--spp", "2", "--seeds", "1", "--reference", cached.string(), "-o", "again"});
  ASSERT_EQ(again.exit_code, 0) << again.output;
  auto again_csv = prism::base::read_file(dir / "again" / "results.csv");
  ASSERT_TRUE(again_csv.ok());
  const auto again_rows = csv_rows(*again_csv);
  ASSERT_EQ(again_rows.size(), 2u);
  EXPECT_EQ(again_rows[1][column("mse_floor")], floor);
  // A half beside the reference that cannot be its half is an error (it was dropped silently,
  // or gave a floor of 0), and the refused run leaves no -o directory behind.
  fs::create_directories(dir / "badhalf");
  const fs::path copy = dir / "badhalf" / "ref.exr";
  fs::copy_file(cached, copy);
  fs::copy_file(cached, dir / "badhalf" / "ref.half.exr");  // the reference itself
  const std::vector<std::string> with_copy = {"bench",        source("scenes/three-emitters.pbrt"),
                                              "--resolution", "32x24",
                                              "--methods",    "hero",
                                              "--spp",        "2",
                                              "--seeds",      "1",
                                              "--reference",  copy.string(),
                                              "-o",           "badhalf_out"};
  CommandRun same = run_prism(dir, with_copy);
  EXPECT_NE(same.exit_code, 0) << same.output;
  EXPECT_NE(same.output.find("holds the same values as --reference"), std::string::npos)
      << same.output;
  EXPECT_FALSE(fs::exists(dir / "badhalf_out"));
  {
    auto exr = prism::image::read_spectral_exr(cached);
    ASSERT_TRUE(exr.ok()) << exr.status();
    auto small = exr->spectral.crop({0, 0, 16, 12});
    ASSERT_TRUE(small.ok());
    auto small_rgb = exr->rgb->crop({0, 0, 16, 12});
    ASSERT_TRUE(small_rgb.ok());
    ASSERT_TRUE(prism::image::write_spectral_exr(dir / "badhalf" / "ref.half.exr",
                                                 exr->wavelengths_nm, *small, *small_rgb,
                                                 exr->metadata)
                    .ok());
  }
  CommandRun wrong = run_prism(dir, with_copy);
  EXPECT_NE(wrong.exit_code, 0) << wrong.output;
  EXPECT_NE(wrong.output.find("is 16x12 with"), std::string::npos) << wrong.output;
  EXPECT_FALSE(fs::exists(dir / "badhalf_out"));

  // The cache names the build that made a reference: this build's own is taken silently, one
  // another build made (after an upgrade, say) with a warning that says how to render it anew.
  std::vector<std::string> reuse = common;
  reuse.insert(reuse.end(), {"--methods", "hero", "--spp", "2", "-o", "reuse"});
  CommandRun reused = run_prism(dir, reuse);
  ASSERT_EQ(reused.exit_code, 0) << reused.output;
  EXPECT_NE(reused.output.find("cached in"), std::string::npos) << reused.output;
  EXPECT_EQ(reused.output.find("another build"), std::string::npos) << reused.output;
  {
    auto exr = prism::image::read_spectral_exr(cached);
    ASSERT_TRUE(exr.ok()) << exr.status();
    ASSERT_EQ(exr->metadata.count("reference_renderer"), 1u);
    EXPECT_EQ(exr->metadata["reference_renderer"].size(), 16u);
    exr->metadata["reference_renderer"] = "0123456789abcdef";
    ASSERT_TRUE(exr->rgb.has_value());
    ASSERT_TRUE(prism::image::write_spectral_exr(cached, exr->wavelengths_nm, exr->spectral,
                                                 *exr->rgb, exr->metadata)
                    .ok());
  }
  CommandRun upgraded = run_prism(dir, reuse);
  ASSERT_EQ(upgraded.exit_code, 0) << upgraded.output;
  EXPECT_NE(upgraded.output.find("made by another build of prism (0123456789abcdef"),
            std::string::npos)
      << upgraded.output;

  // A reference rendered to a target error instead of a spp count (the target-error rounds).
  CommandRun to_error =
      run_prism(dir, {"bench", source("scenes/three-emitters.pbrt"), "--resolution", "32x24",
                      "--methods", "hero", "--spp", "2", "--seeds", "1", "--reference-error", "30%",
                      "--reference-spp", "64", "--reference-cache", "cache", "-o", "to_error"});
  ASSERT_EQ(to_error.exit_code, 0) << to_error.output;
  auto to_error_report = prism::base::read_file(dir / "to_error" / "report.md");
  ASSERT_TRUE(to_error_report.ok());
  EXPECT_NE(to_error_report->find("hero without a prepass to 30 % per pixel"), std::string::npos)
      << *to_error_report;
  // A rerun takes the cached reference and reports the spp it was rendered with (it said the
  // first round's, 16).
  CommandRun to_error_again =
      run_prism(dir, {"bench", source("scenes/three-emitters.pbrt"), "--resolution", "32x24",
                      "--methods", "hero", "--spp", "2", "--seeds", "1", "--reference-error", "30%",
                      "--reference-spp", "64", "--reference-cache", "cache", "-o", "to_error2"});
  ASSERT_EQ(to_error_again.exit_code, 0) << to_error_again.output;
  EXPECT_NE(to_error_again.output.find("cached in"), std::string::npos) << to_error_again.output;
  auto reference_line = [](const std::string& report) {
    const std::size_t at = report.find("reference: ");
    return at == std::string::npos ? std::string() : report.substr(at, report.find('\n', at) - at);
  };
  EXPECT_EQ(reference_line(prism::base::read_file(dir / "to_error2" / "report.md").value()),
            reference_line(*to_error_report));
  // --results reports on rows already rendered: a render flag beside it is refused.
  CommandRun results_with_seeds = run_prism(
      dir, {"bench", "--results", "to_error/results.csv", "--seeds", "3", "-o", "results_seeds"});
  EXPECT_NE(results_with_seeds.exit_code, 0);
  EXPECT_NE(results_with_seeds.output.find("--seeds shapes the renders"), std::string::npos)
      << results_with_seeds.output;
  auto to_error_csv = prism::base::read_file(dir / "to_error" / "results.csv");
  ASSERT_TRUE(to_error_csv.ok());
  const auto to_error_rows = csv_rows(*to_error_csv);
  ASSERT_EQ(to_error_rows.size(), 2u);
  EXPECT_EQ(to_error_rows[1][column("floor_known")], "1");

  const std::vector<std::pair<std::vector<std::string>, std::string>> bad = {
      {{"--methods", "hero,nope", "--spp", "2"}, "unknown method 'nope'"},
      {{"--spp", "2", "--reference-error", "nope"}, "prism: --reference-error 'nope': want"},
      {{"--spp", "2", "--inset", "1,2,3"}, "prism: --inset '1,2,3': want x,y,w,h"},
      {{"--budgets", "10s,5s"}, "--budgets '10s,5s': want increasing durations"},
      {{"--spp", "2", "--inset", "30,20,8,8"}, "--inset 30,20,8,8"},
      {{"--spp", "2", "--clock", "sundial"}, "--clock 'sundial'"},
      {{"--spp", "2", "--baseline", "heor"}, "--baseline 'heor' is not a method"},
      {{"--spp", "2,16777217"}, "16777217 is more than a job takes (1..16777216)"},
      {{"--budgets", "0.1s,0.1000001s"}, "are the same to six digits"},
      {{"--budgets", ""}, "--budgets is empty; leave it out for its default"},
      {{"--spp", "2", "--reference-error", "10%"}, "--reference-spp 8 is below 16"},
      {{"--spp", "2", "--reference", "given.exr"}, "--reference gives the references"},
      // Every scene is checked before the first renders: a second scene that does not exist, or
      // that a method cannot render, ended the run after the first scene's renders, and threw
      // them away.
      {{"missing.pbrt", "--spp", "2"}, "scene file \"missing.pbrt\" does not exist"},
      {{"ortho.pbrt", "--spp", "2", "--methods", "hero,light"},
       "ortho.pbrt, method light: light paths (--integrator light, --caustics light) connect to a "
       "perspective camera"},
  };
  {
    std::ofstream ortho(dir / "ortho.pbrt");
    ortho << "LookAt 0 0 5  0 0 0  0 1 0\nCamera \"orthographic\"\n"
             "Film \"rgb\" \"integer xresolution\" 32 \"integer yresolution\" 24\n"
             "WorldBegin\nLightSource \"point\" \"rgb I\" [1 1 1] \"point3 from\" [0 0 4]\n"
             "Shape \"sphere\"\n";
  }
  for (const auto& [extra, message] : bad) {
    std::vector<std::string> bad_args = common;
    bad_args.insert(bad_args.end(), extra.begin(), extra.end());
    bad_args.insert(bad_args.end(), {"-o", "bad"});
    CommandRun failed = run_prism(dir, bad_args);
    EXPECT_EQ(failed.exit_code, 1) << failed.output;
    EXPECT_NE(failed.output.find(message), std::string::npos) << failed.output;
    EXPECT_FALSE(fs::exists(dir / "bad" / "results.csv"));
  }

  // Another scene into the same directory: its plots replace the earlier run's, whose scene
  // this run does not render (they stayed beside the new report as if they were its own).
  ASSERT_TRUE(fs::exists(dir / "out" / "three-emitters.svg"));
  // Not what a results.csv's scene name reaches outside the directory: "../victim" in the earlier
  // CSV leaves the user's ../victim.png alone.
  {
    std::ofstream(dir / "victim.png") << "a user's file";
    std::string rows = prism::base::read_file(dir / "out" / "results.csv").value();
    const std::size_t first = rows.find('\n') + 1;
    const std::string row = rows.substr(first, rows.find('\n', first) - first + 1);
    rows += "../victim" + row.substr(std::string("three-emitters").size());
    ASSERT_TRUE(prism::base::write_file_atomic(dir / "out" / "results.csv", rows).ok());
  }
  CommandRun other =
      run_prism(dir, {"bench", source("scenes/prism.pbrt"), "--resolution", "16x12", "--methods",
                      "hero", "--spp", "2", "--seeds", "1", "--reference-spp", "8",
                      "--reference-cache", "cache", "-o", "out"});
  ASSERT_EQ(other.exit_code, 0) << other.output;
  EXPECT_TRUE(fs::exists(dir / "out" / "prism.svg"));
  for (const char* ext : {".svg", ".png", ".dat", ".gp"}) {
    EXPECT_FALSE(fs::exists(dir / "out" / (std::string("three-emitters") + ext))) << ext;
  }
  EXPECT_TRUE(fs::exists(dir / "victim.png"));
}
