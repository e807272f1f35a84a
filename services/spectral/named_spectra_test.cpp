#include "services/spectral/named_spectra.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "services/spectral/color.h"

namespace prism::spectral {
namespace {

class NamedSpectraTest : public ::testing::Test {
 protected:
  const SpectrumLibrary lib_storage_ = *SpectrumLibrary::load_builtin();
  const SpectrumLibrary* lib_ = &lib_storage_;
};

// The CIE tables here stop at 780 nm; the D series runs on to Prism's 830 nm by the daylight
// basis (cie_daylight_illuminant). Against CIE 015:2018's D65 table, which runs to 830 nm, and
// the table's own values below 780 nm; C has no basis and stays 0 beyond its table.
TEST_F(NamedSpectraTest, DaylightIlluminantsCoverTheWholeRange) {
  const Spectrum* d65 = lib_->find_spectrum("stdillum-D65");
  ASSERT_NE(d65, nullptr);
  const struct {
    float lambda;
    float value;
  } published[] = {{300, 0.0341f}, {560, 100.0f},   {780, 63.3828f}, {785, 63.8434f},
                   {790, 64.304f}, {795, 61.8779f}, {800, 59.4519f}, {805, 55.7054f},
                   {810, 51.959f}, {815, 54.6998f}, {820, 57.4406f}, {825, 58.8766f},
                   {830, 60.3125f}};
  for (const auto& c : published) {
    EXPECT_NEAR(eval(*d65, c.lambda), c.value, 1e-4f * c.value + 1e-4f) << c.lambda;
  }
  EXPECT_EQ(eval(*d65, 800.0f), eval(cie_d65(), 800.0f));
  for (const char* name : {"stdillum-D50", "stdillum-D55", "stdillum-D75"}) {
    const Spectrum* d = lib_->find_spectrum(name);
    ASSERT_NE(d, nullptr);
    for (float lambda : {790.0f, 810.0f, 830.0f}) EXPECT_GT(eval(*d, lambda), 40.0f) << name;
  }
  EXPECT_EQ(eval(*lib_->find_spectrum("stdillum-C"), 800.0f), 0.0f);
  EXPECT_FALSE(cie_daylight_illuminant("D60").ok());
}

std::vector<std::string> required_spectra() {
  std::vector<std::string> n = {"stdillum-A", "stdillum-D50", "stdillum-D65",
                                "stdillum-C", "stdillum-D55", "stdillum-D75"};
  for (int i = 1; i <= 12; ++i) n.push_back("stdillum-F" + std::to_string(i));
  for (int i = 1; i <= 15; ++i) n.push_back("stdillum-F3." + std::to_string(i));
  for (int i = 1; i <= 5; ++i) n.push_back("stdillum-HP" + std::to_string(i));
  for (int i = 1; i <= 5; ++i) n.push_back("stdillum-LED-B" + std::to_string(i));
  for (const char* s :
       {"stdillum-LED-BH1", "stdillum-LED-RGB1", "stdillum-LED-V1", "stdillum-LED-V2"}) {
    n.push_back(s);
  }
  for (const char* s :
       {"lamp-incandescent", "lamp-cool-white-fl", "lamp-hps", "lamp-lps", "lamp-mercury",
        "lamp-metal-halide", "lamp-f32t8-tl830-triphosphor", "lamp-60-a-w-soft-white",
        "lamp-phosphor-led-yag", "lamp-luxeon-ww-2880", "lamp-philips-tl-84", "lamp-kinoton-75p"}) {
    n.push_back(s);
  }
  for (int i = 1; i <= 24; ++i) {
    n.push_back((i < 10 ? "colorchecker-0" : "colorchecker-") + std::to_string(i));
  }
  for (const char* s : {"colorchecker-dark-skin", "colorchecker-cyan", "colorchecker-white-9.5",
                        "colorchecker-black-2"}) {
    n.push_back(s);
  }
  for (const char* m : {"Ag", "Al", "Au", "Cu", "CuZn", "MgO", "TiO2"}) {
    n.push_back(std::string("metal-") + m + "-eta");
    n.push_back(std::string("metal-") + m + "-k");
  }
  for (const char* i : {"glass-BK7", "glass-BAF10", "glass-F2", "glass-SF11", "glass-fused-silica",
                        "water", "diamond"}) {
    n.push_back(i);
  }
  return n;
}

std::vector<std::string> required_iors() {
  return {"glass-BK7",
          "glass-BAF10",
          "glass-F2",
          "glass-SF11",
          "glass-SF5",
          "glass-SF10",
          "glass-N-BK7",
          "glass-N-SF11",
          "glass-FK51A",
          "glass-LASF9",
          "glass-F5",
          "glass-F10",
          "glass-F11",
          "glass-fused-silica",
          "glass-CaF2",
          "water",
          "diamond",
          "metal-Au-eta",
          "metal-Ag-eta",
          "metal-Al-eta",
          "metal-Cu-eta",
          "metal-CuZn-eta",
          "metal-MgO-eta",
          "metal-TiO2-eta",
          "pbrt-v4-glass-BK7",
          "water-hale-querry-eta",
          "diamond-phillip-taft-eta"};
}

TEST_F(NamedSpectraTest, EveryRequiredSpectrumExistsAndIsFiniteNonNegative) {
  for (const std::string& name : required_spectra()) {
    const Spectrum* s = lib_->find_spectrum(name);
    ASSERT_NE(s, nullptr) << name;
    EXPECT_TRUE(lib_->contains(name));
    for (float l = 360.0f; l <= 830.0f; l += 0.5f) {
      const float v = eval(*s, l);
      ASSERT_TRUE(std::isfinite(v)) << name << " " << l;
      ASSERT_GE(v, 0.0f) << name << " " << l;
    }
  }
}

TEST_F(NamedSpectraTest, EveryNameIsFiniteAndNonNegative) {
  const std::vector<std::string> names = lib_->names();
  EXPECT_TRUE(std::is_sorted(names.begin(), names.end()));
  EXPECT_EQ(std::adjacent_find(names.begin(), names.end()), names.end());
  EXPECT_GT(names.size(), 150u);
  for (const std::string& name : names) {
    if (const Spectrum* s = lib_->find_spectrum(name)) {
      for (float l = 360.0f; l <= 830.0f; l += 1.0f) {
        const float v = eval(*s, l);
        ASSERT_TRUE(std::isfinite(v) && v >= 0.0f) << name << " " << l;
      }
    }
    if (const Ior* i = lib_->find_ior(name)) {
      for (double l = 360.0; l <= 830.0; l += 1.0) {
        ASSERT_TRUE(std::isfinite(eta(*i, l)) && eta(*i, l) > 0.0) << name << " " << l;
      }
    }
  }
}

TEST_F(NamedSpectraTest, IorsAreAvailableAsIorAndAsSpectrum) {
  for (const std::string& name : required_iors()) {
    const Ior* ior = lib_->find_ior(name);
    ASSERT_NE(ior, nullptr) << name;
    const Spectrum* s = lib_->find_spectrum(name);
    ASSERT_NE(s, nullptr) << name;
    for (float l : {400.0f, 550.5f, 700.0f}) EXPECT_NEAR(eval(*s, l), eta(*ior, l), 2e-5) << name;
  }
  EXPECT_TRUE(std::holds_alternative<TabulatedIor>(*lib_->find_ior("metal-Au-eta")));
  EXPECT_TRUE(std::holds_alternative<SellmeierIor>(*lib_->find_ior("glass-BK7")));
  EXPECT_EQ(lib_->find_ior("stdillum-D65"), nullptr);
  EXPECT_EQ(lib_->find_ior("metal-Au-k"), nullptr);
  EXPECT_EQ(lib_->find_spectrum("no-such-spectrum"), nullptr);
  EXPECT_FALSE(lib_->contains("no-such-spectrum"));
}

TEST_F(NamedSpectraTest, IlluminantChromaticitiesMatchCie) {
  const ColorMatching cmf = ColorMatching::cie1931();
  struct Expect {
    const char* name;
    double x, y;
  };
  for (const Expect& e :
       {Expect{"stdillum-A", 0.4476, 0.4074}, Expect{"stdillum-D65", 0.3127, 0.3290},
        Expect{"stdillum-D50", 0.3457, 0.3585}, Expect{"stdillum-F11", 0.3805, 0.3769},
        Expect{"stdillum-LED-B1", 0.4560, 0.4078}}) {
    const Xyz xyz = cmf.to_xyz(*lib_->find_spectrum(e.name));
    const double sum = xyz.x + xyz.y + xyz.z;
    EXPECT_NEAR(xyz.x / sum, e.x, 5e-4) << e.name;
    EXPECT_NEAR(xyz.y / sum, e.y, 5e-4) << e.name;
  }
}

TEST_F(NamedSpectraTest, SanitisedNamesAndUserAdditions) {
  EXPECT_EQ(sanitise_spectrum_name("F32T8/TL830 (Triphosphor)"), "f32t8-tl830-triphosphor");
  EXPECT_EQ(sanitise_spectrum_name("  Kinoton 75P "), "kinoton-75p");
  EXPECT_EQ(sanitise_spectrum_name("3-LED-1 (457/540/605)"), "3-led-1-457-540-605");
  SpectrumLibrary lib;
  EXPECT_TRUE(lib.add_spectrum("mine", ConstantSpectrum{1.0f}).ok());
  EXPECT_EQ(lib.add_spectrum("mine", ConstantSpectrum{2.0f}).code(),
            absl::StatusCode::kAlreadyExists);
  EXPECT_TRUE(lib.add_ior("mine", ConstantIor{1.5}).ok());
  EXPECT_EQ(lib.names(), std::vector<std::string>{"mine"});
}

}  // namespace
}  // namespace prism::spectral
