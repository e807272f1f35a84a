#include "services/spectral/csv_table.h"

#include "absl/strings/match.h"
#include "gtest/gtest.h"
#include "services/spectral/spectrum.h"

namespace prism::spectral {
namespace {

TEST(CsvTableTest, ParsesHeaderRowsCommentsAndBlankLines) {
  auto t = parse_csv_table("# comment\nwavelength_nm, a ,b\r\n400,1,2\n\n500, 3 ,4\n", "x.csv");
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_EQ(t->column_count(), 3);
  EXPECT_EQ(t->row_count(), 2);
  EXPECT_EQ(t->columns()[1], "a");
  EXPECT_EQ(t->column_index("b"), 2);
  EXPECT_EQ(t->column_index("c"), -1);
  EXPECT_EQ(t->line_of_row(1), 5);
  auto a = t->numeric_column("a");
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(*a, (std::vector<double>{1, 3}));
}

TEST(CsvTableTest, ErrorsCarrySourceAndLineNumbers) {
  auto wrong_count = parse_csv_table("wavelength_nm,a\n400,1\n410,2,3\n", "lamp.csv");
  ASSERT_FALSE(wrong_count.ok());
  EXPECT_EQ(wrong_count.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StrContains(wrong_count.status().message(), "lamp.csv:3:"))
      << wrong_count.status();
  EXPECT_TRUE(absl::StrContains(wrong_count.status().message(), "expected 2 cells, found 3"))
      << wrong_count.status();

  auto t = parse_csv_table("wavelength_nm,a\n400,1\n\n410,abc\n", "user.csv");
  ASSERT_TRUE(t.ok());
  auto bad = t->numeric_column("a");
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(absl::StrContains(bad.status().message(), "user.csv:4:")) << bad.status();
  EXPECT_TRUE(absl::StrContains(bad.status().message(), "'abc'")) << bad.status();

  auto quoted = parse_csv_table("wavelength_nm,a\n\"400\",1\n", "q.csv");
  ASSERT_FALSE(quoted.ok());
  EXPECT_TRUE(absl::StrContains(quoted.status().message(), "q.csv:2:")) << quoted.status();

  auto dup = parse_csv_table("wavelength_nm,a,a\n400,1,2\n", "d.csv");
  ASSERT_FALSE(dup.ok());
  EXPECT_TRUE(absl::StrContains(dup.status().message(), "d.csv:1: duplicate column name 'a'"))
      << dup.status();

  EXPECT_FALSE(parse_csv_table("", "empty.csv").ok());
  EXPECT_FALSE(parse_csv_table("wavelength_nm,a\n", "header_only.csv").ok());
  EXPECT_FALSE(parse_csv_table("wavelength_nm,,a\n1,2,3\n", "blank_name.csv").ok());
}

TEST(CsvTableTest, SpectrumFromCsvReportsNonIncreasingWavelengthLine) {
  auto s = PiecewiseLinearSpectrum::from_csv_text("wavelength_nm,v\n400,1\n500,2\n450,3\n", "s.csv",
                                                  "v");
  ASSERT_FALSE(s.ok());
  EXPECT_TRUE(absl::StrContains(s.status().message(), "s.csv:4:")) << s.status();
  EXPECT_TRUE(absl::StrContains(s.status().message(), "strictly increasing")) << s.status();
  EXPECT_FALSE(PiecewiseLinearSpectrum::from_csv_text("wavelength_nm,v\n400,1\n", "s", "w").ok());
  EXPECT_FALSE(
      PiecewiseLinearSpectrum::from_csv_text("wavelength_nm,v\n400,1\n", "s", "wavelength_nm")
          .ok());
  auto ok = PiecewiseLinearSpectrum::from_csv_text("wavelength_nm,v\n400,1\n500,3\n", "s", "v");
  ASSERT_TRUE(ok.ok());
  EXPECT_FLOAT_EQ((*ok)(450.0f), 2.0f);
}

}  // namespace
}  // namespace prism::spectral
