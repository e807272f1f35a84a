// Gathering (spectral ray differentials paper §6.2, docs/estimators.md §6): the coordinator-side
// filter of an eye-traced job's image along each pixel's mean spectral offset.
//
// Eye paths record, per pixel, the offsets on the film (pixels per nm) of the caustic events they
// found, weighted by what each added (TileBuffers::offsets). At pixel x with mean offset m and
// Δλ the job's width at its last sample, the filter assumes L(x, λ) ≈ L(x + t·m·Δλ, λ + t·Δλ)
// for t ∈ [−1, 1] (the caustic keeps its radiance along its own dispersion curve) and averages
// L over K taps on that segment, K = ⌈4·|m|·Δλ⌉ + 1 (at most 129), each tap in the bin of its
// own wavelength, with bilateral weights from the guides (relative depth within about 2 %,
// normals within about 10°). Two things make it fall back to the unbiased value:
//  - disagreement: the coherence |m|² / E|d|² of the pixel's offsets (1 when they all agree, low
//    where caustics cross) below 0.9 blends towards the unbiased value, fully at 0.5 or less;
//  - the caustic's share: only the part of the pixel's energy that came with offsets (Σw over
//    the pixel's total) is filtered.
// Each output pixel is a function of the inputs alone (rows in parallel): deterministic.
#pragma once

#include <span>
#include <vector>

#include "absl/status/statusor.h"
#include "services/image/tile.h"

namespace prism::coordinator {

// Full-image inputs, row-major: the bin means, the per-pixel sample counts, the offset sums
// (kOffsetValues per pixel, the TileResult layout) and the guides' sums (depth, normal x, y, z;
// divided by the count here).
struct GatherInputs {
  const image::SpectralImage* image = nullptr;
  std::span<const std::uint64_t> counts;
  std::span<const double> offsets;
  std::span<const float> depth;
  std::span<const float> normals;
};

struct GatherStats {
  std::uint64_t pixels_with_offsets = 0;
  std::uint64_t pixels_filtered = 0;    // blended in at all
  std::uint64_t pixels_incoherent = 0;  // offsets disagreed: left unfiltered
};

// INVALID_ARGUMENT when the spans do not match the image's size or width_nm is not positive.
absl::StatusOr<image::SpectralImage> gather_filter(const GatherInputs& inputs, double width_nm,
                                                   GatherStats* stats = nullptr);

// Gathering's full-image inputs besides the image, assembled from finished tiles in any order
// (each tile writes its own pixels).
class GatherImages {
 public:
  GatherImages(int width, int height);
  // Copies the tile's counts, offsets and guides; INTERNAL when it has no offsets or guides.
  absl::Status add_tile(const image::TileResult& merged);
  GatherInputs inputs(const image::SpectralImage& image) const {
    return {&image, counts_, offsets_, depth_, normals_};
  }

 private:
  int width_;
  std::vector<std::uint64_t> counts_;
  std::vector<double> offsets_;
  std::vector<float> depth_, normals_;
};

// Δλ at the end of a job of `spp` samples: width·spp^(−1/5).
double gather_width_at(float width_nm, std::uint64_t spp);

}  // namespace prism::coordinator
