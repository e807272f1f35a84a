// Whole-file reads and all-or-nothing writes. An output written with write_file_atomic either
// appears complete under its final name or not at all: the bytes go to a temporary file in the
// same directory, are flushed to disk, and are renamed over the target. A failure removes the
// temporary and leaves any previous file untouched.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <span>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace prism::base {

// Reads a whole file. Refuses files larger than max_bytes with RESOURCE_EXHAUSTED, so untrusted
// paths cannot exhaust memory.
absl::StatusOr<std::string> read_file(const std::filesystem::path& path,
                                      std::uint64_t max_bytes = std::uint64_t{1} << 32);

// Writes bytes to path atomically (see above).
absl::Status write_file_atomic(const std::filesystem::path& path, std::span<const char> bytes);

// For libraries that can only write to a file name (OpenEXR, libpng): `writer` writes to the
// temporary path it is given, and the file is renamed into place only if it returns OK.
absl::Status write_via_temp(
    const std::filesystem::path& path,
    const std::function<absl::Status(const std::filesystem::path&)>& writer);

// Removes the temporaries write_file_atomic and write_via_temp leave in `dir` (not below it)
// when the process dies mid-write, ".<name>.tmp.<pid>.<n>"; only for a directory no other
// process writes to. Errors are ignored: a temporary left is litter, not a fault.
void remove_temporaries(const std::filesystem::path& dir);

// All of `size` bytes at `offset` of an open file, through short transfers and interruptions;
// INTERNAL naming `what` and the offset on an error (a read past the end is one).
absl::Status pwrite_all(int fd, const char* bytes, std::size_t size, std::uint64_t offset,
                        std::string_view what);
absl::Status pread_all(int fd, char* bytes, std::size_t size, std::uint64_t offset,
                       std::string_view what);

// A new read-write file in `dir` with no name (O_TMPFILE, else a unique name unlinked at once),
// so that it never outlives the process and a crash leaves nothing behind; the caller closes
// the descriptor. INTERNAL naming `what` and the directory when it cannot be made.
absl::StatusOr<int> make_anonymous_file(const std::filesystem::path& dir, std::string_view what);

// Creates `dir` and its parents when missing; INTERNAL naming the directory otherwise.
absl::Status make_directories(const std::filesystem::path& dir);

}  // namespace prism::base
