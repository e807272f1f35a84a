// The parameter list that follows a directive: `"type name" value` or `"type name" [values]`,
// as in pbrt-v4. Parsing checks the declaration, the value kinds and counts (rgb takes 3,
// point3 a multiple of 3, ...) and that every number is finite. Scene objects then read the
// parameters they know with the typed getters, each of which marks the parameter used and
// checks its declared type; check_all_used() turns any parameter nobody read into an error
// naming it and its position, like pbrt-v4. Every error starts with `file:line:column: `.
//
// Spectrum-valued strings: a string containing '/' or '.' is a file name (two columns,
// λ in nm and value; comma or whitespace separated; '#' comments; one non-numeric header
// line allowed), resolved relative to the main scene file's directory; any other string is a
// named spectrum, checked with the caller's name predicate.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "services/scene/scene_features.h"
#include "services/scene/source_location.h"
#include "services/scene/spectrum_param.h"
#include "services/scene/tokenizer.h"
#include "services/scene/transform.h"

namespace prism::scene {

enum class ParamType {
  kInteger, kFloat, kPoint2, kVector2, kPoint3, kVector3, kNormal3,
  kRgb, kSpectrum, kBlackbody, kBool, kString, kTexture,
};

const char* param_type_name(ParamType type);

struct Parameter {
  ParamType type = ParamType::kFloat;
  std::string name;
  std::string written_type;  // the type as the scene wrote it ("normal" for kNormal3); messages
  SourceLocation where;  // of the "type name" string
  std::vector<double> numbers;
  std::vector<std::string> strings;
  std::vector<bool> bools;
  mutable bool used = false;
};

// The parameter's type as the scene wrote it (pbrt-v4 has aliases: "normal" for "normal3",
// "point" for "point3", "vector" for "vector3"), else its canonical name: what messages quote.
std::string written_type(const Parameter& p);

// How spectrum parameters find named spectra and spectrum files. Unset predicates accept
// every name; an unset load_table refuses file references.
struct SpectrumSources {
  std::function<bool(std::string_view)> is_known_spectrum;
  std::function<bool(std::string_view)> is_known_ior;
  // Reads and parses the table file `reference` mentioned at `where`.
  std::function<absl::StatusOr<SpectrumTabulated>(const std::string& reference,
                                                  const SourceLocation& where)>
      load_table;
};

// What a spectrum parameter describes; selects the name predicate and the RGB range check.
enum class SpectrumRole { kReflectance, kUnbounded, kIlluminant, kIor };

class ParameterList {
 public:
  // Reads parameters while the next token is a string.
  static absl::StatusOr<ParameterList> parse(Tokenizer& tokens);

  bool has(std::string_view name) const { return find(name) != nullptr; }
  const Parameter* find(std::string_view name) const;

  // Single values; the default when absent. Errors: wrong declared type, more than one value.
  absl::StatusOr<double> get_float(std::string_view name, double fallback) const;
  absl::StatusOr<std::optional<double>> find_float(std::string_view name) const;
  absl::StatusOr<int> get_int(std::string_view name, int fallback) const;
  absl::StatusOr<bool> get_bool(std::string_view name, bool fallback) const;
  absl::StatusOr<std::string> get_string(std::string_view name, std::string_view fallback) const;
  absl::StatusOr<std::optional<std::string>> find_string(std::string_view name) const;
  absl::StatusOr<Vec3> get_point3(std::string_view name, const Vec3& fallback) const;

  // Arrays; empty when absent.
  absl::StatusOr<std::vector<double>> get_floats(std::string_view name) const;
  absl::StatusOr<std::vector<std::int64_t>> get_ints(std::string_view name) const;
  // point3 values (also accepts the vector3 and normal3 types when `type` says so).
  absl::StatusOr<std::vector<Vec3>> get_triples(std::string_view name, ParamType type) const;
  absl::StatusOr<std::vector<std::array<double, 2>>> get_point2s(std::string_view name) const;

  // A spectrum: `spectrum` (table or name or file), `rgb`, `blackbody`, or `float` (constant).
  absl::StatusOr<std::optional<SpectrumParam>> find_spectrum(std::string_view name,
                                                             SpectrumRole role,
                                                             const SpectrumSources& sources) const;

  // Who owns these parameters (`Material "coateddiffuse"`) and the recorder of the parse's
  // features; without a recorder every refusal is an error.
  void set_policy(FeatureRecorder* features, std::string owner) {
    features_ = features;
    owner_ = std::move(owner);
  }
  FeatureRecorder* features() const { return features_; }
  // `Material "coateddiffuse" 'texture albedo'`: the feature a parameter is, for reports.
  std::string feature(const Parameter& p) const;

  // An error if `name` is present: `<message>` at its position. When the recorder allows
  // unsupported input, the refusal is recorded with `substitution` and the parameter dropped.
  absl::Status refuse(std::string_view name, std::string_view message,
                      std::string_view substitution = "the scene without it") const;
  // The first parameter that no getter read, as an error: "unused parameter 'float foo'"
  // (recorded and dropped when the recorder allows unsupported input).
  absl::Status check_all_used() const;
  // Marks every parameter read: they belong to something refused as a whole.
  void mark_all_used() const;
  // The parameters no getter has read so far.
  std::vector<const Parameter*> unused() const;

  const std::vector<Parameter>& parameters() const { return params_; }

 private:
  absl::StatusOr<const Parameter*> typed(std::string_view name,
                                         std::initializer_list<ParamType> types) const;
  const SourceLocation& value_where(const Parameter* p) const;
  std::vector<Parameter> params_;
  std::vector<SourceLocation> value_where_;
  FeatureRecorder* features_ = nullptr;
  std::string owner_;  // parallel to params_: where each value list starts
};

// A finite number from a whole word (a leading '+' is allowed). Errors: not a number, or
// not finite (nan, inf, 1e999), naming `what` (e.g. "float fov" or "Translate").
absl::StatusOr<double> parse_finite_number(std::string_view text, const SourceLocation& where,
                                           std::string_view what);

// Parses a two-column table (see above); `file` names it in errors. Needs >= 2 rows with
// strictly increasing, positive wavelengths and finite values.
absl::StatusOr<SpectrumTabulated> parse_spectrum_table(std::string_view text, const std::string& file);

}  // namespace prism::scene
