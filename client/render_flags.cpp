#include "client/render_flags.h"

#include "services/base/status.h"

namespace prism::client {

void add_render_flags(CLI::App& cmd, RenderFlags& f, RenderCommandOptions& o) {
  cmd.add_option("scene", o.scene, "pbrt-v4 scene file")->required();
  f.output_opt = cmd.add_option(
      "-o,--output", f.output, "Spectral EXR to write (default: the Film filename's stem, here)");
  f.spp_opt = cmd.add_option("--spp", f.spp, "Samples per pixel (default: the scene's)");
  cmd.add_option("--integrator", o.integrator, "uniform or hero (default hero)");
  f.bins_opt =
      cmd.add_option("--bins", f.bins, "Spectral bins, 4..256 (default: nbuckets, else 64)");
  f.resolution_opt =
      cmd.add_option("--resolution", f.resolution, "WxH (default: the scene's Film)");
  f.seed_opt = cmd.add_option("--seed", f.seed, "Sampler seed, 0..2^64-1 (default 0)");
  cmd.add_option("--tile", o.tile, "Tile size in pixels, 4..1024 (default 32)");
  f.samples_per_task_opt = cmd.add_option(
      "--samples-per-task", f.samples_per_task,
      "Split each pixel's samples into tasks of this many (default: one task per tile); part of "
      "the job: it changes the last bits of the output");
  cmd.add_option("--spectral-pdf", o.spectral_pdf,
                 "Sensor wavelength pdf: flat or visible (default flat)");
  cmd.add_option("--emitter-pdf", o.emitter_pdf,
                 "Emitter wavelength pdf: uniform or emitters (default emitters)");
  cmd.add_option("--light-selection", o.light_selection,
                 "Base emitter pmf: uniform, power or spatial (default power)");
  cmd.add_flag("--no-spectral-light-selection", f.no_spectral_light_selection,
               "Do not weight emitter selection by the wavelengths' unit emission");
  f.max_depth_opt = cmd.add_option("--max-depth", f.max_depth,
                                   "Path vertices after the camera (default: the scene's)");
  cmd.add_option("--exposure", o.exposure, "PNG preview exposure in stops (default 0)");
}

absl::Status apply_render_flags(const RenderFlags& f, RenderCommandOptions& o) {
  if (f.output_opt->count() > 0) o.output = f.output;
  if (f.resolution_opt->count() > 0) o.resolution = f.resolution;
  if (f.spp_opt->count() > 0) o.spp = f.spp;
  if (f.bins_opt->count() > 0) o.bins = f.bins;
  if (f.max_depth_opt->count() > 0) o.max_depth = f.max_depth;
  if (f.samples_per_task_opt->count() > 0) o.samples_per_task = f.samples_per_task;
  if (f.seed_opt->count() > 0) {
    PRISM_ASSIGN_OR_RETURN(o.seed, parse_seed(f.seed));
  }
  o.spectral_light_selection = !f.no_spectral_light_selection;
  return absl::OkStatus();
}

}  // namespace prism::client
