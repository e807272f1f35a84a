// prism-bench-wavelength-sampling: the cost of drawing a sample's CMIS lanes from a pixel's
// prepass table (services/spectral/binned_shape.h: bin masses with the job default's shape
// inside each bin) against drawing them from the job's default distribution itself, side by side
// in one run. The default is the emitter mixture of the given lamps on 1 nm cells, mixed
// defensively as RenderScene builds it; the tables are random bin masses, one per pixel of a
// 32x32 tile, visited in pixel order as the tile renderer does, --pixel-samples samples per
// pixel before the next (the tile renderer takes all of a pixel's samples in a task at once by
// default). A table is sampled two ways: by its two-step view (a search over the bins, then over
// the default's cells) and by its composite CDF (one search; what the tile renderer uses), whose
// per-pixel build is timed with its samples. Reported: nanoseconds per lane, best of --repeats,
// and each table way's ratio to the default (goal: at most 1.1). Nothing is asserted.
//
// Usage: prism-bench-wavelength-sampling [--bins 64] [--lanes 4] [--samples 2000000]
//          [--pixel-samples 1024] [--repeats 5] [--lamps stdillum-F11,lamp-lps,stdillum-A]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "absl/strings/str_split.h"
#include "services/spectral/binned_shape.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/pixel_tables.h"
#include "tests/bench/bench_common.h"

namespace prism::bench {
namespace {

int run(int argc, char** argv) {
  auto flags = parse_flags(
      argc, argv, {"--bins", "--lanes", "--samples", "--pixel-samples", "--repeats", "--lamps"});
  if (!flags.ok()) {
    std::fprintf(stderr, "%s\n", std::string(flags.status().message()).c_str());
    return 2;
  }
  const auto bins = flags->number("--bins", 64, 4, 4096);
  const auto lanes = flags->number("--lanes", 4, 1, spectral::kMaxLanes);
  const auto samples = flags->number("--samples", 2000000, 1000, 1e9);
  const auto repeats = flags->number("--repeats", 5, 1, 100);
  const auto pixel_samples = flags->number("--pixel-samples", 1024, 1, 1e9);
  for (const auto* s : {&bins, &lanes, &samples, &repeats, &pixel_samples}) {
    if (!s->ok()) {
      std::fprintf(stderr, "%s\n", std::string(s->status().message()).c_str());
      return 2;
    }
  }
  const auto library = spectral::SpectrumLibrary::load_builtin();
  if (!library.ok()) return 1;
  std::vector<spectral::Spectrum> spectra;
  const std::string lamps = flags->get("--lamps", "stdillum-F11,lamp-lps,stdillum-A");
  for (const std::string& name : std::vector<std::string>(absl::StrSplit(lamps, ','))) {
    const spectral::Spectrum* s = library->find_spectrum(name);
    if (s == nullptr) {
      std::fprintf(stderr, "unknown spectrum '%s'\n", name.c_str());
      return 2;
    }
    spectra.push_back(*s);
  }
  const auto emitters = spectral::WavelengthDistribution::emitters(spectra, 470);
  if (!emitters.ok()) return 1;
  const spectral::WavelengthDistribution job_default = *emitters->mix_defensive(0.05, *emitters);
  const int b_count = int(*bins), c = int(*lanes);
  const spectral::BinnedShape shape = *spectral::BinnedShape::create(job_default, b_count);

  // One random table per pixel of a 32x32 tile, every bin with default mass kept positive.
  constexpr int kPixels = 32 * 32;
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::string bytes;
  std::vector<double> weights(static_cast<std::size_t>(b_count));
  for (int p = 0; p < kPixels; ++p) {
    for (int b = 0; b < b_count; ++b) {
      weights[b] = shape.bin_mass(b) > 0 ? shape.bin_mass(b) * (0.05 + u(rng) * u(rng)) : 0.0;
    }
    spectral::append_pixel_table(spectral::WavelengthDistribution::from_table(weights)->quantise(),
                                 bytes);
  }
  const spectral::PixelTables tables = *spectral::PixelTables::decode(32, 32, b_count, bytes);

  const std::uint64_t n = std::uint64_t(*samples);
  std::vector<double> us(4096);
  for (double& x : us) x = u(rng);
  // As the tile renderer does: one view per pixel, then its samples.
  const std::uint64_t per_pixel = std::uint64_t(*pixel_samples);
  auto time = [&](auto&& view_of) {
    double best = 1e30, sink = 0;
    for (int r = 0; r < int(*repeats); ++r) {
      const auto start = std::chrono::steady_clock::now();
      for (std::uint64_t i0 = 0; i0 < n; i0 += per_pixel) {
        const spectral::WavelengthPdfView view = view_of(int(i0 / per_pixel % kPixels));
        for (std::uint64_t i = i0; i < std::min(n, i0 + per_pixel); ++i) {
          const spectral::SampledWavelengths w = view.sample_lanes(us[i % us.size()], c);
          sink += w.pdf(c - 1);
        }
      }
      const double s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      best = std::min(best, s);
    }
    if (sink == 0) std::printf(" ");
    return best * 1e9 / double(n) / c;
  };
  const double with_default = time([&](int) { return spectral::WavelengthPdfView(job_default); });
  const double with_table =
      time([&](int p) { return tables.view(p % 32, p / 32, job_default, shape); });
  spectral::CompositeCdf composite;
  const double with_composite = time([&](int p) {
    composite.assign(shape, *tables.table(p % 32, p / 32));
    return spectral::WavelengthPdfView(composite);
  });
  std::printf(
      "| lamps | bins | lanes | samples per pixel | default ns/lane | two-step table ns/lane | "
      "ratio | composite table ns/lane (build included) | ratio |\n"
      "|---|---|---|---|---|---|---|---|---|\n"
      "| %s | %d | %d | %llu | %.2f | %.2f | %.2f | %.2f | **%.2f** |\n",
      lamps.c_str(), b_count, c, static_cast<unsigned long long>(per_pixel), with_default,
      with_table, with_table / with_default, with_composite, with_composite / with_default);
  return 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
