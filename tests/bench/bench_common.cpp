#include "tests/bench/bench_common.h"

#include <algorithm>
#include <charconv>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"

namespace prism::bench {

std::filesystem::path source_path(const std::string& relative) {
  return std::filesystem::path(PRISM_SOURCE_DIR) / relative;
}

std::string Flags::get(const std::string& name, const std::string& fallback) const {
  auto it = values.find(name);
  return it == values.end() ? fallback : it->second;
}

absl::StatusOr<double> Flags::number(const std::string& name, double fallback, double lo,
                                     double hi) const {
  auto it = values.find(name);
  if (it == values.end()) return fallback;
  const std::string& text = it->second;
  double value = 0;
  auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(value) ||
      value < lo || value > hi) {
    return absl::InvalidArgumentError(
        absl::StrCat(name, " '", text, "': want a number in ", lo, "..", hi));
  }
  return value;
}

absl::StatusOr<Flags> parse_flags(int argc, char** argv, const std::vector<std::string>& known) {
  Flags flags;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg.rfind("--", 0) != 0) {
      flags.positional.push_back(arg);
      continue;
    }
    if (std::find(known.begin(), known.end(), arg) == known.end()) {
      std::string list;
      for (const std::string& k : known) absl::StrAppend(&list, " ", k);
      return absl::InvalidArgumentError(absl::StrCat("unknown flag ", arg, "; known:", list));
    }
    if (i + 1 >= argc) return absl::InvalidArgumentError(absl::StrCat(arg, " needs a value"));
    flags.values[arg] = argv[++i];
  }
  return flags;
}

absl::StatusOr<std::pair<int, int>> parse_size(const std::string& text) {
  const std::size_t x = text.find('x');
  int w = 0, h = 0;
  if (x != std::string::npos) {
    auto a = std::from_chars(text.data(), text.data() + x, w);
    auto b = std::from_chars(text.data() + x + 1, text.data() + text.size(), h);
    if (a.ec == std::errc() && a.ptr == text.data() + x && b.ec == std::errc() &&
        b.ptr == text.data() + text.size() && w >= 1 && h >= 1 && w <= scene::kMaxResolution &&
        h <= scene::kMaxResolution) {
      return std::pair<int, int>{w, h};
    }
  }
  return absl::InvalidArgumentError(absl::StrCat("size '", text, "': want WxH, e.g. 160x120"));
}

float hashed_unit(std::uint64_t index, std::uint64_t stream) {
  std::uint64_t z = index * 2 + stream + 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  z ^= z >> 31;
  return static_cast<float>(z >> 40) * 0x1.0p-24f;
}

}  // namespace prism::bench
