#include "client/compare_command.h"

#include <charconv>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"

namespace prism::client {

absl::StatusOr<image::Crop> parse_crop(const std::string& text, std::string_view flag) {
  std::vector<std::string> parts = absl::StrSplit(text, ',');
  int values[4] = {};
  bool ok = parts.size() == 4;
  for (std::size_t i = 0; ok && i < 4; ++i) {
    const std::string& p = parts[i];
    auto [end, ec] = std::from_chars(p.data(), p.data() + p.size(), values[i]);
    ok = !p.empty() && ec == std::errc() && end == p.data() + p.size() && values[i] >= 0;
  }
  if (!ok) {
    return absl::InvalidArgumentError(absl::StrCat(
        std::string(flag), " '", text, "': want x,y,w,h as four non-negative integers"));
  }
  return image::Crop{values[0], values[1], values[2], values[3]};
}

absl::StatusOr<std::string> run_compare(const CompareOptions& options) {
  auto comparison = image::compare_exr_files(options.test, options.reference, options.crop);
  if (!comparison.ok()) return comparison.status();
  return options.json ? image::format_comparison_json(*comparison)
                      : image::format_comparison_text(*comparison);
}

}  // namespace prism::client
