#include "worker/daemon/bundle_cache.h"

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "services/base/sha256.h"
#include "services/base/status.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

absl::Status check_hash(std::string_view hash) {
  if (!base::is_sha256_hex(hash)) {
    return absl::InvalidArgumentError(
        absl::StrCat("bundle hash '", std::string(hash), "' is not 64 lower case hex digits"));
  }
  return absl::OkStatus();
}

absl::Status fs_error(const std::string& what, const fs::path& path, const std::error_code& ec) {
  return absl::InternalError(absl::StrCat(what, " ", path.string(), ": ", ec.message()));
}

// A name no other worker process or thread on this cache uses.
std::string temp_name(std::string_view hash) {
  static std::atomic<std::uint64_t> counter{0};
  const auto now = std::chrono::steady_clock::now().time_since_epoch().count();
  return absl::StrCat(".tmp-", std::string(hash.substr(0, 16)), "-", ::getpid(), "-", now, "-",
                      counter.fetch_add(1));
}

}  // namespace

absl::StatusOr<std::optional<fs::path>> BundleCache::find(std::string_view hash) const {
  PRISM_RETURN_IF_ERROR(check_hash(hash));
  const fs::path path = dir_ / std::string(hash);
  std::error_code ec;
  if (fs::is_directory(path, ec)) return std::optional<fs::path>(path);
  return std::optional<fs::path>();
}

absl::StatusOr<fs::path> BundleCache::install(std::string_view hash, std::string_view blob) {
  PRISM_RETURN_IF_ERROR(check_hash(hash));
  PRISM_ASSIGN_OR_RETURN(std::optional<fs::path> cached, find(hash));
  if (cached.has_value()) return *cached;

  absl::StatusOr<scene::UnpackedBundle> bundle = scene::unpack(blob, limits_);
  if (!bundle.ok()) {
    return absl::Status(bundle.status().code(), absl::StrCat("bundle ", std::string(hash), ": ",
                                                             bundle.status().message()));
  }
  if (bundle->content_hash != hash) {
    return absl::InvalidArgumentError(absl::StrCat("bundle asked for as ", std::string(hash),
                                                   " has content hash ", bundle->content_hash));
  }

  std::error_code ec;
  fs::create_directories(dir_, ec);
  if (ec) return fs_error("cannot create the bundle cache", dir_, ec);
  const fs::path temp = dir_ / temp_name(hash);
  const fs::path target = dir_ / std::string(hash);
  absl::Status extracted = scene::extract_to(*bundle, temp);
  if (extracted.ok()) {
    fs::rename(temp, target, ec);
    // Another worker sharing the cache may have installed the same bundle first: its copy is
    // as good as ours (same hash, same bytes).
    if (ec && fs::is_directory(target)) ec.clear();
    if (ec) extracted = fs_error("cannot move the bundle into place at", target, ec);
  }
  std::error_code ignored;
  fs::remove_all(temp, ignored);
  PRISM_RETURN_IF_ERROR(extracted);
  return target;
}

}  // namespace prism::worker
