// The coordinator's half of the multi-pass prepass (algorithms.md §4, multi-pass paper §4):
// after prepass k the coordinator holds the whole estimate image Ĩ^k and its guides, filters it
// with a joint bilateral filter (no apron needed: every neighbour is there), turns each pixel's
// filtered spectrum into a defensively mixed, quantised wavelength table, flags the pixels whose
// estimate matches the emitter mixture (the fallback), and ships each next-pass tile its
// tables (services/spectral/pixel_tables.h has the wire layout and the worker's decoder).
//
// Pipeline, per prepass k = 1..K (schedule from prepass_schedule):
//   render pass k (pass 1 with the job's default distribution, pass k > 1 with the tables of
//   pass k − 1; pixels flagged kMatchesDefault are skipped) → paste every merged tile's
//   finalised means into one SpectralImage and its guides into a GuideImage → filter_estimate →
//   build_tables → encode_tile for the next pass's (or the final pass's) tasks.
//
// Everything here is a pure function of its inputs: rows run in parallel but each output value
// is computed by one thread in a fixed order, so the bytes do not depend on the thread count.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/image/tile.h"
#include "services/spectral/wavelength_distribution.h"

namespace prism::coordinator {

// The job's prepass options (wire: PrepassOptions; CLI: --prepass-*).
struct PrepassParameters {
  int passes = 2;             // K, 1..kMaxPasses
  std::uint32_t spp = 128;    // Ñ, samples per pixel of the last prepass, >= 1
  bool image_scaled = false;  // earlier passes lower the resolution instead of the sample count
  double epsilon = 0.05;      // defensive mixture weight ε, in (0, 1)
  double fallback = 2e-4;     // fallback threshold h on the mean squared difference, >= 0
  double sigma_s = 1.75;      // spatial σ of the bilateral filter, pixels, > 0
  double sigma_r = 0.015;     // range σ on guide feature distances, > 0

  static constexpr int kMaxPasses = 8;

  // INVALID_ARGUMENT naming the first bad field (and its allowed range) when a value is out of
  // range or not finite.
  absl::Status validate() const;
};

// One prepass as the coordinator runs it.
struct PrepassPass {
  int index = 0;           // k, 1..K
  std::uint32_t spp = 0;   // samples per pixel of this pass
  double scale = 1.0;      // linear image scale α_s^k (1 unless image-scaled)
  int width = 0;           // film resolution of this pass: ⌈scale · job width⌉, >= 1
  int height = 0;
};

// The K passes in order. Sample-scaled (the default, §4): pass k renders Ñ/4^(K−k) spp at full
// resolution (Ñ = 128, K = 2: 32 then 128), at least 1. Image-scaled (the paper's "image
// scaled" configuration, which quarters the number of pixels in each earlier pass): pass k
// renders Ñ spp on a film of linear scale α = 2^−(K−k), i.e. ⌈W·α⌉ × ⌈H·α⌉ pixels of the same
// camera, so the last prepass is always at full resolution and the final pass's tables need no
// resampling. The tables an earlier, smaller pass produces for the next, larger one are carried
// over by upsample_tables (nearest pixel centre; the paper's joint bilateral upsampling would
// need the larger pass's guides before it is rendered). The worker must be able to render the
// job's camera at a scaled resolution for image-scaled passes. INVALID_ARGUMENT for invalid
// parameters or a width or height < 1.
absl::StatusOr<std::vector<PrepassPass>> prepass_schedule(const PrepassParameters& params,
                                                          int width, int height);

// A pixel's guide features (from one primary ray per sample, averaged): depth normalised to
// [0, 1], shading normal, albedo (luminance of the reflectance).
struct GuideFeatures {
  float depth = 0.0f;
  float nx = 0.0f, ny = 0.0f, nz = 0.0f;
  float albedo = 0.0f;
};

// The guide image of a prepass: per pixel the mean guide features and whether the pixel has an
// estimate at all (samples were taken). Pixels start invalid.
class GuideImage {
 public:
  // INVALID_ARGUMENT unless 1 <= width, height <= image::kMaxImageSide.
  static absl::StatusOr<GuideImage> create(int width, int height);

  // Stores the mean guides (sums / counts) of every pixel of a merged tile with samples; pixels
  // with no samples stay invalid. INVALID_ARGUMENT (nothing written) when the tile carries no
  // guides or its rect is not inside the image.
  absl::Status add_tile(const image::TileResult& merged);
  // Sets one pixel (in range, PRISM_CHECK) and marks it valid.
  void set(int x, int y, const GuideFeatures& features);

  int width() const { return width_; }
  int height() const { return height_; }
  const GuideFeatures& at(int x, int y) const { return features_[index(x, y)]; }
  bool valid(int x, int y) const { return valid_[index(x, y)] != 0; }

 private:
  GuideImage(int width, int height);
  std::size_t index(int x, int y) const;

  int width_;
  int height_;
  std::vector<GuideFeatures> features_;
  std::vector<std::uint8_t> valid_;
};

// Where a pixel's table came from.
enum class PixelSource : std::uint8_t {
  kLearned,         // its filtered estimate, mixed defensively
  kNoEstimate,      // its filtered estimate was zero or not finite: the emitter mixture (×
                    // sensor), mixed defensively, as a table; later prepasses still render it
  kMatchesDefault,  // the fallback test held (now or in an earlier pass): no table, the job's
                    // default distribution, and later prepasses skip it
};

// The per-pixel tables of a whole image: a quantised CDF (cells + 1 values, as
// QuantisedWavelengthCdf) per pixel, all zeros for kMatchesDefault pixels.
class PixelTableImage {
 public:
  int width() const { return width_; }
  int height() const { return height_; }
  int cells() const { return cells_; }
  // In range (PRISM_CHECK).
  std::span<const std::uint16_t> cdf(int x, int y) const;
  PixelSource source(int x, int y) const { return sources_[index(x, y)]; }

  std::int64_t count(PixelSource source) const;
  // Pixels that use the job's default distribution (kMatchesDefault) over all pixels: the
  // report's "fraction of fallback pixels".
  double fallback_fraction() const;

  // The tables of `rect` in the PdfTable wire layout (pixel_tables.h): kMatchesDefault pixels
  // as all-zero rows. INVALID_ARGUMENT when the rect is empty or not inside the image.
  absl::StatusOr<std::string> encode_tile(const image::TileRect& rect) const;

 private:
  friend absl::StatusOr<PixelTableImage> build_tables(const image::SpectralImage&,
                                                      const PrepassParameters&,
                                                      const spectral::WavelengthDistribution&,
                                                      const spectral::WavelengthDistribution*,
                                                      const PixelTableImage*);
  friend absl::StatusOr<PixelTableImage> upsample_tables(const PixelTableImage&, int, int);
  PixelTableImage(int width, int height, int cells);
  std::size_t index(int x, int y) const;

  int width_;
  int height_;
  int cells_;
  std::vector<std::uint16_t> cdf_;  // per pixel cells + 1 values
  std::vector<PixelSource> sources_;
};

// Joint bilateral filter of the prepass estimate (multi-pass Eq. 9): output pixel j is
// Σ_k G_s(‖k − j‖) G_r(‖f_k − f_j‖) Ĩ_k / Σ_k G_s G_r over the (2R+1)² window, R = ⌈3σ_s⌉,
// G(d) = exp(−d²/2σ²), f = (depth, nx, ny, nz, albedo) the guide features. Only neighbours
// inside the image that are valid count (the guide is valid, every bin is finite, and the pixel
// is not kMatchesDefault in `previous`, whose pixels later prepasses skip): borders and holes are
// handled by normalising over the neighbours that count. An invalid pixel's output is all zero.
// Sums are in double in a fixed neighbour order; rows run in parallel. Values are not clamped
// here (build_tables clamps). INVALID_ARGUMENT when the sizes of estimate, guides and previous
// differ or the sigmas are not positive and finite.
absl::StatusOr<image::SpectralImage> filter_estimate(const image::SpectralImage& estimate,
                                                     const GuideImage& guides, double sigma_s,
                                                     double sigma_r,
                                                     const PixelTableImage* previous = nullptr);

// Per-pixel tables from the filtered estimate (cells = filtered.bins()), per pixel:
//  - kMatchesDefault in `previous` stays kMatchesDefault;
//  - x = max(0, r_filt); if Σx is 0 or not finite the pixel is kNoEstimate and x = E;
//  - otherwise the fallback test: x/mean(x) and E/mean(E) (unit mean over the bins); if their
//    mean squared difference is <= params.fallback the pixel is kMatchesDefault;
//  - otherwise kLearned. The table of a kLearned or kNoEstimate pixel is
//    r_def = ε·p_ε + (1 − ε)·(s·x)/Σ(s·x), p_ε uniform over the bins where E > 0, s the sensor
//    term (1 when `sensor` is null), quantised as WavelengthDistribution::quantise does: every
//    bin with E > 0 keeps a quantised mass of at least ⌊65535·ε/|supp E|⌋ − 1 units (> 0), and
//    every bin with positive mass in r_def at least 1 unit.
// The test uses the filtered estimate, not the raw one: it decides between the table we would
// ship and the default, and the raw estimate's per-bin sampling noise alone (relative variance
// ≈ bins/(lanes·spp), 0.5 for 64 bins at 32 spp × 4 lanes) is thousands of times h, so it
// could never fire; the filter averages over the pixel's similar neighbours first. The sensor
// term multiplies the table like p_s·p_e of §1, then the mixture is taken last, as for the
// job's default distribution, so the defensive floor holds on the shipped table itself.
// `emitters` is the emitter mixture (WavelengthDistribution::emitters(spectra, bins)).
// INVALID_ARGUMENT when params are invalid, emitters or sensor do not have filtered.bins()
// cells, the emitter mixture has no support, or previous's size or cells differ.
absl::StatusOr<PixelTableImage> build_tables(const image::SpectralImage& filtered,
                                             const PrepassParameters& params,
                                             const spectral::WavelengthDistribution& emitters,
                                             const spectral::WavelengthDistribution* sensor,
                                             const PixelTableImage* previous = nullptr);

// The tables of a smaller image-scaled pass carried to a width × height film: each pixel takes
// the table and source of the pixel whose area holds its centre, (⌊(x + ½)·w/W⌋, ⌊(y + ½)·h/H⌋).
// INVALID_ARGUMENT unless width, height are in 1..kMaxImageSide.
absl::StatusOr<PixelTableImage> upsample_tables(const PixelTableImage& tables, int width,
                                                int height);

}  // namespace prism::coordinator
