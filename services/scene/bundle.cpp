#include "services/scene/bundle.h"

#include <algorithm>
#include <charconv>
#include <cstring>
#include <map>
#include <string_view>
#include <system_error>
#include <utility>

#include "absl/container/flat_hash_set.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "services/base/atomic_file.h"
#include "services/base/check.h"
#include "services/base/little_endian.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/scene/path_guard.h"

namespace prism::scene {
namespace {

namespace fs = std::filesystem;

constexpr absl::string_view kMagic = "PRISMBDL";
constexpr std::uint32_t kFormatVersion = 1;
constexpr std::size_t kHashHexBytes = 64;
constexpr std::size_t kHeaderBytes = 8 + 4 + 4 + kHashHexBytes + 8;
constexpr absl::string_view kManifestFirstLine = "prism-bundle 1";

using base::append_le;

std::uint64_t read_le(absl::string_view bytes, std::size_t offset, int count) {
  return base::get_le(bytes.data() + offset, count);
}

bool is_lower_hex(absl::string_view s) {
  return s.size() == kHashHexBytes && std::all_of(s.begin(), s.end(), [](char c) {
           return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
         });
}

std::string_view to_std(absl::string_view s) {
  return std::string_view(s.data(), s.size());
}

absl::Status bad_bundle(absl::string_view message) {
  return absl::InvalidArgumentError(absl::StrCat("scene bundle: ", message));
}

absl::Status too_big(absl::string_view message) {
  return absl::ResourceExhaustedError(absl::StrCat("scene bundle: ", message));
}

absl::Status check_path_limit(absl::string_view path, const BundleLimits& limits) {
  if (path.size() > limits.max_path_bytes) {
    return too_big(absl::StrCat("path '", path.substr(0, 64), "...' is ", path.size(),
                                " bytes, over the limit of ", limits.max_path_bytes));
  }
  return absl::OkStatus();
}

// A file "a" and a file "a/b" cannot both be extracted.
absl::Status check_no_file_directory_clash(const std::vector<BundleEntry>& entries) {
  absl::flat_hash_set<absl::string_view> files;
  for (const BundleEntry& e : entries) files.insert(e.path);
  for (const BundleEntry& e : entries) {
    absl::string_view path = e.path;
    for (std::size_t slash = path.find('/'); slash != absl::string_view::npos;
         slash = path.find('/', slash + 1)) {
      if (files.contains(path.substr(0, slash))) {
        return bad_bundle(absl::StrCat("'", path.substr(0, slash),
                                       "' is both a file and the directory of '", path, "'"));
      }
    }
  }
  return absl::OkStatus();
}

// Parses the manifest text into entries without contents; checks syntax, paths, order and
// limits. Canonical form is checked by the caller by serialising again.
absl::Status parse_manifest(absl::string_view text, const BundleLimits& limits, Bundle& bundle) {
  if (text.empty() || text.back() != '\n') {
    return bad_bundle("manifest does not end with a newline");
  }
  text.remove_suffix(1);
  // Lines are visited lazily: a hostile manifest of empty lines must not become a huge vector.
  std::size_t lines = static_cast<std::size_t>(std::count(text.begin(), text.end(), '\n')) + 1;
  if (lines > 2 && lines - 2 > limits.max_files) {
    return too_big(absl::StrCat(lines - 2, " files, over the limit of ", limits.max_files));
  }
  std::uint64_t total = 0;
  std::size_t line_no = 0;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    ++line_no;
    if (line_no == 1) {
      if (line != kManifestFirstLine) {
        return bad_bundle(absl::StrCat("manifest does not start with '", kManifestFirstLine, "'"));
      }
      continue;
    }
    if (line_no == 2) {
      if (!absl::StartsWith(line, "scene ")) {
        return bad_bundle("manifest line 2 is not 'scene <path>'");
      }
      bundle.scene_path = std::string(line.substr(6));
      continue;
    }
    // "file " + 64 hex + " " + size + " " + path
    std::vector<absl::string_view> fields = absl::StrSplit(line, absl::MaxSplits(' ', 3));
    if (fields.size() != 4 || fields[0] != "file") {
      return bad_bundle(
          absl::StrCat("manifest line ", line_no, " is not 'file <sha256> <size> <path>'"));
    }
    if (!is_lower_hex(fields[1])) {
      return bad_bundle(absl::StrCat("manifest line ", line_no, " has a malformed SHA-256"));
    }
    std::uint64_t size = 0;
    auto [end, ec] = std::from_chars(fields[2].data(), fields[2].data() + fields[2].size(), size);
    if (ec != std::errc() || end != fields[2].data() + fields[2].size() || fields[2].empty()) {
      return bad_bundle(
          absl::StrCat("manifest line ", line_no, " has a malformed size '", fields[2], "'"));
    }
    absl::string_view path = fields[3];
    PRISM_RETURN_IF_ERROR(check_path_limit(path, limits));
    absl::Status plain = check_plain_relative_path(to_std(path));
    if (!plain.ok()) {
      return bad_bundle(absl::StrCat("manifest line ", line_no, ": ", plain.message()));
    }
    if (!bundle.entries.empty()) {
      const std::string& previous = bundle.entries.back().path;
      if (path == previous) return bad_bundle(absl::StrCat("duplicate path '", path, "'"));
      if (path < previous) {
        return bad_bundle(
            absl::StrCat("manifest is not sorted: '", path, "' after '", previous, "'"));
      }
    }
    if (size > limits.max_file_bytes) {
      return too_big(absl::StrCat("file '", path, "' is ", size, " bytes, over the limit of ",
                                  limits.max_file_bytes));
    }
    total += size;  // each term is at most max_file_bytes and there are at most max_files
    if (total > limits.max_total_bytes) {
      return too_big(
          absl::StrCat("files total more than ", limits.max_total_bytes, " bytes, over the limit"));
    }
    bundle.entries.push_back(BundleEntry{std::string(path), size, std::string(fields[1]), {}});
  }
  if (line_no < 2) return bad_bundle("manifest line 2 is not 'scene <path>'");
  if (bundle.find(bundle.scene_path) == nullptr) {
    return bad_bundle(absl::StrCat("scene file '", bundle.scene_path, "' is not in the bundle"));
  }
  return check_no_file_directory_clash(bundle.entries);
}

// Creates dir/<parent of path> one component at a time, refusing anything but real directories.
absl::Status make_parents(const fs::path& root, absl::string_view path) {
  std::vector<absl::string_view> parts = absl::StrSplit(path, '/');
  fs::path current = root;
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    current /= to_std(parts[i]);
    std::error_code ec;
    fs::file_status status = fs::symlink_status(current, ec);
    if (fs::exists(status)) {
      if (fs::is_symlink(status) || !fs::is_directory(status)) {
        return absl::FailedPreconditionError(
            absl::StrCat("cannot extract '", path, "': ", current.string(),
                         " exists and is not a directory (symbolic links are not followed)"));
      }
      continue;
    }
    if (!fs::create_directory(current, ec) && ec) {
      return absl::InternalError(
          absl::StrCat("cannot create directory ", current.string(), ": ", ec.message()));
    }
  }
  return absl::OkStatus();
}

}  // namespace

const BundleEntry* Bundle::find(std::string_view path) const {
  auto it = std::lower_bound(entries.begin(), entries.end(), path,
                             [](const BundleEntry& e, std::string_view p) { return e.path < p; });
  return it != entries.end() && it->path == path ? &*it : nullptr;
}

std::string canonical_manifest(const Bundle& bundle) {
  std::string text = absl::StrCat(kManifestFirstLine, "\nscene ", bundle.scene_path, "\n");
  for (const BundleEntry& e : bundle.entries) {
    absl::StrAppend(&text, "file ", e.sha256, " ", e.size, " ", e.path, "\n");
  }
  return text;
}

absl::StatusOr<Bundle> make_bundle(const fs::path& root_dir, std::string_view scene_relpath,
                                   std::span<const std::string> referenced_relpaths,
                                   const BundleLimits& limits) {
  PRISM_ASSIGN_OR_RETURN(PathGuard guard, PathGuard::create(root_dir));
  std::map<std::string, fs::path> files;  // normalised path -> real path; sorted, unique
  PRISM_ASSIGN_OR_RETURN(ResolvedReference scene, guard.resolve_reference(scene_relpath));
  files.emplace(scene.relative_path, scene.real_path);
  for (const std::string& reference : referenced_relpaths) {
    PRISM_ASSIGN_OR_RETURN(ResolvedReference resolved, guard.resolve_reference(reference));
    files.emplace(std::move(resolved.relative_path), std::move(resolved.real_path));
  }
  if (files.size() > limits.max_files) {
    return too_big(absl::StrCat(files.size(), " files, over the limit of ", limits.max_files));
  }
  Bundle bundle;
  bundle.scene_path = scene.relative_path;
  std::uint64_t total = 0;
  for (auto& [path, real] : files) {
    PRISM_RETURN_IF_ERROR(check_path_limit(path, limits));
    PRISM_ASSIGN_OR_RETURN(std::string contents, base::read_file(real, limits.max_file_bytes));
    total += contents.size();
    if (total > limits.max_total_bytes) {
      return too_big(
          absl::StrCat("files total more than ", limits.max_total_bytes, " bytes, over the limit"));
    }
    std::string hash = base::sha256_hex(contents);
    std::uint64_t size = contents.size();
    bundle.entries.push_back(BundleEntry{path, size, std::move(hash), std::move(contents)});
  }
  bundle.content_hash = base::sha256_hex(canonical_manifest(bundle));
  return bundle;
}

std::string pack(const Bundle& bundle) {
  PRISM_CHECK(bundle.content_hash.size() == kHashHexBytes);
  std::string manifest = canonical_manifest(bundle);
  std::uint64_t data_bytes = 0;
  for (const BundleEntry& e : bundle.entries) {
    PRISM_CHECK(e.contents.size() == e.size);
    data_bytes += e.size;
  }
  std::string blob;
  blob.reserve(kHeaderBytes + manifest.size() + data_bytes);
  blob.append(kMagic.data(), kMagic.size());
  append_le(blob, kFormatVersion, 4);
  append_le(blob, 0, 4);
  blob.append(bundle.content_hash);
  append_le(blob, manifest.size(), 8);
  blob.append(manifest);
  for (const BundleEntry& e : bundle.entries) blob.append(e.contents);
  return blob;
}

absl::StatusOr<UnpackedBundle> unpack(std::string_view blob_in, const BundleLimits& limits) {
  absl::string_view blob(blob_in.data(), blob_in.size());
  if (blob.size() < kHeaderBytes) {
    return bad_bundle(absl::StrCat("truncated: ", blob.size(), " bytes, shorter than the ",
                                   kHeaderBytes, "-byte header"));
  }
  if (blob.substr(0, kMagic.size()) != kMagic)
    return bad_bundle("not a Prism scene bundle (bad magic)");
  std::uint64_t version = read_le(blob, 8, 4);
  if (version != kFormatVersion) {
    return bad_bundle(absl::StrCat("unsupported format version ", version, " (this build reads ",
                                   kFormatVersion, ")"));
  }
  if (read_le(blob, 12, 4) != 0) return bad_bundle("unknown flags set in the header");
  absl::string_view claimed_hash = blob.substr(16, kHashHexBytes);
  if (!is_lower_hex(claimed_hash)) return bad_bundle("malformed content hash in the header");
  std::uint64_t manifest_bytes = read_le(blob, 80, 8);
  if (manifest_bytes > limits.max_manifest_bytes) {
    return too_big(absl::StrCat("manifest is ", manifest_bytes, " bytes, over the limit of ",
                                limits.max_manifest_bytes));
  }
  std::uint64_t remaining = blob.size() - kHeaderBytes;
  if (manifest_bytes > remaining) {
    return bad_bundle(absl::StrCat("truncated: the manifest is ", manifest_bytes,
                                   " bytes but only ", remaining, " follow the header"));
  }
  absl::string_view manifest = blob.substr(kHeaderBytes, manifest_bytes);
  // The hash is checked first so that corruption is reported as such; a blob crafted with a
  // matching hash still goes through every check below.
  std::string actual_hash = base::sha256_hex(to_std(manifest));
  if (actual_hash != claimed_hash) {
    return bad_bundle(absl::StrCat("content hash mismatch: the manifest hashes to ", actual_hash,
                                   " but the bundle claims ", claimed_hash));
  }
  UnpackedBundle bundle;
  PRISM_RETURN_IF_ERROR(parse_manifest(manifest, limits, bundle));
  if (canonical_manifest(bundle) != manifest)
    return bad_bundle("manifest is not in canonical form");
  bundle.content_hash = std::move(actual_hash);

  std::uint64_t data_bytes = 0;
  for (const BundleEntry& e : bundle.entries) data_bytes += e.size;
  std::uint64_t data_available = remaining - manifest_bytes;
  if (data_bytes > data_available) {
    return bad_bundle(absl::StrCat("truncated: the manifest lists ", data_bytes,
                                   " bytes of file data but only ", data_available, " remain"));
  }
  if (data_bytes < data_available) {
    return bad_bundle(
        absl::StrCat(data_available - data_bytes, " unexpected bytes after the last file"));
  }
  std::size_t offset = kHeaderBytes + manifest_bytes;
  for (BundleEntry& e : bundle.entries) {
    absl::string_view contents = blob.substr(offset, e.size);
    offset += e.size;
    if (base::sha256_hex(to_std(contents)) != e.sha256) {
      return bad_bundle(
          absl::StrCat("file '", e.path, "' does not match its SHA-256 (corrupted or tampered)"));
    }
    e.contents = std::string(contents);
  }
  return bundle;
}

absl::Status extract_to(const UnpackedBundle& bundle, const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    return absl::InternalError(
        absl::StrCat("cannot create directory ", dir.string(), ": ", ec.message()));
  }
  fs::path root = fs::canonical(dir, ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot resolve ", dir.string(), ": ", ec.message()));
  for (const BundleEntry& e : bundle.entries) {
    absl::Status plain = check_plain_relative_path(e.path);
    if (!plain.ok()) return bad_bundle(plain.message());
  }
  PRISM_RETURN_IF_ERROR(check_no_file_directory_clash(bundle.entries));
  for (const BundleEntry& e : bundle.entries) {
    PRISM_RETURN_IF_ERROR(make_parents(root, e.path));
    fs::path target = root / e.path;
    fs::file_status status = fs::symlink_status(target, ec);
    if (fs::exists(status) && !fs::is_regular_file(status)) {
      return absl::FailedPreconditionError(absl::StrCat(
          "cannot extract '", e.path, "': ", target.string(), " exists and is not a regular file"));
    }
    PRISM_RETURN_IF_ERROR(base::write_file_atomic(target, e.contents));
  }
  return absl::OkStatus();
}

}  // namespace prism::scene
