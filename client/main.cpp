// The `prism` command line. Each subcommand parses its flags here, runs the library code in
// client/, prints the result on stdout and any error on stderr, and exits non-zero on failure.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <iostream>
#include <string>

#include "client/check_command.h"
#include "client/compare_command.h"

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
  return 1;
}
