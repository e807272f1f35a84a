#include "services/scene/parameters.h"

#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/ascii.h"
#include "services/base/decimal.h"
#include "services/base/status.h"

namespace prism::scene {
namespace {

struct ParamTypeName {
  std::string_view name;
  ParamType type;
};

constexpr ParamTypeName kTypeNames[] = {
    {"integer", ParamType::kInteger}, {"float", ParamType::kFloat},
    {"point2", ParamType::kPoint2},   {"vector2", ParamType::kVector2},
    {"point3", ParamType::kPoint3},   {"point", ParamType::kPoint3},
    {"vector3", ParamType::kVector3}, {"vector", ParamType::kVector3},
    {"normal3", ParamType::kNormal3}, {"normal", ParamType::kNormal3},
    {"rgb", ParamType::kRgb},         {"spectrum", ParamType::kSpectrum},
    {"blackbody", ParamType::kBlackbody}, {"bool", ParamType::kBool},
    {"string", ParamType::kString},   {"texture", ParamType::kTexture},
};

bool is_numeric(ParamType t) {
  switch (t) {
    case ParamType::kInteger: case ParamType::kFloat: case ParamType::kPoint2:
    case ParamType::kVector2: case ParamType::kPoint3: case ParamType::kVector3:
    case ParamType::kNormal3: case ParamType::kRgb: case ParamType::kBlackbody:
      return true;
    default:
      return false;
  }
}

std::string decl(const Parameter& p) { return absl::StrCat(written_type(p), " ", p.name); }

}  // namespace

absl::StatusOr<double> parse_finite_number(std::string_view text, const SourceLocation& where,
                                           std::string_view what) {
  const base::Decimal d = base::parse_decimal(text);
  if (d.error == base::DecimalError::kNotANumber)
    return location_error(where, absl::StrCat("expected a number for '", absl_view(what), "', found '", absl_view(text), "'"));
  if (d.error == base::DecimalError::kNotFinite)
    return location_error(where, absl::StrCat("value '", absl_view(text), "' of '", absl_view(what), "' is not a finite number"));
  return d.value;
}

namespace {

absl::Status check_count(const Parameter& p, const SourceLocation& where, size_t count) {
  auto need = [&](size_t multiple, absl::string_view what) -> absl::Status {
    if (count == 0 || count % multiple != 0)
      return location_error(where, absl::StrCat("'", decl(p), "' needs ", what, ", got ", count,
                                                count == 1 ? " value" : " values"));
    return absl::OkStatus();
  };
  switch (p.type) {
    case ParamType::kRgb:
      if (count != 3) return need(count + 1, "3 values");
      return absl::OkStatus();
    case ParamType::kBlackbody:
      if (count != 1) return need(count + 1, "1 value (a temperature in K)");
      return absl::OkStatus();
    case ParamType::kPoint2: case ParamType::kVector2:
      return need(2, count == 0 ? "at least one point (2 values)" : "a multiple of 2 values");
    case ParamType::kPoint3: case ParamType::kVector3: case ParamType::kNormal3:
      return need(3, count == 0 ? "at least one triple (3 values)" : "a multiple of 3 values");
    default: return need(1, "at least one value");
  }
}

}  // namespace

const char* param_type_name(ParamType type) {
  for (const ParamTypeName& t : kTypeNames)
    if (t.type == type) return t.name.data();  // a literal, NUL-terminated
  return "?";
}

std::string written_type(const Parameter& p) {
  return p.written_type.empty() ? std::string(param_type_name(p.type)) : p.written_type;
}

absl::StatusOr<ParameterList> ParameterList::parse(Tokenizer& tokens) {
  ParameterList list;
  while (true) {
    PRISM_ASSIGN_OR_RETURN(Token head, tokens.peek());
    if (head.kind != Token::Kind::kString) break;
    PRISM_ASSIGN_OR_RETURN(Token decl_tok, tokens.next());
    SourceLocation where = tokens.location(decl_tok);
    std::vector<absl::string_view> words =
        absl::StrSplit(decl_tok.text, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    if (words.size() != 2)
      return location_error(where, absl::StrCat("malformed parameter declaration \"", decl_tok.text,
                                                "\" (expected \"type name\")"));
    Parameter p;
    bool known = false;
    for (const ParamTypeName& t : kTypeNames)
      if (t.name == std::string_view(words[0].data(), words[0].size())) {
        p.type = t.type;
        known = true;
      }
    if (!known)
      return location_error(where, absl::StrCat("unknown parameter type '", words[0], "' in \"",
                                                decl_tok.text, "\""));
    p.name = std::string(words[1]);
    p.written_type = std::string(words[0]);
    p.where = where;
    // The same parameter twice: pbrt-v4 takes the last and lets it shadow the first without a
    // word; under another type the first is unused there, which pbrt-v4 refuses.
    std::optional<std::size_t> shadowed;
    for (std::size_t i = 0; i < list.params_.size(); ++i) {
      const Parameter& other = list.params_[i];
      if (other.name != p.name) continue;
      if (other.type != p.type)
        return location_error(where, absl::StrCat("parameter '", p.name,
                                                  "' given twice with different types (first at ",
                                                  other.where.to_string(), ")"));
      shadowed = i;
    }

    // The value: one word/string, or a bracketed list.
    std::vector<Token> values;
    PRISM_ASSIGN_OR_RETURN(Token first, tokens.next());
    SourceLocation values_at = tokens.location(first);
    if (first.kind == Token::Kind::kOpenBracket) {
      while (true) {
        PRISM_ASSIGN_OR_RETURN(Token v, tokens.next());
        if (v.kind == Token::Kind::kCloseBracket) break;
        if (v.kind == Token::Kind::kEnd)
          return location_error(values_at, absl::StrCat("unterminated '[' in the values of '", decl(p), "'"));
        if (v.kind == Token::Kind::kOpenBracket)
          return location_error(tokens.location(v), absl::StrCat("nested '[' in the values of '", decl(p), "'"));
        values.push_back(std::move(v));
      }
    } else if (first.kind == Token::Kind::kWord || first.kind == Token::Kind::kString) {
      values.push_back(std::move(first));
    } else {
      return location_error(values_at, absl::StrCat("expected a value for '", decl(p), "', found ",
                                                     token_kind_name(first.kind)));
    }
    std::string what = decl(p);

    if (is_numeric(p.type) ||
        (p.type == ParamType::kSpectrum && !values.empty() && values[0].kind == Token::Kind::kWord)) {
      for (const Token& v : values) {
        SourceLocation at = tokens.location(v);
        if (v.kind != Token::Kind::kWord)
          return location_error(at, absl::StrCat("expected a number for '", what, "', found string \"",
                                                 v.text, "\""));
        PRISM_ASSIGN_OR_RETURN(double x, parse_finite_number(v.text, at, what));
        if (p.type == ParamType::kInteger &&
            (x != std::floor(x) || std::abs(x) > std::numeric_limits<std::int32_t>::max()))
          return location_error(at, absl::StrCat("expected an integer for '", what, "', found '", v.text, "'"));
        p.numbers.push_back(x);
      }
      if (p.type != ParamType::kSpectrum) PRISM_RETURN_IF_ERROR(check_count(p, values_at, p.numbers.size()));
      if (p.type == ParamType::kSpectrum && (p.numbers.size() < 4 || p.numbers.size() % 2 != 0))
        return location_error(values_at, absl::StrCat("'", what, "' needs pairs of wavelength and value "
                                                      "(at least 2 pairs), got ", p.numbers.size(), " numbers"));
    } else if (p.type == ParamType::kBool) {
      for (const Token& v : values) {
        if (v.text == "true") p.bools.push_back(true);
        else if (v.text == "false") p.bools.push_back(false);
        else
          return location_error(tokens.location(v), absl::StrCat("expected true or false for '", what,
                                                                 "', found '", v.text, "'"));
      }
      PRISM_RETURN_IF_ERROR(check_count(p, values_at, p.bools.size()));
    } else {
      for (const Token& v : values) {
        if (v.kind != Token::Kind::kString)
          return location_error(tokens.location(v), absl::StrCat("expected a quoted string for '", what,
                                                                 "', found '", v.text, "'"));
        p.strings.push_back(v.text);
      }
      if (p.type == ParamType::kSpectrum && p.strings.size() != 1)
        return location_error(values_at, absl::StrCat("'", what, "' takes one spectrum name or file name"));
      PRISM_RETURN_IF_ERROR(check_count(p, values_at, p.strings.size()));
    }
    if (shadowed.has_value()) {
      list.params_[*shadowed] = std::move(p);
    } else {
      list.params_.push_back(std::move(p));
    }
    list.value_where_.push_back(values_at);
  }
  return list;
}

const Parameter* ParameterList::find(std::string_view name) const {
  for (const Parameter& p : params_)
    if (p.name == name) return &p;
  return nullptr;
}

const SourceLocation& ParameterList::value_where(const Parameter* p) const {
  return value_where_[static_cast<size_t>(p - params_.data())];
}

absl::StatusOr<const Parameter*> ParameterList::typed(std::string_view name,
                                                      std::initializer_list<ParamType> types) const {
  const Parameter* p = find(name);
  if (p == nullptr) return p;
  for (ParamType t : types)
    if (p->type == t) {
      p->used = true;
      return p;
    }
  std::string expected;
  for (ParamType t : types) absl::StrAppend(&expected, expected.empty() ? "" : " or ", "'", absl_view(param_type_name(t)), "'");
  return location_error(p->where, absl::StrCat("parameter '", p->name, "' has type '", written_type(*p),
                                               "', expected ", expected));
}

namespace {
absl::Status single(const Parameter& p, size_t count) {
  if (count != 1)
    return location_error(p.where, absl::StrCat("'", decl(p), "' takes one value, got ", count));
  return absl::OkStatus();
}
}  // namespace

absl::StatusOr<std::optional<double>> ParameterList::find_float(std::string_view name) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {ParamType::kFloat}));
  if (p == nullptr) return std::optional<double>();
  PRISM_RETURN_IF_ERROR(single(*p, p->numbers.size()));
  return std::optional<double>(p->numbers[0]);
}

absl::StatusOr<double> ParameterList::get_float(std::string_view name, double fallback) const {
  PRISM_ASSIGN_OR_RETURN(std::optional<double> v, find_float(name));
  return v.value_or(fallback);
}

absl::StatusOr<int> ParameterList::get_int(std::string_view name, int fallback) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {ParamType::kInteger}));
  if (p == nullptr) return fallback;
  PRISM_RETURN_IF_ERROR(single(*p, p->numbers.size()));
  return static_cast<int>(p->numbers[0]);
}

absl::StatusOr<bool> ParameterList::get_bool(std::string_view name, bool fallback) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {ParamType::kBool}));
  if (p == nullptr) return fallback;
  PRISM_RETURN_IF_ERROR(single(*p, p->bools.size()));
  return static_cast<bool>(p->bools[0]);
}

absl::StatusOr<std::optional<std::string>> ParameterList::find_string(std::string_view name) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {ParamType::kString}));
  if (p == nullptr) return std::optional<std::string>();
  PRISM_RETURN_IF_ERROR(single(*p, p->strings.size()));
  return std::optional<std::string>(p->strings[0]);
}

absl::StatusOr<std::string> ParameterList::get_string(std::string_view name,
                                                      std::string_view fallback) const {
  PRISM_ASSIGN_OR_RETURN(std::optional<std::string> v, find_string(name));
  return v ? *v : std::string(fallback);
}

absl::StatusOr<Vec3> ParameterList::get_point3(std::string_view name, const Vec3& fallback) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {ParamType::kPoint3}));
  if (p == nullptr) return fallback;
  PRISM_RETURN_IF_ERROR(single(*p, p->numbers.size() / 3));
  return Vec3{p->numbers[0], p->numbers[1], p->numbers[2]};
}

absl::StatusOr<std::vector<double>> ParameterList::get_floats(std::string_view name) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {ParamType::kFloat}));
  if (p == nullptr) return std::vector<double>();
  return p->numbers;
}

absl::StatusOr<std::vector<std::int64_t>> ParameterList::get_ints(std::string_view name) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {ParamType::kInteger}));
  std::vector<std::int64_t> out;
  if (p == nullptr) return out;
  out.reserve(p->numbers.size());
  for (double v : p->numbers) out.push_back(static_cast<std::int64_t>(v));
  return out;
}

absl::StatusOr<std::vector<Vec3>> ParameterList::get_triples(std::string_view name, ParamType type) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {type}));
  std::vector<Vec3> out;
  if (p == nullptr) return out;
  out.reserve(p->numbers.size() / 3);
  for (size_t i = 0; i + 2 < p->numbers.size(); i += 3)
    out.push_back({p->numbers[i], p->numbers[i + 1], p->numbers[i + 2]});
  return out;
}

absl::StatusOr<std::vector<std::array<double, 2>>> ParameterList::get_point2s(std::string_view name) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p, typed(name, {ParamType::kPoint2}));
  std::vector<std::array<double, 2>> out;
  if (p == nullptr) return out;
  for (size_t i = 0; i + 1 < p->numbers.size(); i += 2) out.push_back({p->numbers[i], p->numbers[i + 1]});
  return out;
}

absl::StatusOr<std::optional<SpectrumParam>> ParameterList::find_spectrum(
    std::string_view name, SpectrumRole role, const SpectrumSources& sources) const {
  PRISM_ASSIGN_OR_RETURN(const Parameter* p,
                         typed(name, {ParamType::kSpectrum, ParamType::kRgb, ParamType::kBlackbody,
                                      ParamType::kFloat}));
  if (p == nullptr) return std::optional<SpectrumParam>();
  const SourceLocation& at = value_where(p);
  switch (p->type) {
    case ParamType::kFloat:
      PRISM_RETURN_IF_ERROR(single(*p, p->numbers.size()));
      return std::optional<SpectrumParam>(SpectrumConstant{p->numbers[0]});
    case ParamType::kRgb: {
      SpectrumRgb rgb{p->numbers[0], p->numbers[1], p->numbers[2]};
      if (rgb.r < 0 || rgb.g < 0 || rgb.b < 0)
        return location_error(at, absl::StrCat("'", decl(*p), "' has a negative component"));
      if (role == SpectrumRole::kReflectance && (rgb.r > 1 || rgb.g > 1 || rgb.b > 1))
        return location_error(at, absl::StrCat("'", decl(*p), "' is a reflectance and has a component > 1"));
      return std::optional<SpectrumParam>(rgb);
    }
    case ParamType::kBlackbody:
      if (!(p->numbers[0] > 0))
        return location_error(at, absl::StrCat("'", decl(*p), "' needs a temperature > 0 K"));
      return std::optional<SpectrumParam>(SpectrumBlackbody{p->numbers[0]});
    default:
      break;
  }
  if (!p->numbers.empty()) {
    SpectrumTabulated t;
    t.source = "inline";
    for (size_t i = 0; i + 1 < p->numbers.size(); i += 2) {
      double lambda = p->numbers[i];
      if (!(lambda > 0) || (!t.wavelengths_nm.empty() && lambda <= t.wavelengths_nm.back()))
        return location_error(at, absl::StrCat("'", decl(*p), "' needs positive, strictly increasing "
                                               "wavelengths (at ", lambda, " nm)"));
      t.wavelengths_nm.push_back(lambda);
      t.values.push_back(p->numbers[i + 1]);
    }
    return std::optional<SpectrumParam>(std::move(t));
  }
  const std::string& ref = p->strings[0];
  if (ref.find('/') != std::string::npos || ref.find('.') != std::string::npos) {
    if (!sources.load_table)
      return location_error(at, absl::StrCat("spectrum file \"", ref, "\" cannot be read here"));
    PRISM_ASSIGN_OR_RETURN(SpectrumTabulated t, sources.load_table(ref, at));
    return std::optional<SpectrumParam>(std::move(t));
  }
  const auto& known = role == SpectrumRole::kIor ? sources.is_known_ior : sources.is_known_spectrum;
  if (known && !known(ref))
    return location_error(at, absl::StrCat("unknown named spectrum \"", ref, "\""));
  return std::optional<SpectrumParam>(SpectrumNamed{ref});
}

std::string ParameterList::feature(const Parameter& p) const {
  return owner_.empty() ? absl::StrCat("'", decl(p), "'")
                        : absl::StrCat(owner_, " '", decl(p), "'");
}

absl::Status ParameterList::refuse(std::string_view name, std::string_view message,
                                   std::string_view substitution) const {
  const Parameter* p = find(name);
  if (p == nullptr) return absl::OkStatus();
  std::string text = absl::StrCat("'", decl(*p), "': ", absl_view(message));
  if (features_ == nullptr) return location_error(p->where, text);
  p->used = true;
  return features_->refuse(feature(*p), p->where, text, substitution);
}

absl::Status ParameterList::check_all_used() const {
  for (const Parameter& p : params_) {
    if (p.used) continue;
    std::string text = absl::StrCat("unused parameter '", decl(p), "'");
    if (features_ == nullptr) return location_error(p.where, text);
    p.used = true;
    PRISM_RETURN_IF_ERROR(features_->refuse(feature(p), p.where, text, "the scene without it"));
  }
  return absl::OkStatus();
}

void ParameterList::mark_all_used() const {
  for (const Parameter& p : params_) p.used = true;
}

std::vector<const Parameter*> ParameterList::unused() const {
  std::vector<const Parameter*> out;
  for (const Parameter& p : params_)
    if (!p.used) out.push_back(&p);
  return out;
}

absl::StatusOr<SpectrumTabulated> parse_spectrum_table(std::string_view text, const std::string& file) {
  SpectrumTabulated t;
  t.source = file;
  int line_no = 0;
  bool seen_content = false;
  for (absl::string_view line : absl::StrSplit(absl_view(text), '\n')) {
    ++line_no;
    if (size_t hash = line.find('#'); hash != absl::string_view::npos) line = line.substr(0, hash);
    std::vector<absl::string_view> fields = absl::StrSplit(line, absl::ByAnyChar(", \t\r;"), absl::SkipEmpty());
    if (fields.empty()) continue;
    SourceLocation at{file, line_no, 1};
    bool first_line = !seen_content;
    seen_content = true;
    double values[2] = {0, 0};
    bool number[2] = {false, false};
    for (size_t i = 0; i < fields.size() && i < 2; ++i) {
      const base::Decimal d =
          base::parse_decimal(std::string_view(fields[i].data(), fields[i].size()));
      values[i] = d.value;
      number[i] = d.error == base::DecimalError::kNone;
    }
    if (first_line && !number[0]) continue;  // one header line, e.g. "wavelength_nm,value"
    bool numeric = fields.size() == 2 && number[0] && number[1];
    if (fields.size() != 2)
      return location_error(at, absl::StrCat("expected 2 columns (wavelength in nm, value), found ",
                                             fields.size()));
    if (!numeric) return location_error(at, "expected two finite numbers");
    if (!(values[0] > 0) || (!t.wavelengths_nm.empty() && values[0] <= t.wavelengths_nm.back()))
      return location_error(at, "wavelengths must be positive and strictly increasing");
    t.wavelengths_nm.push_back(values[0]);
    t.values.push_back(values[1]);
  }
  if (t.wavelengths_nm.size() < 2)
    return location_error({file, 1, 1}, "a spectrum table needs at least 2 rows");
  return t;
}

}  // namespace prism::scene
