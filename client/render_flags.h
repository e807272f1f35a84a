// The render flags `prism render` and `prism submit` share. They are registered once here, so
// both commands accept the same names, help texts and value types; their ranges, defaults from
// the scene and translation into a job spec are in render_command.h, so both commands also
// render the same thing for the same flags (the farm's output is byte-identical to the embedded
// render's).
#pragma once

#include <CLI/CLI.hpp>
#include <cstdint>
#include <string>

#include "absl/status/status.h"
#include "client/render_command.h"

namespace prism::client {

// The raw values CLI11 fills, and which optional flags were given.
struct RenderFlags {
  std::string output, resolution, seed;
  std::int64_t spp = 0, bins = 0, max_depth = 0, samples_per_task = 0;
  bool no_spectral_light_selection = false;
  double delta = 0, alpha = 0;
  std::int64_t gradient_lanes = 0;
  CLI::Option* gradient_lanes_opt = nullptr;
  std::string tau;           // a value >= 0 or "auto"
  std::string target_error;  // "0.01" or "1%"
  std::int64_t max_spp = 0;
  CLI::Option* target_error_opt = nullptr;
  CLI::Option* max_spp_opt = nullptr;
  std::int64_t prepass_passes = 0, prepass_spp = 0;
  double prepass_epsilon = 0, prepass_fallback = 0, prepass_sigma_s = 0, prepass_sigma_r = 0;
  bool prepass = false, no_prepass = false;
  bool splat = false, gather = false;
  double splat_width = 0, gather_width = 0, caustic_paths = 0;
  CLI::Option* caustic_paths_opt = nullptr;
  CLI::Option* splat_width_opt = nullptr;
  CLI::Option* gather_width_opt = nullptr;
  CLI::Option* delta_opt = nullptr;
  CLI::Option* tau_opt = nullptr;
  CLI::Option* alpha_opt = nullptr;
  CLI::Option* prepass_opt = nullptr;
  CLI::Option* no_prepass_opt = nullptr;
  CLI::Option* prepass_passes_opt = nullptr;
  CLI::Option* prepass_spp_opt = nullptr;
  CLI::Option* prepass_epsilon_opt = nullptr;
  CLI::Option* prepass_fallback_opt = nullptr;
  CLI::Option* prepass_sigma_s_opt = nullptr;
  CLI::Option* prepass_sigma_r_opt = nullptr;
  CLI::Option* output_opt = nullptr;
  CLI::Option* resolution_opt = nullptr;
  CLI::Option* seed_opt = nullptr;
  CLI::Option* spp_opt = nullptr;
  CLI::Option* bins_opt = nullptr;
  CLI::Option* max_depth_opt = nullptr;
  CLI::Option* samples_per_task_opt = nullptr;
};

// Adds the scene argument and the shared render flags to `command`. String-valued options
// (integrator, pdfs, tile, exposure, ...) are bound straight to `options`; `flags` and
// `options` must outlive parsing.
void add_render_flags(CLI::App& command, RenderFlags& flags, RenderCommandOptions& options);

// After parsing: copies the given optional flags into `options` (INVALID_ARGUMENT for a seed
// that is not a decimal 64-bit integer). Ranges are checked later by validate_render_flags().
absl::Status apply_render_flags(const RenderFlags& flags, RenderCommandOptions& options);

}  // namespace prism::client
