#include "services/base/decimal.h"

#include <gtest/gtest.h>

namespace prism::base {
namespace {

TEST(DecimalTest, ReadsWhatFileWritersWrite) {
  const struct {
    const char* text;
    double value;
  } cases[] = {{"1.5", 1.5}, {"+1.5", 1.5}, {"-2e3", -2000.0}, {"0", 0.0},  {"+0.25", 0.25},
               {".5", 0.5},  {"5.", 5.0},   {"1E-3", 1e-3},    {"-0", 0.0}, {"7", 7.0}};
  for (const auto& c : cases) {
    const Decimal d = parse_decimal(c.text);
    EXPECT_EQ(d.error, DecimalError::kNone) << c.text;
    EXPECT_EQ(d.value, c.value) << c.text;
  }
}

TEST(DecimalTest, RefusesWhatIsNotWhollyOneNumber) {
  for (const char* text :
       {"", "+", "-", "+-1", "++1", "1,5", "x", "1e", " 1", "1 ", "1.5f", "0x10", "1..2", "--1"}) {
    EXPECT_EQ(parse_decimal(text).error, DecimalError::kNotANumber) << "'" << text << "'";
  }
}

TEST(DecimalTest, RefusesNumbersThatAreNotFinite) {
  for (const char* text :
       {"nan", "NaN", "-nan", "inf", "+inf", "-infinity", "1e999", "-1e999", "1e-999"}) {
    EXPECT_EQ(parse_decimal(text).error, DecimalError::kNotFinite) << text;
  }
}

// A float parameter reads as it was written (0.4, not 0.400000006 or 0.4000000059604645) and
// reads back as that float; a double that no float holds keeps its own shortest digits and
// reads back as that double.
TEST(DecimalTest, WritesTheShortestDecimalThatReadsBack) {
  EXPECT_EQ(shortest_decimal(double(0.4f)), "0.4");
  EXPECT_EQ(shortest_decimal(double(0.05f)), "0.05");
  EXPECT_EQ(shortest_decimal(0.3), "0.3");
  EXPECT_EQ(shortest_decimal(1e300), "1e+300");
  for (float f : {0.4f, 1.0f / 3.0f, 123456.75f, 1e-30f}) {
    EXPECT_EQ(float(parse_decimal(shortest_decimal(double(f))).value), f) << f;
  }
  for (double d : {0.1 + 0.2, 1.0 / 3.0, 1e300}) {
    EXPECT_EQ(parse_decimal(shortest_decimal(d)).value, d) << d;
  }
}

}  // namespace
}  // namespace prism::base
