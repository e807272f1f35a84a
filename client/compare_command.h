// `prism compare test.exr reference.exr`: error metrics (MSE, relMSE, SSIM, non-finite fraction)
// over spectral bins and over RGB, for the whole image or a crop.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "services/image/metrics.h"

namespace prism::client {

struct CompareOptions {
  std::filesystem::path test;
  std::filesystem::path reference;
  std::optional<image::Crop> crop;
  bool json = false;
};

absl::StatusOr<std::string> run_compare(const CompareOptions& options);

// Parses "x,y,w,h" (non-negative integers); INVALID_ARGUMENT naming the text otherwise.
absl::StatusOr<image::Crop> parse_crop(const std::string& text, std::string_view flag = "--crop");

}  // namespace prism::client
