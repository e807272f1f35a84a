// RGB → spectrum uplifting for reflectances (Jakob & Hanika 2019): a linear-sRGB albedo in
// [0, 1]³ becomes the sigmoid polynomial (sigmoid_polynomial.h) whose colour under the sRGB
// illuminant D65 matches it. The three coefficients are fitted at load time by a small
// Levenberg–Marquardt solver on the CIELAB difference, following a path from grey to the target
// colour so each solve starts close to its answer. For in-gamut colours the round trip
// RGB → spectrum → RGB is exact to ~1e-6; fits are cached per RGB value (after rounding to
// float), so repeated materials cost one lookup.
//
// Inputs: albedo() and fit() need finite channels within [0, 1]; anything else is refused with
// INVALID_ARGUMENT rather than silently clamped, because an albedo above 1 creates energy.
// unbounded() and illuminant() accept any finite channels >= 0 (pbrt-v4's RGBUnboundedSpectrum
// and RGBIlluminantSpectrum: scale m = 2·max(r, g, b), polynomial fitted to rgb/m, so the fit
// stays in the easy middle of the gamut). Grey inputs (r = g = b, including black and white)
// give the exact constant spectrum.
#pragma once

#include <array>
#include <memory>
#include <mutex>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/status/statusor.h"
#include "services/spectral/color.h"
#include "services/spectral/sigmoid_polynomial.h"
#include "services/spectral/spectrum.h"

namespace prism::spectral {

class RgbUplift {
 public:
  // Precomputes the 1 nm CMF × D65 weights. Thread-safe afterwards: fit() may be called
  // concurrently (the cache is guarded by a mutex).
  explicit RgbUplift(const ColorMatching& cmf);

  // The sigmoid polynomial for a linear-sRGB reflectance; see the header comment for errors.
  absl::StatusOr<SigmoidPolynomial> fit(const Rgb& rgb) const;
  absl::StatusOr<RgbAlbedoSpectrum> albedo(const Rgb& rgb) const;
  // m·s(λ) with m = 2·max(r, g, b); its colour under D65 is rgb.
  absl::StatusOr<RgbUnboundedSpectrum> unbounded(const Rgb& rgb) const;
  // m·s(λ)·D65(λ): an emission spectrum whose colour is rgb times the colour of D65 itself, so
  // rgb (1, 1, 1) gives exactly the D65 table (pbrt-v4 convention for sRGB emitters).
  absl::StatusOr<RgbIlluminantSpectrum> illuminant(const Rgb& rgb) const;

  // The linear-sRGB colour of a reflectance spectrum under D65 normalised to Y = 1 (what fit()
  // inverts).
  Rgb to_rgb(const SigmoidPolynomial& p) const;
  // Number of cached fits.
  size_t cache_size() const;

 private:
  struct Cache {
    std::mutex mu;
    absl::flat_hash_map<std::array<float, 3>, SigmoidPolynomial> fits;
  };
  SigmoidPolynomial solve(const std::array<float, 3>& rgb) const;
  absl::StatusOr<RgbUnboundedSpectrum> scaled_fit(const Rgb& rgb) const;

  std::vector<std::array<double, 3>> weights_;  // CMF(λ)·D65(λ)/Σ ȳ·D65 at λ = 360..830 nm
  Xyz white_;                                   // Σ weights: the colour of reflectance 1
  std::shared_ptr<const PiecewiseLinearSpectrum> d65_;
  std::unique_ptr<Cache> cache_;
};

}  // namespace prism::spectral
