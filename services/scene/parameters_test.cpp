#include "services/scene/parameters.h"

#include <gtest/gtest.h>

namespace prism::scene {
namespace {

absl::StatusOr<ParameterList> parse(std::string_view text) {
  Tokenizer t(text, "p.pbrt");
  return ParameterList::parse(t);
}

TEST(Parameters, TypedGettersAndDefaults) {
  absl::StatusOr<ParameterList> p = parse(
      "\"float a\" 1.5 \"integer n\" [ 3 ] \"bool b\" true \"string s\" \"x\" \"point3 p\" [1 2 3] "
      "\"point2 uv\" [0 1 2 3] \"normal N\" [0 0 1]");
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(*p->get_float("a", 0), 1.5);
  EXPECT_EQ(*p->get_float("missing", 7), 7);
  EXPECT_EQ(*p->get_int("n", 0), 3);
  EXPECT_EQ(*p->get_bool("b", false), true);
  EXPECT_EQ(*p->get_string("s", ""), "x");
  EXPECT_EQ(*p->get_point3("p", {}), (Vec3{1, 2, 3}));
  EXPECT_EQ(p->get_point2s("uv")->size(), 2u);
  EXPECT_FALSE(p->check_all_used().ok());
  EXPECT_EQ(p->get_triples("N", ParamType::kNormal3)->size(), 1u);
  EXPECT_TRUE(p->check_all_used().ok());
}

// The same parameter twice under one type: the last wins, as in pbrt-v4 (which reverses the
// list and takes the first match, and lets it shadow the earlier one silently).
TEST(Parameters, TheLastOfARepeatedParameterWins) {
  absl::StatusOr<ParameterList> p =
      parse("\"float radius\" 1 \"float a\" 0 \"float radius\" 2");
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(*p->get_float("radius", 0), 2);
  EXPECT_EQ(*p->get_float("a", 1), 0);
  EXPECT_TRUE(p->check_all_used().ok());
}

TEST(Parameters, ValueErrors) {
  EXPECT_EQ(std::string(parse("\"integer n\" 1.5").status().message()), "p.pbrt:1:13: expected an integer for 'integer n', found '1.5'");
  EXPECT_EQ(std::string(parse("\"float a\" inf").status().message()), "p.pbrt:1:11: value 'inf' of 'float a' is not a finite number");
  EXPECT_EQ(std::string(parse("\"bool b\" maybe").status().message()), "p.pbrt:1:10: expected true or false for 'bool b', found 'maybe'");
  EXPECT_EQ(std::string(parse("\"string s\" [ x ]").status().message()), "p.pbrt:1:14: expected a quoted string for 'string s', found 'x'");
  EXPECT_EQ(std::string(parse("\"point3 p\" [1 2]").status().message()), "p.pbrt:1:12: 'point3 p' needs a multiple of 3 values, got 2 values");
  // Messages quote the type as written: pbrt-v4's alias "normal" is not called "normal3".
  EXPECT_EQ(std::string(parse("\"normal n\" [1 2]").status().message()), "p.pbrt:1:12: 'normal n' needs a multiple of 3 values, got 2 values");
  // Zero is a multiple of 3: an empty list is told it is empty.
  EXPECT_EQ(std::string(parse("\"point3 p\" []").status().message()), "p.pbrt:1:12: 'point3 p' needs at least one triple (3 values), got 0 values");
  EXPECT_EQ(std::string(parse("\"float\" 1").status().message()), "p.pbrt:1:1: malformed parameter declaration \"float\" (expected \"type name\")");
  EXPECT_EQ(std::string(parse("\"float a\" 1 \"rgb a\" [1 1 1]").status().message()), "p.pbrt:1:13: parameter 'a' given twice with different types (first at p.pbrt:1:1)");
  EXPECT_EQ(std::string(parse("\"spectrum s\" [400 1 500]").status().message()),
            "p.pbrt:1:14: 'spectrum s' needs pairs of wavelength and value (at least 2 pairs), got 3 numbers");
}

TEST(Parameters, Spectra) {
  absl::StatusOr<ParameterList> p = parse(
      "\"spectrum a\" [400 1 500 2] \"spectrum b\" \"stdillum-F11\" \"rgb c\" [0.5 2 0] \"blackbody d\" 3000 "
      "\"float e\" 0.25 \"spectrum f\" [500 1 400 2] \"spectrum g\" \"x.csv\"");
  ASSERT_TRUE(p.ok()) << p.status();
  SpectrumSources sources;
  sources.is_known_spectrum = [](std::string_view n) { return n == "stdillum-F11"; };
  EXPECT_EQ(**p->find_spectrum("a", SpectrumRole::kUnbounded, sources),
            SpectrumParam(SpectrumTabulated{{400, 500}, {1, 2}, "inline"}));
  EXPECT_EQ(**p->find_spectrum("b", SpectrumRole::kIlluminant, sources), SpectrumParam(SpectrumNamed{"stdillum-F11"}));
  EXPECT_EQ(**p->find_spectrum("c", SpectrumRole::kIlluminant, sources), SpectrumParam(SpectrumRgb{0.5, 2, 0}));
  EXPECT_EQ(std::string(p->find_spectrum("c", SpectrumRole::kReflectance, sources).status().message()),
            "p.pbrt:1:64: 'rgb c' is a reflectance and has a component > 1");
  EXPECT_EQ(**p->find_spectrum("d", SpectrumRole::kIlluminant, sources), SpectrumParam(SpectrumBlackbody{3000}));
  EXPECT_EQ(**p->find_spectrum("e", SpectrumRole::kReflectance, sources), SpectrumParam(SpectrumConstant{0.25}));
  EXPECT_FALSE(p->find_spectrum("f", SpectrumRole::kUnbounded, sources).ok());
  EXPECT_EQ(std::string(p->find_spectrum("g", SpectrumRole::kUnbounded, sources).status().message()),
            "p.pbrt:1:148: spectrum file \"x.csv\" cannot be read here");
  EXPECT_FALSE(p->find_spectrum("missing", SpectrumRole::kUnbounded, sources)->has_value());
}

TEST(Parameters, SpectrumTables) {
  absl::StatusOr<SpectrumTabulated> t = parse_spectrum_table("# c\nlambda value\n400 1\n500\t2\n600,3\n", "t.csv");
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_EQ(t->wavelengths_nm, (std::vector<double>{400, 500, 600}));
  EXPECT_EQ(t->values, (std::vector<double>{1, 2, 3}));
  EXPECT_EQ(std::string(parse_spectrum_table("400,1,2\n", "t.csv").status().message()),
            "t.csv:1:1: expected 2 columns (wavelength in nm, value), found 3");
  EXPECT_EQ(std::string(parse_spectrum_table("400,1\n", "t.csv").status().message()),
            "t.csv:1:1: a spectrum table needs at least 2 rows");
  EXPECT_EQ(std::string(parse_spectrum_table("400,1\n500,x\n", "t.csv").status().message()), "t.csv:2:1: expected two finite numbers");
}

}  // namespace
}  // namespace prism::scene
