// The `prism` command line. Each subcommand parses its flags here, runs the library code in
// client/, prints the result on stdout and any error on stderr, and exits non-zero on failure.
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cstdint>
#include <cstdio>
#include <iostream>
#include <string>

#include "client/bench_command.h"
#include "client/check_command.h"
#include "client/compare_command.h"
#include "client/farm_commands.h"
#include "client/reconstruct_command.h"
#include "client/render_command.h"
#include "client/render_flags.h"
#include "services/base/float_mode.h"
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
  prism::base::flush_denormals_to_zero();  // before any thread starts (float_mode.h)
  CLI::App app{"Prism: a distributed spectral renderer"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "prism 0.1.0");

  prism::client::CheckOptions check;
  auto* check_cmd = app.add_subcommand("check", "Validate a scene and summarise what it needs");
  check_cmd->add_option("scene", check.scene, "pbrt-v4 scene file")->required();
  check_cmd->add_flag("--json", check.json, "Print the summary as JSON");
  check_cmd->add_flag(
      "--allow-unsupported", check.allow_unsupported,
      "Succeed when the scene uses refused features (render would substitute them)");

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
  reconstruct_cmd->add_option("primal", reconstruct.primal, "Primal spectral EXR (I)")->required();
  reconstruct_cmd
      ->add_option("gradient", reconstruct.gradient, "Gradient spectral EXR (G[b] ~ I[b+k] - I[b])")
      ->required();
  reconstruct_cmd->add_option("-o,--output", reconstruct.output, "Spectral EXR to write")
      ->required();
  double reconstruct_alpha = 0;
  std::string reconstruct_poisson;
  auto* reconstruct_alpha_opt = reconstruct_cmd->add_option(
      "--alpha", reconstruct_alpha,
      "Screening weight alpha > 0 (default: the render's, from the files; else 0.4)");
  auto* reconstruct_poisson_opt = reconstruct_cmd->add_option(
      "--poisson", reconstruct_poisson,
      "Norm: l2 or l1 (default: the render's, from the files; else l2)");
  auto* offset_opt = reconstruct_cmd->add_option(
      "--offset-bins", offset_bins,
      "Gradient offset k in bins (default: the gradient file's prism:gradient_offset_bins)");

  prism::client::RenderCommandOptions render;
  prism::client::RenderFlags render_flags;
  std::string json_path;
  std::int64_t threads = 0;
  auto* render_cmd = app.add_subcommand(
      "render",
      "Render a scene on this machine (the farm's coordinator and worker code, in process)");
  prism::client::add_render_flags(*render_cmd, render_flags, render);
  auto* threads_opt = render_cmd->add_option(
      "--threads", threads, "Render threads (default, or 0: all hardware threads)");
  auto* json_opt =
      render_cmd->add_option("--json", json_path, "JSON report path (default: <output stem>.json)");
  render_cmd->add_option("--spool", render.spool,
                         "auto, always or never: do not hold the finished bins in memory but "
                         "write them into the spectral EXR as the render runs (to a target "
                         "error: keep them on disk beside the outputs); auto: when they "
                         "exceed 1 GiB");
  render_cmd->add_option("--max-memory", render.max_memory,
                         "Refuse a render planned to need more memory than this, e.g. 8G (default: "
                         "the machine's memory or the process's limit, whichever is smaller)");

  prism::client::BenchOptions bench;
  std::int64_t bench_reference_spp = 0, bench_bins = 0, bench_threads = 0;
  std::string bench_cache, bench_resolution, bench_reference_error;
  auto* bench_cmd = app.add_subcommand(
      "bench", "Error against time of the rendering methods on scenes (CSV, report, plots)");
  bench_cmd->add_option("scenes", bench.scenes, "pbrt-v4 scene files");
  bench_cmd
      ->add_option("--results", bench.results,
                   "Instead of rendering: the report and plots of earlier runs' "
                   "results.csv (repeatable; the rows of --methods)")
      ->allow_extra_args(false);
  bench_cmd->add_option(
      "--methods", bench.methods,
      "Comma-separated: uniform, hero, hero+prepass, gradient, light, hero+caustics, "
      "light+splat, hero+caustics+splat, hero+gather (these three judged by their filtered "
      "image), auto (default: uniform, hero, hero+prepass, gradient, auto)");
  auto* budgets_opt = bench_cmd->add_option(
      "--budgets", bench.budgets, "Time budgets per render, e.g. 10s,30s,2m (default 10s,30s)");
  auto* bench_spp_opt =
      bench_cmd->add_option("--spp", bench.spp, "Samples per pixel instead, e.g. 64,256,1024");
  budgets_opt->excludes(bench_spp_opt);
  bench_cmd->add_option("--seeds", bench.seeds, "Renders per method and budget (default 2)");
  bench_cmd
      ->add_option("--reference", bench.references,
                   "Reference spectral EXR, one per scene, in their order (repeatable; "
                   "default: rendered and cached)")
      ->allow_extra_args(false);
  auto* reference_spp_opt = bench_cmd->add_option(
      "--reference-spp", bench_reference_spp,
      "Samples per pixel of a rendered reference (default: 4x the largest budget)");
  auto* reference_error_opt = bench_cmd->add_option(
      "--reference-error", bench_reference_error,
      "Render the reference to this relative error per pixel, e.g. 0.5% (instead of a spp)");
  bench_cmd->add_option("--reference-cache", bench_cache,
                        "Where rendered references are kept (default ~/.cache/prism/references)");
  bench_cmd->add_option("--inset", bench.insets, "A region x,y,w,h also measured (repeatable)")
      ->allow_extra_args(false);
  bench_cmd->add_option("--resolution", bench_resolution, "Film resolution WxH (default: scene)");
  auto* bench_bins_opt = bench_cmd->add_option("--bins", bench_bins, "Spectral bins");
  auto* bench_threads_opt = bench_cmd->add_option("--threads", bench_threads, "Render threads");
  bench_cmd->add_option("--clock", bench.clock, "wall or cpu (default wall)");
  bench_cmd->add_option("--baseline", bench.baseline,
                        "Method the equal-time ratios divide by (default hero)");
  bench_cmd->add_option("-o,--output", bench.output, "Output directory (default ./bench)");
  bench_cmd->add_flag("--allow-unsupported", bench.allow_unsupported,
                      "Render scenes with unsupported input, substituting it");

  // The farm subcommands share the connection flags.
  prism::client::FarmConnection farm;
  auto add_connection = [&](CLI::App* cmd) {
    cmd->add_option("--coordinator", farm.address,
                    "Coordinator HOST:PORT (default: $PRISM_COORDINATOR)");
    cmd->add_option("--token", farm.token, "API token (default: $PRISM_API_TOKEN)");
    cmd->add_option("--tls-ca", farm.tls_ca, "PEM roots to verify the coordinator (TLS)");
  };

  add_connection(bench_cmd);

  prism::client::SubmitOptions submit;
  prism::client::RenderFlags submit_flags;
  auto* submit_cmd = app.add_subcommand("submit", "Submit a scene to the farm");
  prism::client::add_render_flags(*submit_cmd, submit_flags, submit.render);
  add_connection(submit_cmd);
  submit_cmd->add_flag("--wait", submit.wait, "Watch the job, then fetch its outputs");
  submit_cmd->add_option("--client-token", submit.client_token,
                         "Idempotency key (default: hash of bundle and spec): the same key "
                         "returns the same job, unless it failed or was cancelled");

  prism::client::SubmitOptions pack;
  prism::client::RenderFlags pack_flags;
  std::string pack_bundle;
  auto* pack_cmd = app.add_subcommand(
      "pack", "Write a scene's bundle and print the SubmitJobRequest JSON (for the HTTP API)");
  prism::client::add_render_flags(*pack_cmd, pack_flags, pack.render);
  pack_cmd->add_option("--bundle", pack_bundle, "Packed bundle to write (POST /api/v1/bundles)")
      ->required();
  pack_cmd->add_option("--client-token", pack.client_token,
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

  // CLI11 answers a misspelt command with "A subcommand is required"; name it instead.
  if (argc > 1 && argv[1][0] != '-') {
    bool known = false;
    std::string names;
    for (const CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; })) {
      known = known || sub->get_name() == argv[1];
      names += (names.empty() ? "" : ", ") + sub->get_name();
    }
    if (!known) {
      std::cerr << "prism: unknown command '" << argv[1] << "'; the commands are " << names
                << " (prism --help)\n";
      return 2;
    }
  }
  CLI11_PARSE(app, argc, argv);

  for (CLI::App* cmd :
       {submit_cmd, status_cmd, jobs_cmd, watch_cmd, cancel_cmd, fetch_cmd, workers_cmd}) {
    if (!cmd->parsed()) continue;
    if (absl::Status resolved = prism::client::resolve_connection(farm); !resolved.ok()) {
      return report(resolved);
    }
  }
  if (pack_cmd->parsed()) {
    // The render flags come with -o, which a pack has no use for (it writes --bundle and prints
    // the request); taking it silently let a user think the job's output was named.
    if (pack_cmd->get_option("--output")->count() > 0) {
      std::cerr << "prism: pack writes --bundle and prints the request; -o names the outputs of "
                   "`prism render` or `prism submit --wait` (a job's outputs are fetched with "
                   "`prism fetch JOB -o FILE`)\n";
      return 1;
    }
    if (absl::Status applied = prism::client::apply_render_flags(pack_flags, pack.render);
        !applied.ok()) {
      return report(applied);
    }
    pack.render.warnings = &std::cerr;
    return report(prism::client::run_pack(pack, pack_bundle));
  }
  if (submit_cmd->parsed()) {
    if (absl::Status applied = prism::client::apply_render_flags(submit_flags, submit.render);
        !applied.ok()) {
      return report(applied);
    }
    submit.progress = &std::cerr;
    submit.render.warnings = &std::cerr;
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

  if (check_cmd->parsed()) {
    absl::StatusOr<prism::client::CheckReport> checked = prism::client::run_check(check);
    if (!checked.ok()) return report(checked.status());
    std::cout << checked->text;
    return checked->renders ? 0 : 1;
  }
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
    if (reconstruct_alpha_opt->count() > 0) reconstruct.alpha = reconstruct_alpha;
    if (reconstruct_poisson_opt->count() > 0) reconstruct.poisson = reconstruct_poisson;
    return report(prism::client::run_reconstruct(reconstruct));
  }
  if (bench_cmd->parsed()) {
    // --results reports on rows already rendered: a flag that shapes renders would do nothing.
    if (!bench.results.empty()) {
      for (const char* name :
           {"--budgets", "--spp", "--seeds", "--reference", "--reference-spp", "--reference-error",
            "--reference-cache", "--inset", "--resolution", "--bins", "--threads", "--clock",
            "--allow-unsupported", "--coordinator", "--token", "--tls-ca"}) {
        if (bench_cmd->get_option(name)->count() > 0) {
          std::cerr << "prism: " << name
                    << " shapes the renders; --results reports on rows already rendered (their "
                       "report and plots take --methods, --baseline and -o)\n";
          return 1;
        }
      }
    }
    // An empty list given (--budgets "" from a script's empty variable) is not the default.
    for (const char* name : {"--budgets", "--spp", "--methods"}) {
      if (bench_cmd->get_option(name)->count() > 0 &&
          bench_cmd->get_option(name)->as<std::string>().empty()) {
        std::cerr << "prism: " << name << " is empty; leave it out for its default\n";
        return 1;
      }
    }
    if (reference_spp_opt->count() > 0) bench.reference_spp = bench_reference_spp;
    if (reference_error_opt->count() > 0) {
      auto parsed = prism::client::parse_target_error(bench_reference_error, "--reference-error");
      if (!parsed.ok()) {
        std::cerr << "prism: " << parsed.status().message() << "\n";
        return 1;
      }
      bench.reference_error = *parsed;
    }
    if (!bench_cache.empty()) bench.reference_cache = bench_cache;
    if (!bench_resolution.empty()) bench.resolution = bench_resolution;
    if (bench_bins_opt->count() > 0) bench.bins = bench_bins;
    if (bench_threads_opt->count() > 0) bench.threads = bench_threads;
    if (!farm.address.empty()) {
      // --coordinator sends every render to the farm; the token may come from the environment.
      if (absl::Status resolved = prism::client::resolve_connection(farm); !resolved.ok()) {
        return report(resolved);
      }
      bench.farm = farm;
    }
    bench.log = &std::cerr;
    prism::worker::EmbreeDevice device;
    return report(prism::client::run_bench(bench, device));
  }
  if (render_cmd->parsed()) {
    if (absl::Status applied = prism::client::apply_render_flags(render_flags, render);
        !applied.ok()) {
      return report(applied);
    }
    if (json_opt->count() > 0) render.json = json_path;
    if (threads_opt->count() > 0) render.threads = threads;
    if (isatty(STDERR_FILENO)) render.progress = &std::cerr;
    render.warnings = &std::cerr;
    // The flags are checked before Embree starts, so a typo costs nothing.
    if (absl::Status flags = prism::client::validate_render_flags(render); !flags.ok()) {
      return report(flags);
    }
    prism::worker::EmbreeDevice device;
    return report(prism::client::run_render(render, device));
  }
  return 1;
}
