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
#include "client/farm_commands.h"
#include "client/reconstruct_command.h"
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

  prism::client::ReconstructOptions reconstruct;
  int offset_bins = 0;
  auto* reconstruct_cmd = app.add_subcommand(
      "reconstruct", "Screened Poisson reconstruction of a saved primal and gradient EXR pair");
  reconstruct_cmd->add_option("primal", reconstruct.primal, "Primal spectral EXR (I)")
      ->required();
  reconstruct_cmd->add_option("gradient", reconstruct.gradient,
                              "Gradient spectral EXR (G[b] ~ I[b+k] - I[b])")
      ->required();
  reconstruct_cmd->add_option("-o,--output", reconstruct.output, "Spectral EXR to write")
      ->required();
  reconstruct_cmd->add_option("--alpha", reconstruct.alpha,
                              "Screening weight alpha > 0 (default 0.2)");
  reconstruct_cmd->add_option("--poisson", reconstruct.poisson, "Norm: l2 or l1 (default l2)");
  auto* offset_opt = reconstruct_cmd->add_option(
      "--offset-bins", offset_bins,
      "Gradient offset k in bins (default: the gradient file's prism:gradient_offset_bins)");

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

  // The farm subcommands share the connection flags.
  prism::client::FarmConnection farm;
  auto add_connection = [&](CLI::App* cmd) {
    cmd->add_option("--coordinator", farm.address,
                    "Coordinator HOST:PORT (default: $PRISM_COORDINATOR)");
    cmd->add_option("--token", farm.token, "API token (default: $PRISM_API_TOKEN)");
    cmd->add_option("--tls-ca", farm.tls_ca, "PEM roots to verify the coordinator (TLS)");
  };

  prism::client::SubmitOptions submit;
  std::string submit_output, submit_resolution, submit_seed;
  std::int64_t submit_spp = 0, submit_bins = 0, submit_depth = 0;
  bool submit_no_sls = false;
  auto* submit_cmd = app.add_subcommand("submit", "Submit a scene to the farm");
  submit_cmd->add_option("scene", submit.render.scene, "pbrt-v4 scene file")->required();
  add_connection(submit_cmd);
  auto* s_output = submit_cmd->add_option("-o,--output", submit_output,
                                          "Spectral EXR to write with --wait (default render.exr)");
  auto* s_spp = submit_cmd->add_option("--spp", submit_spp, "Samples per pixel");
  submit_cmd->add_option("--integrator", submit.render.integrator, "uniform or hero");
  auto* s_bins = submit_cmd->add_option("--bins", submit_bins, "Spectral bins, 4..256");
  auto* s_res = submit_cmd->add_option("--resolution", submit_resolution, "WxH");
  auto* s_seed = submit_cmd->add_option("--seed", submit_seed, "Sampler seed");
  submit_cmd->add_option("--tile", submit.render.tile, "Tile size in pixels, 4..1024");
  submit_cmd->add_option("--spectral-pdf", submit.render.spectral_pdf, "flat or visible");
  submit_cmd->add_option("--emitter-pdf", submit.render.emitter_pdf, "uniform or emitters");
  submit_cmd->add_option("--light-selection", submit.render.light_selection,
                         "uniform, power or spatial");
  submit_cmd->add_flag("--no-spectral-light-selection", submit_no_sls,
                       "Do not weight emitter selection by the wavelengths' unit emission");
  auto* s_depth = submit_cmd->add_option("--max-depth", submit_depth, "Path vertices");
  submit_cmd->add_flag("--wait", submit.wait, "Watch the job, then fetch its outputs");
  submit_cmd->add_option("--client-token", submit.client_token,
                         "Idempotency key (default: hash of bundle and spec)");

  std::string job_id, fetch_output;
  auto* status_cmd = app.add_subcommand("status", "Show a farm job");
  status_cmd->add_option("job", job_id, "Job id")->required();
  add_connection(status_cmd);
  auto* jobs_cmd = app.add_subcommand("jobs", "List the farm's jobs");
  add_connection(jobs_cmd);
  auto* watch_cmd = app.add_subcommand("watch", "Follow a farm job until it finishes");
  watch_cmd->add_option("job", job_id, "Job id")->required();
  add_connection(watch_cmd);
  auto* cancel_cmd = app.add_subcommand("cancel", "Cancel a farm job");
  cancel_cmd->add_option("job", job_id, "Job id")->required();
  add_connection(cancel_cmd);
  auto* fetch_cmd = app.add_subcommand("fetch", "Download a finished job's outputs");
  fetch_cmd->add_option("job", job_id, "Job id")->required();
  auto* f_output = fetch_cmd->add_option("-o,--output", fetch_output, "Spectral EXR to write");
  add_connection(fetch_cmd);
  auto* workers_cmd = app.add_subcommand("workers", "List the farm's workers");
  add_connection(workers_cmd);

  CLI11_PARSE(app, argc, argv);

  for (CLI::App* cmd : {submit_cmd, status_cmd, jobs_cmd, watch_cmd, cancel_cmd, fetch_cmd,
                        workers_cmd}) {
    if (!cmd->parsed()) continue;
    if (absl::Status resolved = prism::client::resolve_connection(farm); !resolved.ok()) {
      return report(resolved);
    }
  }
  if (submit_cmd->parsed()) {
    prism::client::RenderCommandOptions& r = submit.render;
    if (s_output->count() > 0) r.output = submit_output;
    if (s_res->count() > 0) r.resolution = submit_resolution;
    if (s_spp->count() > 0) r.spp = submit_spp;
    if (s_bins->count() > 0) r.bins = submit_bins;
    if (s_depth->count() > 0) r.max_depth = submit_depth;
    if (s_seed->count() > 0) {
      auto parsed = prism::client::parse_seed(submit_seed);
      if (!parsed.ok()) return report(parsed.status());
      r.seed = *parsed;
    }
    r.spectral_light_selection = !submit_no_sls;
    submit.progress = &std::cerr;
    submit.progress_is_terminal = isatty(STDERR_FILENO) != 0;
    return report(prism::client::run_submit(farm, submit));
  }
  if (status_cmd->parsed()) return report(prism::client::run_status(farm, job_id));
  if (jobs_cmd->parsed()) return report(prism::client::run_jobs(farm));
  if (watch_cmd->parsed()) {
    return report(prism::client::run_watch(farm, job_id, std::cerr, isatty(STDERR_FILENO) != 0));
  }
  if (cancel_cmd->parsed()) return report(prism::client::run_cancel(farm, job_id));
  if (fetch_cmd->parsed()) {
    std::optional<std::filesystem::path> out;
    if (f_output->count() > 0) out = fetch_output;
    return report(prism::client::run_fetch(farm, job_id, out));
  }
  if (workers_cmd->parsed()) return report(prism::client::run_workers(farm));

  if (check_cmd->parsed()) return report(prism::client::run_check(check));
  if (compare_cmd->parsed()) {
    if (!crop.empty()) {
      auto parsed = prism::client::parse_crop(crop);
      if (!parsed.ok()) return report(parsed.status());
      compare.crop = *parsed;
    }
    return report(prism::client::run_compare(compare));
  }
  if (reconstruct_cmd->parsed()) {
    if (offset_opt->count() > 0) reconstruct.offset_bins = offset_bins;
    return report(prism::client::run_reconstruct(reconstruct));
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
