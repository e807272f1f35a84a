// The job's default wavelength distribution cut at the output bins, so that a per-pixel table of
// bin masses (the prepass's learned tables, docs/estimators.md §4) can be sampled with the
// default's own shape inside each bin:
//
//   q(λ) = m_b · d(λ) / D_b   for λ in bin b,
//
// m_b the table's mass of bin b, d the default density (1 nm cells, with an emitter's narrow
// lines), D_b = ∫_b d. A table thus only moves mass between bins and never smears a line over
// its bin. Where D_b = 0 (no default mass in the bin) q is uniform inside the bin.
//
// Bins here are the cells of a QuantisedWavelengthCdf with `bins` cells: bin b covers
// [360 + b·w, 360 + (b+1)·w), w = 470/bins nm (a float λ within an ulp of an edge may be counted
// on either side, the same way by sample, pdf and cdf).
//
// Invariants: sample() returns exactly pdf(λ) for the λ it returns (the bin and the default
// cell of λ are looked up by the same arithmetic in both), never returns a λ where the table or
// d is zero, and inverts the composite CDF continuously inside each (bin, cell) piece. A sample
// costs two short guided searches: the table's bin (from the pixel's guide, build_guide), then
// the default cell of the same fraction of the bin's default mass (from the default's own search
// guide, so it costs what a default sample's search does). CompositeCdf below samples the same
// density with one search, for a build per pixel.
// Construction allocates; sampling and evaluation do not. Coordinator and worker build it from
// the same default distribution and get the same D_b bit for bit.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "absl/status/statusor.h"
#include "services/spectral/sampled.h"
#include "services/spectral/wavelength_distribution.h"

namespace prism::spectral {

class CompositeCdf;

class BinnedShape {
 public:
  // INVALID_ARGUMENT unless 1 <= bins <= WavelengthDistribution::kMaxCells.
  static absl::StatusOr<BinnedShape> create(const WavelengthDistribution& shape, int bins);

  int bins() const { return bins_; }
  // D_b: the default distribution's probability mass over bin b (Σ_b D_b = 1 up to rounding).
  double bin_mass(int b) const { return bin_mass_[static_cast<std::size_t>(b)]; }
  const std::vector<double>& bin_masses() const { return bin_mass_; }

  // `table` must have bins() cells (PRISM_CHECK). `guide` (guide_entries(bins()) values,
  // build_guide of the table) and the default's search guide only make the searches shorter:
  // without `guide`, sample() searches all bins and then all default cells of the chosen bin
  // (the reference the guided searches are tested against), and the sample is the same.
  WavelengthSample sample(const QuantisedWavelengthCdf& table, double u,
                          const std::uint16_t* guide = nullptr) const;
  float pdf(const QuantisedWavelengthCdf& table, float lambda_nm) const;
  double cdf(const QuantisedWavelengthCdf& table, float lambda_nm) const;
  // CMIS lanes (docs/estimators.md §2): lane s at Q⁻¹((u + s/C) mod 1).
  SampledWavelengths sample_lanes(const QuantisedWavelengthCdf& table, double u, int lanes,
                                  const std::uint16_t* guide = nullptr) const;

  // A table's search guide over the quantised CDF's integer units: G = 2^m >= 2·bins intervals
  // of 2^(16 − m) units each, so a value's interval is one shift. guide[j] (j < G) is the bin
  // holding the value j·2^(16 − m), guide[G] the last bin; a value in interval j lies in a bin of
  // [guide[j], guide[j + 1]], one or two bins for most values. guide.size() must be
  // guide_entries(table.cells()) (PRISM_CHECK).
  static int guide_entries(int bins);
  static void build_guide(const QuantisedWavelengthCdf& table, std::span<std::uint16_t> guide);

 private:
  friend class CompositeCdf;
  BinnedShape() = default;
  // Density of the composite at a λ in bin b and default cell c, from the table's integer mass.
  float density(int table_units, int b, int c) const;
  // The bin and default cell of a λ in Λ (one multiplication each; sample, pdf and cdf all look
  // them up here, which is what makes them agree exactly).
  int bin_of(float lambda_nm) const;
  int cell_of(float lambda_nm) const;
  // λ clamped into the floats with bin_of(λ) == b and (c < 0 or) cell_of(λ) == c.
  float settle(float lambda, int b, int c) const;
  // For n uniform cells looked up with `scale`: the first and last float of each.
  static void float_ranges(int n, double scale, std::vector<float>& first,
                           std::vector<float>& last);

  int bins_ = 0;
  int cells_ = 0;  // cells of the default distribution
  double bin_scale_ = 0, cell_scale_ = 0, cell_width_ = 0;
  std::vector<double> cell_cdf_;               // cells_ + 1 values
  std::vector<double> cell_lower_;             // lower edge of each default cell, nm
  std::vector<double> bin_lower_;              // lower edge of each bin, nm
  std::vector<float> bin_first_, bin_last_;    // the floats bin_of maps to each bin
  std::vector<float> cell_first_, cell_last_;  // the floats cell_of maps to each cell
  std::vector<double> cell_density_;           // per nm, mass / cell width
  std::vector<double> inv_cell_mass_;          // 1 / mass of each default cell, 0 where it is 0
  std::vector<double> bin_mass_;               // D_b
  std::vector<double> inv_bin_mass_;           // 1 / D_b, 0 where D_b = 0
  std::vector<double> bin_cdf_;                // default CDF at the lower edge of bin b
  std::vector<int> first_cell_;                // default cells overlapping bin b: [first, last]
  std::vector<int> last_cell_;
  int guide_shift_ = 0;                 // 16 − m for the tables' guides (guide_entries)
  std::vector<int> cell_search_guide_;  // the default's search_guide()
  // The pieces a table's composite density is constant on (CompositeCdf): every overlap of a bin
  // and a default cell, in λ order. Per piece its cell, lower edge and width in nm, the fraction
  // of its bin's default mass below it (of its width where D_b = 0), and the floats with bin_of
  // == its bin and cell_of == its cell. bin_piece_[b] is bin b's first piece (bins + 1 values).
  std::vector<int> piece_cell_;
  std::vector<double> piece_lower_, piece_width_, piece_fraction_;
  std::vector<float> piece_first_, piece_last_;
  std::vector<int> bin_piece_;
};

// A pixel table's whole composite CDF (BinnedShape above) over the pieces where its density is
// constant, with a search guide: a lane then costs one guided search, as a default lane does,
// instead of a search over the table's bins and another over the default's cells. Building it
// costs a few microseconds per pixel (a pass over the pieces and the guide), which the tile
// renderer pays once per pixel and task, before that pixel's samples, where the task has at
// least kMinSamples of them.
//
// Invariants: sample() returns exactly the BinnedShape's pdf(table, λ) for the λ it returns
// (same bin and cell lookup, same density arithmetic) and the same distribution as
// BinnedShape::sample(table, u): the same inverse CDF, evaluated piece by piece, so the λ of a
// u agrees with it to rounding, not bit for bit. Assigning reuses the buffers; sampling does
// not allocate. The shape and table must outlive the uses of an assignment.
class CompositeCdf {
 public:
  // The samples of a pixel in one task from which the tile renderer builds the composite. Four
  // lanes per sample pay for a build (about 2.7 µs) from about 32 samples on
  // (prism-bench-wavelength-sampling --pixel-samples, docs/benchmarks.md "Cost of a lane"); a
  // lower threshold would speed up only the prepass's passes of 32 to 127 samples per pixel, by
  // at most about 1 % (lanes are 1–3 % of a render), and the tests split the two ways here.
  static constexpr std::uint64_t kMinSamples = 128;

  // `table` must have shape.bins() cells (PRISM_CHECK).
  void assign(const BinnedShape& shape, const QuantisedWavelengthCdf& table);

  WavelengthSample sample(double u) const;
  // CMIS lanes (docs/estimators.md §2): lane s at Q⁻¹((u + s/C) mod 1).
  SampledWavelengths sample_lanes(double u, int lanes) const;
  const BinnedShape& shape() const { return *shape_; }
  const QuantisedWavelengthCdf& table() const { return *table_; }

 private:
  // What a lane reads of the piece it falls in, together.
  struct Piece {
    double lower = 0;           // its lower edge, nm
    double slope = 0;           // its width over its mass: nm per unit of u
    float first = 0, last = 0;  // the floats with its bin and cell (BinnedShape)
    float pdf = 0;              // the density, BinnedShape::density of its bin and cell
  };

  const BinnedShape* shape_ = nullptr;
  const QuantisedWavelengthCdf* table_ = nullptr;
  std::vector<double> cdf_;  // per piece its lower CDF value, then 1 twice (cdf_guide.h)
  std::vector<Piece> pieces_;
  // base::build_cdf_guide's guide of cdf_: 2^m >= four intervals of u per piece.
  std::vector<std::uint16_t> guide_;
};

}  // namespace prism::spectral
