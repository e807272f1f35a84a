#include "services/job/job_parameters.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace prism::job {
namespace {

absl::Status bad_field(const std::string& field, double value, const std::string& allowed) {
  return absl::InvalidArgumentError(
      absl::StrCat("prepass ", field, " is ", value, "; it must be ", allowed));
}

}  // namespace

std::string_view to_string(PoissonNorm norm) {
  return norm == PoissonNorm::kL1 ? "l1" : norm == PoissonNorm::kWeighted ? "weighted" : "l2";
}

absl::StatusOr<PoissonNorm> parse_poisson_norm(const std::string& text) {
  if (text == "l2") return PoissonNorm::kL2;
  if (text == "l1") return PoissonNorm::kL1;
  if (text == "weighted") return PoissonNorm::kWeighted;
  return absl::InvalidArgumentError(
      absl::StrCat("Poisson norm '", text, "': want l2, l1 or weighted"));
}

absl::Status PrepassParameters::validate() const {
  if (passes < 1 || passes > kMaxPasses) {
    return bad_field("passes", passes, absl::StrCat("1 to ", kMaxPasses));
  }
  if (spp < 1) return bad_field("spp", spp, "at least 1");
  if (!(std::isfinite(epsilon) && epsilon > 0.0 && epsilon < 1.0)) {
    return bad_field("epsilon", epsilon, "in (0, 1)");
  }
  if (!(std::isfinite(fallback) && fallback >= 0.0 && fallback < 1.0)) {
    return bad_field("fallback", fallback, "in [0, 1)");
  }
  if (!(std::isfinite(sigma_s) && sigma_s > 0.0 && sigma_s <= kMaxSigmaS)) {
    return bad_field("sigma_s", sigma_s, absl::StrCat("in (0, ", kMaxSigmaS, "] pixels"));
  }
  if (!(std::isfinite(sigma_r) && sigma_r > 0.0)) {
    return bad_field("sigma_r", sigma_r, "finite and > 0");
  }
  return absl::OkStatus();
}

std::uint32_t budgeted_prepass_spp(std::uint64_t spp, int passes, bool image_scaled) {
  const int shift = image_scaled ? 2 : 3;  // a pass costs 4^−(K−k) or 8^−(K−k) of the last
  double share = 0.0;
  for (int k = 1; k <= std::max(1, passes); ++k) share += std::ldexp(1.0, -shift * (passes - k));
  const double n =
      std::min<double>(std::floor(kBudgetShare * double(spp) / share), kMaxBudgetedSpp);
  if (n < kMinBudgetedSpp) return 0;
  // Sample-scaled, the first pass renders ⌊Ñ/8^(K−1)⌋ spp (prepass_schedule).
  if (!image_scaled && passes > 1 && std::ldexp(n, -shift * (passes - 1)) < kMinDecisionSpp) {
    return 0;
  }
  return std::uint32_t(n);
}

}  // namespace prism::job
