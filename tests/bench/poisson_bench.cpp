// prism-bench-poisson: throughput of the per-pixel screened Poisson reconstruction
// (coordinator/poisson.h, L2) against memcpy of the same bytes in the same run.
//
// For each bin count: a W×H image of random I (uniform [0, 1)) and G (uniform [−1, 1)), offset
// k = round(0.15·B), α = 0.2. The solver reads I and G and writes Î; the copy baseline copies I
// and G (memcpy into two destination buffers), so both read the same input bytes, and the copy
// writes twice what the solver writes. Throughput is input bytes (I + G) per second; the ratio
// solver/copy is the fraction of copy bandwidth the solver reaches (goal ≥ 0.5). Each figure is
// the best of --repeats runs (wall time), single thread and all threads (TBB, rows in parallel
// as reconstruct_image does; the copy split the same way). Buffers are written before timing, so
// no run pays for page faults. The L1 option (IRLS) is timed once per bin count for reference.
//
// Usage: prism-bench-poisson [--resolution 1024x1024] [--bins 64,15] [--repeats 5]
//          [--alpha 0.2] [--threads N (default: all hardware threads)] [--l1 on|off]
//          [--kernel auto|sse2|avx2|avx512]
#include <tbb/blocked_range.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <vector>

#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "coordinator/poisson.h"
#include "services/base/check.h"
#include "tests/bench/bench_common.h"

namespace prism::bench {
namespace {

using Clock = std::chrono::steady_clock;

float uniform(std::uint64_t index, std::uint64_t stream) {
  return hashed_unit(index, stream);
}

struct Figures {
  double solve = 0;  // seconds
  double copy = 0;
};

int run(int argc, char** argv) {
  auto flags = parse_flags(
      argc, argv,
      {"--resolution", "--bins", "--repeats", "--alpha", "--threads", "--l1", "--kernel"});
  if (!flags.ok()) {
    std::cerr << "prism-bench-poisson: " << flags.status().message() << "\n";
    return 1;
  }
  auto size = parse_size(flags->get("--resolution", "1024x1024"));
  auto repeats = flags->number("--repeats", 5, 1, 100);
  auto alpha = flags->number("--alpha", 0.2, job::kMinPoissonAlpha, job::kMaxPoissonAlpha);
  auto threads = flags->number("--threads", tbb::info::default_concurrency(), 1, 1024);
  const bool time_l1 = flags->get("--l1", "on") != "off";
  const std::string kernel_name = flags->get("--kernel", "auto");
  coordinator::PoissonKernel kernel = coordinator::PoissonKernel::kAuto;
  for (auto k : {coordinator::PoissonKernel::kSse2, coordinator::PoissonKernel::kAvx2,
                 coordinator::PoissonKernel::kAvx512}) {
    if (kernel_name == coordinator::to_string(k)) kernel = k;
  }
  if (!size.ok() || !repeats.ok() || !alpha.ok() || !threads.ok()) {
    for (const absl::Status& s :
         {size.status(), repeats.status(), alpha.status(), threads.status()}) {
      if (!s.ok()) std::cerr << "prism-bench-poisson: " << s.message() << "\n";
    }
    return 1;
  }
  std::vector<int> bin_counts;
  const std::vector<std::string> bin_list = absl::StrSplit(flags->get("--bins", "64,15"), ',');
  for (const std::string& b : bin_list) bin_counts.push_back(std::atoi(b.c_str()));
  const auto [width, height] = *size;
  const std::int64_t pixels = std::int64_t{width} * height;
  const int all_threads = static_cast<int>(*threads);

  std::printf(
      "Poisson reconstruction (L2) vs memcpy, %dx%d, alpha %g, best of %d, threads 1 and "
      "%d\n",
      width, height, *alpha, static_cast<int>(*repeats), all_threads);
  std::printf("%5s %3s %7s %7s %10s %10s %10s %10s %7s %10s\n", "bins", "k", "kernel", "threads",
              "solve ms", "solve MB/s", "copy ms", "copy MB/s", "ratio", "L1 ms");
  for (int bins : bin_counts) {
    const int k = static_cast<int>(std::lround(0.15 * bins));
    auto solver = coordinator::PoissonSolver::create(bins, k, *alpha, kernel);
    if (!solver.ok()) {
      std::cerr << "prism-bench-poisson: " << solver.status().message() << "\n";
      return 1;
    }
    const std::size_t n = static_cast<std::size_t>(pixels) * bins;
    const std::size_t row = static_cast<std::size_t>(width) * bins;
    std::vector<float> primal(n), gradient(n), out(n), copy_a(n), copy_b(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n), [&](const auto& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i) {
        primal[i] = uniform(i, 0);
        gradient[i] = 2.0f * uniform(i, 1) - 1.0f;
        out[i] = copy_a[i] = copy_b[i] = 0.0f;
      }
    });
    const double input_mb = 2.0 * n * sizeof(float) / 1e6;

    auto solve_rows = [&] {
      tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& r) {
        for (int y = r.begin(); y < r.end(); ++y) {
          const std::size_t o = static_cast<std::size_t>(y) * row;
          const absl::Status s = solver->solve_pixels(
              job::PoissonNorm::kL2, std::span(primal).subspan(o, row),
              std::span(gradient).subspan(o, row), std::span(out).subspan(o, row));
          PRISM_CHECK(s.ok());
        }
      });
    };
    auto copy_rows = [&] {
      tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& r) {
        const std::size_t o = static_cast<std::size_t>(r.begin()) * row;
        const std::size_t bytes = static_cast<std::size_t>(r.size()) * row * sizeof(float);
        std::memcpy(copy_a.data() + o, primal.data() + o, bytes);
        std::memcpy(copy_b.data() + o, gradient.data() + o, bytes);
      });
    };
    double l1_ms = 0;
    for (int t : {1, all_threads}) {
      tbb::task_arena arena(t);
      Figures f;
      arena.execute([&] {
        f.solve = best_seconds(static_cast<int>(*repeats), solve_rows);
        f.copy = best_seconds(static_cast<int>(*repeats), copy_rows);
      });
      if (t == all_threads && time_l1) {
        arena.execute([&] {
          l1_ms = 1e3 * best_seconds(1, [&] {
                    tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const auto& r) {
                      for (int y = r.begin(); y < r.end(); ++y) {
                        const std::size_t o = static_cast<std::size_t>(y) * row;
                        PRISM_CHECK(solver
                                        ->solve_pixels(job::PoissonNorm::kL1,
                                                       std::span(primal).subspan(o, row),
                                                       std::span(gradient).subspan(o, row),
                                                       std::span(out).subspan(o, row))
                                        .ok());
                      }
                    });
                  });
        });
      }
      std::printf("%5d %3d %7s %7d %10.1f %10.0f %10.1f %10.0f %7.2f %10s\n", bins, k,
                  std::string(coordinator::to_string(solver->kernel())).c_str(), t, 1e3 * f.solve,
                  input_mb / f.solve, 1e3 * f.copy, input_mb / f.copy, f.copy / f.solve,
                  t == all_threads && time_l1 ? absl::StrFormat("%.0f", l1_ms).c_str() : "");
      if (all_threads == 1) break;
    }
  }
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
