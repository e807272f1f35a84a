// The wavelength density p(λ) used to draw path wavelengths (docs/estimators.md §1–2, §4):
// piecewise constant on N uniform cells over Λ = [360, 830] nm. Cell i covers [360 + i·w, 360 +
// (i+1)·w), w = 470/N nm (λ = 830 belongs to the last cell), and has probability mass m_i (Σ m_i =
// 1) and density m_i / w per nm.
//
// Invariants: sample() returns exactly pdf(λ) for the λ it returns (same stored table, same cell
// lookup), never returns a λ in a zero-mass cell, and inverts the cdf continuously inside a cell.
// Construction allocates; sampling and evaluation do not.
//
// QuantisedWavelengthCdf is the compact form shipped per pixel to workers: N + 1 16-bit CDF
// values with q_0 = 0, q_N = 65535, cell mass (q_{i+1} − q_i)/65535. It samples and evaluates
// from those integers alone, so a coordinator and a worker holding the same bytes agree exactly.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "absl/functional/function_ref.h"
#include "absl/status/statusor.h"
#include "services/spectral/sampled.h"
#include "services/spectral/spectrum.h"

namespace prism::spectral {

// The uniform cells every distribution here uses: cell c of n covers [360 + c·470/n,
// 360 + (c+1)·470/n) nm (λ = 830 belongs to the last). cell_lower is that lower edge in double;
// uniform_cell_of the cell holding lambda_nm, or -1 outside Λ (the one lookup that sampling and
// evaluation share, so they agree exactly).
double uniform_cell_lower(int c, int n);
int uniform_cell_of(float lambda_nm, int n);
// The first and last float that `index` maps to each of n uniform cells, for a lookup `index`
// that is non-decreasing in λ, maps Λ onto 0..n−1 and differs from uniform_cell_of at most by
// rounding near the edges (so that each edge's float neighbourhood holds the change of cell).
// Sampling settles a λ into its cell with one clamp to these.
void uniform_cell_floats(int n, absl::FunctionRef<int(float)> index, std::vector<float>& first,
                         std::vector<float>& last);

struct WavelengthSample {
  float lambda = 0.0f;  // nm
  float pdf = 0.0f;     // per nm
};

class WavelengthDistribution {
 public:
  static constexpr int kMaxCells = 16384;
  static constexpr int kDefaultCells = 470;  // 1 nm cells
  static constexpr double kDefaultDefensiveEpsilon = 0.05;

  // Uniform over Λ.
  static absl::StatusOr<WavelengthDistribution> flat(int cells = kDefaultCells);
  // pbrt-v4's visible-wavelength density p(λ) ∝ 1/cosh²(0.0072·(λ − 538)), discretised by the
  // exact integral over each cell (∫ sech²(a(λ−c)) dλ = tanh(a(λ−c))/a).
  static absl::StatusOr<WavelengthDistribution> visible(int cells = kDefaultCells);
  // p_e ∝ Σ_j S_j / ∫_Λ S_j (each emitter normalised to unit integral, multi-pass Eq. 7), cell
  // masses from exact (or quadrature) integrals of each spectrum over the cell. INVALID_ARGUMENT
  // if the list is empty, or an emitter's integral over some cell is negative or not finite, or
  // it has no power in Λ.
  static absl::StatusOr<WavelengthDistribution> emitters(std::span<const Spectrum> spectra,
                                                         int cells = kDefaultCells);
  // Cell masses proportional to `weights` (one per cell). INVALID_ARGUMENT for a cell count
  // outside 1..kMaxCells, a negative or non-finite weight, or all weights zero.
  static absl::StatusOr<WavelengthDistribution> from_table(std::span<const double> weights);
  // p ∝ a·b (sensor × emitter term, §1). INVALID_ARGUMENT if the cell counts differ or the
  // product is zero everywhere.
  static absl::StatusOr<WavelengthDistribution> product(const WavelengthDistribution& a,
                                                        const WavelengthDistribution& b);

  // ε·p_ε + (1 − ε)·p, p_ε uniform over the cells where support has positive mass (pass the
  // emitter distribution: its support is where any emitter emits). INVALID_ARGUMENT unless
  // 0 <= ε <= 1, the cell counts match and the support is not empty.
  absl::StatusOr<WavelengthDistribution> mix_defensive(double epsilon,
                                                       const WavelengthDistribution& support) const;

  // Inverse-cdf sample for u in [0, 1) (values outside are clamped into it).
  WavelengthSample sample(double u) const;
  // Density per nm at lambda_nm; 0 outside Λ.
  float pdf(float lambda_nm) const;
  // P(Λ' <= λ), continuous and piecewise linear, 0 below Λ and 1 above.
  double cdf(float lambda_nm) const;
  // CMIS lane rotation (docs/estimators.md §2): lane s gets λ_s = P⁻¹((u + s/C) mod 1) and
  // pdf p(λ_s); lane 0 is the hero. lanes in 1..kMaxLanes.
  SampledWavelengths sample_lanes(double u, int lanes) const;

  int cells() const { return static_cast<int>(mass_.size()); }
  double cell_width() const;  // nm
  double cell_mass(int i) const { return mass_[i]; }
  // P(Λ' < lower edge of cell i), i in 0..cells(); cell_cdf(cells()) == 1 exactly.
  double cell_cdf(int i) const { return cdf_[i]; }
  float cell_pdf(int i) const { return pdf_[i]; }
  // The cell holding lambda_nm, or -1 outside Λ.
  int cell_of(float lambda_nm) const;
  // sample()'s search guide (2^m + 1 cells, see guide_ below): for j/2^m <= u < (j+1)/2^m the
  // last cell c with cell_cdf(c) <= u lies in [guide[j], guide[j + 1]].
  std::span<const int> search_guide() const { return guide_; }

  // The quantised CDF (cells() + 1 values) whose every positive-mass cell keeps a mass of at
  // least 1/65535, so quantisation never removes support; cells() must be <= kMaxCells.
  std::vector<std::uint16_t> quantise() const;

  // Reusable buffers for quantise_weights; they grow to the largest cell count seen, so a
  // caller quantising many tables of one size allocates only on the first.
  struct QuantiseScratch {
    std::vector<double> cdf, mass, remainder;
    std::vector<std::int64_t> units;
    std::vector<int> order;
  };
  // Writes from_table(weights)->quantise() into cdf_out (weights.size() + 1 values) with the
  // same bytes, without building the distribution: for per-pixel tables in bulk. The caller
  // guarantees what from_table checks (1..kMaxCells finite weights >= 0 with a positive finite
  // sum; PRISM_CHECK) and cdf_out.size() == weights.size() + 1.
  static void quantise_weights(std::span<const double> weights, std::span<std::uint16_t> cdf_out,
                               QuantiseScratch& scratch);

 private:
  explicit WavelengthDistribution(std::vector<double> masses);
  // Largest-remainder quantisation of masses summing to 1 into cdf (masses.size() + 1 values).
  static void quantise_masses(std::span<const double> mass, std::span<std::uint16_t> cdf,
                              QuantiseScratch& scratch);
  std::vector<double> mass_;
  std::vector<double> cdf_;  // cells() + 1 values, cdf_[0] = 0, cdf_.back() = 1 exactly
  std::vector<float> pdf_;   // mass_ / w
  // Where sample()'s search starts: 2^m + 1 cells, the first 2^m >= 4·cells() (wavelength_
  // distribution.cpp, guide_cells).
  std::vector<int> guide_;
  // Per cell: its lower edge in nm, and the first and last float cell_of maps to it, so that
  // sample() settles λ into its cell with one clamp.
  std::vector<double> lower_;
  std::vector<float> first_, last_;
};

// A non-owning view of a quantised CDF (see the header comment). Cheap to copy; the bytes must
// outlive it.
class QuantisedWavelengthCdf {
 public:
  static constexpr std::uint16_t kTotal = 65535;
  // INVALID_ARGUMENT unless there are 2..kMaxCells+1 values, non-decreasing, from 0 to 65535.
  static absl::StatusOr<QuantisedWavelengthCdf> create(std::span<const std::uint16_t> cdf);

  WavelengthSample sample(double u) const;
  float pdf(float lambda_nm) const;
  double cdf(float lambda_nm) const;
  SampledWavelengths sample_lanes(double u, int lanes) const;
  int cells() const { return static_cast<int>(cdf_.size()) - 1; }
  float cell_pdf(int i) const;
  // The cells() + 1 quantised CDF values, q_0 = 0 to q_N = kTotal.
  std::span<const std::uint16_t> values() const { return cdf_; }

 private:
  explicit QuantisedWavelengthCdf(std::span<const std::uint16_t> cdf) : cdf_(cdf) {}
  std::span<const std::uint16_t> cdf_;
};

}  // namespace prism::spectral
