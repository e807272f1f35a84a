// The report's job-derived parts (coordinator/outputs.h's RenderReport): the scene's features
// not rendered exactly as pbrt-v4 renders them, and the gradient and prepass sections from the
// job's settings. `prism render` and the farm fill their reports with the same two calls.
#pragma once

#include <vector>

#include "coordinator/outputs.h"
#include "services/job/job_parameters.h"
#include "services/scene/scene_description.h"

namespace prism::coordinator {

// The scene's features a report lists: every one not rendered exactly as pbrt-v4 would.
std::vector<SceneFeatureNote> reported_features(const scene::SceneDescription& scene);

// The report's gradient and prepass sections from the job's settings (their measured figures,
// counters and times, are the caller's to fill).
void add_job_sections(const job::JobParameters& parameters, RenderReport& report);

}  // namespace prism::coordinator
