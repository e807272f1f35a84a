// The `prism` command line. Each subcommand parses its flags here, runs the library code in
// client/, prints the result on stdout and any error on stderr, and exits non-zero on failure.
#include <CLI/CLI.hpp>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <iostream>
#include <string>

#include "client/check_command.h"
#include "client/compare_command.h"
#include "client/render_command.h"
#include "worker/embree_device.h"

namespace {

int report(const absl::StatusOr<std::string>& result) {
  if (!result.ok()) {
    std::cerr << "prism: " << result.status().message() << "\n";
    return 1;
  }
  std::cout << *result;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Prism: a distributed spectral renderer"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "prism 0.1.0");

  prism::client::CheckOptions check;
  auto* check_cmd = app.add_subcommand("check", "Validate a scene and summarise what it needs");
  check_cmd->add_option("scene", check.scene, "pbrt-v4 scene file")->required();
  check_cmd->add_flag("--json", check.json, "Print the summary as JSON");

  prism::client::CompareOptions compare;
  std::string crop;
  auto* compare_cmd =
      app.add_subcommand("compare", "Error metrics of an EXR against a reference EXR");
  compare_cmd->add_option("test", compare.test, "Image to evaluate (EXR)")->required();
  compare_cmd->add_option("reference", compare.reference, "Reference image (EXR)")->required();
  compare_cmd->add_option("--crop", crop, "Region x,y,w,h in pixels");
  compare_cmd->add_flag("--json", compare.json, "Print the metrics as JSON");

  prism::client::RenderCommandOptions render;
  std::string output, json_path, resolution, seed;
  std::int64_t spp = 0, bins = 0, threads = 0, max_depth = 0;
  bool no_spectral_light_selection = false;
  auto* render_cmd = app.add_subcommand(
      "render",
      "Render a scene on this machine (the farm's coordinator and worker code, in process)");
  render_cmd->add_option("scene", render.scene, "pbrt-v4 scene file")->required();
  auto* output_opt = render_cmd->add_option(
      "-o,--output", output, "Spectral EXR to write (default: the Film filename's stem, here)");
  auto* spp_opt = render_cmd->add_option("--spp", spp, "Samples per pixel (default: the scene's)");
  render_cmd->add_option("--integrator", render.integrator, "uniform or hero (default hero)");
  auto* bins_opt =
      render_cmd->add_option("--bins", bins, "Spectral bins, 4..256 (default: nbuckets, else 64)");
  auto* resolution_opt =
      render_cmd->add_option("--resolution", resolution, "WxH (default: the scene's Film)");
  auto* threads_opt = render_cmd->add_option("--threads", threads,
                                             "Render threads (default: all hardware threads)");
  auto* seed_opt = render_cmd->add_option("--seed", seed, "Sampler seed, 0..2^64-1 (default 0)");
  render_cmd->add_option("--tile", render.tile, "Tile size in pixels, 4..1024 (default 32)");
  auto* json_opt =
      render_cmd->add_option("--json", json_path, "JSON report path (default: <output stem>.json)");
  render_cmd->add_option("--spectral-pdf", render.spectral_pdf,
                         "Sensor wavelength pdf: flat or visible (default flat)");
  render_cmd->add_option("--emitter-pdf", render.emitter_pdf,
                         "Emitter wavelength pdf: uniform or emitters (default emitters)");
  render_cmd->add_option("--light-selection", render.light_selection,
                         "Base emitter pmf: uniform, power or spatial (default power)");
  render_cmd->add_flag("--no-spectral-light-selection", no_spectral_light_selection,
                       "Do not weight emitter selection by the wavelengths' unit emission");
  auto* depth_opt = render_cmd->add_option("--max-depth", max_depth,
                                           "Path vertices after the camera (default: the scene's)");
  render_cmd->add_option("--exposure", render.exposure,
                         "PNG preview exposure in stops (default 0)");

  CLI11_PARSE(app, argc, argv);

  if (check_cmd->parsed()) return report(prism::client::run_check(check));
  if (compare_cmd->parsed()) {
    if (!crop.empty()) {
      auto parsed = prism::client::parse_crop(crop);
      if (!parsed.ok()) return report(parsed.status());
      compare.crop = *parsed;
    }
    return report(prism::client::run_compare(compare));
  }
  if (render_cmd->parsed()) {
    if (output_opt->count() > 0) render.output = output;
    if (json_opt->count() > 0) render.json = json_path;
    if (resolution_opt->count() > 0) render.resolution = resolution;
    if (spp_opt->count() > 0) render.spp = spp;
    if (bins_opt->count() > 0) render.bins = bins;
    if (threads_opt->count() > 0) render.threads = threads;
    if (depth_opt->count() > 0) render.max_depth = max_depth;
    if (seed_opt->count() > 0) {
      auto parsed = prism::client::parse_seed(seed);
      if (!parsed.ok()) return report(parsed.status());
      render.seed = *parsed;
    }
    render.spectral_light_selection = !no_spectral_light_selection;
    if (isatty(STDERR_FILENO)) render.progress = &std::cerr;
    // The flags are checked before Embree starts, so a typo costs nothing.
    if (absl::Status flags = prism::client::validate_render_flags(render); !flags.ok()) {
      return report(flags);
    }
    prism::worker::EmbreeDevice device;
    return report(prism::client::run_render(render, device));
  }
  return 1;
}
