// The built-in named spectra and refractive indices, from the data files embedded at build time
// (embedded_data.h); nothing is read from disk. A SpectrumLibrary is an ordinary value built by
// its owner (the scene loader) and passed down by const&; lookups never allocate and returned
// pointers stay valid for the library's lifetime (std::map nodes are stable).
//
// Names (pbrt-v4's where pbrt-v4 has the spectrum):
//   stdillum-A                      CIE A from its defining formula (1 nm, 300–830 nm)
//   stdillum-<X>                    every column of the CIE tables under its CIE name:
//                                   C D50 D55 D65 D75 ID50 ID65, F1…F12, F3.1…F3.15, HP1…HP5,
//                                   LED-B1…LED-B5 LED-BH1 LED-RGB1 LED-V1 LED-V2.
//                                   stdillum-D50 is the CIE table (pbrt-v4's differs; data/README).
//   lamp-<name>                     measured/modelled lamps (data/lamps): the source column name
//                                   lower-cased, every run of other characters than [a-z0-9.]
//                                   turned into one '-', e.g. "F32T8/TL830 (Triphosphor)" →
//                                   lamp-f32t8-tl830-triphosphor, "Kinoton 75P" → lamp-kinoton-75p.
//   colorchecker-<patch>            the 24 Ohta ColorChecker reflectances, e.g.
//   colorchecker-NN                 colorchecker-dark-skin, colorchecker-white-9.5; also by chart
//                                   number colorchecker-01 … colorchecker-24.
//   metal-<M>-eta, metal-<M>-k      pbrt-v4 conductor tables, M ∈ Ag Al Au Cu CuZn MgO TiO2.
//   glass-<SCHOTT name>             Sellmeier IORs: glass-N-BK7 N-BAF10 F2 N-F2 SF5 N-SF5 SF10
//                                   N-SF10 SF11 N-SF11 N-FK51A N-LASF9, glass-fused-silica,
//                                   glass-CaF2, water (20 °C), diamond.
//   glass-BK7 glass-BAF10 glass-FK51A glass-LASF9 glass-F5 glass-F10 glass-F11
//                                   pbrt-v4's names. They map to the Sellmeier IOR of the SCHOTT
//                                   glass pbrt-v4's table was made from (N-BK7, N-BAF10, N-FK51A,
//                                   N-LASF9, N-SF5, N-SF10, N-SF11): exact and smoothly
//                                   differentiable. They agree with pbrt-v4's tables within 5e-4
//                                   over 400–780 nm (BK7 exactly at the table samples; the
//                                   flints differ by up to 4e-4 in the blue).
//   pbrt-v4-glass-<name>            pbrt-v4's own tabulated tables under the same pbrt names.
//   water-hale-querry-eta/-k, diamond-phillip-taft-eta/-k   tabulated n, k.
// Kinds: every name is a Spectrum. IOR names (glass-*, water, diamond) are also available as a
// Spectrum: n sampled at 1 nm. Every tabulated spectrum of a refractive index (metal-*-eta,
// pbrt-v4-glass-*, *-eta) is also available as an Ior (TabulatedIor).
#pragma once

#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/spectral/ior.h"
#include "services/spectral/spectrum.h"

namespace prism::spectral {

class SpectrumLibrary {
 public:
  // An empty library (add to it with add_spectrum / add_ior).
  SpectrumLibrary() = default;
  // Every built-in spectrum and IOR listed above. An error would mean the embedded data is
  // malformed (a build problem), reported rather than aborting.
  static absl::StatusOr<SpectrumLibrary> load_builtin();

  // nullptr when the name is unknown (or has no such kind).
  const Spectrum* find_spectrum(std::string_view name) const;
  const Ior* find_ior(std::string_view name) const;
  bool contains(std::string_view name) const;
  // Every name, sorted, without duplicates.
  std::vector<std::string> names() const;

  // Adds a named spectrum or IOR, e.g. one loaded from a user's file. ALREADY_EXISTS if the
  // name is taken for that kind.
  absl::Status add_spectrum(std::string name, Spectrum spectrum);
  absl::Status add_ior(std::string name, Ior ior);

 private:
  std::map<std::string, Spectrum, std::less<>> spectra_;
  std::map<std::string, Ior, std::less<>> iors_;
};

// The naming rule for lamp columns above, without the "lamp-" prefix.
std::string sanitise_spectrum_name(std::string_view raw);

}  // namespace prism::spectral
