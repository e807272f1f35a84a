#include "client/reconstruct_command.h"

#include <charconv>
#include <cmath>
#include <system_error>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "coordinator/outputs.h"
#include "coordinator/poisson.h"
#include "services/base/decimal.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/spectral/color.h"

namespace prism::client {
namespace {

namespace fs = std::filesystem;

std::string quoted(const fs::path& path) {
  return absl::StrCat("'", path.string(), "'");
}

absl::Status with_context(const absl::Status& status, const std::string& context) {
  return absl::Status(status.code(), absl::StrCat(context, ": ", status.message()));
}

// The file's wavelengths must be Prism's grid for its bin count, or "bin b + k" would not mean
// "δ further along the spectrum".
absl::Status check_prism_grid(const image::SpectralExr& exr, const std::string& role,
                              const fs::path& path) {
  const std::vector<double> grid = image::bin_centres_nm(exr.spectral.bins());
  for (std::size_t b = 0; b < grid.size(); ++b) {
    if (std::abs(exr.wavelengths_nm[b] - grid[b]) > 1e-9 * grid[b]) {
      return absl::InvalidArgumentError(
          absl::StrCat(role, " file ", quoted(path), ": channel ", b, " is at ",
                       exr.wavelengths_nm[b], " nm, not on Prism's grid of ", grid.size(),
                       " bins over [360, 830] nm (", grid[b], " nm)"));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<int> offset_from_metadata(const image::SpectralExr& gradient, const fs::path& path) {
  const auto it = gradient.metadata.find(std::string(image::kMetaGradientOffsetBins));
  if (it == gradient.metadata.end()) {
    return absl::InvalidArgumentError(
        absl::StrCat("gradient file ", quoted(path),
                     " has no prism:", std::string(image::kMetaGradientOffsetBins),
                     " metadata; pass --offset-bins K (the gradient offset in bins)"));
  }
  const std::string& text = it->second;
  int k = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), k);
  if (text.empty() || ec != std::errc() || end != text.data() + text.size()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "gradient file ", quoted(path), ": prism:", std::string(image::kMetaGradientOffsetBins),
        " = '", text, "' is not an integer; pass --offset-bins K to override it"));
  }
  return k;
}

// A file Prism wrote with --primal-and-gradients says what it holds (prism:content); one
// without the key (written by an older Prism or another tool) is taken as given.
absl::Status check_content(const image::SpectralExr& file, std::string_view role,
                           const fs::path& path) {
  const auto it = file.metadata.find(std::string(image::kMetaContent));
  if (it == file.metadata.end() || it->second == role) return absl::OkStatus();
  return absl::InvalidArgumentError(absl::StrCat(
      absl::string_view(role.data(), role.size()), " file ", quoted(path), " holds the ",
      it->second, " of its render (prism:", std::string(image::kMetaContent),
      "); give the primal file first, then the gradient file"));
}

// The two files must come from one render: where both carry Prism's record of the render, the
// records agree. A file without them (another tool's) is taken as given.
absl::Status check_same_render(const image::SpectralExr& primal, const fs::path& primal_path,
                               const image::SpectralExr& gradient, const fs::path& gradient_path) {
  for (const char* key :
       {"scene", "job_id", "integrator", "seed", "spp", "bins", "max_depth", "spectral_pdf",
        "emitter_pdf", "gradient_offset_bins", "gradient_delta", "gradient_tau"}) {
    const auto p = primal.metadata.find(key);
    const auto g = gradient.metadata.find(key);
    if (p == primal.metadata.end() || g == gradient.metadata.end() || p->second == g->second) {
      continue;
    }
    return absl::InvalidArgumentError(absl::StrCat(
        "primal file ", quoted(primal_path), " and gradient file ", quoted(gradient_path),
        " come from different renders (prism:", key, " is '", p->second, "' in one and '",
        g->second, "' in the other); give the .primal.exr and .gradient.exr one render wrote"));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::string> run_reconstruct(const ReconstructOptions& options) {
  // Flags first: a typo should not cost reading two large files.
  if (options.poisson.has_value() && *options.poisson == "weighted") {
    return absl::InvalidArgumentError(
        "--poisson weighted needs the per-bin variances of I and G, which the primal and "
        "gradient EXRs do not carry: reconstruct with l2 or l1, or render with --poisson weighted");
  }
  if (options.poisson.has_value() && *options.poisson != "l2" && *options.poisson != "l1") {
    return absl::InvalidArgumentError(
        absl::StrCat("Poisson norm '", *options.poisson, "': want l2 or l1"));
  }
  auto alpha_in_range = [](double a) {
    return std::isfinite(a) && a >= job::kMinPoissonAlpha && a <= job::kMaxPoissonAlpha;
  };
  if (options.alpha.has_value() && !alpha_in_range(*options.alpha)) {
    return absl::InvalidArgumentError(
        absl::StrCat("--alpha ", *options.alpha, ": want a finite value in [",
                     job::kMinPoissonAlpha, ", ", job::kMaxPoissonAlpha, "] (alpha must be > 0)"));
  }
  if (options.output.empty() || options.output.extension() != ".exr") {
    return absl::InvalidArgumentError(
        absl::StrCat("-o ", quoted(options.output), ": want an output path ending in .exr"));
  }
  const fs::path out_dir =
      options.output.parent_path().empty() ? fs::path(".") : options.output.parent_path();
  if (!fs::is_directory(out_dir)) {
    return absl::NotFoundError(absl::StrCat("-o ", quoted(options.output), ": directory ",
                                            quoted(out_dir), " does not exist"));
  }
  if (fs::is_directory(options.output)) {
    return absl::InvalidArgumentError(
        absl::StrCat("-o ", quoted(options.output), " is a directory"));
  }
  PRISM_RETURN_IF_ERROR(coordinator::check_not_special_file(options.output));
  std::error_code ec;
  if (fs::equivalent(options.primal, options.gradient, ec)) {
    return absl::InvalidArgumentError(
        absl::StrCat("the primal and the gradient file are the same file, ", quoted(options.primal),
                     "; give the render's .primal.exr and .gradient.exr"));
  }
  for (const fs::path& input : {options.primal, options.gradient}) {
    if (fs::exists(options.output) && fs::equivalent(options.output, input, ec)) {
      return absl::InvalidArgumentError(absl::StrCat(
          "-o ", quoted(options.output), " is an input file; write the reconstruction elsewhere"));
    }
  }

  auto primal = image::read_spectral_exr(options.primal);
  if (!primal.ok()) return with_context(primal.status(), "primal file");
  auto gradient = image::read_spectral_exr(options.gradient);
  if (!gradient.ok()) return with_context(gradient.status(), "gradient file");
  const image::SpectralImage& pi = primal->spectral;
  const image::SpectralImage& gi = gradient->spectral;
  if (pi.width() != gi.width() || pi.height() != gi.height() || pi.bins() != gi.bins()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "primal file ", quoted(options.primal), " is ", pi.width(), "x", pi.height(), " with ",
        pi.bins(), " bins but gradient file ", quoted(options.gradient), " is ", gi.width(), "x",
        gi.height(), " with ", gi.bins(), " bins; they must match"));
  }
  PRISM_RETURN_IF_ERROR(check_prism_grid(*primal, "primal", options.primal));
  PRISM_RETURN_IF_ERROR(check_prism_grid(*gradient, "gradient", options.gradient));
  PRISM_RETURN_IF_ERROR(check_content(*primal, "primal", options.primal));
  PRISM_RETURN_IF_ERROR(check_content(*gradient, "gradient", options.gradient));
  PRISM_RETURN_IF_ERROR(check_same_render(*primal, options.primal, *gradient, options.gradient));
  // The gradient file names its primal by the hash of its pixels: two renders of an edited
  // scene under the same name and options differ there.
  if (auto named = gradient->metadata.find(std::string(image::kMetaPrimalSha256));
      named != gradient->metadata.end()) {
    const std::span<const float> data = pi.data();
    const std::string hash = base::sha256_hex(
        std::string_view(reinterpret_cast<const char*>(data.data()), data.size() * sizeof(float)));
    if (hash != named->second) {
      return absl::InvalidArgumentError(absl::StrCat(
          "gradient file ", quoted(options.gradient), " belongs with another primal than ",
          quoted(options.primal), " (its prism:", std::string(image::kMetaPrimalSha256),
          " is not the hash of this primal's pixels); give the .primal.exr and .gradient.exr "
          "one render wrote"));
    }
  }

  // α and the norm: the flags, else what the render used (its files record both), else the
  // defaults; the render's image is then what this writes.
  // Rounded through float, as a job holds it (JobSpec), so `--alpha A` here reconstructs what
  // `prism render --alpha A` did, bit for bit.
  double alpha = double(static_cast<float>(options.alpha.value_or(job::kDefaultPoissonAlpha)));
  std::string poisson = options.poisson.value_or("l2");
  for (const auto& [file, path] :
       {std::pair{&*gradient, &options.gradient}, std::pair{&*primal, &options.primal}}) {
    if (!options.alpha.has_value()) {
      if (auto it = file->metadata.find(std::string(image::kMetaPoissonAlpha));
          it != file->metadata.end()) {
        double recorded = 0;
        if (!absl::SimpleAtod(it->second, &recorded) || !alpha_in_range(recorded)) {
          return absl::InvalidArgumentError(
              absl::StrCat(quoted(*path), ": prism:", std::string(image::kMetaPoissonAlpha), " = '",
                           it->second, "' is not a usable alpha; pass --alpha"));
        }
        alpha = double(static_cast<float>(recorded));  // the job held it as a float
      }
    }
    if (!options.poisson.has_value()) {
      if (auto it = file->metadata.find(std::string(image::kMetaPoissonNorm));
          it != file->metadata.end()) {
        if (it->second == "weighted") {
          return absl::InvalidArgumentError(absl::StrCat(
              quoted(*path),
              " comes from a render reconstructed with --poisson weighted, which needs the "
              "per-bin variances these files do not carry: pass --poisson l2 or l1 to "
              "reconstruct them anyway"));
        }
        if (it->second == "l2" || it->second == "l1") poisson = it->second;
      }
    }
  }
  const job::PoissonNorm norm = *job::parse_poisson_norm(poisson);

  int k = 0;
  if (options.offset_bins) {
    k = *options.offset_bins;
  } else {
    PRISM_ASSIGN_OR_RETURN(k, offset_from_metadata(*gradient, options.gradient));
  }
  auto solver = coordinator::PoissonSolver::create(pi.bins(), k, alpha);
  if (!solver.ok()) {
    return with_context(solver.status(),
                        options.offset_bins
                            ? std::string("--offset-bins")
                            : absl::StrCat("gradient file ", quoted(options.gradient)));
  }
  auto result = coordinator::reconstruct_image(*solver, norm, pi, gi);
  if (!result.ok()) {
    return with_context(result.status(),
                        absl::StrCat(quoted(options.primal), " and ", quoted(options.gradient)));
  }
  const spectral::ColorMatching cmf = spectral::ColorMatching::cie1931();
  auto rgb = coordinator::to_linear_srgb(*result, cmf);
  if (!rgb.ok()) return with_context(rgb.status(), "colour conversion of the reconstruction");
  // As `prism render` makes a gradient render's RGB (coordinator::tile_rgb): the primal's RGB,
  // its samples' exact RGB, plus the reconstruction's change of the bins' RGB. A primal file
  // without R, G, B gets the reconstructed bins' RGB alone.
  if (primal->rgb.has_value() && primal->rgb->width() == pi.width() &&
      primal->rgb->height() == pi.height()) {
    auto plain = coordinator::to_linear_srgb(pi, cmf);
    if (!plain.ok()) return with_context(plain.status(), "colour conversion of the primal");
    for (int y = 0; y < pi.height(); ++y) {
      for (int x = 0; x < pi.width(); ++x) {
        for (int c = 0; c < 3; ++c) {
          rgb->value(x, y, c) =
              static_cast<float>(double(primal->rgb->value(x, y, c)) + double(rgb->value(x, y, c)) -
                                 double(plain->value(x, y, c)));
        }
      }
    }
  }

  image::ExrMetadata metadata = primal->metadata;
  metadata[std::string(image::kMetaPoissonAlpha)] = base::shortest_decimal(alpha);
  metadata[std::string(image::kMetaPoissonNorm)] = std::string(job::to_string(norm));
  metadata[std::string(image::kMetaGradientOffsetBins)] = absl::StrCat(k);
  const auto delta = gradient->metadata.find(std::string(image::kMetaGradientDelta));
  if (delta != gradient->metadata.end()) {
    metadata[std::string(image::kMetaGradientDelta)] = delta->second;
  }
  metadata[std::string(image::kMetaContent)] = "reconstruction";
  metadata["version"] = coordinator::prism_version();
  PRISM_RETURN_IF_ERROR(image::write_spectral_exr(options.output, *result, *rgb, metadata));
  return absl::StrCat("wrote ", options.output.string(), ": ", pi.width(), "x", pi.height(), ", ",
                      pi.bins(), " bins, k ", k, ", alpha ", base::shortest_decimal(alpha), ", ",
                      std::string(job::to_string(norm)), "\n");
}

}  // namespace prism::client
