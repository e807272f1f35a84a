#include "client/render_flags.h"

#include <string>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/job/render_options.h"

namespace prism::client {

void add_render_flags(CLI::App& cmd, RenderFlags& f, RenderCommandOptions& o) {
  cmd.add_option("scene", o.scene, "pbrt-v4 scene file")->required();
  f.output_opt = cmd.add_option("-o,--output", f.output,
                                "Spectral EXR to write (default: the Film filename's stem, here)");
  f.spp_opt = cmd.add_option("--spp", f.spp, "Samples per pixel (default: the scene's)");
  cmd.add_option("--integrator", o.integrator,
                 "auto (a pilot picks hero, gradient or uniform; hero where nothing depends on "
                 "wavelength), uniform, hero, gradient or light (light paths to a perspective "
                 "camera; --spp counts batches of one path per pixel) (default auto)");
  cmd.add_option("--caustics", o.caustics,
                 "off, or light: caustic paths (light, delta chain, the first non-delta surface "
                 "the camera sees) by light tracing, the rest by hero or uniform (default off; "
                 "auto may choose light)");
  f.caustic_paths_opt = cmd.add_option(
      "--caustic-paths", f.caustic_paths,
      "With --caustics light: light paths per pixel and sample, 1/256..1 (default 1; when auto "
      "chooses light-traced caustics, the share its pilot fits to the scene)");
  cmd.add_flag("--splat", f.splat,
               "Differential splatting of the light paths (--integrator light or --caustics "
               "light; with auto it means --caustics light): also writes <stem>.filtered.exr and "
               "<stem>.filtered.png, the caustics smoothed along their dispersion (biased, "
               "consistent; the main image stays unbiased)");
  f.splat_width_opt = cmd.add_option(
      "--splat-width", f.splat_width,
      absl::StrCat("With --splat: the spectral neighbourhood Δλ in nm at the first sample, "
                   "shrinking as (s+1)^(-1/5), ",
                   job::kMinSplatWidthNm, "..", job::kMaxSplatWidthNm, " (default ",
                   job::kDefaultSplatWidthNm, "; implies --splat)"));
  cmd.add_flag("--gather", f.gather,
               "Gathering for eye-traced images (hero or uniform; with auto it means hero): also "
               "writes <stem>.filtered.exr and <stem>.filtered.png, the image filtered along each "
               "pixel's mean spectral offset of its caustics, left alone where offsets disagree "
               "(biased, consistent; the main image stays unbiased)");
  f.gather_width_opt =
      cmd.add_option("--gather-width", f.gather_width,
                     absl::StrCat("With --gather: Δλ in nm at 1 spp, shrinking as spp^(-1/5), ",
                                  job::kMinSplatWidthNm, "..", job::kMaxSplatWidthNm, " (default ",
                                  job::kDefaultSplatWidthNm, "; implies --gather)"));
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
  f.target_error_opt = cmd.add_option(
      "--target-error", f.target_error,
      "Render until each pixel's relative standard error (of its luminance) is at most this, "
      "e.g. 0.01 or 1%: --spp is the first round's, rounds double it where needed");
  cmd.add_option("--target-error-scope", o.target_error_scope,
                 "pixel (every pixel meets the target) or image (the image's mean does); default "
                 "pixel");
  f.max_spp_opt = cmd.add_option("--max-spp", f.max_spp,
                                 "With --target-error: stop at this spp (default 65536)");
  f.max_depth_opt = cmd.add_option("--max-depth", f.max_depth,
                                   "Path vertices after the camera (default: the scene's)");
  cmd.add_option("--exposure", o.exposure, "PNG preview exposure in stops (default 0)");
  cmd.add_option("--exr-compression", o.exr_compression,
                 absl::StrCat("Lossless compression of the EXR outputs: none, rle, zips, zip or "
                              "piz (default ",
                              std::string(image::name(image::kDefaultExrCompression)), ")"));

  f.delta_opt = cmd.add_option("--delta", f.delta,
                               "Gradient: spectral offset as a fraction of the range, snapped to "
                               "whole bins (default 0.15)");
  f.tau_opt = cmd.add_option("--tau", f.tau,
                             "Gradient: shift threshold, a value >= 0 in the image's units, or "
                             "auto: chosen by a short pilot render (default auto)");
  f.alpha_opt =
      cmd.add_option("--alpha", f.alpha,
                     "Gradient: screened Poisson weight of --poisson l2 and l1, > 0 (default 0.4)");
  f.gradient_lanes_opt =
      cmd.add_option("--gradient-lanes", f.gradient_lanes,
                     absl::StrCat("Gradient: hero wavelengths carried by each base path, 1..",
                                  job::kMaxGradientLanes,
                                  "; events are shifted only after a smooth dispersive refraction "
                                  "(default: 1 where a material can refract so, else ",
                                  job::kSceneGradientLanes, ")"));
  cmd.add_option("--poisson", o.poisson,
                 "Gradient: reconstruction l2 (one alpha), l1 (IRLS) or weighted (per-bin inverse "
                 "variances of I and G, unbiased but slower to converge; default l2)");
  cmd.add_flag("--primal-and-gradients", o.primal_and_gradients,
               "Gradient: also write the raw primal and gradient EXRs (<stem>.primal.exr, "
               "<stem>.gradient.exr)");
  f.prepass_opt = cmd.add_flag("--prepass", f.prepass,
                               "Learn per-pixel wavelength pdfs in a prepass (default: off)");
  f.no_prepass_opt = cmd.add_flag("--no-prepass", f.no_prepass, "No prepass");
  cmd.add_flag("--allow-unsupported", o.allow_unsupported,
               "Render a scene with pbrt-v4 features Prism does not support, each replaced by "
               "the substitution `prism check` lists (and the JSON report records)");
  f.prepass_opt->excludes(f.no_prepass_opt);
  f.prepass_passes_opt =
      cmd.add_option("--prepass-passes", f.prepass_passes, "Prepass passes K (default 2)");
  f.prepass_spp_opt = cmd.add_option("--prepass-spp", f.prepass_spp,
                                     "Samples per pixel of the last prepass (default: 8 % of the "
                                     "job's samples over the passes, at most 128; no prepass "
                                     "under 16, nor where the first of several passes would get "
                                     "under 8 spp: under 900 spp with two)");
  cmd.add_option("--prepass-mode", o.prepass_mode,
                 "samples (earlier passes take fewer samples) or image (earlier passes a smaller "
                 "film); default samples");
  f.prepass_epsilon_opt = cmd.add_option("--prepass-epsilon", f.prepass_epsilon,
                                         "Least share of the default distribution in a learned "
                                         "table (default 0.05)");
  f.prepass_fallback_opt = cmd.add_option("--prepass-fallback", f.prepass_fallback,
                                          "Least predicted variance reduction for a pixel to get "
                                          "a table, in [0, 1) (default 0.05)");
  f.prepass_sigma_s_opt = cmd.add_option("--prepass-sigma-s", f.prepass_sigma_s,
                                         "Bilateral filter spatial sigma, pixels (default 1.75)");
  f.prepass_sigma_r_opt = cmd.add_option("--prepass-sigma-r", f.prepass_sigma_r,
                                         "Bilateral filter range sigma (default 0.015)");
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
  auto take = [](const CLI::Option* opt, auto value, auto& target) {
    if (opt->count() > 0) target = value;
  };
  take(f.delta_opt, f.delta, o.delta);
  if (f.tau_opt->count() > 0) {
    if (f.tau == "auto") {
      o.tau_auto = true;
    } else {
      double tau = 0;
      std::size_t used = 0;
      try {
        tau = std::stod(f.tau, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || used != f.tau.size()) {
        return absl::InvalidArgumentError(
            absl::StrCat("--tau '", f.tau, "': want a value >= 0 or auto"));
      }
      o.tau = tau;
    }
  }
  take(f.alpha_opt, f.alpha, o.alpha);
  take(f.gradient_lanes_opt, f.gradient_lanes, o.gradient_lanes);
  if (f.target_error_opt->count() > 0) {
    PRISM_ASSIGN_OR_RETURN(o.target_error, parse_target_error(f.target_error));
  }
  take(f.max_spp_opt, f.max_spp, o.max_spp);
  if (f.splat_width_opt->count() > 0) {
    o.splat_width = f.splat_width;
  } else if (f.splat) {
    o.splat_width = job::kDefaultSplatWidthNm;
  }
  take(f.caustic_paths_opt, f.caustic_paths, o.caustic_paths);
  if (f.gather_width_opt->count() > 0) {
    o.gather_width = f.gather_width;
  } else if (f.gather) {
    o.gather_width = job::kDefaultSplatWidthNm;
  }
  take(f.prepass_passes_opt, f.prepass_passes, o.prepass_passes);
  take(f.prepass_spp_opt, f.prepass_spp, o.prepass_spp);
  take(f.prepass_epsilon_opt, f.prepass_epsilon, o.prepass_epsilon);
  take(f.prepass_fallback_opt, f.prepass_fallback, o.prepass_fallback);
  take(f.prepass_sigma_s_opt, f.prepass_sigma_s, o.prepass_sigma_s);
  take(f.prepass_sigma_r_opt, f.prepass_sigma_r, o.prepass_sigma_r);
  if (f.prepass_opt->count() > 0) o.prepass = true;
  if (f.no_prepass_opt->count() > 0) o.prepass = false;
  return absl::OkStatus();
}

}  // namespace prism::client
