// The text `prism check` prints for a scene: image size, samples, spectral bins, geometry
// counts, emitters and their spectra as written, dispersive materials, media and warnings.
// The caller appends the bundle's content hash. Pure formatting of a SceneDescription; the
// output is deterministic (scene order), one fact per line.
#pragma once

#include <string>

#include "services/scene/scene_description.h"

namespace prism::scene {

std::string format_scene_summary(const SceneDescription& scene);

}  // namespace prism::scene
