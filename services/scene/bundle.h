// Scene bundles: a scene file plus every asset it references, named by a content hash, so a job
// can ship its scene once and workers can fetch it by hash.
//
// A bundle holds entries {path, size, sha256, contents}, sorted by path (bytewise) with no
// duplicates; every path is in the normalised relative form of path_guard.h, exactly as the
// scene names the file, and `scene_path` is one of them. Its content hash is the SHA-256 (lower
// case hex) of the canonical manifest text:
//
//   prism-bundle 1\n
//   scene <scene path>\n
//   file <sha256 hex> <size in decimal, no leading zeros> <path>\n     (one per entry, sorted)
//
// Since it names files only by relative path, the hash does not depend on where the scene lives
// or on the order in which its files were listed; since each line carries the file's SHA-256,
// it covers every byte of every file.
//
// Packed form (format version 1), integers little-endian:
//
//   offset  0   8 bytes   magic "PRISMBDL"
//           8   uint32    format version, 1
//          12   uint32    flags, 0
//          16   64 bytes  content hash, lower case hex
//          80   uint64    manifest length M
//          88   M bytes   canonical manifest text
//        88+M             file contents, in manifest order, each exactly its listed size,
//                         and nothing after the last one
//
// unpack() trusts nothing in a blob: it checks the magic, version, flags, every length against
// the bytes that remain, the manifest's syntax, canonical form, sort order and uniqueness, every
// path (plain, not both a file and a directory), the BundleLimits, the content hash, and every
// file's SHA-256. Malformed or tampered blobs are INVALID_ARGUMENT and limits RESOURCE_EXHAUSTED,
// each message saying what was wrong.
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace prism::scene {

struct BundleLimits {
  std::uint64_t max_files = 10'000;
  std::uint64_t max_file_bytes = std::uint64_t{1} << 30;   // 1 GiB
  std::uint64_t max_total_bytes = std::uint64_t{4} << 30;  // 4 GiB, all files together
  std::uint64_t max_path_bytes = 1024;
  std::uint64_t max_manifest_bytes = std::uint64_t{16} << 20;  // 16 MiB
};

struct BundleEntry {
  std::string path;        // normalised, relative to the scene root
  std::uint64_t size = 0;  // == contents.size()
  std::string sha256;      // of contents, lower case hex
  std::string contents;
};

struct Bundle {
  std::string scene_path;            // the path of the entry holding the scene file
  std::vector<BundleEntry> entries;  // sorted by path, unique
  std::string content_hash;          // sha256_hex(canonical_manifest(*this))

  // The entry with this normalised path, or nullptr.
  const BundleEntry* find(std::string_view path) const;
};

// What unpack() returns: a Bundle whose every field has been checked against the blob.
using UnpackedBundle = Bundle;

// The manifest text described above, for the bundle's entries and scene path.
std::string canonical_manifest(const Bundle& bundle);

// Reads the scene file and every referenced file under `root_dir` into a bundle. Paths are
// references relative to root_dir as PathGuard accepts them; they are confined to root_dir,
// normalised, de-duplicated and sorted, and the scene file is always included. Errors are those
// of PathGuard::resolve, file reads, and RESOURCE_EXHAUSTED for the limits.
absl::StatusOr<Bundle> make_bundle(const std::filesystem::path& root_dir,
                                   std::string_view scene_relpath,
                                   std::span<const std::string> referenced_relpaths,
                                   const BundleLimits& limits = {});

// Serialises a bundle in the packed form above. The bundle must be consistent (as make_bundle
// and unpack produce it); sizes that disagree with contents are a bug and abort.
std::string pack(const Bundle& bundle);

// Parses and fully validates a packed bundle (see above).
absl::StatusOr<UnpackedBundle> unpack(std::string_view blob, const BundleLimits& limits = {});

// Writes every entry to dir/<path>, creating dir and subdirectories as needed; each file is
// written atomically. Paths are checked again, and an existing symbolic link or non-directory
// on the way to a file is refused, so nothing is written outside dir. Files already in dir that
// the bundle does not name are left alone.
absl::Status extract_to(const UnpackedBundle& bundle, const std::filesystem::path& dir);

}  // namespace prism::scene
