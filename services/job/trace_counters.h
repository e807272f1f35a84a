// The names of the tracer's counters (worker::TraceCounters), in the order a render's report
// lists them. The coordinator reports a farm job's counters under these names, zeros included,
// without linking the tracer; worker::counter_list gives the same names (tested there).
#pragma once

#include <array>
#include <string_view>

namespace prism::job {

inline constexpr std::array<std::string_view, 17> kTraceCounterNames = {
    "camera_rays",
    "rays",
    "lane_splits",
    "non_finite",
    "early_stops",
    "gradient_events",
    "gradient_shifted_paths",
    "gradient_shifts",
    "gradient_shifts_failed",
    "gradient_shifts_wasted",
    "gradient_divergences",
    "gradient_reconnections",
    "gradient_repeated_divergences",
    "gradient_samples",
    "gradient_lanes",
    "light_splats",
    "splat_lines",
};

}  // namespace prism::job
