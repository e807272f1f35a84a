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

}  // namespace
}  // namespace prism::base
