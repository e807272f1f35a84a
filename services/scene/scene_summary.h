// The text `prism check` prints for a scene: image size, samples, spectral bins, geometry
// counts, emitters and their spectra as written, dispersive materials, media and warnings.
// The caller appends the bundle's content hash. Pure formatting of a SceneDescription; the
// output is deterministic (scene order), one fact per line.
#pragma once

#include <string>

#include "services/scene/scene_description.h"

namespace prism::scene {

std::string format_scene_summary(const SceneDescription& scene);

// One line per feature the scene uses (scene_features.h), in first-use order, after a count by
// status: "  refused      Shape \"curve\" (s.pbrt:8:7): <why>; --allow-unsupported renders
// <substitution>".
std::string format_scene_features(const std::vector<FeatureUse>& features);

}  // namespace prism::scene
