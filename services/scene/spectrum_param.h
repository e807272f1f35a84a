// Spectra and indices of refraction as written in a scene file. The parser never evaluates a
// spectrum: it records what the file says (a constant, an RGB colour, a table, a pbrt-v4
// spectrum name, a blackbody temperature), and the renderer turns it into sampled values with
// services/spectral. Keeping the written form lets `prism check` report emitters "as
// written" and lets the analysis tell which materials are dispersive and how many distinct
// emitter spectra a scene has (operator== compares written forms).
//
// Invariants established by the parser: every number is finite; tables have >= 2 samples,
// strictly increasing wavelengths (nm) and finite values; RGB components are >= 0;
// blackbody temperatures are > 0 K; Sellmeier has exactly 3+3 coefficients, Cauchy 2..4.
#pragma once

#include <array>
#include <string>
#include <variant>
#include <vector>

namespace prism::scene {

// The same value at every wavelength. Our extension: a `float` parameter where a spectrum is
// expected; also the form of pbrt-v4's numeric defaults (diffuse reflectance 0.5, ...).
struct SpectrumConstant {
  double value = 0.0;
  friend bool operator==(const SpectrumConstant&, const SpectrumConstant&) = default;
};

// An `rgb` parameter. pbrt-v4 uplifts it by context: an albedo spectrum for reflectances
// (components must be <= 1), an unbounded spectrum for media coefficients, and for emitters
// an RGB illuminant spectrum (uplifted colour times the colour space's illuminant, D65 for
// sRGB). The context is the field that holds the value.
struct SpectrumRgb {
  double r = 0.0, g = 0.0, b = 0.0;
  friend bool operator==(const SpectrumRgb&, const SpectrumRgb&) = default;
};

// Piecewise-linear samples: inline `spectrum [λ v λ v ...]` or a file of λ,value rows.
// Outside the table the renderer clamps to zero, as pbrt-v4's PiecewiseLinearSpectrum.
struct SpectrumTabulated {
  std::vector<double> wavelengths_nm;
  std::vector<double> values;
  // "inline", or the file's path relative to the scene root.
  std::string source;
  friend bool operator==(const SpectrumTabulated&, const SpectrumTabulated&) = default;
};

// A pbrt-v4 named spectrum ("stdillum-F11", "glass-BK7", "metal-Cu-eta", ...).
struct SpectrumNamed {
  std::string name;
  friend bool operator==(const SpectrumNamed&, const SpectrumNamed&) = default;
};

// Planck's law at `kelvin`; pbrt-v4 normalises it to a peak of 1 before any light scaling.
struct SpectrumBlackbody {
  double kelvin = 0.0;
  friend bool operator==(const SpectrumBlackbody&, const SpectrumBlackbody&) = default;
};

using SpectrumParam =
    std::variant<SpectrumConstant, SpectrumRgb, SpectrumTabulated, SpectrumNamed, SpectrumBlackbody>;

// Index of refraction of a dielectric (or a conductor's eta): `float eta`, a named or
// tabulated `spectrum eta`, or our extensions `float cauchy` and `float sellmeier`.
struct IorConstant {
  double eta = 1.5;
  friend bool operator==(const IorConstant&, const IorConstant&) = default;
};
struct IorNamed {
  std::string name;
  friend bool operator==(const IorNamed&, const IorNamed&) = default;
};
struct IorTabulated {
  SpectrumTabulated table;
  friend bool operator==(const IorTabulated&, const IorTabulated&) = default;
};
// n(λ) = A + B/λ² + C/λ⁴ + D/λ⁶ with λ in µm (B in µm², C in µm⁴, ...); 2 to 4 coefficients
// in that order, missing ones are zero.
struct IorCauchy {
  std::vector<double> coefficients;
  friend bool operator==(const IorCauchy&, const IorCauchy&) = default;
};
// n²(λ) = 1 + Σ_i B_i λ² / (λ² − C_i), λ in µm, C_i in µm² (the SCHOTT catalogue form).
struct IorSellmeier {
  std::array<double, 3> b{};
  std::array<double, 3> c{};
  friend bool operator==(const IorSellmeier&, const IorSellmeier&) = default;
};

using IorParam = std::variant<IorConstant, IorNamed, IorTabulated, IorCauchy, IorSellmeier>;

// The value as a user wrote it, for summaries: `named "stdillum-F11"`, `blackbody 2700 K`,
// `rgb (1, 0.5, 0.2)`, `table "light.csv" (76 samples, 400-700 nm)`, `constant 5`.
std::string describe(const SpectrumParam& s);
std::string describe(const IorParam& ior);

// True when the index of refraction varies with wavelength: anything but a constant (a
// table whose values are all equal counts as constant). Named IORs are assumed dispersive.
bool is_dispersive(const IorParam& ior);

}  // namespace prism::scene
