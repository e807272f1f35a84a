#include "client/reconstruct_command.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <random>
#include <regex>
#include <string>

#include "coordinator/outputs.h"
#include "services/base/sha256.h"
#include "services/image/exr_spectral.h"
#include "services/spectral/color.h"

namespace prism::client {
namespace {

namespace fs = std::filesystem;

class ReconstructCommandTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("prism_reconstruct_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A random primal with values in [1, 2), so every float difference I[b+k] − I[b] is exact
  // (Sterbenz) and G = DI holds exactly; then the reconstruction must return I bit for bit.
  image::SpectralImage primal(int w, int h, int bins, unsigned seed = 1) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> dist(1.0f, 2.0f);
    auto img = image::SpectralImage::create(w, h, bins);
    for (float& v : img->data()) v = dist(rng);
    return *img;
  }
  image::SpectralImage exact_gradient(const image::SpectralImage& in, int k) {
    auto g = image::SpectralImage::create(in.width(), in.height(), in.bins());
    for (int y = 0; y < in.height(); ++y) {
      for (int x = 0; x < in.width(); ++x) {
        for (int b = 0; b < in.bins(); ++b) {
          g->value(x, y, b) = in.value(x, y, (b + k) % in.bins()) - in.value(x, y, b);
        }
      }
    }
    return *g;
  }
  void write(const fs::path& path, const image::SpectralImage& img,
             const image::ExrMetadata& metadata = {},
             const std::optional<image::RgbImage>& rgb = std::nullopt) {
    auto zero = image::RgbImage::create(img.width(), img.height());
    ASSERT_TRUE(image::write_spectral_exr(path, img, rgb.value_or(*zero), metadata).ok());
  }
  ReconstructOptions options() {
    ReconstructOptions o;
    o.primal = dir_ / "primal.exr";
    o.gradient = dir_ / "gradient.exr";
    o.output = dir_ / "out.exr";
    return o;
  }

  fs::path dir_;
};

TEST_F(ReconstructCommandTest, ConsistentPairReconstructsThePrimal) {
  const int k = 5;
  const image::SpectralImage in = primal(7, 4, 32);
  // The primal's own RGB, as a render writes it (its samples' exact RGB): random here.
  auto primal_rgb = image::RgbImage::create(in.width(), in.height());
  std::mt19937 rng(7);
  for (float& v : primal_rgb->data()) v = std::uniform_real_distribution<float>(0.f, 3.f)(rng);
  write(dir_ / "primal.exr", in, {{"spp", "64"}, {"integrator", "gradient"}}, *primal_rgb);
  // The gradient file names its primal by the hash of its pixels, as a render writes it.
  const std::string pixels_hash = base::sha256_hex(std::string_view(
      reinterpret_cast<const char*>(in.data().data()), in.data().size() * sizeof(float)));
  write(dir_ / "gradient.exr", exact_gradient(in, k),
        {{std::string(image::kMetaGradientOffsetBins), "5"},
         {std::string(image::kMetaGradientDelta), "0.15"},
         {std::string(image::kMetaPrimalSha256), pixels_hash}});
  for (const char* norm : {"l2", "l1"}) {
    ReconstructOptions o = options();
    o.poisson = norm;
    auto summary = run_reconstruct(o);
    ASSERT_TRUE(summary.ok()) << summary.status();
    EXPECT_NE(summary->find("7x4, 32 bins, k 5, alpha 0.4"), std::string::npos) << *summary;
    auto out = image::read_spectral_exr(o.output);
    ASSERT_TRUE(out.ok()) << out.status();
    ASSERT_EQ(out->spectral.data().size(), in.data().size());
    for (std::size_t i = 0; i < in.data().size(); ++i) {
      if (std::string(norm) == "l2") {
        ASSERT_EQ(out->spectral.data()[i], in.data()[i]) << i;
      } else {
        ASSERT_NEAR(out->spectral.data()[i], in.data()[i], 4 * std::ldexp(1.0f, -23)) << i;
      }
    }
    EXPECT_EQ(out->metadata.at(std::string(image::kMetaPoissonAlpha)), "0.4");
    EXPECT_EQ(out->metadata.at(std::string(image::kMetaPoissonNorm)), norm);
    EXPECT_EQ(out->metadata.at(std::string(image::kMetaGradientOffsetBins)), "5");
    EXPECT_EQ(out->metadata.at(std::string(image::kMetaGradientDelta)), "0.15");
    EXPECT_EQ(out->metadata.at("spp"), "64");  // the primal's metadata carries over
    // RGB as `prism render` makes a gradient render's: the primal's RGB plus the
    // reconstruction's change of the bins' RGB (none for l2 here, which returns I exactly).
    EXPECT_EQ(out->metadata.at(std::string(image::kMetaContent)), "reconstruction");
    ASSERT_TRUE(out->rgb.has_value());
    const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
    auto reconstructed_rgb = coordinator::to_linear_srgb(out->spectral, cmf);
    auto plain_rgb = coordinator::to_linear_srgb(in, cmf);
    ASSERT_TRUE(reconstructed_rgb.ok() && plain_rgb.ok());
    for (std::size_t i = 0; i < primal_rgb->data().size(); ++i) {
      ASSERT_EQ(out->rgb->data()[i], static_cast<float>(double(primal_rgb->data()[i]) +
                                                        double(reconstructed_rgb->data()[i]) -
                                                        double(plain_rgb->data()[i])))
          << i;
    }
  }
}

TEST_F(ReconstructCommandTest, OffsetFlagSuppliesAndOverridesK) {
  const image::SpectralImage in = primal(3, 3, 16, 2);
  write(dir_ / "primal.exr", in);
  write(dir_ / "gradient.exr", exact_gradient(in, 3));  // no k in the file
  ReconstructOptions o = options();
  auto missing = run_reconstruct(o);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("gradient.exr' has no prism:gradient_offset_bins"),
            std::string::npos)
      << missing.status();
  EXPECT_NE(missing.status().message().find("--offset-bins"), std::string::npos);
  EXPECT_FALSE(fs::exists(o.output));

  o.offset_bins = 3;
  ASSERT_TRUE(run_reconstruct(o).ok());
  auto out = image::read_spectral_exr(o.output);
  ASSERT_TRUE(out.ok());
  for (std::size_t i = 0; i < in.data().size(); ++i)
    ASSERT_EQ(out->spectral.data()[i], in.data()[i]);

  // A wrong k in the file is overridden by the flag; a wrong k alone gives a different image.
  write(dir_ / "gradient.exr", exact_gradient(in, 3),
        {{std::string(image::kMetaGradientOffsetBins), "4"}});
  ASSERT_TRUE(run_reconstruct(o).ok());
  out = image::read_spectral_exr(o.output);
  EXPECT_EQ(out->spectral.data()[0], in.data()[0]);
  o.offset_bins.reset();
  ASSERT_TRUE(run_reconstruct(o).ok());
  out = image::read_spectral_exr(o.output);
  bool differs = false;
  for (std::size_t i = 0; i < in.data().size(); ++i)
    differs |= out->spectral.data()[i] != in.data()[i];
  EXPECT_TRUE(differs);
}

TEST_F(ReconstructCommandTest, RefusesBadInputWithoutWriting) {
  const image::SpectralImage in = primal(4, 3, 16, 3);
  write(dir_ / "primal.exr", in);
  write(dir_ / "gradient.exr", exact_gradient(in, 2),
        {{std::string(image::kMetaGradientOffsetBins), "2"}});
  write(dir_ / "small.exr", primal(4, 2, 16));
  write(dir_ / "bins.exr", primal(4, 3, 15));
  image::SpectralImage bad = exact_gradient(in, 2);
  bad.value(1, 2, 9) = std::nanf("");
  write(dir_ / "nan.exr", bad, {{std::string(image::kMetaGradientOffsetBins), "2"}});
  write(dir_ / "bad_k.exr", exact_gradient(in, 2),
        {{std::string(image::kMetaGradientOffsetBins), "two"}});
  write(dir_ / "big_k.exr", exact_gradient(in, 2),
        {{std::string(image::kMetaGradientOffsetBins), "16"}});
  // A labelled pair, as --primal-and-gradients writes it (prism:content).
  write(dir_ / "labelled.primal.exr", in, {{std::string(image::kMetaContent), "primal"}});
  write(dir_ / "labelled.gradient.exr", exact_gradient(in, 2),
        {{std::string(image::kMetaGradientOffsetBins), "2"},
         {std::string(image::kMetaContent), "gradient"}});

  struct Case {
    std::string name;
    ReconstructOptions options;
    std::string message;
  };
  std::vector<Case> cases;
  // An edit naming both files.
  auto pair = [&](const char* primal, const char* gradient) {
    return [&, primal, gradient](ReconstructOptions& o) {
      o.primal = dir_ / primal;
      o.gradient = dir_ / gradient;
    };
  };
  auto add = [&](std::string name, auto edit, std::string message) {
    ReconstructOptions o = options();
    edit(o);
    cases.push_back({std::move(name), o, std::move(message)});
  };
  add(
      "missing primal", [&](auto& o) { o.primal = dir_ / "none.exr"; }, "primal file: .*none.exr");
  add(
      "missing gradient", [&](auto& o) { o.gradient = dir_ / "none.exr"; },
      "gradient file: .*none.exr");
  add(
      "size", [&](auto& o) { o.gradient = dir_ / "small.exr"; },
      "primal.exr' is 4x3 with 16 bins but gradient file '.*small.exr' is 4x2");
  add(
      "bins", [&](auto& o) { o.gradient = dir_ / "bins.exr"; }, "with 15 bins; they must match");
  add(
      "nan", [&](auto& o) { o.gradient = dir_ / "nan.exr"; },
      "pixel \\(1, 2\\) gradient\\[9\\] = nan");
  add(
      "k text", [&](auto& o) { o.gradient = dir_ / "bad_k.exr"; }, "'two' is not an integer");
  add(
      "k range", [&](auto& o) { o.gradient = dir_ / "big_k.exr"; }, "big_k.exr.*k = 16");
  add(
      "k flag", [&](auto& o) { o.offset_bins = 0; }, "--offset-bins: .*k = 0");
  add(
      "alpha 0", [&](auto& o) { o.alpha = 0; }, "--alpha 0: ");
  add(
      "alpha nan", [&](auto& o) { o.alpha = std::nan(""); }, "--alpha nan: ");
  add(
      "alpha negative", [&](auto& o) { o.alpha = -1; }, "--alpha -1: ");
  add(
      "norm", [&](auto& o) { o.poisson = "l3"; }, "'l3': want l2 or l1");
  add("swapped", pair("labelled.gradient.exr", "labelled.primal.exr"),
      "primal file '.*labelled.gradient.exr' holds the gradient of its render");
  add(
      "gradient is a primal", [&](auto& o) { o.gradient = dir_ / "labelled.primal.exr"; },
      "gradient file '.*labelled.primal.exr' holds the primal of its render");
  // A reconstruction is labelled as one (it carried the primal's label, and was reconstructed
  // again without a word).
  write(dir_ / "reconstructed.exr", in, {{std::string(image::kMetaContent), "reconstruction"}});
  add(
      "a reconstruction as the primal", [&](auto& o) { o.primal = dir_ / "reconstructed.exr"; },
      "primal file '.*reconstructed.exr' holds the reconstruction of its render");
  // Files from two renders, each labelled rightly (an ordinary render of another scene taken
  // for the primal went through without a word).
  write(dir_ / "seed2.primal.exr", in,
        {{std::string(image::kMetaContent), "primal"}, {"scene", "a.pbrt"}, {"seed", "2"}});
  write(dir_ / "seed1.gradient.exr", exact_gradient(in, 2),
        {{std::string(image::kMetaGradientOffsetBins), "2"},
         {std::string(image::kMetaContent), "gradient"},
         {"scene", "a.pbrt"},
         {"seed", "1"}});
  write(dir_ / "hero.exr", in, {{"scene", "b.pbrt"}, {"integrator", "hero"}});
  write(dir_ / "a.gradient.exr", exact_gradient(in, 2),
        {{std::string(image::kMetaGradientOffsetBins), "2"},
         {std::string(image::kMetaContent), "gradient"},
         {"scene", "a.pbrt"},
         {"integrator", "gradient"}});
  // Two renders that record the same scene name and options, of an edited scene: the gradient
  // file names another primal's pixels.
  write(dir_ / "other.gradient.exr", exact_gradient(in, 2),
        {{std::string(image::kMetaGradientOffsetBins), "2"},
         {std::string(image::kMetaPrimalSha256), std::string(64, '0')}});
  add("an edited scene's pair", pair("primal.exr", "other.gradient.exr"),
      "gradient file '.*other.gradient.exr' belongs with another primal than '.*primal.exr'");
  add("two seeds", pair("seed2.primal.exr", "seed1.gradient.exr"),
      "come from different renders \\(prism:seed is '2' in one and '1' in the other\\)");
  add("another scene's render", pair("hero.exr", "a.gradient.exr"),
      "come from different renders \\(prism:scene is 'b.pbrt' in one and 'a.pbrt'");
  add(
      "same file", [&](auto& o) { o.gradient = o.primal; },
      "the primal and the gradient file are the same file");
  add(
      "output extension", [&](auto& o) { o.output = dir_ / "out.png"; }, "ending in .exr");
  add(
      "output directory", [&](auto& o) { o.output = dir_ / "no" / "out.exr"; }, "does not exist");
  for (const Case& c : cases) {
    auto result = run_reconstruct(c.options);
    ASSERT_FALSE(result.ok()) << c.name;
    EXPECT_TRUE(std::regex_search(std::string(result.status().message()), std::regex(c.message)))
        << c.name << ": " << result.status();
    EXPECT_FALSE(fs::exists(c.options.output)) << c.name;
  }
  // Overwriting an input is refused and leaves it intact.
  ReconstructOptions o = options();
  o.output = o.primal;
  auto same = run_reconstruct(o);
  ASSERT_FALSE(same.ok());
  EXPECT_NE(same.status().message().find("is an input file"), std::string::npos);
  EXPECT_TRUE(image::read_spectral_exr(o.primal).ok());
  // A pipe (or a device) named as the output would be replaced by the rename that writes it.
  ASSERT_EQ(::mkfifo((dir_ / "pipe.exr").c_str(), 0600), 0);
  ReconstructOptions to_pipe = options();
  to_pipe.primal = dir_ / "labelled.primal.exr";
  to_pipe.gradient = dir_ / "labelled.gradient.exr";
  to_pipe.output = dir_ / "pipe.exr";
  auto refused = run_reconstruct(to_pipe);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("pipe.exr': it is a device or other special file"),
            std::string::npos)
      << refused.status();
  EXPECT_TRUE(fs::is_fifo(dir_ / "pipe.exr"));
}

}  // namespace
}  // namespace prism::client
