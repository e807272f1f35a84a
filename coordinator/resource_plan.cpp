#include "coordinator/resource_plan.h"

#include <sys/resource.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "coordinator/spectral_stream.h"
#include "services/image/tile.h"

namespace prism::coordinator {
namespace {

using u64 = std::uint64_t;

u64 pixels(int width, int height) {
  return u64(width) * u64(height);
}

// Saturating: a plan for an absurd job must stay comparable, not wrap.
u64 add(u64 a, u64 b) {
  return a > ~u64{0} - b ? ~u64{0} : a + b;
}
u64 mul(u64 a, u64 b) {
  return b != 0 && a > ~u64{0} / b ? ~u64{0} : a * b;
}

u64 sum(const std::vector<ResourceItem>& items) {
  u64 total = 0;
  for (const ResourceItem& item : items) total = add(total, item.bytes);
  return total;
}

void push(std::vector<ResourceItem>& items, std::string what, u64 bytes) {
  if (bytes > 0) items.push_back({std::move(what), bytes});
}

// The prepass's whole-image state (prepass_run.h, prepass.h): the accumulated moments, the
// filter's output and its leave-one-out copy, the tables with their mixture weights, the
// guides, and the final pass's tables. 10 floats per bin and 16 per pixel: measured, a 512x512
// 64-bin two-pass prepass peaked 561 MiB above the render without it (9 per bin), rounded up.
u64 prepass_bytes(u64 image_pixels, int bins) {
  return mul(image_pixels, u64(10 * bins + 16) * sizeof(float));
}

// The target-error tracker (target_error.h) keeps every unfinished tile's merged sums.
u64 target_error_bytes(u64 image_pixels, const job::RenderOptions& render) {
  return mul(image_pixels, tile_result_bytes_per_pixel(render, false));
}

// OpenEXR's line buffers: twice the threads, each a block of up to 32 rows (PIZ) of every
// channel, raw and compressed.
u64 exr_buffer_bytes(int width, int bins, int threads) {
  return mul(mul(u64(2 * std::max(1, threads)) * 32 * 2, u64(width)), u64(bins + 3) * 4);
}

std::string summary(const std::vector<ResourceItem>& items) {
  std::vector<ResourceItem> sorted = items;
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const ResourceItem& a, const ResourceItem& b) { return a.bytes > b.bytes; });
  std::string out;
  for (std::size_t i = 0; i < sorted.size() && i < 4; ++i) {
    absl::StrAppend(&out, i == 0 ? "" : ", ", sorted[i].what, " ", format_bytes(sorted[i].bytes));
  }
  if (sorted.size() > 4) absl::StrAppend(&out, ", ...");
  return out;
}

}  // namespace

u64 ResourcePlan::memory_bytes() const {
  return sum(memory);
}
u64 ResourcePlan::disk_bytes() const {
  return sum(disk);
}

u64 tile_result_bytes_per_pixel(const job::RenderOptions& render, bool prepass, bool encoded) {
  const u64 bins = u64(render.bins);
  const u64 sum = encoded ? 4 : 8;  // one value of a buffer of sums
  u64 bytes = 2 * sum * bins + 8;   // sums and squares, count
  bytes += 6 * sum;                 // RGB sums and squares
  if (render.integrator == job::IntegratorKind::kGradient) {
    bytes += 6 * sum * bins + 8;  // gradients, their squares and the half-sample buffers
  }
  if (render.splats_differentials()) bytes += sum * bins + 3 * sum;
  if (render.gathers()) bytes += 8 * u64(image::kOffsetValues);
  if (prepass) bytes += 20;  // depth, normal, albedo
  return bytes + 8 * 8;      // trace counters
}

ResourcePlan plan_local_render(const LocalRenderShape& s) {
  ResourcePlan plan;
  const u64 n = pixels(s.width, s.height);
  const u64 bins = u64(s.render.bins);
  if (s.spooled) {
    // The rows of tiles a SpectralStream holds (a spool holds fewer: a row read back and a tile).
    push(plan.memory, "streamed bins' bands",
         mul(mul(u64(s.tile_size), u64(s.width)), bins * 4 * u64(kStreamBandsHeld)));
    push(plan.disk, "spooled bins", mul(n, bins * 4));
    push(plan.memory, "RGB", mul(n, 12));
  } else {
    push(plan.memory, "spectral image", mul(n, bins * 4));
    push(plan.memory, "RGB and standard errors", mul(n, 24));
  }
  if (s.keep_primal_and_gradients)
    push(plan.memory, "primal and gradient images", mul(n, bins * 8));
  if (s.render.splats_differentials() || s.render.gathers()) {
    push(plan.memory, "filtered image", mul(n, bins * 4 + 12));
  }
  if (s.render.gathers()) {
    // Its inputs (counts, offsets, depth, normals) and the filter's working copy of the bins.
    push(plan.memory, "gathering", mul(n, 8 + 8 * u64(image::kOffsetValues) + 16 + bins * 4));
  }
  if (s.prepass) push(plan.memory, "prepass state", prepass_bytes(n, s.render.bins));
  if (s.target_error) push(plan.memory, "target-error sums", target_error_bytes(n, s.render));
  const u64 tile_bytes = mul(s.largest_tile_area, tile_result_bytes_per_pixel(s.render, s.prepass));
  push(plan.memory, "tiles in flight", mul(tile_bytes, u64(2 * std::max(1, s.threads))));
  push(plan.memory, "output buffers",
       add(mul(n, 3), exr_buffer_bytes(s.width, s.render.bins, s.threads)));
  return plan;
}

ResourcePlan plan_farm_job(const job::JobParameters& p) {
  ResourcePlan plan;
  const u64 n = pixels(p.width, p.height);
  const u64 bins = u64(p.render.bins);
  const bool prepass = p.prepass.has_value();
  push(plan.memory, "RGB image", mul(n, 12));
  if (prepass) push(plan.memory, "prepass state", prepass_bytes(n, p.render.bins));
  if (p.target_error.has_value()) {
    push(plan.memory, "target-error sums", target_error_bytes(n, p.render));
    // The convergence plot's per-pixel sums of tiles still going on (convergence.h).
    push(plan.memory, "convergence sums", mul(n, 24));
  }
  // Finalising: a row of tiles read back and finalised, the PNG, and per kind of output its
  // whole-image RGB (gradient: primal and gradient; splatting: filtered) or, for gathering,
  // the whole spectral image, its filtered copy and the gathering inputs.
  u64 finalising = add(mul(mul(u64(p.tile_size), u64(p.width)), bins * 4 * 2), mul(n, 3));
  if (p.outputs.primal_and_gradients) finalising = add(finalising, mul(n, 24));
  if (p.render.splats_differentials()) finalising = add(finalising, mul(n, 12));
  if (p.render.gathers()) {
    finalising = add(finalising, mul(n, bins * 8 + 12 + 8 + 8 * u64(image::kOffsetValues) + 16));
  }
  push(plan.memory, "finalising", finalising);

  // Each final-pass tile once: its range results are released as it is stored (result_pack.h).
  const u64 per_pixel = tile_result_bytes_per_pixel(p.render, false, true);
  push(plan.disk, "finished tiles", mul(n, per_pixel));
  // Until then a tile's range results wait for its last range, each a whole tile's worth.
  // Workers take a job's tasks tile by tile, so about two tiles are in flight at a time.
  const u64 spp =
      p.target_error.has_value() ? std::max<u64>(p.target_error->max_spp, p.spp) : p.spp;
  const u64 ranges =
      p.samples_per_task == 0 ? 1 : (spp + p.samples_per_task - 1) / p.samples_per_task;
  if (ranges > 1) {
    const u64 tile_area = std::min(n, mul(u64(p.tile_size), u64(p.tile_size)));
    const u64 tiles_in_flight = std::min<u64>(2, (n + tile_area - 1) / std::max<u64>(1, tile_area));
    push(plan.disk, "range results of the tiles in flight",
         mul(mul(tiles_in_flight * tile_area, per_pixel), ranges));
  }
  u64 outputs = add(mul(n, (bins + 3) * 4), mul(n, 12 + 3));  // spectral EXR, RGB EXR, PNG
  if (p.outputs.primal_and_gradients) outputs = add(outputs, mul(n, (bins + 3) * 8));
  if (p.render.splats_differentials() || p.render.gathers()) {
    outputs = add(outputs, mul(n, (bins + 3) * 4 + 3));
  }
  push(plan.disk, "outputs", outputs);
  return plan;
}

MemoryBudget machine_memory_budget() {
  MemoryBudget budget;
  const long pages = ::sysconf(_SC_PHYS_PAGES);
  const long page = ::sysconf(_SC_PAGESIZE);
  budget.bytes = pages > 0 && page > 0 ? u64(pages) * u64(page) : ~u64{0};
  budget.source = "physical memory";
  auto consider = [&](u64 bytes, const char* source, bool address_space) {
    if (bytes < budget.bytes) budget = {bytes, source, address_space};
  };
  rlimit limit{};
  if (::getrlimit(RLIMIT_AS, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY) {
    consider(u64(limit.rlim_cur), "RLIMIT_AS", true);
  }
  if (::getrlimit(RLIMIT_DATA, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY) {
    consider(u64(limit.rlim_cur), "RLIMIT_DATA", false);
  }
  // cgroup v2: the process's group's memory.max ("max" when unlimited).
  std::ifstream cgroup_file("/proc/self/cgroup");
  std::string line;
  while (std::getline(cgroup_file, line)) {
    if (line.rfind("0::", 0) != 0) continue;
    std::ifstream max_file("/sys/fs/cgroup" + line.substr(3) + "/memory.max");
    std::string value;
    if (max_file >> value && value != "max") {
      u64 bytes = 0;
      auto [ptr, ec] = std::from_chars(value.data(), value.data() + value.size(), bytes);
      if (ec == std::errc() && ptr == value.data() + value.size()) {
        consider(bytes, "cgroup memory.max", false);
      }
    }
  }
  return budget;
}

u64 memory_in_use(bool address_space) {
  std::ifstream statm("/proc/self/statm");
  u64 size = 0, resident = 0;
  const long page = ::sysconf(_SC_PAGESIZE);
  if (page <= 0 || !(statm >> size >> resident)) return 0;
  return (address_space ? size : resident) * u64(page);
}

absl::StatusOr<u64> free_disk_bytes(const std::filesystem::path& dir) {
  struct statvfs fs {};
  if (::statvfs(dir.c_str(), &fs) != 0) {
    return absl::InternalError(absl::StrCat("cannot read the free space of ", dir.string()));
  }
  return mul(u64(fs.f_bavail), u64(fs.f_frsize));
}

u64 directory_bytes(const std::filesystem::path& dir) {
  u64 bytes = 0;
  std::error_code ec;
  for (auto it = std::filesystem::recursive_directory_iterator(dir, ec);
       !ec && it != std::filesystem::recursive_directory_iterator(); it.increment(ec)) {
    std::error_code size_ec;
    if (it->is_regular_file(size_ec)) {
      const u64 size = it->file_size(size_ec);
      if (!size_ec) bytes += size;
    }
  }
  return bytes;
}

std::string format_bytes(u64 bytes) {
  static constexpr const char* kUnits[] = {"B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
  double value = double(bytes);
  int unit = 0;
  while (value >= 1024.0 && unit < 6) {
    value /= 1024.0;
    ++unit;
  }
  if (unit == 0) return absl::StrCat(bytes, " B");
  return absl::StrFormat(value < 10.0 ? "%.1f %s" : "%.0f %s", value, kUnits[unit]);
}

absl::StatusOr<u64> parse_bytes(std::string_view text) {
  auto invalid = [&] {
    return absl::InvalidArgumentError(absl::StrCat(
        "'", std::string(text), "' is not a byte count: want e.g. 1073741824, 512M, 12G or 1.5T"));
  };
  std::size_t digits = 0;
  while (digits < text.size() &&
         (std::isdigit(static_cast<unsigned char>(text[digits])) || text[digits] == '.')) {
    ++digits;
  }
  if (digits == 0) return invalid();
  double number = 0;
  auto [ptr, ec] = std::from_chars(text.data(), text.data() + digits, number);
  if (ec != std::errc() || ptr != text.data() + digits) return invalid();
  std::string_view suffix = text.substr(digits);
  double scale = 1;
  if (!suffix.empty()) {
    const std::string_view units = "KMGT";
    const std::size_t k = units.find(static_cast<char>(std::toupper(suffix[0])));
    if (k == std::string_view::npos) return invalid();
    scale = std::ldexp(1.0, 10 * int(k + 1));
    suffix.remove_prefix(1);
    if (suffix != "" && suffix != "B" && suffix != "iB") return invalid();
  }
  const double bytes = std::floor(number * scale);
  if (!(bytes >= 1) || bytes > std::ldexp(1.0, 62)) {
    return absl::InvalidArgumentError(
        absl::StrCat("byte count '", std::string(text), "' is out of range: want 1 byte to 4 EiB"));
  }
  return u64(bytes);
}

absl::Status check_memory(const std::string& job, const ResourcePlan& plan, u64 in_use,
                          u64 available, const std::string& source, const std::string& advice) {
  const u64 need = plan.memory_bytes();
  if (add(need, in_use) <= available) return absl::OkStatus();
  return absl::ResourceExhaustedError(
      absl::StrCat(job, " needs about ", format_bytes(need), " of memory (", summary(plan.memory),
                   ") besides the ", format_bytes(in_use), " in use, more than the ",
                   format_bytes(available), " allowed (", source, "); ", advice));
}

absl::Status check_disk(const std::string& job, const ResourcePlan& plan, u64 available,
                        const std::string& source, const std::string& advice) {
  const u64 need = plan.disk_bytes();
  if (need <= available) return absl::OkStatus();
  return absl::ResourceExhaustedError(absl::StrCat(
      job, " needs about ", format_bytes(need), " of disk (", summary(plan.disk),
      "), more than the ", format_bytes(available), " available (", source, "); ", advice));
}

namespace {
constexpr char kPermanentRefusal[] = "type.prism.dev/permanent-refusal";
}  // namespace

absl::Status permanent_refusal(absl::Status status) {
  status.SetPayload(kPermanentRefusal, absl::Cord("1"));
  return status;
}

bool is_permanent_refusal(const absl::Status& status) {
  return status.GetPayload(kPermanentRefusal).has_value();
}

}  // namespace prism::coordinator
