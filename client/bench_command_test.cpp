#include "client/bench_command.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "absl/strings/str_replace.h"
#include "absl/strings/str_split.h"

namespace prism::client {
namespace {

BenchRow row(const std::string& method, const std::string& budget, double seconds, double rel_mse,
             const std::string& region = "image", int seed = 1) {
  BenchRow r;
  r.scene = "box";
  r.method = method;
  r.budget = budget;
  r.seed = seed;
  r.region = region;
  r.spp = 16;
  r.seconds = seconds;
  r.metrics.rel_mse = rel_mse;
  r.metrics.mse = rel_mse / 10;
  r.metrics.ssim = 0.9;
  return r;
}

TEST(BenchCommandTest, BudgetsAreIncreasingDurations) {
  auto b = parse_budgets("10s,30,1.5m");
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(*b, (std::vector<double>{10, 30, 90}));
  for (const char* bad :
       {"", "10s,5s", "0s", "-1", "10x", "s", "10s,,20s", "nan", "1e300s", "10s,10081m"}) {
    auto parsed = parse_budgets(bad);
    EXPECT_FALSE(parsed.ok()) << bad;
    if (!parsed.ok()) {
      EXPECT_NE(std::string(parsed.status().message()).find("--budgets"), std::string::npos);
    }
  }
}

// A region with commas is one quoted field; every row has the header's column count.
TEST(BenchCommandTest, CsvQuotesRegionsAndKeepsItsColumns) {
  const std::string csv =
      bench_csv({row("hero", "10s", 10.5, 0.01), row("hero", "10s", 10.5, 0.02, "1,2,3,4")});
  std::vector<std::string> lines = absl::StrSplit(csv, '\n', absl::SkipEmpty());
  ASSERT_EQ(lines.size(), 3u);
  EXPECT_NE(lines[2].find(",\"1,2,3,4\","), std::string::npos) << lines[2];
  const auto columns = [](const std::string& line) {
    int n = 1;
    bool quoted = false;
    for (char c : line) {
      if (c == '"') quoted = !quoted;
      if (c == ',' && !quoted) ++n;
    }
    return n;
  };
  EXPECT_EQ(columns(lines[1]), columns(lines[0]));
  EXPECT_EQ(columns(lines[2]), columns(lines[0]));
}

// parse_bench_csv reads back what bench_csv wrote (quoted regions, %.9g numbers) and names the
// file and line of what it cannot read.
TEST(BenchCommandTest, ResultsReadBackAsTheRowsTheyWere) {
  BenchRow a = row("auto", "10s", 10.5, 0.0123456789, "1,2,3,4", 2);
  a.ran = "hero+\"caustics\"";
  a.floor_known = true;
  a.rel_mse_floor = 1.5e-7;
  const std::string csv = bench_csv({row("hero", "10s", 10.5, 0.01), a});
  auto rows = parse_bench_csv(csv, "r.csv");
  ASSERT_TRUE(rows.ok()) << rows.status();
  ASSERT_EQ(rows->size(), 2u);
  EXPECT_EQ(bench_csv(*rows), csv);
  const BenchRow& b = (*rows)[1];
  EXPECT_EQ(b.region, "1,2,3,4");
  EXPECT_EQ(b.ran, a.ran);
  EXPECT_EQ(b.seed, 2);
  EXPECT_TRUE(b.floor_known);
  EXPECT_DOUBLE_EQ(b.metrics.rel_mse, 0.0123456789);

  EXPECT_THAT(parse_bench_csv("scene,method\n", "r.csv").status().message(),
              ::testing::HasSubstr("r.csv:1: not a prism bench results.csv"));
  std::string cut = csv.substr(0, csv.rfind(',', csv.size() - 2)) + "\n";
  EXPECT_THAT(parse_bench_csv(cut, "r.csv").status().message(),
              ::testing::HasSubstr("r.csv:3: 16 fields, want 17"));
  std::string word = csv;
  word.replace(word.find("10.5"), 4, "ten");
  EXPECT_THAT(parse_bench_csv(word, "r.csv").status().message(),
              ::testing::HasSubstr("r.csv:2: column 7 'ten' is not a finite number"));
  // CRLF line ends (a spreadsheet's) and a blank line at the end read as the same rows; a
  // non-finite number is refused here rather than by the plotter after the report is written.
  auto crlf = parse_bench_csv(absl::StrReplaceAll(csv, {{"\n", "\r\n"}}) + "\r\n", "r.csv");
  ASSERT_TRUE(crlf.ok()) << crlf.status();
  EXPECT_EQ(bench_csv(*crlf), csv);
  std::string infinite = csv;
  infinite.replace(infinite.find("10.5"), 4, "inf");
  EXPECT_THAT(parse_bench_csv(infinite, "r.csv").status().message(),
              ::testing::HasSubstr("r.csv:2: column 7 'inf' is not a finite number"));
}

// The equal-time ratio divides by the baseline's relMSE interpolated log-linearly at the
// method's seconds: hero's curve through (1 s, 0.1) and (4 s, 0.025) is 0.05 at 2 s, so a
// method with 0.025 at 2 s is at 0.5; means are over seeds.
TEST(BenchCommandTest, ReportGivesEqualTimeRatiosAgainstTheBaseline) {
  std::vector<BenchRow> rows = {row("hero", "a", 1, 0.1), row("hero", "b", 4, 0.025),
                                row("gradient", "a", 2, 0.02, "image", 1),
                                row("gradient", "a", 2, 0.03, "image", 2),
                                row("gradient", "b", 8, 0.004)};
  const std::string report = bench_report(rows, "hero", "# header\n");
  EXPECT_EQ(report.rfind("# header\n", 0), 0u);
  EXPECT_NE(report.find("| gradient | a | 16 | 2.00 | 0.0025 | 0.025 | 0.9000 | 0.500 |"),
            std::string::npos)
      << report;
  // Beyond the baseline's last point its error falls as 1/time: 0.025 · 4/8 = 0.0125.
  EXPECT_NE(report.find("| gradient | b | 16 | 8.00 | 0.0004 | 0.004 | 0.9000 | 0.320 "
                        "(extrapolated) |"),
            std::string::npos)
      << report;
  EXPECT_NE(report.find("| hero | a | 16 | 1.00 | 0.01 | 0.1 | 0.9000 | 1.000 |"),
            std::string::npos)
      << report;
  // Auto's rows name the method that ran.
  BenchRow chose = row("auto", "a", 2, 0.02);
  chose.ran = "gradient";
  const std::string with_auto = bench_report({rows[0], chose}, "hero", "");
  EXPECT_NE(with_auto.find("| auto (gradient) | a | 16 |"), std::string::npos) << with_auto;
  // ... and auto is set against the best of the others at its own seconds: at 2 s hero's curve
  // is at 0.05 and gradient's (means over seeds, 0.025 at 2 s) lower, so auto's 0.02 is 0.8 of
  // gradient's.
  std::vector<BenchRow> all = rows;
  all.push_back(chose);
  const std::string against = bench_report(all, "hero", "");
  // The seeds' spread: gradient's two seeds at budget a are 0.02 and 0.03 (auto has one).
  EXPECT_NE(against.find("| box | whole image | a | gradient | 0.800 | gradient | 1.50 |"),
            std::string::npos)
      << against;
  // With one seed on both sides there is no spread to give.
  const std::string single = bench_report({rows[0], rows[1], chose}, "hero", "");
  EXPECT_NE(single.find("| box | whole image | a | gradient | 0.400 | hero | – |"),
            std::string::npos)
      << single;
  EXPECT_EQ(bench_report(rows, "hero", "").find("auto against the best"), std::string::npos);
  const std::string without = bench_report(rows, "uniform", "");
  EXPECT_NE(without.find("'uniform' was not among the methods"), std::string::npos);
}

// One data block per method and region with positive errors, in time order; insets dashed.
TEST(BenchCommandTest, PlotHasACurvePerMethodAndDashedInsets) {
  std::vector<BenchRow> rows = {row("hero", "b", 4, 0.025), row("hero", "a", 1, 0.1),
                                row("hero", "a", 1, 0.2, "0,0,8,8"),
                                row("gradient", "a", 2, -0.001)};
  const BenchPlot plot = bench_plot(rows, "box", "wall", "/d/box.dat", "/d/box.svg", "/d/box.png");
  EXPECT_EQ(plot.data, "# hero image\n1 0.1 16\n4 0.025 16\n\n\n# hero 0,0,8,8\n1 0.2 16\n\n\n");
  EXPECT_NE(plot.script.find("index 0 using 1:2 with linespoints lc 1 lw 2.5 pt 7 dt 1 title "
                             "'hero'"),
            std::string::npos)
      << plot.script;
  EXPECT_NE(plot.script.find("index 1 using 1:2 with linespoints lc 1 lw 1.5 pt 6 dt 2 title "
                             "'hero, inset 0,0,8,8'"),
            std::string::npos)
      << plot.script;
  // The gradient's only point is not positive: no curve (a log axis cannot show it).
  EXPECT_EQ(plot.script.find("gradient"), std::string::npos);
  // Names relative to the script's directory, so it reruns there; bench adds a .tmp suffix.
  EXPECT_NE(plot.script.find("set output 'box.svg'.suffix"), std::string::npos) << plot.script;
  EXPECT_NE(plot.script.find("set output 'box.png'.suffix"), std::string::npos);
  EXPECT_NE(plot.script.find("set logscale xy"), std::string::npos);
  // With an inset's long titles the key takes two columns (one row of five would run off the
  // image); the test below has no inset and keeps one row.
  EXPECT_NE(plot.script.find("set key below noenhanced width 2 maxcols 2\n"), std::string::npos)
      << plot.script;
  // The axes fit the plotted points (1..4 s, relMSE 0.025..0.2), not whole decades.
  EXPECT_NE(plot.script.find("set xrange [0.8:5]\nset yrange [0.0166667:0.3]\n"
                             "set xtics (1, 2, 5)\nset ytics (0.02, 0.05, 0.1, 0.2)\n"),
            std::string::npos)
      << plot.script;
}

TEST(BenchCommandTest, PlotTicsStayReadableInsideADecadeAndOverMany) {
  // 3 and 3.5 s: no 1-2-5 value in [2.4, 4.375], so every multiple of the decade; relMSE over
  // eight decades: whole decades only.
  const BenchPlot plot = bench_plot({row("hero", "a", 3, 1.5e-9), row("hero", "b", 3.5, 0.02)},
                                    "box", "cpu", "/d/box.dat", "/d/box.svg", "/d/box.png");
  EXPECT_NE(plot.script.find("set xtics (3, 4)\n"), std::string::npos) << plot.script;
  EXPECT_NE(plot.script.find("set key below noenhanced width 1\n"), std::string::npos)
      << plot.script;
  EXPECT_NE(plot.script.find("set ytics (1e-09, 1e-08, 1e-07, 1e-06, 1e-05, 0.0001, 0.001, 0.01)"
                             "\n"),
            std::string::npos)
      << plot.script;
}

TEST(BenchReportTest, WarnsWhereTheReferencesNoiseIsMostOfTheError) {
  auto row = [](const char* method, double mse, double floor, bool known) {
    BenchRow r;
    r.scene = "box";
    r.method = method;
    r.budget = "64spp";
    r.seed = 1;
    r.region = "image";
    r.metrics.mse = mse;
    r.metrics.rel_mse = mse;
    r.mse_floor = r.rel_mse_floor = floor;
    r.floor_known = known;
    return r;
  };
  // A floor of a tenth of the error: no warning; of two thirds, or above the error: one each.
  EXPECT_EQ(reference_warnings({row("hero", 0.9, 0.1, true)}), "");
  EXPECT_EQ(reference_warnings({row("hero", 0.9, 5.0, false)}), "");  // unknown floor
  const std::string two_thirds =
      reference_warnings({row("hero", 0.9, 0.1, true), row("uniform", 0.5, 1.0, true)});
  EXPECT_NE(two_thirds.find("- box, image: the reference's own noise is 67 % of the error "
                            "measured for uniform at 64spp (seed 1);"),
            std::string::npos)
      << two_thirds;
  const std::string negative = reference_warnings({row("hero", -0.1, 1.0, true)});
  EXPECT_NE(negative.find("whose error minus the floor is negative"), std::string::npos)
      << negative;
  // And the report carries them.
  EXPECT_NE(bench_report({row("hero", -0.1, 1.0, true)}, "hero", "# header\n").find("**Warning:**"),
            std::string::npos);
}

}  // namespace
}  // namespace prism::client
