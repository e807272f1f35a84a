// prism-bench-prepass-reconstruction: the coordinator's prepass reconstruction cost
// (prepass.h) on synthetic moments: one joint bilateral filter of the whole image's 2·bins moment
// channels (for scale), then build_tables as the coordinator runs it (that filter with and without
// each pixel, the validation of every candidate table, its filter, the choice and quantisation),
// encoding every tile's PdfTable bytes and decoding them as a worker does. The estimate is noisy
// and the guides have edges (blocks of different depth, normal and albedo), so the range weights
// matter as in a render; the cost does not depend on the scene beyond the image size, the bins
// and σ_s (window (2⌈3σ_s⌉ + 1)²). Per stage the best of --repeats of the process's CPU time
// (all threads; on a shared machine wall time measures the neighbours) and of wall time.
//
// Usage: prism-bench-prepass-reconstruction [--resolution 640x480] [--bins 64] [--tile 32]
//          [--sigma-s 1.75] [--threads N] [--repeats 3]
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "coordinator/prepass.h"
#include "services/spectral/pixel_tables.h"
#include "tests/bench/bench_common.h"

namespace prism::bench {
namespace {

struct Stamp {
  std::chrono::steady_clock::time_point wall;
  double cpu;
};

Stamp now() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return {std::chrono::steady_clock::now(), double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec)};
}

struct Best {
  double cpu = 1e30, wall = 1e30;
  void add(const Stamp& start) {
    const Stamp end = now();
    cpu = std::min(cpu, end.cpu - start.cpu);
    wall = std::min(wall, std::chrono::duration<double>(end.wall - start.wall).count());
  }
};

int run(int argc, char** argv) {
  absl::StatusOr<Flags> flags = parse_flags(
      argc, argv, {"--resolution", "--bins", "--tile", "--sigma-s", "--threads", "--repeats"});
  if (!flags.ok()) {
    std::fprintf(stderr, "%s\n", std::string(flags.status().message()).c_str());
    return 2;
  }
  const absl::StatusOr<std::pair<int, int>> size =
      parse_size(flags->get("--resolution", "640x480"));
  if (!size.ok()) {
    std::fprintf(stderr, "%s\n", std::string(size.status().message()).c_str());
    return 2;
  }
  const auto [width, height] = *size;
  const absl::StatusOr<double> bins = flags->number("--bins", 64, 4, 256);
  const absl::StatusOr<double> tile = flags->number("--tile", 32, 1, 4096);
  const absl::StatusOr<double> sigma_s = flags->number("--sigma-s", 1.75, 0.1, 16);
  const absl::StatusOr<double> threads =
      flags->number("--threads", tbb::info::default_concurrency(), 1, 1024);
  const absl::StatusOr<double> repeats = flags->number("--repeats", 3, 1, 100);
  for (const auto* s : {&bins, &tile, &sigma_s, &threads, &repeats}) {
    if (!s->ok()) {
      std::fprintf(stderr, "%s\n", std::string(s->status().message()).c_str());
      return 2;
    }
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(*threads));
  const int b_count = int(*bins), t_side = int(*tile);

  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  coordinator::GuideImage guides = *coordinator::GuideImage::create(width, height);
  // The moments (prepass.h MomentImage): per bin K, then per bin U.
  image::SpectralImage estimate = *image::SpectralImage::create(width, height, 2 * b_count);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      // 24-pixel blocks of different surfaces; inside a block the guides vary slightly.
      const int block = (x / 24) * 7 + (y / 24) * 3;
      const float a = float(block % 5) / 5.0f;
      guides.set(x, y, {a + 0.002f * u(rng), a, 0.1f, 1.0f - a, 0.2f + 0.1f * float(block % 3)});
      for (int b = 0; b < b_count; ++b) {
        const float shape = 1.0f + std::sin(0.1f * float(b * (1 + block % 4)));
        estimate.value(x, y, b) = shape * (0.5f + u(rng));  // ~30 % noise, as at low spp
        estimate.value(x, y, b_count + b) = 0.3f * shape * u(rng);
      }
    }
  }
  std::vector<double> ew(static_cast<std::size_t>(b_count));
  for (int b = 0; b < b_count; ++b) {
    ew[b] = b < b_count / 8 ? 0.0 : 1.0 + 0.5 * std::cos(0.2 * b);
  }
  double ew_total = 0;
  for (double w : ew) ew_total += w;
  for (double& w : ew) w /= ew_total;

  Best filter, tables_time, encode, decode;
  double fallback = 0.0;
  std::size_t bytes = 0;
  for (int r = 0; r < int(*repeats); ++r) {
    Stamp t = now();
    const image::SpectralImage filtered =
        *coordinator::filter_estimate(estimate, guides, *sigma_s, 0.015);
    filter.add(t);
    t = now();
    const coordinator::PixelTableImage tables = *coordinator::build_tables(
        estimate, guides, {}, ew, {}, coordinator::VarianceModel{4, 4, true});
    tables_time.add(t);
    fallback = tables.fallback_fraction();
    std::vector<std::string> encoded;
    std::vector<image::TileRect> rects;
    t = now();
    for (int y0 = 0; y0 < height; y0 += t_side) {
      for (int x0 = 0; x0 < width; x0 += t_side) {
        rects.push_back({x0, y0, std::min(width, x0 + t_side), std::min(height, y0 + t_side)});
        encoded.push_back(*tables.encode_tile(rects.back()));
      }
    }
    encode.add(t);
    bytes = 0;
    t = now();
    for (std::size_t i = 0; i < rects.size(); ++i) {
      const absl::StatusOr<spectral::PixelTables> decoded =
          spectral::PixelTables::decode(rects[i].width(), rects[i].height(), b_count, encoded[i]);
      if (!decoded.ok()) {
        std::fprintf(stderr, "%s\n", std::string(decoded.status().message()).c_str());
        return 1;
      }
      bytes += encoded[i].size();
    }
    decode.add(t);
  }
  const double mpix = double(width) * height / 1e6;
  std::printf("prepass reconstruction: %dx%d, %d bins, sigma_s %.2f (window %d^2), %d threads\n",
              width, height, b_count, *sigma_s, 2 * int(std::ceil(3 * *sigma_s)) + 1,
              int(*threads));
  std::printf("  %-26s %8s %8s %12s\n", "stage", "CPU s", "wall s", "CPU us/pixel");
  const auto line = [&](const char* name, const Best& b) {
    std::printf("  %-26s %8.3f %8.3f %12.2f\n", name, b.cpu, b.wall, b.cpu / mpix);
  };
  line("one filter of the moments", filter);
  line("build_tables (all of it)", tables_time);
  line("encode all tiles", encode);
  line("decode all tiles", decode);
  std::printf("  %.1f MB of PdfTable bytes, fallback fraction %.3f\n", double(bytes) / 1e6,
              fallback);
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
