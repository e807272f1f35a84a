#include "services/scene/spectrum_param.h"

#include <algorithm>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"

namespace prism::scene {
namespace {

std::string describe_table(const SpectrumTabulated& t) {
  std::string where = t.source == "inline" ? "inline table" : absl::StrCat("table \"", t.source, "\"");
  if (t.wavelengths_nm.empty()) return where;
  return absl::StrCat(where, " (", t.wavelengths_nm.size(), " samples, ", t.wavelengths_nm.front(),
                      "-", t.wavelengths_nm.back(), " nm)");
}

}  // namespace

std::string describe(const SpectrumParam& s) {
  struct Visitor {
    std::string operator()(const SpectrumConstant& c) const { return absl::StrCat("constant ", c.value); }
    std::string operator()(const SpectrumRgb& c) const {
      return absl::StrCat("rgb (", c.r, ", ", c.g, ", ", c.b, ")");
    }
    std::string operator()(const SpectrumTabulated& t) const { return describe_table(t); }
    std::string operator()(const SpectrumNamed& n) const { return absl::StrCat("named \"", n.name, "\""); }
    std::string operator()(const SpectrumBlackbody& b) const {
      return absl::StrCat("blackbody ", b.kelvin, " K");
    }
  };
  return std::visit(Visitor{}, s);
}

std::string describe(const IorParam& ior) {
  struct Visitor {
    std::string operator()(const IorConstant& c) const { return absl::StrCat("constant ", c.eta); }
    std::string operator()(const IorNamed& n) const { return absl::StrCat("named \"", n.name, "\""); }
    std::string operator()(const IorTabulated& t) const { return describe_table(t.table); }
    std::string operator()(const IorCauchy& c) const {
      return absl::StrCat("cauchy [", absl::StrJoin(c.coefficients, " "), "]");
    }
    std::string operator()(const IorSellmeier& s) const {
      return absl::StrCat("sellmeier B [", absl::StrJoin(s.b, " "), "] C [", absl::StrJoin(s.c, " "),
                          "] um^2");
    }
  };
  return std::visit(Visitor{}, ior);
}

bool is_dispersive(const IorParam& ior) {
  struct Visitor {
    bool operator()(const IorConstant&) const { return false; }
    bool operator()(const IorNamed&) const { return true; }
    bool operator()(const IorTabulated& t) const {
      const auto& v = t.table.values;
      return std::any_of(v.begin(), v.end(), [&](double x) { return x != v.front(); });
    }
    bool operator()(const IorCauchy& c) const {
      return std::any_of(c.coefficients.begin() + 1, c.coefficients.end(),
                         [](double x) { return x != 0.0; });
    }
    bool operator()(const IorSellmeier& s) const {
      return std::any_of(s.b.begin(), s.b.end(), [](double x) { return x != 0.0; });
    }
  };
  return std::visit(Visitor{}, ior);
}

}  // namespace prism::scene
