// The coordinator's scene bundles, content addressed under the data directory:
//   bundles/<hash>          the packed bundle (its presence is what has() checks)
//   bundles/<hash>.scene    the scene file's path inside the bundle
//   scenes/<hash>/          the extracted files the scene loader checked
// A bundle is checked before anything uses it: unpack() validates the packed form, the files
// are extracted to a fresh directory under tmp/ and the scene loader (whose PathGuard refuses
// anything that escapes the scene's directory) loads it; only a bundle that loads is published,
// extracted scene first and packed bytes last, so a crash leaves no half-published bundle.
// Thread-safe: its state is the files, and concurrent uploads of one bundle publish the same
// bytes.
#pragma once

#include <spdlog/spdlog.h>

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"

namespace prism::coordinator {

class BundleStore {
 public:
  // `data_dir` must hold bundles/, scenes/ and tmp/; `library` must outlive the store.
  BundleStore(std::filesystem::path data_dir, std::uint64_t max_bundle_bytes,
              const spectral::SpectrumLibrary& library, std::shared_ptr<spdlog::logger> logger);

  // `bytes` is a packed bundle whose content hash must equal `claimed_hash` (when not empty).
  // RESOURCE_EXHAUSTED over max_bundle_bytes; INVALID_ARGUMENT for a malformed bundle, a hash
  // mismatch or a scene that does not load (the loader's message). Returns the content hash.
  absl::StatusOr<std::string> upload(const std::string& claimed_hash, std::string_view bytes);
  bool has(const std::string& hash) const;
  // The packed bundle; NOT_FOUND for an unknown hash.
  absl::StatusOr<std::string> bytes(const std::string& hash) const;
  // The path of the bundle's scene file inside it; NOT_FOUND for an unknown hash.
  absl::StatusOr<std::string> scene_path(const std::string& hash) const;
  // The checked scene of a stored bundle, loaded again (with or without substitutions).
  absl::StatusOr<scene::LoadedScene> load_scene(bool allow_unsupported, const std::string& hash,
                                                const std::string& scene_path) const;

 private:
  std::filesystem::path bundle_path(const std::string& hash) const;
  std::filesystem::path scene_dir(const std::string& hash) const;

  std::filesystem::path data_dir_;
  std::uint64_t max_bundle_bytes_;
  const spectral::SpectrumLibrary& library_;
  std::shared_ptr<spdlog::logger> logger_;
  std::atomic<std::uint64_t> temp_counter_{0};
};

}  // namespace prism::coordinator
