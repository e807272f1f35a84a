// `prism reconstruct PRIMAL.exr GRADIENT.exr -o OUT.exr`: the per-pixel screened Poisson
// reconstruction (coordinator/poisson.h) of a saved primal and gradient pair. Both inputs are
// spectral EXRs on Prism's grid with the same size and bins; the gradient file follows the
// convention in services/image/exr_spectral.h (G[b] ≈ I[b+k] − I[b], k in the metadata key
// gradient_offset_bins, which --offset-bins overrides or supplies). The output is a spectral EXR
// with R, G, B (the same colour conversion as `prism render`), the primal's metadata, and
// poisson_alpha, poisson_norm and gradient_offset_bins recording how it was made.
//
// Every check (flags, both files, grids, sizes, k, finite values) happens before anything is
// written, and the write is atomic: on any error no output file appears.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "services/job/job_parameters.h"

namespace prism::client {

struct ReconstructOptions {
  std::filesystem::path primal;
  std::filesystem::path gradient;
  std::filesystem::path output;
  // Unset: what the files record of the render (prism:poisson_alpha, prism:poisson_norm), else
  // kDefaultPoissonAlpha and l2.
  std::optional<double> alpha;
  std::optional<std::string> poisson;  // l2 or l1
  std::optional<int> offset_bins;
};

// A one-line summary of what was written, or an error naming the flag or file at fault.
absl::StatusOr<std::string> run_reconstruct(const ReconstructOptions& options);

}  // namespace prism::client
