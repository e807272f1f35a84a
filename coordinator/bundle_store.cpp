#include "coordinator/bundle_store.h"

#include <algorithm>
#include <span>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "coordinator/resource_plan.h"
#include "services/base/atomic_file.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/scene/bundle.h"

namespace prism::coordinator {

namespace fs = std::filesystem;

BundleStore::BundleStore(fs::path data_dir, std::uint64_t max_bundle_bytes,
                         const spectral::SpectrumLibrary& library,
                         std::shared_ptr<spdlog::logger> logger)
    : data_dir_(std::move(data_dir)),
      max_bundle_bytes_(max_bundle_bytes),
      library_(library),
      logger_(std::move(logger)) {}

fs::path BundleStore::bundle_path(const std::string& hash) const {
  return data_dir_ / "bundles" / hash;
}

fs::path BundleStore::scene_dir(const std::string& hash) const {
  return data_dir_ / "scenes" / hash;
}

absl::StatusOr<std::string> BundleStore::upload(const std::string& claimed_hash,
                                                std::string_view bytes) {
  if (bytes.size() > max_bundle_bytes_) {
    return permanent_refusal(absl::ResourceExhaustedError(absl::StrCat(
        "bundle of ", bytes.size(), " bytes is over the limit of ", max_bundle_bytes_, " bytes")));
  }
  scene::BundleLimits limits;
  limits.max_total_bytes = std::min(limits.max_total_bytes, max_bundle_bytes_);
  limits.max_file_bytes = std::min(limits.max_file_bytes, max_bundle_bytes_);
  PRISM_ASSIGN_OR_RETURN(scene::UnpackedBundle bundle, scene::unpack(bytes, limits));
  const std::string hash = bundle.content_hash;
  if (!claimed_hash.empty() && claimed_hash != hash) {
    return absl::InvalidArgumentError(absl::StrCat("bundle hash mismatch: the upload claims ",
                                                   claimed_hash, " but its content hash is ",
                                                   hash));
  }
  if (has(hash)) return hash;

  const fs::path tmp = data_dir_ / "tmp" / absl::StrCat("bundle-", ++temp_counter_, "-", hash);
  std::error_code ec;
  fs::remove_all(tmp, ec);
  absl::Status extracted = scene::extract_to(bundle, tmp);
  if (!extracted.ok()) {
    fs::remove_all(tmp, ec);
    return extracted;
  }
  // The upload checks that the scene is well formed; whether its unsupported features may be
  // substituted is each job's choice (JobSpec.allow_unsupported), checked at submit.
  scene::LoadOptions load = scene::with_library_names(library_);
  load.allow_unsupported = true;
  absl::StatusOr<scene::LoadedScene> loaded = scene::load_scene(tmp / bundle.scene_path, load);
  if (!loaded.ok()) {
    fs::remove_all(tmp, ec);
    logger_->info("refused bundle {}: {}", hash, loaded.status().ToString());
    if (loaded.status().code() == absl::StatusCode::kResourceExhausted) return loaded.status();
    return absl::InvalidArgumentError(
        absl::StrCat("the bundle's scene does not load: ", loaded.status().message()));
  }
  // Publish: the extracted scene, its scene path, then the packed bundle (has()'s marker).
  const fs::path dest = scene_dir(hash);
  if (!fs::exists(dest)) {
    fs::rename(tmp, dest, ec);
    if (ec && !fs::exists(dest)) {
      return absl::InternalError(
          absl::StrCat("cannot move the extracted bundle to ", dest.string(), ": ", ec.message()));
    }
  }
  fs::remove_all(tmp, ec);
  const std::string scene_path = bundle.scene_path;
  PRISM_RETURN_IF_ERROR(
      base::write_file_atomic(bundle_path(hash) += ".scene", std::span<const char>(scene_path)));
  PRISM_RETURN_IF_ERROR(base::write_file_atomic(bundle_path(hash),
                                                std::span<const char>(bytes.data(), bytes.size())));
  logger_->info("stored bundle {} ({} bytes, scene {})", hash, bytes.size(), scene_path);
  return hash;
}

bool BundleStore::has(const std::string& hash) const {
  if (!base::is_sha256_hex(hash)) return false;
  std::error_code ec;
  return fs::is_regular_file(bundle_path(hash), ec);
}

absl::StatusOr<std::string> BundleStore::bytes(const std::string& hash) const {
  if (!has(hash)) {
    return absl::NotFoundError(absl::StrCat("no bundle ", hash, " on the coordinator"));
  }
  return base::read_file(bundle_path(hash));
}

absl::StatusOr<std::string> BundleStore::scene_path(const std::string& hash) const {
  if (!has(hash)) {
    return absl::NotFoundError(absl::StrCat("no bundle ", hash, " on the coordinator"));
  }
  return base::read_file(bundle_path(hash) += ".scene", 1 << 16);
}

absl::StatusOr<scene::LoadedScene> BundleStore::load_scene(bool allow_unsupported,
                                                           const std::string& hash,
                                                           const std::string& scene_path) const {
  scene::LoadOptions load = scene::with_library_names(library_);
  load.allow_unsupported = allow_unsupported;
  return scene::load_scene(scene_dir(hash) / scene_path, load);
}

}  // namespace prism::coordinator
