#include "client/check_command.h"

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "services/scene/bundle.h"
#include "services/scene/scene_loader.h"
#include "services/scene/scene_summary.h"
#include "services/scene/wavelength_dependence.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::client {
namespace {

std::string name_of(const scene::Material& m) {
  return m.name.empty() ? "(anonymous)" : m.name;
}

nlohmann::json to_json(const scene::LoadedScene& loaded, const scene::Bundle& bundle,
                       bool renders) {
  const scene::SceneDescription& s = loaded.description;
  auto dependence = scene::analyze_wavelength_dependence(s);
  nlohmann::json j;
  j["scene"] = loaded.scene_relpath;
  j["width"] = s.film.x_resolution;
  j["height"] = s.film.y_resolution;
  j["spp"] = s.sampler.samples_per_pixel;
  // The bins a render takes without --bins: the Film's nbuckets, else the default (it was null).
  j["bins"] = s.film.bins.value_or(spectral::WavelengthGrid::kDefaultBins);
  j["bins_from_scene"] = s.film.bins.has_value();
  j["film"] = s.film.type == scene::FilmType::kSpectral ? "spectral" : "rgb";
  j["max_depth"] = s.integrator.max_depth;
  j["shapes"] = s.shapes.size();
  j["triangles"] = s.triangle_count();
  j["area_lights"] = s.area_light_count();
  j["lights"] = s.lights.size();
  nlohmann::json emitters = nlohmann::json::array();
  for (const auto& spectrum : dependence.emitter_spectra)
    emitters.push_back(scene::describe(spectrum));
  j["emitter_spectra"] = emitters;
  nlohmann::json dispersive = nlohmann::json::array();
  for (int m : dependence.dispersive_materials) dispersive.push_back(name_of(s.materials[m]));
  j["dispersive_materials"] = dispersive;
  nlohmann::json media = nlohmann::json::array();
  for (int m : dependence.media) media.push_back(s.media[m].name);
  j["media"] = media;
  j["needs_spectral_transport"] = dependence.needs_spectral_transport();
  j["warnings"] = s.warnings;
  nlohmann::json features = nlohmann::json::array();
  for (const scene::FeatureUse& f : s.features) {
    nlohmann::json entry = {{"feature", f.feature},
                            {"status", scene::feature_status_name(f.status)},
                            {"where", f.where.to_string()},
                            {"uses", f.uses},
                            {"note", f.note}};
    if (f.status == scene::FeatureStatus::kRefused) entry["substitution"] = f.substitution;
    features.push_back(entry);
  }
  j["features"] = features;
  j["refused"] = scene::count_features(s.features, scene::FeatureStatus::kRefused);
  j["renders"] = renders;
  j["bundle_hash"] = bundle.content_hash;
  j["bundle_files"] = bundle.entries.size();
  return j;
}

}  // namespace

absl::StatusOr<CheckReport> run_check(const CheckOptions& options) {
  PRISM_ASSIGN_OR_RETURN(spectral::SpectrumLibrary library,
                         spectral::SpectrumLibrary::load_builtin());
  // Substituting lets the check go on past the first refusal and list them all.
  scene::LoadOptions load = scene::with_library_names(library);
  load.allow_unsupported = true;
  absl::StatusOr<scene::LoadedScene> read = scene::load_scene(options.scene, load);
  absl::StatusOr<scene::Bundle> bundled =
      read.ok() ? scene::make_bundle(read->root, read->scene_relpath, read->description.files)
                : absl::StatusOr<scene::Bundle>(read.status());
  if (!bundled.ok()) {
    // With --json a scene that does not load is a JSON answer too (a tool reading stdout got
    // nothing): its error, "file:line:column: what" as on stderr.
    if (!options.json) return bundled.status();
    nlohmann::json j;
    j["scene"] = options.scene.string();
    j["renders"] = false;
    j["error"] = std::string(bundled.status().message());
    return CheckReport{j.dump(2) + "\n", false};
  }
  const scene::LoadedScene& loaded = *read;
  const scene::Bundle& bundle = *bundled;
  const int refused =
      scene::count_features(loaded.description.features, scene::FeatureStatus::kRefused);
  CheckReport report;
  report.renders = refused == 0 || options.allow_unsupported;
  if (options.json) {
    report.text = to_json(loaded, bundle, report.renders).dump(2) + "\n";
    return report;
  }
  report.text = absl::StrCat(
      scene::format_scene_summary(loaded.description),
      scene::format_scene_features(loaded.description.features), "bundle: ", bundle.entries.size(),
      " files, hash ", bundle.content_hash, "\n",
      refused == 0 ? ""
      : report.renders
          ? absl::StrCat("renders with --allow-unsupported: ", refused,
                         " refused features are substituted as listed\n")
          : absl::StrCat("prism render refuses this scene: ", refused,
                         " features are not supported (--allow-unsupported substitutes them as "
                         "listed)\n"));
  return report;
}

}  // namespace prism::client
