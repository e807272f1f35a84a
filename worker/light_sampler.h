// Emitter selection for next-event estimation (docs/estimators.md §3). An "emitter" is one light
// object (an area light over a whole shape, a point, a spot, the environment). The pmf of
// choosing emitter e at a shading point x for the path's live lanes is
//
//   q(e | x, λ) ∝ q_base(e | x) · Σ_{live lanes s} Ê[e][bin(λ_s)]     (spectral factor on)
//   q(e | x, λ) ∝ q_base(e | x)                                       (spectral factor off)
//
// where Ê[e][b] is e's spectrum integrated over bin b and normalised to Σ_b Ê[e][b] = 1 ("unit
// emission"), and q_base is uniform, proportional to power, or `spatial`: a voxel grid over the
// scene bounds whose cells store each emitter's estimated unoccluded contribution at the cell
// (built in a short deterministic preprocess: up to 8³ cells, probed at each cell's corners and
// centre with a fixed point set; 10 % of every cell's pmf is spread uniformly over the emitters
// with positive power, so q_base(e) > 0 for every emitting e everywhere and NEE stays unbiased
// where a probe saw nothing). The pmf is symmetric in the lane set, so the
// hero MIS stays consistent, and the same q is evaluated when a BSDF-sampled ray hits an
// emitter. Sampling is O(C · log E) with a prefix table per (cell, bin).
#pragma once

#include <vector>

#include "absl/status/statusor.h"
#include "services/job/render_options.h"
#include "services/spectral/sampled.h"
#include "services/spectral/wavelength_grid.h"
#include "worker/light.h"

namespace prism::worker {

struct LightChoice {
  int light = -1;  // index into the light list
  float pmf = 0;   // q(e | x, λ)
};

// The bins of the spectral factor's table Ê[e][b] in a render: fixed, not the job's bins, so
// which emitter a path picks, and with it every sample's value at its own wavelengths (the RGB
// outputs), does not depend on --bins.
inline constexpr int kLightSelectionBins = 64;

class LightSampler {
 public:
  // `lights` must outlive the sampler. The spatial grid (kSpatial) is estimated here from the
  // geometry's bounds with a fixed, seedless point set, so it is identical on every worker.
  static absl::StatusOr<LightSampler> create(const std::vector<Light>& lights,
                                             const Geometry& geometry,
                                             const spectral::WavelengthGrid& grid,
                                             job::LightSelectionKind base, bool spectral_factor);

  // Picks an emitter for shading point p; nullopt when the scene has no lights or every pmf is
  // zero for these lanes.
  std::optional<LightChoice> sample(const Vec3f& p, const SampledWavelengths& lambda,
                                    float u) const;
  // q(e | p, λ) for a given emitter (the pmf sample() would have used).
  float pmf(const Vec3f& p, const SampledWavelengths& lambda, int light) const;

  // Ê[e][b] (rows sum to 1), exposed for tests and for the prepass defensive support.
  const std::vector<std::vector<float>>& unit_emission() const { return unit_emission_; }

 private:
  int cell_of(const Vec3f& p) const;

  const std::vector<Light>* lights_ = nullptr;
  spectral::WavelengthGrid grid_;
  job::LightSelectionKind base_ = job::LightSelectionKind::kPower;
  bool spectral_factor_ = true;
  std::vector<std::vector<float>> unit_emission_;  // [light][bin]
  // Per cell (one cell unless spatial): q_base per light, and per bin the prefix sums of
  // q_base(e)·Ê[e][b] over e (size lights + 1).
  struct Cell {
    std::vector<float> base;
    std::vector<std::vector<double>> prefix;  // [bin][light + 1]
    std::vector<double> base_prefix;          // [light + 1], spectral factor off
  };
  std::vector<Cell> cells_;
  Bounds3f bounds_;
  int resolution_ = 1;  // cells per axis
};

}  // namespace prism::worker
