// Admission control: what a job will hold in memory and on disk, planned from its parameters
// before anything is allocated, checked against what the machine (or the operator) allows. A
// job that does not fit is refused at once with the numbers (RESOURCE_EXHAUSTED), instead of
// dying of std::bad_alloc hours later or filling the disk: `prism render` checks its plan in
// LocalRender::create, the coordinator at submit against the sum of its unfinished jobs.
//
// A plan lists the buffers that grow with the image, each named, in bytes, as the code that
// allocates them sizes them (the spectral image is width x height x bins float32, a tile
// result's sums are float64, ...). Allocations that do not grow with the image (the scene, its
// BVH, the libraries) are not in the plan: the caller adds the memory already in use when it
// checks. A plan is an upper bound of what is held at once, not a measurement;
// docs/benchmarks.md compares it with measured peaks.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "services/job/job_parameters.h"

namespace prism::coordinator {

struct ResourceItem {
  std::string what;
  std::uint64_t bytes = 0;
};

struct ResourcePlan {
  std::vector<ResourceItem> memory;  // held at the same time at the peak
  std::vector<ResourceItem> disk;    // on disk at the peak
  std::uint64_t memory_bytes() const;
  std::uint64_t disk_bytes() const;
};

// The bytes of one pixel of a merged tile result with the job's options: sums, squares and
// counts, plus gradients, RGB, filtered sums, offsets and guides when the job makes them; in
// memory (doubles), or as the tile codec stores them (`encoded`: float32 sums; a sparse
// encoding's left-out blocks are not counted off).
std::uint64_t tile_result_bytes_per_pixel(const job::RenderOptions& render, bool prepass,
                                          bool encoded = false);

// What `prism render` holds for a job: the finished images, the prepass's and the target
// error's whole-image state, gathering's inputs, the tiles in flight (2 per thread, each
// `largest_tile_area` pixels) and the output writers' buffers.
struct LocalRenderShape {
  int width = 0;
  int height = 0;
  job::RenderOptions render;
  bool prepass = false;
  bool target_error = false;
  bool keep_primal_and_gradients = false;
  int threads = 1;
  std::uint64_t largest_tile_area = 0;
  // The bins are not held as a whole image: a SpectralStream writes them into the spectral EXR
  // while rendering (a few rows of tiles in memory), or a SpectralSpool keeps them on disk.
  bool spooled = false;
  int tile_size = 32;
};
ResourcePlan plan_local_render(const LocalRenderShape& shape);

// What the coordinator holds for one job (memory: its RGB image, prepass and target-error
// state, and what finalising adds) and writes for it (disk: the finished tiles and the outputs).
ResourcePlan plan_farm_job(const job::JobParameters& params);

// How much memory this process may use, and why: the smallest of the physical memory, the
// address-space and data-segment limits (RLIMIT_AS, RLIMIT_DATA) and the cgroup's memory.max.
struct MemoryBudget {
  std::uint64_t bytes = 0;
  std::string source;  // "physical memory", "RLIMIT_AS", "RLIMIT_DATA", "cgroup memory.max", ...
  // The limit counts address space (RLIMIT_AS): compare with the virtual size, not the RSS.
  bool address_space = false;
};
MemoryBudget machine_memory_budget();
// What this process holds now: its virtual size when `address_space`, else its resident set.
std::uint64_t memory_in_use(bool address_space);

// Free bytes for an unprivileged writer on the filesystem holding `dir`; INTERNAL naming the
// directory when statvfs fails.
absl::StatusOr<std::uint64_t> free_disk_bytes(const std::filesystem::path& dir);
// The bytes of the regular files under `dir`, at any depth; 0 when it does not exist (what
// cannot be read counts nothing).
std::uint64_t directory_bytes(const std::filesystem::path& dir);

// "17.2 GiB", "320 MiB", "12 KiB", "512 B".
std::string format_bytes(std::uint64_t bytes);
// A byte count with an optional binary suffix: "1073741824", "512M", "12G", "1.5T" (K, M, G, T,
// optionally followed by "iB" or "B"). INVALID_ARGUMENT naming the text otherwise, or when it is
// zero or over 2^62.
absl::StatusOr<std::uint64_t> parse_bytes(std::string_view text);

// RESOURCE_EXHAUSTED when `in_use` + the plan's memory exceeds `available`, with the plan's
// largest items, e.g. "rendering 8192x8192 with 63 bins needs about 17.9 GiB of memory
// (spectral image 15.8 GiB, RGB and standard errors 1.5 GiB, ...) besides the 40 MiB in use,
// more than the 15.6 GiB allowed (RLIMIT_AS); <advice>".
// A RESOURCE_EXHAUSTED refusal that waiting cannot cure (a job over what the coordinator holds
// even with nothing else to do, a bundle over the size limit), marked with a status payload so
// that the HTTP API answers 413 instead of 429, which clients and proxies retry.
absl::Status permanent_refusal(absl::Status status);
bool is_permanent_refusal(const absl::Status& status);

absl::Status check_memory(const std::string& job, const ResourcePlan& plan, std::uint64_t in_use,
                          std::uint64_t available, const std::string& source,
                          const std::string& advice);
// The same for the plan's disk bytes against `available` bytes (of `source`).
absl::Status check_disk(const std::string& job, const ResourcePlan& plan, std::uint64_t available,
                        const std::string& source, const std::string& advice);

}  // namespace prism::coordinator
