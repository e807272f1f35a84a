#include "services/scene/scene_features.h"

#include "absl/strings/str_cat.h"

namespace prism::scene {

const char* feature_status_name(FeatureStatus status) {
  switch (status) {
    case FeatureStatus::kSupported:
      return "supported";
    case FeatureStatus::kApproximated:
      return "approximated";
    case FeatureStatus::kIgnored:
      return "ignored";
    case FeatureStatus::kRefused:
      return "refused";
  }
  return "?";
}

void FeatureRecorder::add(std::string_view feature, FeatureStatus status,
                          const SourceLocation& where, std::string_view note,
                          std::string_view substitution) {
  if (out_ == nullptr) return;
  // One entry per feature and outcome: a scene with 10,000 diffuse materials lists one.
  for (FeatureUse& use : *out_) {
    if (use.feature == feature && use.status == status && use.note == note &&
        use.substitution == substitution) {
      ++use.uses;
      return;
    }
  }
  out_->push_back(FeatureUse{std::string(feature), status, where, 1, std::string(note),
                             std::string(substitution)});
}

void FeatureRecorder::supported(std::string_view feature, const SourceLocation& where,
                                std::string_view note) {
  add(feature, FeatureStatus::kSupported, where, note, {});
}

void FeatureRecorder::approximated(std::string_view feature, const SourceLocation& where,
                                   std::string_view note) {
  add(feature, FeatureStatus::kApproximated, where, note, {});
}

void FeatureRecorder::ignored(std::string_view feature, const SourceLocation& where,
                              std::string_view note) {
  add(feature, FeatureStatus::kIgnored, where, note, {});
}

absl::Status FeatureRecorder::refuse(std::string_view feature, const SourceLocation& where,
                                     std::string_view message, std::string_view substitution) {
  if (!allow_unsupported_) return location_error(where, message);
  add(feature, FeatureStatus::kRefused, where, message, substitution);
  return absl::OkStatus();
}

std::vector<std::string> feature_warnings(const std::vector<FeatureUse>& features,
                                          bool include_ignored) {
  std::vector<std::string> out;
  for (const FeatureUse& f : features) {
    const std::string at = absl::StrCat(f.where.to_string(), ": warning: ");
    switch (f.status) {
      case FeatureStatus::kSupported:
        break;
      case FeatureStatus::kIgnored:
        if (!include_ignored) break;
        [[fallthrough]];
      case FeatureStatus::kApproximated:
        out.push_back(
            absl::StrCat(at, f.feature, " ", feature_status_name(f.status), ": ", f.note));
        break;
      case FeatureStatus::kRefused:
        out.push_back(absl::StrCat(at, f.note, "; rendered as ", f.substitution));
        break;
    }
  }
  return out;
}

int count_features(const std::vector<FeatureUse>& features, FeatureStatus status) {
  int n = 0;
  for (const FeatureUse& f : features) n += f.status == status;
  return n;
}

}  // namespace prism::scene
