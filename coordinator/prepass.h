// The coordinator's half of the multi-pass prepass (docs/estimators.md §4, multi-pass paper §4,
// with the changes of issue 11): after prepass k the coordinator holds the whole image's per-pixel
// second moments and guides, filters them with a joint bilateral filter (no apron needed: every
// neighbour is there), and gives each pixel the table of bin masses that its predicted variance
// per sample says is best: a mixture α·learned + (1 − α)·default, α = 0 (the job's default
// distribution) unless a table is predicted to do better. Tables hold bin masses only; workers
// sample inside each bin with the default's shape (services/spectral/binned_shape.h), so an
// emitter's narrow lines keep their shape. Each next-pass tile is shipped its tables
// (services/spectral/pixel_tables.h has the wire layout and the worker's decoder).
//
// Why second moments: the error reported is the spectral MSE, Σ_b Var_b, and among densities
// with the default's shape inside each bin it is smallest for masses w'_b ∝ sqrt(K_b), K_b bin
// b's second moment scaled by the mass it was sampled with (VarianceModel has the exact form),
// not for masses proportional to the mean spectrum.
//
// Pipeline, per prepass k = 1..K (schedule from prepass_schedule):
//   render pass k with the job's default distribution (every pass: tables learned from samples
//   drawn with earlier tables had heavy-tailed moments, docs/benchmarks.md) → add every merged
//   tile's moments to a MomentImage and its guides to a GuideImage → build_tables (filter,
//   learn, validate, choose) → after the last pass, encode_tile for the final pass's tasks.
//
// Everything here is a pure function of its inputs: rows run in parallel but each output value
// is computed by one thread in a fixed order, so the bytes do not depend on the thread count.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/image/tile.h"
#include "services/job/job_parameters.h"
#include "services/spectral/wavelength_distribution.h"

namespace prism::coordinator {

// One prepass as the coordinator runs it.
struct PrepassPass {
  int index = 0;          // k, 1..K
  std::uint32_t spp = 0;  // samples per pixel of this pass
  double scale = 1.0;     // linear image scale α_s^k (1 unless image-scaled)
  int width = 0;          // film resolution of this pass: ⌈scale · job width⌉, >= 1
  int height = 0;
};

// The K passes in order. Sample-scaled (the default): pass k renders Ñ/8^(K−k) spp at full
// resolution (Ñ = 128, K = 2: 16 then 128), at least 1. The paper quarters the samples; an
// eighth keeps pass 1, which decides whether the prepass goes on at all (kMinImageGain), at about
// 1 % of a job's time, so a job that gains nothing loses little. Image-scaled (the paper's "image
// scaled" configuration, which quarters the number of pixels in each earlier pass): pass k
// renders Ñ spp on a film of linear scale α = 2^−(K−k), i.e. ⌈W·α⌉ × ⌈H·α⌉ pixels of the same
// camera, so the last prepass is always at full resolution and the final pass's tables need no
// resampling. The tables an earlier, smaller pass produces for the next, larger one are carried
// over by upsample_tables (nearest pixel centre; the paper's joint bilateral upsampling would
// need the larger pass's guides before it is rendered). The worker must be able to render the
// job's camera at a scaled resolution for image-scaled passes. INVALID_ARGUMENT for invalid
// parameters or a width or height < 1.
absl::StatusOr<std::vector<PrepassPass>> prepass_schedule(const job::PrepassParameters& params,
                                                          int width, int height);

// A pixel's guide features (from one primary ray per sample, averaged): depth normalised to
// [0, 1] by the far side of the scene's bounding sphere, shading normal, albedo (a diffuse
// surface's reflectance averaged over the lanes, 1 for every other material).
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
  kLearned,         // a learned table (α > 0) predicted to lower the pixel's variance
  kNoEstimate,      // no usable moments (no samples, or nothing but zeros): the job's default
                    // distribution, an all-zero row; later prepasses skip it
  kMatchesDefault,  // α = 0 was predicted best (now or in an earlier pass): the job's default
                    // distribution, an all-zero row; later prepasses skip it
};

// The mixture weights a pixel's table may take: q = α·learned + (1 − α)·default, α from
// {0, ¼, ½, ¾, 1 − ε}; index 0 (α = 0) is the default distribution itself.
inline constexpr int kAlphaChoices = 5;
double alpha_choice(int index, double epsilon);

// E[L(L−1)] for the lanes L that a sample of C lanes puts in a bin of mass m:
// ⌊Cm⌋·(⌊Cm⌋ − 1 + 2·frac(Cm)); 0 when Cm < 1.
double pairs_of_lanes(int lanes, double mass);

// How the final pass's error depends on a pixel's bin masses m, from its moments K_b and U_b
// (MomentImage, measured with the prepass's C_p lanes) for a final pass of C lanes. A lane's value
// in bin b is Y = f/(C·q); a sample puts L_b lanes in bin b, L_b ∈ {⌊C·m_b⌋, ⌈C·m_b⌉} (the CMIS
// rotation spaces its lanes 1/C apart in probability). Per sample, bin b's variance is
//   V_b(m) = (r·K_b − U_b/C) / m_b  +  h(C·m_b) · U_b / (C·m_b)²,      r = C_p / C,
// the spread of the lanes' values given that they hit the bin plus the spread of their count,
// h(x) = frac(x)·(1 − frac(x)). With at most one lane in the bin (m_b < 1/C) this is
// r·K_b/m_b − U_b, the per-sample variance E[X_b²] − μ_b². Stratified wavelengths (the Sobol
// sampler gives each bin its share of a pixel's lanes exactly over the pixel's samples) leave the
// count term out. Sensor weights s_b scale bin b's variance by s_b².
struct VarianceModel {
  int prepass_lanes = 4;  // C_p
  int final_lanes = 4;    // C
  bool stratified = false;

  // V_b for moments k = K_b, u = U_b and mass m > 0.
  double bin_variance(double k, double u, double m) const;
  // r·K_b − U_b/C: the part that 1/m_b scales.
  double divided(double k, double u) const;
};

// The learned shapes a table may take (masses over the bins with D_b > 0): kSecondMoment ∝
// sqrt(r·K_b), which minimises Σ_b r·K_b/m_b, the per-sample variance while each bin gets at most
// one lane; kWithinLane ∝ sqrt(max(0, r·K_b − U_b/C)), which minimises the first term alone, all
// there is when the wavelengths are stratified and the count of lanes in a bin is exact.
enum class TableShape : std::uint8_t { kSecondMoment = 0, kWithinLane = 1 };
inline constexpr int kTableShapes = 2;

// The per-pixel tables of a whole image: a quantised CDF of bin masses (cells + 1 values, as
// QuantisedWavelengthCdf) per pixel, all zeros for pixels on the default distribution, with what
// the choice predicted. A table's masses are sampled with the job's default shape inside each bin
// (services/spectral/binned_shape.h).
class PixelTableImage {
 public:
  int width() const { return width_; }
  int height() const { return height_; }
  int cells() const { return cells_; }
  // In range (PRISM_CHECK).
  std::span<const std::uint16_t> cdf(int x, int y) const;
  PixelSource source(int x, int y) const { return sources_[index(x, y)]; }
  // The index into alpha_choice of the pixel's mixture weight (0 for the default), and the
  // shape it mixes in.
  int alpha_index(int x, int y) const { return alpha_[index(x, y)]; }
  TableShape shape(int x, int y) const { return shape_[index(x, y)]; }
  // The predicted variance per sample of the pixel's spectrum (Σ over bins, sensor-weighted)
  // under the job's default distribution and under its table (equal when it has none): the
  // pixel's own unbiased estimates, so they are noisy and may be negative; 0 where nothing was
  // estimated.
  float predicted_default_variance(int x, int y) const { return variance_default_[index(x, y)]; }
  float predicted_variance(int x, int y) const { return variance_chosen_[index(x, y)]; }

  std::int64_t count(PixelSource source) const;
  // Pixels that use the job's default distribution (no table) over all pixels: the report's
  // "fraction of fallback pixels".
  double fallback_fraction() const;
  // Pixels per alpha_choice index, and the learned pixels per TableShape.
  std::array<std::int64_t, kAlphaChoices> alpha_histogram() const;
  std::array<std::int64_t, kTableShapes> shape_histogram() const;
  // 1 − Σ predicted variance / Σ predicted default variance over all pixels: the predicted
  // fraction of the image's variance per sample that the tables remove (0 when nothing was
  // estimated).
  double predicted_gain() const;
  // The same from the smoothed validations the choices were made with (each pixel's from its
  // neighbours'): a little optimistic (each pixel took its best), but far less noisy than the
  // pixels' own estimates, whose few large values dominate a small prepass. The prepass's
  // decisions to go on or keep its tables use this one.
  double decision_gain() const;
  // Every pixel back on the default distribution (the prepass predicted too little to go on).
  void reset_to_default();
  // A copy in which every pixel with a table has `cdf` (cells + 1 values) instead: later prepasses
  // sample the default's own bin masses where a table was learned (see PrepassRun).
  PixelTableImage with_tables(std::span<const std::uint16_t> cdf) const;

  // The tables of `rect` in the PdfTable wire layout (pixel_tables.h): pixels without a table
  // as all-zero rows. INVALID_ARGUMENT when the rect is empty or not inside the image.
  absl::StatusOr<std::string> encode_tile(const image::TileRect& rect) const;

 private:
  friend absl::StatusOr<PixelTableImage> build_tables(const image::SpectralImage&,
                                                      const GuideImage&,
                                                      const job::PrepassParameters&,
                                                      std::span<const double>,
                                                      std::span<const double>, const VarianceModel&,
                                                      const PixelTableImage*);
  friend absl::StatusOr<PixelTableImage> upsample_tables(const PixelTableImage&, int, int);
  PixelTableImage(int width, int height, int cells);
  std::size_t index(int x, int y) const;
  bool has_table(std::size_t i) const { return sources_[i] == PixelSource::kLearned; }

  int width_;
  int height_;
  int cells_;
  std::vector<std::uint16_t> cdf_;  // per pixel cells + 1 values
  std::vector<PixelSource> sources_;
  std::vector<std::uint8_t> alpha_;
  std::vector<TableShape> shape_;
  std::vector<float> variance_default_;
  std::vector<float> variance_chosen_;
  std::vector<float> judged_default_;  // the smoothed validations of the default and the choice
  std::vector<float> judged_chosen_;
};

// The per-pixel moments a prepass pass measured, as the tables need them: an image of 2·bins
// channels. Channel bins + b holds U_b, an unbiased estimate of μ_b² (μ̂_b² − (M_b − μ̂_b²)/(n − 1)
// from the pixel's mean μ̂_b and mean square M_b of bin b's per-sample values; 0 for n < 2).
// Channel b < bins holds K_b = w_b·M_b − pairs_of_lanes(C, w_b)·U_b/(C²·w_b), w_b the bin mass
// the pixel was sampled with: C·w_b²·E[Y²] for a lane's value Y in the bin, the products of two
// lanes in one bin taken out. K_b does not depend on the sampling masses when the shape inside
// each bin is the default's (binned_shape.h): E[Y²] = ∫_b f²/(C²q²)·q/w_b and q scales by w_b
// inside bin b, so passes sampled with different tables estimate the same K; nor does μ_b.
//
// MomentImage accumulates the passes at one resolution: each pixel's moments are the
// sample-count-weighted mean of every pass that sampled it.
class MomentImage {
 public:
  // INVALID_ARGUMENT for sizes out of range (SpectralImage's limits with 2·bins channels).
  static absl::StatusOr<MomentImage> create(int width, int height, int bins);

  // Adds the moments of a merged prepass tile. `sampled_with`: the tables the pass sampled with
  // (null for the job's default distribution everywhere), at this image's size; a pixel without
  // a table was sampled with `default_masses` (D_b, bins values); `lanes` the lanes C the pass
  // traced (kPrepassLanes, >= 1). Pixels without samples are
  // left as they are. INVALID_ARGUMENT when the tile is not inside the image or has other bins,
  // or the span has the wrong size.
  absl::Status add_tile(const image::TileResult& merged, const PixelTableImage* sampled_with,
                        std::span<const double> default_masses, int lanes);

  int width() const { return moments_.width(); }
  int height() const { return moments_.height(); }
  int bins() const { return moments_.bins() / 2; }
  // The 2·bins channel image described above (zero where nothing was sampled).
  const image::SpectralImage& moments() const { return moments_; }
  double samples(int x, int y) const {
    return samples_[std::size_t(y) * std::size_t(width()) + std::size_t(x)];
  }

 private:
  explicit MomentImage(image::SpectralImage moments);
  image::SpectralImage moments_;
  std::vector<double> samples_;
};

// Joint bilateral filter of the prepass estimate (multi-pass Eq. 9): output pixel j is
// Σ_k G_s(‖k − j‖) G_r(‖f_k − f_j‖) Ĩ_k / Σ_k G_s G_r over the (2R+1)² window, R = ⌈3σ_s⌉,
// G(d) = exp(−d²/2σ²), f = (depth, nx, ny, nz, albedo) the guide features. Only neighbours
// inside the image that are valid count (the guide is valid, every bin is finite, and the pixel
// is not kMatchesDefault in `previous`, whose pixels later prepasses skip): borders and holes are
// handled by normalising over the neighbours that count. An invalid pixel's output is all zero.
// Sums are of the neighbours' differences from the centre, in float in a fixed neighbour order
// (a constant image stays exactly constant); rows run in parallel. Values are not clamped
// here (build_tables clamps). With `leave_one_out`, it is also given the same filter without the
// centre pixel (Σ over the neighbours k ≠ j), all zero where no neighbour counts: an estimate
// independent of the pixel's own samples. INVALID_ARGUMENT when the sizes of estimate, guides and
// previous differ or the sigmas are not positive and finite.
absl::StatusOr<image::SpectralImage> filter_estimate(const image::SpectralImage& estimate,
                                                     const GuideImage& guides, double sigma_s,
                                                     double sigma_r,
                                                     const PixelTableImage* previous = nullptr,
                                                     image::SpectralImage* leave_one_out = nullptr);

// Per-pixel tables from a prepass's moments (a MomentImage's, 2·bins channels) and guides. Per
// pixel:
//  - kMatchesDefault or kNoEstimate in `previous` stays so (later prepasses skipped it);
//  - the learned shapes (TableShape) of the filtered moments (filter_estimate);
//  - candidates: the default D (α = 0) and, for each shape and each α > 0 of alpha_choice,
//    m = α·w + (1 − α)·D;
//  - validation: each candidate built from the shape learned without the pixel itself
//    (filter_estimate's leave_one_out) is judged by V(m) = Σ_b s_b²·V_b(m) (VarianceModel) from
//    the pixel's own moments: an unbiased estimate of that table's variance per sample (the
//    pixel's samples did not shape it; a table fitted to the same samples would always look best,
//    it chases their noise); the V of every candidate is then filtered like the moments but
//    without the pixel itself, so each pixel's choice rests on its similar neighbours'
//    validations and its own V stays an unbiased judge of that choice (in expectation only:
//    from a few samples per pixel the penalty of a starved bin shows only in the rare pixel
//    whose samples landed there, so the usual sum of these V over an image is optimistic,
//    docs/benchmarks.md "The prepass's first pass at small budgets");
//  - the pixel takes the candidate with the smallest filtered V and keeps the default
//    (kMatchesDefault, α = 0) unless V <= (1 − params.fallback)·V(D) and V(D) > 0; without usable
//    moments, or without neighbours, it is kNoEstimate or kMatchesDefault;
//  - a learned pixel's table is that candidate with the shape learned from every sample,
//    quantised as WavelengthDistribution::quantise does (every bin with D_b > 0 keeps at least
//    (1 − α)·D_b >= ε·D_b of mass before quantisation, and any positive mass at least one unit).
// predicted_default_variance and predicted_variance are the pixel's own V(D) and V of the choice.
// `default_masses` are D_b (BinnedShape::bin_masses of the job's default distribution),
// `sensor_weights` s_b (bins values, mean 1) or empty for a flat sensor. INVALID_ARGUMENT when
// params are invalid, the spans, guides or previous do not match the moments' size, or the
// default masses are negative, not finite or all zero.
absl::StatusOr<PixelTableImage> build_tables(const image::SpectralImage& moments,
                                             const GuideImage& guides,
                                             const job::PrepassParameters& params,
                                             std::span<const double> default_masses,
                                             std::span<const double> sensor_weights,
                                             const VarianceModel& model,
                                             const PixelTableImage* previous = nullptr);

// The tables of a smaller image-scaled pass carried to a width × height film: each pixel takes
// the table and source of the pixel whose area holds its centre, (⌊(x + ½)·w/W⌋, ⌊(y + ½)·h/H⌋).
// INVALID_ARGUMENT unless width, height are in 1..kMaxImageSide.
absl::StatusOr<PixelTableImage> upsample_tables(const PixelTableImage& tables, int width,
                                                int height);

}  // namespace prism::coordinator
