#include "services/spectral/wavelength_grid.h"

#include <cmath>
#include <limits>

#include "gtest/gtest.h"

namespace prism::spectral {
namespace {

TEST(WavelengthGridTest, RefusesBinCountsOutsideRange) {
  EXPECT_FALSE(WavelengthGrid::create(3).ok());
  EXPECT_FALSE(WavelengthGrid::create(257).ok());
  EXPECT_FALSE(WavelengthGrid::create(0).ok());
  EXPECT_FALSE(WavelengthGrid::create(-64).ok());
  EXPECT_EQ(WavelengthGrid::create(3).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(WavelengthGrid::create(4).ok());
  EXPECT_TRUE(WavelengthGrid::create(256).ok());
  EXPECT_EQ(WavelengthGrid().bins(), 64);
}

TEST(WavelengthGridTest, BoundsAndCentres) {
  const WavelengthGrid g = *WavelengthGrid::create(47);
  EXPECT_FLOAT_EQ(g.bin_width(), 10.0f);
  EXPECT_FLOAT_EQ(g.lower(0), 360.0f);
  EXPECT_FLOAT_EQ(g.upper(46), 830.0f);
  EXPECT_FLOAT_EQ(g.centre(0), 365.0f);
  EXPECT_FLOAT_EQ(g.centre(46), 825.0f);
  for (int b = 0; b + 1 < g.bins(); ++b) EXPECT_EQ(g.upper(b), g.lower(b + 1));
}

TEST(WavelengthGridTest, BinOfEdgeCases) {
  for (int bins = WavelengthGrid::kMinBins; bins <= WavelengthGrid::kMaxBins; ++bins) {
    const WavelengthGrid g = *WavelengthGrid::create(bins);
    EXPECT_EQ(g.bin_of(360.0f), 0);
    EXPECT_EQ(g.bin_of(830.0f), bins - 1);
    EXPECT_EQ(g.bin_of(std::nextafter(360.0f, 0.0f)), -1);
    EXPECT_EQ(g.bin_of(std::nextafter(830.0f, 1000.0f)), -1);
    for (int b = 0; b < bins; ++b) {
      ASSERT_EQ(g.bin_of(g.lower(b)), b) << bins << " bins";
      ASSERT_EQ(g.bin_of(std::nextafter(g.upper(b), 0.0f)), b) << bins << " bins";
      ASSERT_EQ(g.bin_of(g.centre(b)), b);
    }
  }
  const WavelengthGrid g;
  EXPECT_EQ(g.bin_of(std::numeric_limits<float>::quiet_NaN()), -1);
  EXPECT_EQ(g.bin_of(-std::numeric_limits<float>::infinity()), -1);
  EXPECT_EQ(g.bin_of(200.0f), -1);
}

TEST(WavelengthGridTest, WrapIsCyclic) {
  const WavelengthGrid g = *WavelengthGrid::create(64);
  EXPECT_EQ(g.wrap(0), 0);
  EXPECT_EQ(g.wrap(63), 63);
  EXPECT_EQ(g.wrap(64), 0);
  EXPECT_EQ(g.wrap(-1), 63);
  EXPECT_EQ(g.wrap(-65), 63);
  EXPECT_EQ(g.wrap(64 * 3 + 5), 5);
  EXPECT_EQ(g.wrap(10 + 10), 20);
}

TEST(WavelengthGridTest, WrapWavelengthIsCyclic) {
  EXPECT_FLOAT_EQ(wrap_wavelength(500.0f), 500.0f);
  EXPECT_FLOAT_EQ(wrap_wavelength(830.0f), 360.0f);
  EXPECT_FLOAT_EQ(wrap_wavelength(840.0f), 370.0f);
  EXPECT_FLOAT_EQ(wrap_wavelength(350.0f), 820.0f);
  EXPECT_FLOAT_EQ(wrap_wavelength(360.0f - 470.0f * 2 + 1.0f), 361.0f);
  for (float l = -1000.0f; l < 2000.0f; l += 0.37f) {
    const float w = wrap_wavelength(l);
    ASSERT_GE(w, kLambdaMin);
    ASSERT_LT(w, kLambdaMax);
  }
  EXPECT_LT(wrap_wavelength(std::nextafter(360.0f, 0.0f)), kLambdaMax);
  EXPECT_TRUE(std::isnan(wrap_wavelength(std::numeric_limits<float>::quiet_NaN())));
}

}  // namespace
}  // namespace prism::spectral
