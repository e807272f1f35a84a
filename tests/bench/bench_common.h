// Shared pieces of the benchmark programs: loading a scene the way `prism render` does and
// reading `--name value` flags. Benchmarks print figures; they assert nothing.
#pragma once

#include <algorithm>
#include <chrono>
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

// The best (smallest) wall time of `repeats` runs of `run`, in seconds.
template <typename F>
double best_seconds(int repeats, F&& run) {
  double best = 1e300;
  for (int r = 0; r < repeats; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    run();
    best = std::min(best,
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  return best;
}

// A deterministic value in [0, 1) from an index and a stream: SplitMix64, cheap enough for
// filling benchmark inputs of 10^8 values.
float hashed_unit(std::uint64_t index, std::uint64_t stream = 0);

}  // namespace prism::bench
