#include "services/job/job_parameters.h"

#include <gtest/gtest.h>

#include <limits>
#include <string>
#include <vector>

#include "services/base/testing/status_says.h"

namespace prism::job {
namespace {

TEST(PoissonNormTest, ParsesItsThreeNamesAndRefusesOthers) {
  EXPECT_EQ(*parse_poisson_norm("l2"), PoissonNorm::kL2);
  EXPECT_EQ(*parse_poisson_norm("l1"), PoissonNorm::kL1);
  EXPECT_EQ(*parse_poisson_norm("weighted"), PoissonNorm::kWeighted);
  EXPECT_EQ(to_string(PoissonNorm::kWeighted), "weighted");
  auto bad = parse_poisson_norm("L3");
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("'L3'"), std::string::npos);
  EXPECT_EQ(to_string(PoissonNorm::kL1), "l1");
}

TEST(PrepassParametersTest, ValidateNamesTheBadField) {
  EXPECT_TRUE(PrepassParameters{}.validate().ok());
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  struct Case {
    PrepassParameters p;
    const char* field;
  };
  std::vector<Case> cases;
  auto with = [](auto edit) {
    PrepassParameters p;
    edit(p);
    return p;
  };
  cases.push_back({with([](auto& p) { p.passes = 0; }), "passes"});
  cases.push_back({with([](auto& p) { p.passes = 9; }), "passes"});
  cases.push_back({with([](auto& p) { p.spp = 0; }), "spp"});
  cases.push_back({with([](auto& p) { p.epsilon = 0.0; }), "epsilon"});
  cases.push_back({with([](auto& p) { p.epsilon = 1.0; }), "epsilon"});
  cases.push_back({with([=](auto& p) { p.epsilon = nan; }), "epsilon"});
  cases.push_back({with([](auto& p) { p.fallback = -1e-9; }), "fallback"});
  cases.push_back({with([=](auto& p) { p.fallback = inf; }), "fallback"});
  cases.push_back({with([](auto& p) { p.fallback = 1.0; }), "fallback"});
  cases.push_back({with([](auto& p) { p.sigma_s = 0.0; }), "sigma_s"});
  cases.push_back({with([=](auto& p) { p.sigma_s = inf; }), "sigma_s"});
  cases.push_back({with([](auto& p) { p.sigma_s = 1000.0; }), "sigma_s"});
  cases.push_back({with([](auto& p) { p.sigma_r = -0.015; }), "sigma_r"});
  cases.push_back({with([=](auto& p) { p.sigma_r = nan; }), "sigma_r"});
  for (const Case& c : cases) {
    const absl::Status s = c.p.validate();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << c.field;
    EXPECT_TRUE(status_says(s, std::string("prepass ") + c.field + " is")) << s;
  }
  // Edges that are allowed.
  EXPECT_TRUE(with([](auto& p) { p.fallback = 0.0; }).validate().ok());
  EXPECT_TRUE(with([](auto& p) { p.passes = 8; }).validate().ok());
}

}  // namespace
}  // namespace prism::job
