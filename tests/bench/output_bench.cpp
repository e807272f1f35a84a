// prism-bench-output: how long a render's outputs take to write, per EXR compression and thread
// count, against writing the same bytes raw. The input is a real render (`--input`, a spectral
// EXR such as `prism render ... -o big.exr` writes: noise compresses as a render's noise does);
// without one, a synthetic image of smooth spectra plus hashed noise at --resolution and --bins.
//
// For each compression (image::ExrCompression) and each thread count it writes the spectral EXR
// (bins + R, G, B, float32) as `prism render` does, atomically (temporary file, fsync, rename),
// into --dir, and prints the best of --repeats wall times, the file size relative to the raw
// float32 bytes, and the time relative to the baseline: write_file_atomic of the raw bytes
// (one buffer, fsync, rename) in the same run. The PNG preview and RGB EXR are timed once each.
// A ratio near 1 means the compression costs no more than the disk; the render's own time is
// what the acceptance compares against (docs/benchmarks.md).
//
// Usage: prism-bench-output [--input render.exr] [--resolution 2048x2048] [--bins 64]
//          [--threads 1,2] [--compressions none,rle,zips,zip,piz] [--repeats 2] [--dir /tmp]
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <span>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "services/base/atomic_file.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/image/png.h"
#include "tests/bench/bench_common.h"

namespace prism::bench {
namespace {

using Clock = std::chrono::steady_clock;

// Smooth spectra that vary across the image, times 1 ± 50 % noise per value (one sample per
// pixel is that noisy).
absl::StatusOr<image::SpectralExr> synthetic(int width, int height, int bins) {
  PRISM_ASSIGN_OR_RETURN(image::SpectralImage spectral,
                         image::SpectralImage::create(width, height, bins));
  PRISM_ASSIGN_OR_RETURN(image::RgbImage rgb, image::RgbImage::create(width, height));
  std::span<float> values = spectral.data();
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const std::size_t pixel = std::size_t(y) * width + x;
      for (int b = 0; b < bins; ++b) {
        const double phase = 6.0 * b / bins + 4.0 * x / width + 3.0 * y / height;
        const std::size_t i = pixel * bins + b;
        values[i] = static_cast<float>((1.0 + std::sin(phase)) * (0.5 + hashed_unit(i)));
      }
      for (int c = 0; c < 3; ++c) rgb.data()[pixel * 3 + c] = values[pixel * bins + c];
    }
  }
  return image::SpectralExr{image::bin_centres_nm(bins), std::move(spectral), std::move(rgb), {}};
}

int run(int argc, char** argv) {
  auto flags = parse_flags(
      argc, argv,
      {"--input", "--resolution", "--bins", "--threads", "--compressions", "--repeats", "--dir"});
  if (!flags.ok()) {
    std::cerr << "prism-bench-output: " << flags.status().message() << "\n";
    return 1;
  }
  auto repeats = flags->number("--repeats", 2, 1, 100);
  if (!repeats.ok()) {
    std::cerr << "prism-bench-output: " << repeats.status().message() << "\n";
    return 1;
  }
  std::vector<int> thread_counts;
  for (absl::string_view t : absl::StrSplit(flags->get("--threads", "1,2"), ',')) {
    int n = 0;
    if (!absl::SimpleAtoi(t, &n) || n < 1 || n > 256) {
      std::cerr << "prism-bench-output: --threads wants counts in 1..256, got '" << std::string(t)
                << "'\n";
      return 1;
    }
    thread_counts.push_back(n);
  }
  std::vector<image::ExrCompression> compressions;
  for (absl::string_view c :
       absl::StrSplit(flags->get("--compressions", "none,rle,zips,zip,piz"), ',')) {
    std::optional<image::ExrCompression> parsed =
        image::parse_exr_compression(std::string_view(c.data(), c.size()));
    if (!parsed.has_value()) {
      std::cerr << "prism-bench-output: unknown compression '" << std::string(c) << "'\n";
      return 1;
    }
    compressions.push_back(*parsed);
  }

  absl::StatusOr<image::SpectralExr> input;
  std::string source;
  if (flags->values.count("--input") != 0) {
    source = flags->get("--input", "");
    input = image::read_spectral_exr(source);
  } else {
    auto size = parse_size(flags->get("--resolution", "2048x2048"));
    auto bins = flags->number("--bins", 64, 1, 256);
    if (!size.ok() || !bins.ok()) {
      std::cerr << "prism-bench-output: " << (!size.ok() ? size.status() : bins.status()).message()
                << "\n";
      return 1;
    }
    source = "synthetic";
    input = synthetic(size->first, size->second, static_cast<int>(*bins));
  }
  if (!input.ok() || !input->rgb.has_value()) {
    std::cerr << "prism-bench-output: "
              << (input.ok() ? "the input has no R, G, B channels" : input.status().ToString())
              << "\n";
    return 1;
  }
  const image::SpectralImage& spectral = input->spectral;
  const image::RgbImage& rgb = *input->rgb;
  const std::filesystem::path dir = flags->get("--dir", "/tmp");
  const std::filesystem::path exr = dir / absl::StrFormat("prism-bench-output-%d.exr", getpid());

  // Raw: the same float32 values (bins + RGB), one buffer.
  std::vector<char> raw(spectral.data().size_bytes() + rgb.data().size_bytes());
  std::memcpy(raw.data(), spectral.data().data(), spectral.data().size_bytes());
  std::memcpy(raw.data() + spectral.data().size_bytes(), rgb.data().data(),
              rgb.data().size_bytes());
  const double raw_mib = static_cast<double>(raw.size()) / (1 << 20);
  bool failed = false;
  auto check = [&](const absl::Status& status) {
    if (!status.ok() && !failed) {
      std::cerr << "prism-bench-output: " << status << "\n";
      failed = true;
    }
  };
  const double raw_seconds = best_seconds(static_cast<int>(*repeats), [&] {
    check(base::write_file_atomic(exr, std::span<const char>(raw)));
  });
  std::printf("input: %s, %dx%d, %d bins; raw float32 %.0f MiB; best of %d; dir %s\n",
              source.c_str(), spectral.width(), spectral.height(), spectral.bins(), raw_mib,
              static_cast<int>(*repeats), dir.c_str());
  std::printf("raw write (write_file_atomic): %.2f s (%.0f MiB/s)\n\n", raw_seconds,
              raw_mib / raw_seconds);
  std::printf(
      "| compression | threads | seconds | MiB/s of raw | size / raw | time / raw write |\n");
  std::printf("|---|---|---|---|---|---|\n");
  for (image::ExrCompression compression : compressions) {
    for (int threads : thread_counts) {
      const image::ExrWriteOptions options{compression, threads};
      const double seconds = best_seconds(static_cast<int>(*repeats), [&] {
        check(image::write_spectral_exr(exr, input->wavelengths_nm, spectral, rgb, {}, options));
      });
      std::error_code ec;
      const double size = static_cast<double>(std::filesystem::file_size(exr, ec));
      std::printf("| %s | %d | %.2f | %.0f | %.3f | %.2f |\n",
                  std::string(image::name(compression)).c_str(), threads, seconds,
                  raw_mib / seconds, size / static_cast<double>(raw.size()), seconds / raw_seconds);
      std::fflush(stdout);
    }
  }
  const std::filesystem::path png = dir / absl::StrFormat("prism-bench-output-%d.png", getpid());
  const double png_seconds = best_seconds(static_cast<int>(*repeats),
                                          [&] { check(image::write_png_preview(png, rgb, 0.0f)); });
  const double rgb_seconds = best_seconds(static_cast<int>(*repeats), [&] {
    check(image::write_rgb_exr(exr, rgb, image::ExrPixelType::kFloat, {},
                               {image::kDefaultExrCompression, thread_counts.back()}));
  });
  std::printf("\nPNG preview: %.2f s; RGB EXR (%s, %d threads): %.2f s\n", png_seconds,
              std::string(image::name(image::kDefaultExrCompression)).c_str(), thread_counts.back(),
              rgb_seconds);
  std::filesystem::remove(exr);
  std::filesystem::remove(png);
  return failed ? 1 : 0;
}

}  // namespace
}  // namespace prism::bench

int main(int argc, char** argv) {
  return prism::bench::run(argc, argv);
}
