// What a scene uses, feature by feature, and what Prism does with each: the policy for pbrt-v4
// input Prism does not render exactly as pbrt-v4 would.
//
// - supported: rendered as pbrt-v4 renders it (or deliberately more correctly; the note says).
// - approximated: rendered, but the converged image can differ from pbrt-v4's in a way the note
//   names (a texture looked up without pbrt-v4's ray-differential filtering).
// - ignored: accepted and dropped because it cannot change the converged image (the sampler
//   type, `Accelerator`, the film's `savefp16`).
// - refused: changes the image and Prism does not implement it. Loading fails with the
//   feature, the file and the line, unless the load allows unsupported input: then the refusal
//   is recorded with what Prism rendered instead (`substitution`) and loading goes on.
//
// Every use goes through one FeatureRecorder during a parse; the result is
// SceneDescription::features, which `prism check` lists and every render report carries.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "services/scene/source_location.h"

namespace prism::scene {

enum class FeatureStatus { kSupported, kApproximated, kIgnored, kRefused };

const char* feature_status_name(FeatureStatus status);  // "supported", ...

struct FeatureUse {
  std::string feature;  // `Material "coateddiffuse"`, `Film "rgb" 'bool savefp16'`
  FeatureStatus status = FeatureStatus::kSupported;
  SourceLocation where;  // the first use
  int uses = 1;
  std::string note;          // why approximated, ignored or refused
  std::string substitution;  // refused only: what was rendered instead
};

class FeatureRecorder {
 public:
  // `out` collects the uses (may be null).
  FeatureRecorder(bool allow_unsupported, std::vector<FeatureUse>* out)
      : allow_unsupported_(allow_unsupported), out_(out) {}

  bool allow_unsupported() const { return allow_unsupported_; }

  void supported(std::string_view feature, const SourceLocation& where, std::string_view note = {});
  void approximated(std::string_view feature, const SourceLocation& where, std::string_view note);
  void ignored(std::string_view feature, const SourceLocation& where, std::string_view note);
  // Strict: the error "where: message". Allowing unsupported input: records the refusal with
  // `substitution` and returns OK; the caller then renders the substitution.
  absl::Status refuse(std::string_view feature, const SourceLocation& where,
                      std::string_view message, std::string_view substitution);

 private:
  void add(std::string_view feature, FeatureStatus status, const SourceLocation& where,
           std::string_view note, std::string_view substitution);

  bool allow_unsupported_ = false;
  std::vector<FeatureUse>* out_ = nullptr;
};

// How many entries have `status`.
int count_features(const std::vector<FeatureUse>& features, FeatureStatus status);

// What a render prints about the features it does not render exactly as pbrt-v4 would, one
// line each: "file:line:column: warning: <feature> ignored: <note>", "... approximated: ...",
// "...: <refusal>; rendered as <substitution>". Renders leave the ignored ones to the report
// (include_ignored false): they cannot change the image.
std::vector<std::string> feature_warnings(const std::vector<FeatureUse>& features,
                                          bool include_ignored = true);

}  // namespace prism::scene
