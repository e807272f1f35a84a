// Colorimetry for spectral output: the CIE 1931 2° colour-matching functions (1 nm table over
// 360–830 nm, embedded), spectrum → XYZ, binned spectrum → XYZ, and XYZ → linear sRGB / ACEScg.
//
// Conventions (pbrt-v4, docs/estimators.md §9): XYZ = Σ_{λ=360..830, 1 nm} CMF(λ)·S(λ) /
// kCieYIntegral, so a spectrum whose photometric sum Σ ȳ·S equals kCieYIntegral has Y = 1.
// Consequently the CIE D65 spectrum scaled to Y = 1 maps to linear sRGB ≈ (1, 1, 1), and a
// reflectance seen under such a D65 has the sRGB colour of the reflectance itself (no adaptation
// needed).
//
// White points: sRGB is defined for D65, so XYZ → sRGB needs no adaptation. ACEScg (AP1
// primaries) uses the ACES white (x, y) = (0.32168, 0.33767), about D60; xyz_to_acescg first
// applies a Bradford chromatic adaptation from D65 to that white, so D65 white → (1, 1, 1) in
// both spaces. All matrices are derived at compile time from the primaries' chromaticities.
#pragma once

#include <array>
#include <span>
#include <vector>

#include "services/spectral/spectrum.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::spectral {

// pbrt-v4's CIE_Y_integral: Σ ȳ over the 1 nm table (the table itself sums to 106.856917).
inline constexpr double kCieYIntegral = 106.856895;

struct Xyz {
  double x = 0.0, y = 0.0, z = 0.0;
};
struct Rgb {
  double r = 0.0, g = 0.0, b = 0.0;
};
struct Lab {
  double l = 0.0, a = 0.0, b = 0.0;
};

// XYZ weights of each bin of a grid: weight[b] = ∫_bin CMF(λ) dλ / kCieYIntegral, with the CMFs
// linearly interpolated between their 1 nm samples. For bin averages v[b] (per nm),
// XYZ = Σ_b v[b]·weight[b], which integrates the piecewise-constant spectrum exactly.
class XyzBinWeights {
 public:
  const WavelengthGrid& grid() const { return grid_; }
  std::span<const Xyz> weights() const { return weights_; }
  // bin_values.size() must equal grid().bins().
  Xyz to_xyz(std::span<const float> bin_values) const;

 private:
  friend class ColorMatching;
  XyzBinWeights(WavelengthGrid grid, std::vector<Xyz> w) : grid_(grid), weights_(std::move(w)) {}
  WavelengthGrid grid_;
  std::vector<Xyz> weights_;
};

// The CIE 1931 2° standard observer. Build once (it parses the embedded table) and pass by
// const&; all queries are const and thread-safe.
class ColorMatching {
 public:
  static ColorMatching cie1931();

  // x̄, ȳ, z̄ at lambda_nm, linear between the 1 nm samples; 0 outside [360, 830]. No allocation.
  Xyz cmf(float lambda_nm) const;
  // The linear sRGB matching functions (xyz_to_linear_srgb of x̄, ȳ, z̄) at lambda_nm, linear
  // between the 1 nm samples: a sample's RGB without a matrix per sample.
  Rgb srgb(float lambda_nm) const;
  // Σ ȳ over the table (≈ 106.857).
  double y_sum() const { return y_sum_; }
  // XYZ of a spectrum by the 1 nm sum above, divided by kCieYIntegral.
  Xyz to_xyz(const Spectrum& s) const;
  // Σ_{λ=360..830} ȳ(λ)·S(λ): pbrt-v4's photometric integral that light spectra are divided by.
  double photometric_sum(const Spectrum& s) const;
  XyzBinWeights bin_weights(const WavelengthGrid& grid) const;

 private:
  ColorMatching() = default;
  std::vector<std::array<double, 3>> table_;       // index i ↔ λ = 360 + i nm
  std::vector<std::array<double, 3>> srgb_table_;  // table_ in linear sRGB
  std::vector<PiecewiseLinearSpectrum> curves_;    // x̄, ȳ, z̄ for exact bin integrals
  double y_sum_ = 0.0;
};

// A CIE D-series illuminant, `name` D50, D55, D65 or D75 (relative SPD, 100 at 560 nm), over
// 300–830 nm: the CIE table to 780 nm (data/illuminants/cie_standard_illuminants_300_780_5nm.csv),
// then the CIE daylight basis S0 + M1·S1 + M2·S2 at the illuminant's correlated colour
// temperature (CIE 015:2018 §4.1.2, M1 and M2 rounded to three decimals as the CIE does) up to
// 830 nm, where the table stops short of Prism's range. The basis reproduces the table to 2.4e-4
// where both exist, and gives the CIE's published D65 values from 785 to 830 nm (pbrt-v4's D65
// runs to 830 nm too). INVALID_ARGUMENT for another name.
absl::StatusOr<PiecewiseLinearSpectrum> cie_daylight_illuminant(std::string_view name);
// cie_daylight_illuminant("D65").
PiecewiseLinearSpectrum cie_d65();

Rgb xyz_to_linear_srgb(const Xyz& xyz);
Xyz linear_srgb_to_xyz(const Rgb& rgb);
// Bradford D65 → ACES white, then XYZ → AP1. Expects XYZ relative to a D65 white.
Rgb xyz_to_acescg(const Xyz& xyz);

// The sRGB transfer function (IEC 61966-2-1) on one channel; linear values outside [0, 1] are
// extended symmetrically (sign kept) rather than clipped.
double srgb_encode(double linear);
double srgb_decode(double encoded);

// CIELAB of xyz relative to white (both with the same Y scale).
Lab xyz_to_lab(const Xyz& xyz, const Xyz& white);

}  // namespace prism::spectral
