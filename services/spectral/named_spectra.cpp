#include "services/spectral/named_spectra.h"

#include <cctype>
#include <set>
#include <utility>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "services/spectral/absl_string_view.h"
#include "services/spectral/color.h"
#include "services/spectral/csv_table.h"
#include "services/spectral/embedded_data.h"

namespace prism::spectral {
namespace {

absl::StatusOr<CsvTable> embedded_table(std::string_view path) {
  return parse_csv_table(embedded_file(path), path);
}

// Adds every non-wavelength column of an embedded table as prefix + name_of(column).
template <typename NameOf>
absl::Status add_columns(SpectrumLibrary& lib, std::string_view path, std::string_view prefix,
                         const NameOf& name_of) {
  PRISM_ASSIGN_OR_RETURN(const CsvTable table, embedded_table(path));
  for (int c = 1; c < table.column_count(); ++c) {
    PRISM_ASSIGN_OR_RETURN(PiecewiseLinearSpectrum s,
                           PiecewiseLinearSpectrum::from_csv(table, table.columns()[c]));
    PRISM_RETURN_IF_ERROR(
        lib.add_spectrum(absl::StrCat(to_absl(prefix), name_of(table.columns()[c])), std::move(s)));
  }
  return absl::OkStatus();
}

// A tabulated refractive index: the spectrum, and the same table as an Ior.
absl::Status add_refractive_table(SpectrumLibrary& lib, std::string name,
                                  PiecewiseLinearSpectrum table) {
  PRISM_ASSIGN_OR_RETURN(TabulatedIor ior, TabulatedIor::create(table));
  PRISM_RETURN_IF_ERROR(lib.add_ior(name, std::move(ior)));
  return lib.add_spectrum(std::move(name), std::move(table));
}

// An analytic IOR, also as a 1 nm tabulated spectrum.
absl::Status add_analytic_ior(SpectrumLibrary& lib, const std::string& name, const Ior& ior) {
  PRISM_RETURN_IF_ERROR(lib.add_ior(name, ior));
  return lib.add_spectrum(name, to_spectrum(ior));
}

absl::Status add_sellmeier(SpectrumLibrary& lib) {
  constexpr std::string_view kPath = "dispersion/sellmeier_coefficients.csv";
  PRISM_ASSIGN_OR_RETURN(const CsvTable table, embedded_table(kPath));
  PRISM_ASSIGN_OR_RETURN(const std::vector<double> a0, table.numeric_column("A0"));
  std::vector<std::vector<double>> b, c;
  for (int k = 1; k <= SellmeierIor::kMaxTerms; ++k) {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> bk,
                           table.numeric_column(absl::StrCat("B", k), /*allow_empty=*/true));
    PRISM_ASSIGN_OR_RETURN(std::vector<double> ck,
                           table.numeric_column(absl::StrCat("C", k, "_um2"), true));
    b.push_back(std::move(bk));
    c.push_back(std::move(ck));
  }
  const int material = table.column_index("material");
  if (material < 0)
    return absl::InternalError(absl::StrCat(to_absl(kPath), ": no material column"));
  std::map<std::string, Ior, std::less<>> by_material;
  for (int r = 0; r < table.row_count(); ++r) {
    std::vector<double> br, cr;
    for (int k = 0; k < SellmeierIor::kMaxTerms; ++k) {
      if (std::isnan(b[k][r])) break;
      br.push_back(b[k][r]);
      cr.push_back(c[k][r]);
    }
    auto ior = SellmeierIor::create(a0[r], br, cr);
    if (!ior.ok()) {
      return absl::InternalError(
          absl::StrCat(to_absl(kPath), ":", table.line_of_row(r), ": ", ior.status().message()));
    }
    const std::string& raw = table.cell(r, material);
    std::string name;
    if (raw == "water" || raw == "diamond") {
      name = raw;
    } else if (raw == "fused_silica") {
      name = "glass-fused-silica";
    } else {
      name = absl::StrCat("glass-", raw);
    }
    by_material.emplace(raw, *ior);
    PRISM_RETURN_IF_ERROR(add_analytic_ior(lib, name, *ior));
  }
  // pbrt-v4's glass names → the SCHOTT glass its table was made from
  // (data/dispersion/pbrt_v4_glass).
  constexpr std::pair<const char*, const char*> kPbrtNames[] = {
      {"glass-BK7", "N-BK7"},     {"glass-BAF10", "N-BAF10"}, {"glass-FK51A", "N-FK51A"},
      {"glass-LASF9", "N-LASF9"}, {"glass-F5", "N-SF5"},      {"glass-F10", "N-SF10"},
      {"glass-F11", "N-SF11"}};
  for (const auto& [pbrt, schott] : kPbrtNames) {
    auto it = by_material.find(schott);
    if (it == by_material.end()) {
      return absl::InternalError(absl::StrCat(to_absl(kPath), ": no row for ", schott));
    }
    PRISM_RETURN_IF_ERROR(add_analytic_ior(lib, pbrt, it->second));
  }
  return absl::OkStatus();
}

absl::Status add_pbrt_glass_tables(SpectrumLibrary& lib) {
  constexpr std::pair<const char*, const char*> kFiles[] = {
      {"glass-BK7", "glass-BK7"},     {"glass-BAF10", "glass-BAF10"},
      {"glass-FK51A", "glass-FK51A"}, {"glass-LASF9", "glass-LASF9"},
      {"glass-F5", "glass-SF5"},      {"glass-F10", "glass-SF10"},
      {"glass-F11", "glass-SF11"}};
  for (const auto& [pbrt, file] : kFiles) {
    const std::string path = absl::StrCat("dispersion/pbrt_v4_glass/", file, "_eta.csv");
    PRISM_ASSIGN_OR_RETURN(const CsvTable table, embedded_table(path));
    PRISM_ASSIGN_OR_RETURN(PiecewiseLinearSpectrum s,
                           PiecewiseLinearSpectrum::from_csv(table, "eta"));
    PRISM_RETURN_IF_ERROR(add_refractive_table(lib, absl::StrCat("pbrt-v4-", pbrt), std::move(s)));
  }
  return absl::OkStatus();
}

absl::Status add_eta_k(SpectrumLibrary& lib, std::string_view path, std::string_view eta_column,
                       std::string_view k_column, const std::string& prefix) {
  PRISM_ASSIGN_OR_RETURN(const CsvTable table, embedded_table(path));
  PRISM_ASSIGN_OR_RETURN(PiecewiseLinearSpectrum eta,
                         PiecewiseLinearSpectrum::from_csv(table, eta_column));
  PRISM_ASSIGN_OR_RETURN(PiecewiseLinearSpectrum k,
                         PiecewiseLinearSpectrum::from_csv(table, k_column));
  PRISM_RETURN_IF_ERROR(add_refractive_table(lib, prefix + "-eta", std::move(eta)));
  return lib.add_spectrum(prefix + "-k", std::move(k));
}

}  // namespace

std::string sanitise_spectrum_name(std::string_view raw) {
  std::string out;
  bool pending_dash = false;
  for (char ch : raw) {
    const unsigned char u = static_cast<unsigned char>(ch);
    if (std::isalnum(u) || ch == '.') {
      if (pending_dash && !out.empty()) out.push_back('-');
      pending_dash = false;
      out.push_back(static_cast<char>(std::tolower(u)));
    } else {
      pending_dash = true;
    }
  }
  return out;
}

absl::StatusOr<SpectrumLibrary> SpectrumLibrary::load_builtin() {
  SpectrumLibrary lib;
  auto same = [](const std::string& column) { return column; };

  {
    PRISM_ASSIGN_OR_RETURN(const CsvTable a,
                           embedded_table("illuminants/cie_A_formula_300_830_1nm.csv"));
    PRISM_ASSIGN_OR_RETURN(PiecewiseLinearSpectrum s, PiecewiseLinearSpectrum::from_csv(a, "A"));
    PRISM_RETURN_IF_ERROR(lib.add_spectrum("stdillum-A", std::move(s)));
  }
  {
    // Column A of this table duplicates the formula above at 5 nm, so it is skipped.
    constexpr std::string_view kPath = "illuminants/cie_standard_illuminants_300_780_5nm.csv";
    PRISM_ASSIGN_OR_RETURN(const CsvTable table, embedded_table(kPath));
    for (int c = 1; c < table.column_count(); ++c) {
      const std::string& column = table.columns()[c];
      if (column == "A") continue;
      // The D series runs on to 830 nm by the CIE daylight basis (cie_daylight_illuminant);
      // C and the indoor daylights ID50, ID65 are defined to 780 nm.
      const bool daylight =
          column == "D50" || column == "D55" || column == "D65" || column == "D75";
      PRISM_ASSIGN_OR_RETURN(PiecewiseLinearSpectrum s,
                             daylight ? cie_daylight_illuminant(column)
                                      : PiecewiseLinearSpectrum::from_csv(table, column));
      PRISM_RETURN_IF_ERROR(
          lib.add_spectrum(absl::StrCat("stdillum-", table.columns()[c]), std::move(s)));
    }
  }
  for (std::string_view path : {"illuminants/cie_fluorescent_F1_F12_380_780_5nm.csv",
                                "illuminants/cie_fluorescent_F3_1_F3_15_380_780_5nm.csv",
                                "illuminants/cie_hp_discharge_HP1_HP5_380_780_5nm.csv",
                                "illuminants/cie_led_illuminants_380_780_5nm.csv"}) {
    PRISM_RETURN_IF_ERROR(add_columns(lib, path, "stdillum-", same));
  }
  for (std::string_view path :
       {"lamps/nist_cqs_traditional_lamps_380_780_5nm.csv",
        "lamps/nist_cqs_philips_lamps_380_780_5nm.csv", "lamps/nist_cqs_led_lamps_380_780_5nm.csv",
        "lamps/rit_pointer_lamps_380_780_5nm.csv",
        "lamps/kinoton_75p_xenon_projector_380_780_2nm.csv"}) {
    PRISM_RETURN_IF_ERROR(add_columns(lib, path, "lamp-", sanitise_spectrum_name));
  }
  {
    constexpr std::string_view kPath = "reflectance/colorchecker_classic_ohta1997_380_780_5nm.csv";
    PRISM_ASSIGN_OR_RETURN(const CsvTable table, embedded_table(kPath));
    for (int c = 1; c < table.column_count(); ++c) {
      const std::string& column = table.columns()[c];  // "01_dark_skin"
      if (column.size() < 4 || column[2] != '_') {
        return absl::InternalError(
            absl::StrCat(to_absl(kPath), ": unexpected column '", column, "'"));
      }
      PRISM_ASSIGN_OR_RETURN(PiecewiseLinearSpectrum s,
                             PiecewiseLinearSpectrum::from_csv(table, column));
      PRISM_RETURN_IF_ERROR(
          lib.add_spectrum(absl::StrCat("colorchecker-", column.substr(0, 2)), s));
      PRISM_RETURN_IF_ERROR(lib.add_spectrum(
          absl::StrCat("colorchecker-", sanitise_spectrum_name(column.substr(3))), std::move(s)));
    }
  }
  for (const char* metal : {"Ag", "Al", "Au", "Cu", "CuZn", "MgO", "TiO2"}) {
    PRISM_RETURN_IF_ERROR(add_eta_k(lib, absl::StrCat("metals/pbrt_v4/", metal, "_eta_k.csv"),
                                    "eta", "k", absl::StrCat("metal-", metal)));
  }
  PRISM_RETURN_IF_ERROR(add_sellmeier(lib));
  PRISM_RETURN_IF_ERROR(add_pbrt_glass_tables(lib));
  PRISM_RETURN_IF_ERROR(add_eta_k(lib, "dispersion/water_hale_querry_1973_n_k_200_2500nm.csv", "n",
                                  "k", "water-hale-querry"));
  PRISM_RETURN_IF_ERROR(add_eta_k(lib, "dispersion/diamond_phillip_taft_1964_n_k_200_2500nm.csv",
                                  "n", "k", "diamond-phillip-taft"));
  return lib;
}

const Spectrum* SpectrumLibrary::find_spectrum(std::string_view name) const {
  auto it = spectra_.find(name);
  return it == spectra_.end() ? nullptr : &it->second;
}

const Ior* SpectrumLibrary::find_ior(std::string_view name) const {
  auto it = iors_.find(name);
  return it == iors_.end() ? nullptr : &it->second;
}

bool SpectrumLibrary::contains(std::string_view name) const {
  return spectra_.contains(name) || iors_.contains(name);
}

std::vector<std::string> SpectrumLibrary::names() const {
  std::set<std::string> all;
  for (const auto& [name, s] : spectra_) all.insert(name);
  for (const auto& [name, i] : iors_) all.insert(name);
  return {all.begin(), all.end()};
}

absl::Status SpectrumLibrary::add_spectrum(std::string name, Spectrum spectrum) {
  if (spectra_.contains(name)) {
    return absl::AlreadyExistsError(absl::StrCat("a spectrum named '", name, "' already exists"));
  }
  spectra_.emplace(std::move(name), std::move(spectrum));
  return absl::OkStatus();
}

absl::Status SpectrumLibrary::add_ior(std::string name, Ior ior) {
  if (iors_.contains(name)) {
    return absl::AlreadyExistsError(absl::StrCat("an IOR named '", name, "' already exists"));
  }
  iors_.emplace(std::move(name), std::move(ior));
  return absl::OkStatus();
}

}  // namespace prism::spectral
