// Shared pieces of the benchmark programs: loading a scene the way `prism render` does and
// reading `--name value` flags. Benchmarks print figures; they assert nothing.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "client/evaluation.h"
#include "services/scene/scene_description.h"
#include "services/spectral/named_spectra.h"

namespace prism::bench {

// A scene loaded as `prism render` and `prism bench` load it (client/evaluation.h).
using LoadedBenchScene = evaluation::BenchScene;
using evaluation::load_bench_scene;

// A path relative to the source tree (PRISM_SOURCE_DIR), so the benchmarks run from anywhere.
std::filesystem::path source_path(const std::string& relative);

// `--name value` pairs and positional arguments. INVALID_ARGUMENT for a flag without a value or
// a flag not in `known`.
struct Flags {
  std::map<std::string, std::string> values;
  std::vector<std::string> positional;

  std::string get(const std::string& name, const std::string& fallback) const;
  // INVALID_ARGUMENT naming the flag when the value is not a number in [lo, hi].
  absl::StatusOr<double> number(const std::string& name, double fallback, double lo,
                                double hi) const;
};
absl::StatusOr<Flags> parse_flags(int argc, char** argv, const std::vector<std::string>& known);

// "WxH" -> (W, H).
absl::StatusOr<std::pair<int, int>> parse_size(const std::string& text);

}  // namespace prism::bench
