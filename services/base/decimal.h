// Reading a decimal number from the text of a scene, spectrum or mesh file: std::from_chars's
// general format (no locale, no allocation) plus the leading '+' that strtod and file writers
// allow and from_chars does not. One reading for every text format, so they accept and refuse
// the same numbers: the scene parser's parameters and spectrum files, and OBJ meshes.
#pragma once

#include <charconv>
#include <cmath>
#include <string>
#include <string_view>
#include <system_error>

namespace prism::base {

enum class DecimalError {
  kNone,
  kNotANumber,  // empty, or not wholly a number ("1,5", "x", "1e")
  kNotFinite,   // "nan", "inf", or beyond a double's range either way ("1e999", "1e-999")
};

struct Decimal {
  double value = 0.0;
  DecimalError error = DecimalError::kNone;
};

// The whole of `text` as one finite double.
inline Decimal parse_decimal(std::string_view text) {
  Decimal d;
  if (!text.empty() && text.front() == '+') {
    text.remove_prefix(1);
    if (!text.empty() && text.front() == '-') {  // "+-1"
      d.error = DecimalError::kNotANumber;
      return d;
    }
  }
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), d.value);
  if (text.empty() || end != text.data() + text.size() ||
      (ec != std::errc() && ec != std::errc::result_out_of_range)) {
    d.error = DecimalError::kNotANumber;
  } else if (ec == std::errc::result_out_of_range || !std::isfinite(d.value)) {
    d.error = DecimalError::kNotFinite;
  }
  return d;
}

// Writing one: the shortest decimal that reads back as exactly `value`; for a value a float
// holds exactly (a parameter that travelled as a float) the shortest that reads back as that
// float: 0.4, not 0.4000000059604645. Finite values only.
inline std::string shortest_decimal(double value) {
  char buffer[64];
  const float narrow = static_cast<float>(value);
  const auto [end, ec] = double(narrow) == value
                             ? std::to_chars(buffer, buffer + sizeof buffer, narrow)
                             : std::to_chars(buffer, buffer + sizeof buffer, value);
  return ec == std::errc() ? std::string(buffer, end) : std::string();
}

}  // namespace prism::base
