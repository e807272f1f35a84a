#include "client/bench_command.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <map>
#include <set>
#include <thread>

#include "absl/algorithm/container.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_replace.h"
#include "absl/strings/str_split.h"
#include "client/compare_command.h"
#include "client/evaluation.h"
#include "client/render_command.h"
#include "coordinator/local_render.h"
#include "services/base/atomic_file.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"
#include "services/job/job_spec.h"

extern char** environ;

namespace prism::client {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

constexpr std::uint64_t kReferenceSeed = 1000003;
constexpr std::uint64_t kCalibrationSeed = 999;
constexpr std::uint64_t kMaxReferenceSpp = std::uint64_t{1} << 20;

// A CSV field: quoted when it holds a comma, a quote or a line break.
std::string csv_field(const std::string& text) {
  if (text.find_first_of(",\"\n") == std::string::npos) return text;
  std::string out = "\"";
  for (char c : text) {
    if (c == '"') out.push_back('"');
    out.push_back(c);
  }
  out.push_back('"');
  return out;
}

// A gnuplot single-quoted string ('' stands for one quote).
std::string gnuplot_string(const std::string& text) {
  std::string out = "'";
  for (char c : text) {
    if (c == '\'') out.push_back('\'');
    out.push_back(c);
  }
  out.push_back('\'');
  return out;
}

// Tics for a log axis over [lo, hi] (0 < lo <= hi): the 1-2-5 values of each decade inside it;
// every integer multiple of a decade where those are fewer than three, and whole decades where
// they are more than twelve. gnuplot's own log tics sit at whole decades only, so a range inside
// one decade would show no number at all.
std::string log_tics(double lo, double hi) {
  auto tics_of = [&](std::initializer_list<int> mantissas) {
    std::vector<double> tics;
    for (int d = int(std::floor(std::log10(lo))); d <= int(std::ceil(std::log10(hi))); ++d) {
      for (int m : mantissas) {
        const double v = m * std::pow(10.0, d);
        if (v >= lo && v <= hi) tics.push_back(v);
      }
    }
    return tics;
  };
  std::vector<double> tics = tics_of({1, 2, 5});
  if (tics.size() < 3) tics = tics_of({1, 2, 3, 4, 5, 6, 7, 8, 9});
  if (tics.size() > 12) tics = tics_of({1});
  std::string out = "(";
  for (std::size_t i = 0; i < tics.size(); ++i) {
    absl::StrAppend(&out, i ? ", " : "", absl::StrFormat("%.6g", tics[i]));
  }
  return absl::StrCat(out, ")");
}

std::string number(double v) {
  return absl::StrFormat("%.6g", v);
}

// Means over seeds of one (scene, region, method, budget).
struct Cell {
  std::uint64_t spp = 0;
  double seconds = 0, mse = 0, rel_mse = 0, ssim = 0;
  // The seeds' lowest and highest relMSE: their ratio is how far two renders of one method
  // apart can land, the noise a comparison of means sits in.
  double rel_mse_low = 0, rel_mse_high = 0;
  int count = 0;
  std::string ran;  // the method that ran, when it is not the method's name (auto's choice)
};

// Keys in the order they first appear.
template <typename T>
void remember(std::vector<T>& order, const T& key) {
  if (std::find(order.begin(), order.end(), key) == order.end()) order.push_back(key);
}

struct Grouped {
  std::vector<std::string> scenes, regions, methods, budgets;
  std::map<std::tuple<std::string, std::string, std::string, std::string>, Cell> cells;

  const Cell* find(const std::string& scene, const std::string& region, const std::string& method,
                   const std::string& budget) const {
    auto it = cells.find({scene, region, method, budget});
    return it == cells.end() ? nullptr : &it->second;
  }
  // The method's curve in (scene, region): one point per budget.
  std::vector<evaluation::ConvergencePoint> curve(const std::string& scene,
                                                  const std::string& region,
                                                  const std::string& method) const {
    std::vector<evaluation::ConvergencePoint> points;
    for (const std::string& b : budgets) {
      if (const Cell* c = find(scene, region, method, b)) {
        points.push_back({c->spp, c->seconds, c->rel_mse});
      }
    }
    return points;
  }
};

Grouped group(const std::vector<BenchRow>& rows) {
  Grouped g;
  for (const BenchRow& r : rows) {
    remember(g.scenes, r.scene);
    remember(g.regions, r.region);
    remember(g.methods, r.method);
    remember(g.budgets, r.budget);
    Cell& c = g.cells[{r.scene, r.region, r.method, r.budget}];
    c.spp = r.spp;
    // What ran for each seed, when it is not the method's name (auto's choices).
    if (!r.ran.empty() && r.ran != r.method &&
        !absl::c_linear_search(absl::StrSplit(c.ran, ", "), r.ran)) {
      c.ran = c.ran.empty() ? r.ran : absl::StrCat(c.ran, ", ", r.ran);
    }
    c.seconds += r.seconds;
    c.mse += r.metrics.mse;
    c.rel_mse += r.metrics.rel_mse;
    c.rel_mse_low = c.count == 0 ? r.metrics.rel_mse : std::min(c.rel_mse_low, r.metrics.rel_mse);
    c.rel_mse_high = c.count == 0 ? r.metrics.rel_mse : std::max(c.rel_mse_high, r.metrics.rel_mse);
    c.ssim += r.metrics.ssim;
    ++c.count;
  }
  for (auto& [key, c] : g.cells) {
    c.seconds /= c.count;
    c.mse /= c.count;
    c.rel_mse /= c.count;
    c.ssim /= c.count;
  }
  return g;
}

absl::StatusOr<double> parse_positive(const std::string& text, const std::string& what) {
  double value = 0;
  auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(value) ||
      !(value > 0)) {
    return absl::InvalidArgumentError(
        absl::StrCat(what, ": '", text, "' is not a positive number"));
  }
  return value;
}

// A method's render options on top of the bench's shared ones.
absl::StatusOr<RenderCommandOptions> method_options(const std::string& method,
                                                    const RenderCommandOptions& base) {
  RenderCommandOptions o = base;
  o.prepass = false;
  if (method == "uniform") {
    o.integrator = "uniform";
  } else if (method == "hero") {
    o.integrator = "hero";
  } else if (method == "hero+prepass") {
    o.integrator = "hero";
    o.prepass = true;
  } else if (method == "gradient") {
    o.integrator = "gradient";
  } else if (method == "light") {
    o.integrator = "light";
  } else if (method == "hero+caustics") {
    o.integrator = "hero";
    o.caustics = "light";
  } else if (method == "light+splat") {
    o.integrator = "light";
    o.splat_width = job::kDefaultSplatWidthNm;
  } else if (method == "hero+caustics+splat") {
    o.integrator = "hero";
    o.caustics = "light";
    o.splat_width = job::kDefaultSplatWidthNm;
  } else if (method == "hero+gather") {
    o.integrator = "hero";
    o.gather_width = job::kDefaultSplatWidthNm;
  } else if (method == "auto") {
    o.integrator = "auto";
    o.prepass.reset();
  } else {
    return absl::InvalidArgumentError(absl::StrCat("--methods: unknown method '", method,
                                                   "' (choose from uniform, hero, hero+prepass, "
                                                   "gradient, light, hero+caustics, light+splat, "
                                                   "hero+caustics+splat, hero+gather, auto)"));
  }
  return o;
}

struct Timed {
  coordinator::LocalRenderResult result;
  double wall = 0, cpu = 0;
  std::string ran;  // the method that ran (auto's choice)
  double on(const std::string& clock) const { return clock == "cpu" ? cpu : wall; }
};

// One render of the method: its pilot (τ), prepass, final pass and reconstruction, timed.
absl::StatusOr<Timed> timed_method(worker::EmbreeDevice& device,
                                   const evaluation::BenchScene& scene,
                                   const RenderCommandOptions& options) {
  const double cpu_start = evaluation::process_cpu_seconds();
  PRISM_ASSIGN_OR_RETURN(PreparedRender prepared,
                         prepare_render(options, device, scene.description, *scene.library,
                                        scene.bundle_hash, scene.scene_relpath));
  const double prepare_cpu = evaluation::process_cpu_seconds() - cpu_start;
  PRISM_ASSIGN_OR_RETURN(evaluation::TimedRender timed,
                         evaluation::timed_render(device, scene, prepared.local));
  // The pilots (τ, auto) are part of what the method costs.
  const bool piloted =
      prepared.pilot_seconds.has_value() || prepared.auto_pilot_seconds.has_value();
  return Timed{std::move(timed.result),
               timed.wall_seconds +
                   (prepared.tau_pilot_in_auto ? 0.0 : prepared.pilot_seconds.value_or(0.0)) +
                   prepared.auto_pilot_seconds.value_or(0.0),
               timed.cpu_seconds + (piloted ? prepare_cpu : 0.0),
               absl::StrCat(job::name(prepared.job.render.integrator),
                            prepared.job.render.light_caustics ? "+caustics" : "",
                            prepared.job.prepass.has_value() ? "+prepass" : "",
                            // The filters, so that light+splat is not reported as "light".
                            prepared.job.render.splats_differentials() ? "+splat" : "",
                            prepared.job.render.gathers() ? "+gather" : "")};
}

// The seconds a method takes at a given spp, from its renders so far: seconds = fixed + spp·rate,
// fitted through the two latest renders at different spp (the fixed part is what a farm job
// spends in scheduling and transfers, or a pilot), or proportional through the latest one.
class CostModel {
 public:
  void add(std::uint64_t spp, double seconds) {
    if (!points_.empty() && points_.back().first == spp) points_.pop_back();
    points_.emplace_back(spp, std::max(seconds, 1e-6));
    if (points_.size() > 2) points_.erase(points_.begin());
  }
  // The spp expected to take `seconds` (at least 1).
  std::uint64_t spp_for(double seconds) const {
    const auto [spp, t] = points_.back();
    double rate = t / double(spp), fixed = 0;
    if (points_.size() == 2) {
      const auto [spp0, t0] = points_.front();
      const double slope = (t - t0) / (double(spp) - double(spp0));
      if (slope > 0) {
        rate = slope;
        fixed = std::clamp(t - slope * double(spp), 0.0, std::min(t, t0));
      }
    }
    const double n = (seconds - fixed) / rate;
    return n < 1 ? 1 : static_cast<std::uint64_t>(std::min(n, 1e12));
  }

 private:
  std::vector<std::pair<std::uint64_t, double>> points_;
};

// One render of the method as a farm job (see the header), in `scratch`, which it empties.
absl::StatusOr<Timed> farm_method(const FarmConnection& farm, const fs::path& scratch,
                                  const std::string& client_token,
                                  const RenderCommandOptions& options) {
  SubmitOptions submit;
  submit.render = options;
  submit.render.threads.reset();
  submit.render.json.reset();
  submit.render.progress = nullptr;
  submit.render.warnings = nullptr;
  submit.render.output = scratch / "render.exr";
  submit.client_token = client_token;
  submit.wait = true;
  std::error_code ec;
  fs::remove_all(scratch, ec);
  fs::create_directories(scratch, ec);
  if (ec) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot create ", scratch.string(), ": ", ec.message()));
  }
  const auto start = Clock::now();
  const absl::Status submitted = run_submit(farm, submit).status();
  const double wall = std::chrono::duration<double>(Clock::now() - start).count();
  absl::StatusOr<image::SpectralExr> read = submitted.ok()
                                                ? image::read_spectral_exr(scratch / "render.exr")
                                                : absl::StatusOr<image::SpectralExr>(submitted);
  // The fetched outputs are only read here: nothing of them stays behind, even on an error.
  fs::remove_all(scratch, ec);
  if (!read.ok()) return read.status();
  image::SpectralExr exr = *std::move(read);
  const auto meta = [&](std::string_view key) -> std::string {
    auto it = exr.metadata.find(std::string(key));
    return it == exr.metadata.end() ? std::string() : it->second;
  };
  std::optional<coordinator::TargetErrorOutcome> target;
  if (const std::string spp = meta("target_error_spp_max"); !spp.empty()) {
    target.emplace();
    const auto [end, parse] = std::from_chars(spp.data(), spp.data() + spp.size(), target->max_spp);
    if (parse != std::errc() || end != spp.data() + spp.size()) {
      return absl::InternalError(
          absl::StrCat("the farm's output has a bad target_error_spp_max '", spp, "'"));
    }
  }
  PRISM_ASSIGN_OR_RETURN(image::RgbImage no_rgb, image::RgbImage::create(1, 1));
  coordinator::LocalRenderResult result{
      std::move(exr.spectral), no_rgb, no_rgb, {}, {}, {}, {}, {}, {}, {}, {}, {}};
  result.stats.target_error = target;
  return Timed{
      std::move(result), wall, 0.0,
      absl::StrCat(meta(image::kMetaIntegrator), meta("caustics") == "light" ? "+caustics" : "",
                   meta("prepass_passes").empty() ? "" : "+prepass")};
}

// With `auto` and other methods among the rows: per scene, region and budget, auto's relMSE over
// the lowest of the other methods' at auto's own seconds (each curve interpolated as for the
// baseline), which method that was, and the seeds' spread: the larger of auto's and that
// method's highest over lowest relMSE among their seeds at the budget ("–" with one seed), the
// noise the ratio of their means sits in. Empty otherwise.
std::string auto_against_best(const Grouped& g) {
  if (std::find(g.methods.begin(), g.methods.end(), "auto") == g.methods.end() ||
      g.methods.size() < 2) {
    return {};
  }
  std::string out =
      "\n## auto against the best of the others at equal time\n\n"
      "| scene | region | budget | auto ran | auto ÷ best | best | seeds' spread |\n"
      "|---|---|---|---|---|---|---|\n";
  auto spread = [](const Cell* c) {
    return c != nullptr && c->count > 1 && c->rel_mse_low > 0
               ? std::optional<double>(c->rel_mse_high / c->rel_mse_low)
               : std::nullopt;
  };
  for (const std::string& scene : g.scenes) {
    for (const std::string& region : g.regions) {
      for (const std::string& b : g.budgets) {
        const Cell* a = g.find(scene, region, "auto", b);
        if (a == nullptr || !(a->rel_mse > 0)) continue;
        std::optional<double> best;
        std::string best_method;
        bool extrapolated = false;
        for (const std::string& m : g.methods) {
          if (m == "auto") continue;
          bool beyond = false;
          const std::optional<double> e =
              evaluation::error_at_time(g.curve(scene, region, m), a->seconds, &beyond);
          if (e.has_value() && *e > 0 && (!best.has_value() || *e < *best)) {
            best = e;
            best_method = m;
            extrapolated = beyond;
          }
        }
        if (!best.has_value()) continue;
        const std::optional<double> s_auto = spread(a),
                                    s_best = spread(g.find(scene, region, best_method, b));
        const std::string seeds =
            s_auto.has_value() || s_best.has_value()
                ? absl::StrFormat("%.2f", std::max(s_auto.value_or(1.0), s_best.value_or(1.0)))
                : "–";
        absl::StrAppend(
            &out, "| ", scene, " | ", region == "image" ? "whole image" : region, " | ", b, " | ",
            a->ran.empty() ? "auto" : a->ran, " | ", absl::StrFormat("%.3f", a->rel_mse / *best),
            extrapolated ? " (extrapolated)" : "", " | ", best_method, " | ", seeds, " |\n");
      }
    }
  }
  return out;
}

std::string home_cache() {
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg != nullptr && *xdg != '\0') {
    return (fs::path(xdg) / "prism" / "references").string();
  }
  if (const char* home = std::getenv("HOME"); home != nullptr && *home != '\0') {
    return (fs::path(home) / ".cache" / "prism" / "references").string();
  }
  return {};
}

// Runs gnuplot on `script` in the script's directory (its file names are relative to it), its
// outputs written under a .tmp suffix; its messages go to `log`.
absl::Status run_gnuplot(const fs::path& script, const fs::path& log) {
  const fs::path absolute_log = fs::absolute(log);
  const fs::path dir = fs::absolute(script).parent_path();
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addchdir_np(&actions, dir.c_str());
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, absolute_log.c_str(),
                                   O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
  std::string program = "gnuplot", e = "-e", suffix = "suffix='.tmp'",
              argument = script.filename().string();
  char* argv[] = {program.data(), e.data(), suffix.data(), argument.data(), nullptr};
  pid_t pid = 0;
  const int spawned = posix_spawnp(&pid, "gnuplot", &actions, nullptr, argv, environ);
  posix_spawn_file_actions_destroy(&actions);
  if (spawned != 0) {
    return absl::FailedPreconditionError(
        absl::StrCat("cannot run gnuplot (", std::strerror(spawned),
                     "): install it with deploy/install-deps.sh (Debian package gnuplot-nox)"));
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    absl::StatusOr<std::string> text = base::read_file(log);
    return absl::InternalError(absl::StrCat("gnuplot failed on ", script.string(), ": ",
                                            text.ok() ? *text : std::string("(no log)")));
  }
  return absl::OkStatus();
}

// gnuplot exits 0 when its terminal could not write the file (a full disk), so a plot is checked
// for its end: a PNG's IEND chunk, an SVG's closing tag.
absl::Status check_plot_is_whole(const fs::path& file) {
  PRISM_ASSIGN_OR_RETURN(std::string bytes, base::read_file(file));
  bool whole = false;
  if (file.string().ends_with(".png.tmp")) {
    static constexpr char kEnd[] = {'I', 'E', 'N', 'D', '\xAE', '\x42', '\x60', '\x82'};
    whole = bytes.size() >= 20 && bytes.compare(bytes.size() - 8, 8, kEnd, 8) == 0;
  } else {
    whole = bytes.find("</svg>", bytes.size() > 64 ? bytes.size() - 64 : 0) != std::string::npos;
  }
  if (whole) return absl::OkStatus();
  return absl::DataLossError(absl::StrCat(
      "gnuplot wrote ", file.string(), " incomplete (", bytes.size(),
      " bytes; is the disk full?); the plots are not written, results.csv and report.md are"));
}

}  // namespace

absl::StatusOr<std::vector<double>> parse_budgets(const std::string& text) {
  std::vector<double> out;
  for (absl::string_view part : absl::StrSplit(text, ',')) {
    std::string digits(part);
    double unit = 1;
    if (!digits.empty() && (digits.back() == 's' || digits.back() == 'm')) {
      unit = digits.back() == 'm' ? 60 : 1;
      digits.pop_back();
    }
    auto value = parse_positive(digits, absl::StrCat("--budgets '", text, "'"));
    if (!value.ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat("--budgets '", text, "': want increasing durations such as 10s,30s,2m"));
    }
    const double seconds = *value * unit;
    // A budget has to become a sample count: 1e300 s was refused as "--spp 1000000000000".
    constexpr double kWeek = 7 * 24 * 3600;
    if (seconds > kWeek) {
      return absl::InvalidArgumentError(absl::StrCat("--budgets '", text, "': ", seconds,
                                                     " s is over a week; want at most 604800 s"));
    }
    if (!out.empty() && seconds <= out.back()) {
      return absl::InvalidArgumentError(
          absl::StrCat("--budgets '", text, "': want increasing durations such as 10s,30s,2m"));
    }
    out.push_back(seconds);
  }
  return out;
}

std::string bench_csv(const std::vector<BenchRow>& rows) {
  std::string out =
      "scene,method,budget,seed,region,spp,seconds,wall_seconds,cpu_seconds,mse,rel_mse,ssim,"
      "mse_floor,rel_mse_floor,floor_known,nonfinite_fraction,ran\n";
  for (const BenchRow& r : rows) {
    absl::StrAppend(&out, csv_field(r.scene), ",", csv_field(r.method), ",", csv_field(r.budget),
                    ",", r.seed, ",", csv_field(r.region), ",", r.spp, ",",
                    absl::StrFormat("%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g", r.seconds,
                                    r.wall_seconds, r.cpu_seconds, r.metrics.mse, r.metrics.rel_mse,
                                    r.metrics.ssim, r.mse_floor, r.rel_mse_floor),
                    ",", r.floor_known ? 1 : 0, ",",
                    absl::StrFormat("%.9g", r.metrics.nonfinite_fraction), ",",
                    csv_field(r.ran.empty() ? r.method : r.ran), "\n");
  }
  return out;
}

absl::StatusOr<std::vector<BenchRow>> parse_bench_csv(const std::string& original,
                                                      const std::string& name) {
  std::vector<BenchRow> rows;
  // A file that passed through a Windows editor or a spreadsheet: CRLF line ends.
  const std::string text = absl::StrReplaceAll(original, {{"\r\n", "\n"}});
  const std::string header = bench_csv({});
  if (text.rfind(header, 0) != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(name, ":1: not a prism bench results.csv (want the header ", header, ")"));
  }
  std::size_t at = header.size();
  for (int line = 2; at < text.size(); ++line) {
    // The fields of one line, quoted ones unquoted ("" stands for one quote).
    std::vector<std::string> fields(1);
    bool quoted = false;
    for (; at < text.size() && (quoted || text[at] != '\n'); ++at) {
      const char c = text[at];
      if (c == '"') {
        if (quoted && at + 1 < text.size() && text[at + 1] == '"') {
          fields.back().push_back('"');
          ++at;
        } else {
          quoted = !quoted;
        }
      } else if (c == ',' && !quoted) {
        fields.emplace_back();
      } else {
        fields.back().push_back(c);
      }
    }
    ++at;  // the line break
    auto bad = [&](const std::string& what) {
      return absl::InvalidArgumentError(absl::StrCat(name, ":", line, ": ", what));
    };
    if (fields.size() == 1 && fields[0].empty()) continue;  // a blank line
    if (fields.size() != 17) return bad(absl::StrCat(fields.size(), " fields, want 17"));
    BenchRow r;
    r.scene = fields[0];
    r.method = fields[1];
    r.budget = fields[2];
    r.region = fields[4];
    r.ran = fields[16];
    double* numbers[] = {&r.seconds,     &r.wall_seconds,    &r.cpu_seconds,
                         &r.metrics.mse, &r.metrics.rel_mse, &r.metrics.ssim,
                         &r.mse_floor,   &r.rel_mse_floor,   &r.metrics.nonfinite_fraction};
    const int columns[] = {6, 7, 8, 9, 10, 11, 12, 13, 15};
    for (int i = 0; i < 9; ++i) {
      if (!absl::SimpleAtod(fields[columns[i]], numbers[i]) || !std::isfinite(*numbers[i])) {
        return bad(absl::StrCat("column ", columns[i] + 1, " '", fields[columns[i]],
                                "' is not a finite number"));
      }
    }
    if (!absl::SimpleAtoi(fields[3], &r.seed) || !absl::SimpleAtoi(fields[5], &r.spp) ||
        (fields[14] != "0" && fields[14] != "1")) {
      return bad("seed, spp or floor_known is not an integer of its range");
    }
    r.floor_known = fields[14] == "1";
    rows.push_back(std::move(r));
  }
  return rows;
}

std::string reference_warnings(const std::vector<BenchRow>& rows) {
  // Per scene and region, the worst row: the largest share of its measured error that is the
  // reference's own noise (the floor subtracted from it).
  std::map<std::pair<std::string, std::string>, const BenchRow*> worst;
  auto share = [](const BenchRow& r) {
    // Of MSE and of relMSE, which weigh the pixels differently: the larger.
    auto of = [](double floor, double minus_floor) {
      const double raw = minus_floor + floor;
      return raw > 0 ? floor / raw : 0.0;
    };
    return std::max(of(r.mse_floor, r.metrics.mse), of(r.rel_mse_floor, r.metrics.rel_mse));
  };
  for (const BenchRow& r : rows) {
    if (!r.floor_known) continue;
    const BenchRow*& w = worst[{r.scene, r.region}];
    if (w == nullptr || share(r) > share(*w)) w = &r;
  }
  std::string out;
  for (const auto& [key, r] : worst) {
    if (share(*r) <= 0.5) continue;
    absl::StrAppend(
        &out, absl::StrFormat(
                  "- %s, %s: the reference's own noise is %.0f %% of the error measured for %s "
                  "at %s (seed %d)%s; figures this close to the reference's noise are not "
                  "reliable: render the reference longer (--reference-spp, --reference-error)\n",
                  key.first, key.second, 100 * share(*r), r->method, r->budget, r->seed,
                  r->metrics.rel_mse < 0 || r->metrics.mse < 0
                      ? ", whose error minus the floor is negative"
                      : ""));
  }
  return out;
}

std::string bench_report(const std::vector<BenchRow>& rows, const std::string& baseline,
                         const std::string& header) {
  const Grouped g = group(rows);
  std::string out = header;
  if (const std::string warnings = reference_warnings(rows); !warnings.empty()) {
    absl::StrAppend(&out, "\n**Warning:**\n\n", warnings);
  }
  const bool has_baseline =
      std::find(g.methods.begin(), g.methods.end(), baseline) != g.methods.end();
  if (!has_baseline) {
    absl::StrAppend(&out, "\nThe baseline '", baseline,
                    "' was not among the methods: no equal-time ratios.\n");
  }
  for (const std::string& scene : g.scenes) {
    for (const std::string& region : g.regions) {
      bool any = false;
      for (const std::string& m : g.methods) {
        for (const std::string& b : g.budgets) any |= g.find(scene, region, m, b) != nullptr;
      }
      if (!any) continue;
      absl::StrAppend(
          &out, "\n## ", scene, ": ", region == "image" ? "whole image" : region,
          "\n\n| method | budget | spp | seconds | MSE | relMSE | SSIM |",
          has_baseline ? absl::StrCat(" relMSE ÷ ", baseline, " at equal time |") : std::string(),
          "\n|---|---|---|---|---|---|---|", has_baseline ? "---|" : "", "\n");
      const auto base_curve = has_baseline ? g.curve(scene, region, baseline)
                                           : std::vector<evaluation::ConvergencePoint>{};
      for (const std::string& m : g.methods) {
        for (const std::string& b : g.budgets) {
          const Cell* c = g.find(scene, region, m, b);
          if (c == nullptr) continue;
          absl::StrAppend(&out, "| ", m, c->ran.empty() ? "" : absl::StrCat(" (", c->ran, ")"),
                          " | ", b, " | ", c->spp, " | ", absl::StrFormat("%.2f", c->seconds),
                          " | ", number(c->mse), " | ", number(c->rel_mse), " | ",
                          absl::StrFormat("%.4f", c->ssim), " |");
          if (has_baseline) {
            bool extrapolated = false;
            const std::optional<double> base =
                evaluation::error_at_time(base_curve, c->seconds, &extrapolated);
            if (base.has_value() && *base > 0 && c->rel_mse > 0) {
              absl::StrAppend(&out, " ", absl::StrFormat("%.3f", c->rel_mse / *base),
                              extrapolated ? " (extrapolated)" : "", " |");
            } else {
              absl::StrAppend(&out, " – |");
            }
          }
          absl::StrAppend(&out, "\n");
        }
      }
    }
  }
  absl::StrAppend(&out, auto_against_best(g));
  return out;
}

BenchPlot bench_plot(const std::vector<BenchRow>& rows, const std::string& scene,
                     const std::string& clock, const fs::path& data_file, const fs::path& svg,
                     const fs::path& png) {
  const Grouped g = group(rows);
  BenchPlot plot;
  std::vector<std::string> series;
  int index = 0;
  // The plotted points' extent: gnuplot's own log ranges round out to whole decades, which for
  // budgets of 3 s and 10 s leaves the curves a fifth of the width.
  double x_lo = HUGE_VAL, x_hi = 0, y_lo = HUGE_VAL, y_hi = 0;
  bool any_inset = false;
  for (std::size_t mi = 0; mi < g.methods.size(); ++mi) {
    const std::string& method = g.methods[mi];
    for (std::size_t ri = 0; ri < g.regions.size(); ++ri) {
      const std::string& region = g.regions[ri];
      std::vector<evaluation::ConvergencePoint> points = g.curve(scene, region, method);
      std::erase_if(points, [](const evaluation::ConvergencePoint& p) {
        return !(p.error > 0) || !(p.seconds > 0);
      });
      if (points.empty()) continue;
      std::sort(points.begin(), points.end(),
                [](const auto& a, const auto& b) { return a.seconds < b.seconds; });
      absl::StrAppend(&plot.data, "# ", method, " ", region, "\n");
      for (const auto& p : points) {
        absl::StrAppend(&plot.data, absl::StrFormat("%.9g %.9g %d\n", p.seconds, p.error, p.spp));
        x_lo = std::min(x_lo, p.seconds);
        x_hi = std::max(x_hi, p.seconds);
        y_lo = std::min(y_lo, p.error);
        y_hi = std::max(y_hi, p.error);
      }
      absl::StrAppend(&plot.data, "\n\n");
      const bool inset = region != "image";
      any_inset = any_inset || inset;
      series.push_back(
          absl::StrCat(gnuplot_string(data_file.filename().string()), " index ", index,
                       " using 1:2 with linespoints lc ", mi + 1, " lw ", inset ? "1.5" : "2.5",
                       " pt ", inset ? 6 : 7, " dt ", inset ? 2 : 1, " title ",
                       gnuplot_string(inset ? absl::StrCat(method, ", inset ", region) : method)));
      ++index;
    }
  }
  const std::string axes = absl::StrCat(
      "set title ", gnuplot_string(scene), "\nset logscale xy\nset xlabel ",
      gnuplot_string(clock == "cpu" ? "seconds (process CPU)" : "seconds (wall clock)"),
      "\nset ylabel ", gnuplot_string("relMSE over spectral bins (minus the reference floor)"),
      // The key below the plot, a column wider than gnuplot reckons (its estimate of the
      // cairo font's widths runs short: titles overlapped their neighbours' samples), and in two
      // columns where the insets' long titles would run off the image's edge.
      "\nset key below noenhanced ", any_inset ? "width 2 maxcols 2" : "width 1",
      "\nset grid xtics ytics mxtics mytics\n"
      "set format x '%g'\nset format y '%.0e'\n",
      series.empty()
          ? ""
          : absl::StrFormat("set xrange [%.6g:%.6g]\nset yrange [%.6g:%.6g]\n"
                            "set xtics %s\nset ytics %s\n",
                            x_lo / 1.25, x_hi * 1.25, y_lo / 1.5, y_hi * 1.5,
                            log_tics(x_lo / 1.25, x_hi * 1.25), log_tics(y_lo / 1.5, y_hi * 1.5)));
  const std::string draw = series.empty()
                               ? std::string(
                                     "set label 1 'no positive errors to plot' at graph 0.3,0.5\n"
                                     "plot [1:10] [1e-6:1] NaN notitle\n")
                               : absl::StrCat("plot ", absl::StrJoin(series, ", \\\n     "), "\n");
  plot.script = absl::StrCat(
      "# Drawn by prism bench: relMSE against seconds for ", scene, ", one curve per method,\n",
      "# insets dashed. Rerun in this directory with: gnuplot <this file>\n",
      "# (prism bench itself passes -e \"suffix='.tmp'\" and moves the files into place.)\n",
      "if (!exists(\"suffix\")) suffix = ''\n",
      "set terminal svg size 900,600 dynamic font 'Sans,12' background rgb 'white'\n",
      "set output ", gnuplot_string(svg.filename().string()), ".suffix\n", axes, draw,
      "set output\nset terminal pngcairo size 1200,800 font 'Sans,12' background rgb 'white'\n",
      "set output ", gnuplot_string(png.filename().string()), ".suffix\nreplot\nset output\n");
  return plot;
}

// Per scene: its plot's data, gnuplot script, SVG and PNG in `dir` (bench_plot), each written
// whole or not at all; their paths are appended to `summary`.
absl::Status write_plots(const std::vector<BenchRow>& rows, const std::vector<std::string>& scenes,
                         const std::string& clock, const fs::path& dir, std::string& summary) {
  std::error_code ec;
  for (const std::string& stem : scenes) {
    const fs::path data = dir / (stem + ".dat");
    const fs::path script = dir / (stem + ".gp");
    const fs::path svg = dir / (stem + ".svg");
    const fs::path png = dir / (stem + ".png");
    const BenchPlot plot = bench_plot(rows, stem, clock, data, svg, png);
    PRISM_RETURN_IF_ERROR(base::write_file_atomic(data, plot.data));
    PRISM_RETURN_IF_ERROR(base::write_file_atomic(script, plot.script));
    PRISM_RETURN_IF_ERROR(run_gnuplot(script, dir / (stem + ".gnuplot.log")));
    for (const fs::path& out : {svg, png}) {
      if (absl::Status whole = check_plot_is_whole(fs::path(out.string() + ".tmp")); !whole.ok()) {
        fs::remove(fs::path(svg.string() + ".tmp"), ec);
        fs::remove(fs::path(png.string() + ".tmp"), ec);
        return whole;
      }
    }
    for (const fs::path& out : {svg, png}) {
      fs::rename(fs::path(out.string() + ".tmp"), out, ec);
      if (ec) {
        return absl::InternalError(
            absl::StrCat("cannot move ", out.string(), ".tmp into place: ", ec.message()));
      }
    }
    fs::remove(dir / (stem + ".gnuplot.log"), ec);
    absl::StrAppend(&summary, ", ", svg.string(), ", ", png.string());
  }
  return absl::OkStatus();
}

absl::StatusOr<std::string> run_bench(const BenchOptions& options, worker::EmbreeDevice& device) {
  std::vector<std::string> methods = absl::StrSplit(options.methods, ',');
  if (!options.results.empty()) {
    if (!options.scenes.empty()) {
      return absl::InvalidArgumentError("give scenes to render or --results to report, not both");
    }
    std::vector<BenchRow> rows;
    std::set<std::string> seen;  // a row given twice (the same file twice) counts once
    std::set<std::string> methods_read;
    for (const fs::path& path : options.results) {
      PRISM_ASSIGN_OR_RETURN(const std::string text, base::read_file(path));
      PRISM_ASSIGN_OR_RETURN(std::vector<BenchRow> read, parse_bench_csv(text, path.string()));
      for (BenchRow& r : read) {
        methods_read.insert(r.method);
        if (!absl::c_linear_search(methods, r.method)) continue;
        if (!seen.insert(bench_csv({r})).second) continue;
        rows.push_back(std::move(r));
      }
    }
    if (rows.empty()) {
      return absl::InvalidArgumentError(absl::StrCat(
          "--results: no row of the method(s) ", options.methods, " (the files have ",
          methods_read.empty() ? std::string("no rows") : absl::StrJoin(methods_read, ", "),
          "); name them with --methods"));
    }
    std::error_code ec;
    fs::create_directories(options.output, ec);
    const fs::path report = options.output / "report.md";
    PRISM_RETURN_IF_ERROR(base::write_file_atomic(
        report, bench_report(rows, options.baseline,
                             absl::StrCat("# prism bench\n\nThe rows of ", options.results.size(),
                                          " results file(s), methods ", options.methods, ".\n"))));
    std::string summary = absl::StrCat("wrote ", report.string(), " from ", rows.size(), " rows");
    // The plots too, on the clock the rows were timed with (CPU where every row's seconds are
    // its CPU seconds).
    std::vector<std::string> scenes;
    bool cpu = !rows.empty();
    for (const BenchRow& r : rows) {
      if (!absl::c_linear_search(scenes, r.scene)) scenes.push_back(r.scene);
      cpu = cpu && r.seconds == r.cpu_seconds;
    }
    PRISM_RETURN_IF_ERROR(write_plots(rows, scenes, cpu ? "cpu" : "wall", options.output, summary));
    return absl::StrCat(summary, "\n");
  }
  // ---- Flags, all checked before any render.
  if (options.scenes.empty()) return absl::InvalidArgumentError("prism bench needs a scene");
  for (const std::string& m : methods) {
    PRISM_RETURN_IF_ERROR(method_options(m, RenderCommandOptions{}).status());
  }
  if (!method_options(options.baseline, RenderCommandOptions{}).ok()) {
    return absl::InvalidArgumentError(
        absl::StrCat("--baseline '", options.baseline, "' is not a method (--methods lists them)"));
  }
  if (std::set<std::string>(methods.begin(), methods.end()).size() != methods.size()) {
    return absl::InvalidArgumentError(
        absl::StrCat("--methods '", options.methods, "' names a method twice"));
  }
  if (!options.budgets.empty() && !options.spp.empty()) {
    return absl::InvalidArgumentError("give --budgets or --spp, not both");
  }
  const bool by_time = options.spp.empty();
  std::vector<double> budgets;
  std::vector<std::uint64_t> spps;
  if (by_time) {
    PRISM_ASSIGN_OR_RETURN(budgets,
                           parse_budgets(options.budgets.empty() ? "10s,30s" : options.budgets));
    // Each budget is a row label (six digits): two that print alike would merge in the report.
    for (std::size_t i = 1; i < budgets.size(); ++i) {
      if (number(budgets[i]) == number(budgets[i - 1])) {
        return absl::InvalidArgumentError(
            absl::StrCat("--budgets '", options.budgets, "': ", number(budgets[i - 1]), "s and ",
                         budgets[i], "s are the same to six digits, the labels of the rows"));
      }
    }
  } else {
    PRISM_ASSIGN_OR_RETURN(spps, evaluation::parse_spp_list(options.spp));
  }
  if (options.seeds < 1 || options.seeds > 64) {
    return absl::InvalidArgumentError(absl::StrCat("--seeds ", options.seeds, " is outside 1..64"));
  }
  if (options.clock != "wall" && options.clock != "cpu") {
    return absl::InvalidArgumentError(
        absl::StrCat("--clock '", options.clock, "': choose wall or cpu"));
  }
  if (options.farm.has_value()) {
    if (options.clock != "wall") {
      return absl::InvalidArgumentError(
          "--clock cpu measures this process; on the farm (--coordinator) renders are timed on "
          "the wall clock, from the submission to the fetched outputs");
    }
    if (options.threads.has_value()) {
      return absl::InvalidArgumentError(
          "--threads: on the farm (--coordinator) the workers render with their own threads");
    }
  }
  if (!options.references.empty() &&
      (options.reference_spp.has_value() || options.reference_error.has_value() ||
       options.reference_cache.has_value())) {
    return absl::InvalidArgumentError(
        "--reference gives the references: --reference-spp, --reference-error and "
        "--reference-cache are for the references bench renders, and would do nothing");
  }
  if (!options.references.empty() && options.references.size() != options.scenes.size()) {
    return absl::InvalidArgumentError(absl::StrCat("give one --reference per scene (",
                                                   options.scenes.size(), " scenes, ",
                                                   options.references.size(), " references)"));
  }
  // To a target error the reference starts with a 16-spp round, up to --reference-spp (which
  // said "--max-spp 4 is below --spp 16", naming flags not given).
  if (options.reference_error.has_value() && options.reference_spp.has_value() &&
      *options.reference_spp < 16) {
    return absl::InvalidArgumentError(
        absl::StrCat("--reference-spp ", *options.reference_spp,
                     " is below 16: a reference to --reference-error starts with a round of 16 "
                     "samples per pixel, and --reference-spp is its most"));
  }
  if (options.reference_spp.has_value() &&
      (*options.reference_spp < 2 || std::uint64_t(*options.reference_spp) > kMaxReferenceSpp)) {
    return absl::InvalidArgumentError(absl::StrCat("--reference-spp ", *options.reference_spp,
                                                   " is outside 2..", kMaxReferenceSpp));
  }
  std::vector<image::Crop> insets;
  for (const std::string& text : options.insets) {
    PRISM_ASSIGN_OR_RETURN(image::Crop crop, parse_crop(text, "--inset"));
    insets.push_back(crop);
  }
  RenderCommandOptions base;
  base.resolution = options.resolution;
  base.bins = options.bins;
  base.threads = options.threads;
  base.allow_unsupported = options.allow_unsupported;
  PRISM_RETURN_IF_ERROR(validate_render_flags(base));
  const fs::path cache = options.reference_cache.has_value() ? *options.reference_cache
                         : home_cache().empty()              ? options.output / "references"
                                                             : fs::path(home_cache());
  std::error_code ec;
  const bool output_existed = fs::exists(options.output, ec);
  fs::create_directories(options.output, ec);
  if (ec) {
    return absl::InvalidArgumentError(absl::StrCat("cannot create the output directory ",
                                                   options.output.string(), ": ", ec.message()));
  }
  // Until every scene has passed its checks, an error takes back the directory made for it
  // (it left an empty -o behind).
  struct RemoveIfUnused {
    const fs::path& dir;
    bool armed;
    ~RemoveIfUnused() {
      std::error_code ignored;
      if (armed && fs::is_empty(dir, ignored)) fs::remove(dir, ignored);
    }
  } output_guard{options.output, !output_existed};
  if (!device.valid()) {
    return absl::InternalError(
        absl::StrCat("could not create the Embree device: ", device.take_error().message()));
  }
  if (options.farm.has_value()) {
    // Asked first, so an unreachable farm, or one whose jobs no worker would take, costs nothing.
    FarmConnection probe = *options.farm;
    probe.deadline = std::min(probe.deadline, std::chrono::milliseconds(10000));
    PRISM_ASSIGN_OR_RETURN(int live, live_workers(probe));
    if (live == 0) {
      return absl::FailedPreconditionError(
          absl::StrCat("the farm at ", options.farm->address,
                       " has no idle or busy worker to render the bench's jobs; start one with "
                       "prism-worker --coordinator ",
                       options.farm->address));
    }
  }
  auto log = [&](const std::string& line) {
    if (options.log != nullptr) *options.log << "bench: " << line << "\n" << std::flush;
  };
  // Every render of this run is a job of its own on the farm: a client token from the run's
  // nonce and a counter, so neither a rerun of the bench nor a repeated configuration is
  // answered with an earlier job's outputs (and time).
  const fs::path scratch = options.output / ".farm";
  const std::string nonce = base::sha256_hex(
      absl::StrCat("prism bench ", std::chrono::system_clock::now().time_since_epoch().count(), " ",
                   ::getpid(), " ", fs::absolute(options.output).string()));
  std::uint64_t submissions = 0;
  auto render_method = [&](const evaluation::BenchScene& scene,
                           const RenderCommandOptions& o) -> absl::StatusOr<Timed> {
    if (!options.farm.has_value()) return timed_method(device, scene, o);
    return farm_method(*options.farm, scratch,
                       base::sha256_hex(absl::StrCat(nonce, " ", submissions++)), o);
  };

  std::vector<BenchRow> rows;
  std::string header = absl::StrCat(
      "# prism bench\n\nClock: ", options.clock, "; ", options.seeds, " seed(s); threads: ",
      options.threads.has_value() && *options.threads > 0 ? absl::StrCat(*options.threads)
                                                          : std::string("all"),
      " (", std::thread::hardware_concurrency(), " hardware)",
      options.farm.has_value()
          ? absl::StrCat("; on the farm at ", options.farm->address,
                         " (the workers' threads; seconds from submission to fetched outputs)")
          : std::string(),
      ". Seconds include the τ pilot, the "
      "prepass and the reconstruction, not the scene build. Errors are over spectral bins, mean "
      "over seeds; MSE and relMSE are minus the reference's noise floor where it is known.\n");
  std::string summary;

  // ---- Every scene, checked before any render: a bad path, an inset or a reference that does
  // not fit, or a method the scene cannot take would otherwise end a long run after hours.
  struct SceneSetup {
    evaluation::BenchScene scene;
    std::string stem;
    RenderCommandOptions base;
    int width = 0, height = 0, bins = 0;
    std::vector<std::pair<std::string, std::optional<image::Crop>>> regions;
    std::optional<image::SpectralExr> reference;  // --reference, read
    std::optional<image::SpectralImage> half;     // its .half.exr, when there is one
  };
  std::vector<SceneSetup> setups;
  std::vector<std::string> stems;
  for (std::size_t si = 0; si < options.scenes.size(); ++si) {
    const fs::path& path = options.scenes[si];
    SceneSetup setup;
    PRISM_ASSIGN_OR_RETURN(setup.scene,
                           evaluation::load_bench_scene(path, options.allow_unsupported));
    const evaluation::BenchScene& scene = setup.scene;
    std::string stem = path.stem().string();
    for (int n = 2; std::find(stems.begin(), stems.end(), stem) != stems.end(); ++n) {
      stem = absl::StrCat(path.stem().string(), "-", n);
    }
    stems.push_back(stem);
    setup.stem = stem;
    setup.base = base;
    setup.base.scene = path;

    // The film this bench renders (the scene's, or --resolution) and its regions.
    RenderCommandOptions probe = setup.base;
    probe.integrator = "hero";
    probe.spp = 1;
    PRISM_ASSIGN_OR_RETURN(
        v1::JobSpec probe_spec,
        job_spec_of(probe, scene.description, scene.bundle_hash, scene.scene_relpath));
    const int width = setup.width = static_cast<int>(probe_spec.width());
    const int height = setup.height = static_cast<int>(probe_spec.height());
    const int bins = setup.bins = static_cast<int>(probe_spec.bins());
    setup.regions.push_back({"image", {}});
    for (std::size_t i = 0; i < insets.size(); ++i) {
      if (auto rect = image::crop_rect(insets[i], width, height); !rect.ok()) {
        return absl::InvalidArgumentError(absl::StrCat("--inset ", options.insets[i], ": ",
                                                       rect.status().message(), " (", scene.name,
                                                       " renders ", width, "x", height, ")"));
      }
      setup.regions.push_back({options.insets[i], insets[i]});
    }
    if (!options.references.empty()) {
      const fs::path& ref_path = options.references[si];
      PRISM_ASSIGN_OR_RETURN(image::SpectralExr exr, image::read_spectral_exr(ref_path));
      // A gradient render's raw gradient file holds differences of bins, not radiance.
      if (auto content = exr.metadata.find(std::string(image::kMetaContent));
          content != exr.metadata.end() && content->second == "gradient") {
        return absl::InvalidArgumentError(absl::StrCat(
            "--reference ", ref_path.string(),
            " holds the gradient of a gradient render (prism:content), not an image; give the "
            "render's image"));
      }
      if (exr.spectral.width() != width || exr.spectral.height() != height ||
          exr.spectral.bins() != bins) {
        return absl::InvalidArgumentError(
            absl::StrCat("--reference ", ref_path.string(), " is ", exr.spectral.width(), "x",
                         exr.spectral.height(), " with ", exr.spectral.bins(), " bins; ",
                         scene.name, " renders ", width, "x", height, " with ", bins, " bins"));
      }
      // Its independent half (a cached reference's .half.exr), which gives the noise floor:
      // one that cannot be that half is an error, not a floor silently dropped or made 0.
      fs::path half_path = ref_path;
      half_path.replace_extension(".half.exr");
      if (fs::exists(half_path)) {
        PRISM_ASSIGN_OR_RETURN(image::SpectralExr half, image::read_spectral_exr(half_path));
        if (half.spectral.width() != width || half.spectral.height() != height ||
            half.spectral.bins() != bins) {
          return absl::InvalidArgumentError(absl::StrCat(
              half_path.string(), " (the half beside --reference ", ref_path.string(), ") is ",
              half.spectral.width(), "x", half.spectral.height(), " with ", half.spectral.bins(),
              " bins, not the reference's ", width, "x", height, " with ", bins,
              "; remove it (the noise floor is then unknown) or give the matching half"));
        }
        const std::span<const float> a = half.spectral.data(), b = exr.spectral.data();
        if (std::equal(a.begin(), a.end(), b.begin(), b.end())) {
          return absl::InvalidArgumentError(absl::StrCat(
              half_path.string(), " holds the same values as --reference ", ref_path.string(),
              ": it is not an independent half, and its noise floor would be 0"));
        }
        setup.half = std::move(half.spectral);
      }
      setup.reference = std::move(exr);
    }
    // Each method's job and scene as it would render them (at 4x4 and 1 spp: light paths refuse
    // some cameras and lights only when the scene is built). Not auto, which takes whatever the
    // scene allows.
    for (const std::string& method : methods) {
      if (method == "auto") continue;
      PRISM_ASSIGN_OR_RETURN(RenderCommandOptions o, method_options(method, setup.base));
      o.resolution = "4x4";
      o.spp = 1;
      o.max_memory.clear();
      absl::Status usable = [&]() -> absl::Status {
        PRISM_ASSIGN_OR_RETURN(PreparedRender prepared,
                               prepare_render(o, device, scene.description, *scene.library,
                                              scene.bundle_hash, scene.scene_relpath));
        return coordinator::LocalRender::create(device, scene.description, *scene.library,
                                                prepared.local)
            .status();
      }();
      if (!usable.ok()) {
        return absl::Status(usable.code(),
                            absl::StrCat(scene.name, ", method ", method, ": ", usable.message()));
      }
    }
    setups.push_back(std::move(setup));
  }
  output_guard.armed = false;

  // One scene's renders, its rows added to `rows`.
  auto bench_scene = [&](std::size_t si) -> absl::Status {
    SceneSetup& setup = setups[si];
    const evaluation::BenchScene& scene = setup.scene;
    const std::string& stem = setup.stem;
    const RenderCommandOptions& scene_base = setup.base;
    const int width = setup.width, height = setup.height, bins = setup.bins;
    const auto& regions = setup.regions;

    // Calibration: the clock's seconds per sample of a method, from a short render.
    // Calibration: a method's cost model, from renders of 4 spp and up (each at least four
    // times the last) until one after the first takes an eighth of the first budget, so that the
    // fixed part of its time (a pilot, a farm job's scheduling) is seen apart from the per-sample
    // part.
    auto calibrate = [&](const RenderCommandOptions& o) -> absl::StatusOr<CostModel> {
      RenderCommandOptions c = o;
      c.seed = kCalibrationSeed;
      CostModel model;
      std::uint64_t spp = 4;
      for (int step = 0; step < 5; ++step) {
        c.spp = static_cast<std::int64_t>(spp);
        PRISM_ASSIGN_OR_RETURN(Timed t, render_method(scene, c));
        model.add(spp, t.on(options.clock));
        // Two renders at least: a first one may carry one-off costs (the farm fetching the
        // bundle), which would otherwise pass for the per-sample part.
        if (step > 0 && t.on(options.clock) >= budgets.front() / 8) break;
        spp = std::max(4 * spp, model.spp_for(budgets.front() / 4));
      }
      return model;
    };

    // ---- The reference.
    std::optional<evaluation::Reference> reference;
    bool floor_known = false;
    std::string reference_text;
    if (setup.reference.has_value()) {
      const fs::path& ref_path = options.references[si];
      image::SpectralExr& exr = *setup.reference;
      image::SpectralImage half_image = exr.spectral;
      fs::path half_path = ref_path;
      half_path.replace_extension(".half.exr");
      if (setup.half.has_value()) {
        half_image = std::move(*setup.half);
        floor_known = true;
      }
      reference = evaluation::Reference{std::move(exr.spectral), std::move(half_image), 0, 0, 0};
      reference_text = absl::StrCat(ref_path.string(),
                                    floor_known ? " (noise floor from " + half_path.string() + ")"
                                                : " (noise floor unknown)");
    } else {
      RenderCommandOptions ref = scene_base;
      ref.integrator = "hero";
      ref.prepass = false;
      std::uint64_t spp = 0;
      if (options.reference_error.has_value()) {
        ref.target_error = *options.reference_error;
        ref.max_spp = options.reference_spp.value_or(
            static_cast<std::int64_t>(job::kDefaultTargetErrorMaxSpp));
        spp = 16;
      } else if (options.reference_spp.has_value()) {
        spp = static_cast<std::uint64_t>(*options.reference_spp);
      } else if (by_time) {
        PRISM_ASSIGN_OR_RETURN(CostModel cost, calibrate(ref));
        // About four times the largest budget, at the nearest power of two, so that a rerun
        // whose calibration measures a little differently finds the cached reference.
        const double wanted = double(cost.spp_for(4 * budgets.back()));
        spp = std::uint64_t{1} << std::clamp(int(std::lround(std::log2(wanted))), 1, 20);
      } else {
        spp = 4 * spps.back();
      }
      if (!options.reference_error.has_value()) {
        spp = std::clamp<std::uint64_t>(spp + (spp & 1), 2, kMaxReferenceSpp);
      }
      ref.spp = static_cast<std::int64_t>(spp);
      ref.seed = kReferenceSeed;
      PRISM_ASSIGN_OR_RETURN(PreparedRender prepared,
                             prepare_render(ref, device, scene.description, *scene.library,
                                            scene.bundle_hash, scene.scene_relpath));
      evaluation::HalfRenderer on_farm;
      if (options.farm.has_value()) {
        on_farm = [&, ref](const coordinator::LocalRenderOptions& half)
            -> absl::StatusOr<evaluation::TimedRender> {
          RenderCommandOptions o = ref;
          o.seed = half.render.seed;
          o.spp = static_cast<std::int64_t>(half.spp);
          if (half.target_error.has_value()) {
            o.target_error = half.target_error->relative;
            o.max_spp = static_cast<std::int64_t>(half.target_error->max_spp);
          }
          PRISM_ASSIGN_OR_RETURN(Timed t, render_method(scene, o));
          return evaluation::TimedRender{std::move(t.result), t.wall, t.cpu};
        };
      }
      PRISM_ASSIGN_OR_RETURN(reference, evaluation::cached_reference(device, scene, prepared.local,
                                                                     cache, "bench", on_farm));
      floor_known = true;
      reference_text =
          options.reference_error.has_value()
              ? absl::StrCat("hero without a prepass to ", number(100 * *options.reference_error),
                             " % per pixel (up to ", reference->spp,
                             " spp) in two independent halves (cached in ", cache.string(), ")")
              : absl::StrCat("hero without a prepass, ", reference->spp,
                             " spp in two independent halves (cached in ", cache.string(), ")");
    }
    absl::StrAppend(&header, "\n", stem, ": ", width, "x", height, ", ", bins,
                    " bins; reference: ", reference_text, ".\n");
    std::vector<image::ErrorMetrics> floors;
    for (const auto& [name, crop] : regions) {
      image::ErrorMetrics floor;
      floor.mse = floor.rel_mse = 0;
      if (floor_known) {
        PRISM_ASSIGN_OR_RETURN(floor, reference->floor(crop));
      }
      floors.push_back(floor);
    }

    // ---- The methods, interleaved: each budget and seed renders every method in turn, so that
    // the clock's drift over the minutes a scene takes falls on every method alike instead of on
    // whichever ran last (on the 2-core VM a render's CPU time wandered by 12 % within a minute,
    // docs/benchmarks.md). The calibrations run first; a method's spp for a budget is found by
    // its seed 1 and kept for the other seeds.
    struct MethodRun {
      std::string name;
      RenderCommandOptions options;
      CostModel cost;
      std::uint64_t spp = 0;
    };
    std::vector<MethodRun> runs;
    for (const std::string& method : methods) {
      MethodRun r;
      r.name = method;
      PRISM_ASSIGN_OR_RETURN(r.options, method_options(method, scene_base));
      if (by_time) {
        PRISM_ASSIGN_OR_RETURN(r.cost, calibrate(r.options));
      }
      runs.push_back(std::move(r));
    }
    const std::size_t count = by_time ? budgets.size() : spps.size();
    for (std::size_t bi = 0; bi < count; ++bi) {
      const std::string budget =
          by_time ? absl::StrCat(number(budgets[bi]), "s") : absl::StrCat(spps[bi], "spp");
      for (int seed = 1; seed <= options.seeds; ++seed) {
        for (MethodRun& run : runs) {
          const std::string& method = run.name;
          const RenderCommandOptions& mo = run.options;
          CostModel& cost = run.cost;
          std::uint64_t& spp = run.spp;
          if (seed == 1) spp = by_time ? cost.spp_for(budgets[bi]) : spps[bi];
          RenderCommandOptions o = mo;
          o.seed = static_cast<std::uint64_t>(seed);
          o.spp = static_cast<std::int64_t>(spp);
          PRISM_ASSIGN_OR_RETURN(Timed t, render_method(scene, o));
          if (by_time && seed == 1) {
            // Up to two corrections while the render misses the budget by more than a quarter;
            // the other seeds then render at the spp found.
            cost.add(spp, t.on(options.clock));
            for (int retry = 0;
                 retry < 2 && std::abs(t.on(options.clock) - budgets[bi]) > 0.25 * budgets[bi];
                 ++retry) {
              const std::uint64_t next = cost.spp_for(budgets[bi]);
              if (next == spp) break;
              spp = next;
              o.spp = static_cast<std::int64_t>(spp);
              PRISM_ASSIGN_OR_RETURN(t, render_method(scene, o));
              cost.add(spp, t.on(options.clock));
            }
          }
          // The splatting and gathering methods are judged by their filtered image.
          const bool filtered = mo.splat_width.has_value() || mo.gather_width.has_value();
          if (filtered && !t.result.filtered.has_value()) {
            return absl::InternalError(absl::StrCat(method, " rendered no filtered image"));
          }
          const image::SpectralImage& judged = filtered ? *t.result.filtered : t.result.image;
          for (std::size_t ri = 0; ri < regions.size(); ++ri) {
            PRISM_ASSIGN_OR_RETURN(
                image::ErrorMetrics m,
                image::compare_spectral(judged, reference->image, regions[ri].second));
            BenchRow row;
            row.scene = stem;
            row.method = method;
            row.budget = budget;
            row.seed = seed;
            row.region = regions[ri].first;
            row.ran = t.ran;
            row.spp = spp;
            row.seconds = t.on(options.clock);
            row.wall_seconds = t.wall;
            row.cpu_seconds = t.cpu;
            row.mse_floor = floors[ri].mse;
            row.rel_mse_floor = floors[ri].rel_mse;
            row.floor_known = floor_known;
            m.mse -= row.mse_floor;
            m.rel_mse -= row.rel_mse_floor;
            row.metrics = m;
            rows.push_back(row);
          }
          log(absl::StrCat(stem, " ", method, " ", budget, " seed ", seed, ": ", spp, " spp, ",
                           absl::StrFormat("%.2f", t.on(options.clock)), " s, relMSE ",
                           number(rows[rows.size() - regions.size()].metrics.rel_mse)));
        }
      }
    }
    return absl::OkStatus();
  };

  // ---- Outputs: the CSV and the report first, then the plots; rewritten after each scene, so
  // that a run that fails (or is stopped) keeps the scenes it finished.
  const fs::path csv = options.output / "results.csv";
  const fs::path report = options.output / "report.md";
  // A run before this one into the same directory: the plots of its scenes that this run does
  // not render would stay beside this run's report as though they were its own.
  std::vector<std::string> earlier_scenes;
  if (absl::StatusOr<std::string> earlier = base::read_file(csv); earlier.ok()) {
    if (auto rows_before = parse_bench_csv(*earlier, csv.string()); rows_before.ok()) {
      for (const BenchRow& r : *rows_before) remember(earlier_scenes, r.scene);
    }
  }
  // The CSV and the report cover every scene so far; a scene's plot depends on its own rows
  // alone, so each is drawn once, when its scene is done.
  std::string plotted;
  auto write_outputs = [&](std::size_t scene) -> absl::Status {
    PRISM_RETURN_IF_ERROR(base::write_file_atomic(csv, bench_csv(rows)));
    PRISM_RETURN_IF_ERROR(
        base::write_file_atomic(report, bench_report(rows, options.baseline, header)));
    return write_plots(rows, {stems[scene]}, options.clock, options.output, plotted);
  };
  for (std::size_t si = 0; si < setups.size(); ++si) {
    if (absl::Status done = bench_scene(si); !done.ok()) {
      if (si == 0) return done;
      return absl::Status(
          done.code(),
          absl::StrCat(done.message(), " (the results of the ", si, si == 1 ? " scene" : " scenes",
                       " finished before ", setups[si].scene.name, " are in ", csv.string(), ")"));
    }
    PRISM_RETURN_IF_ERROR(write_outputs(si));
  }
  if (const std::string warnings = reference_warnings(rows); !warnings.empty()) {
    log(absl::StrCat("warning:\n", warnings));
  }
  absl::StrAppend(&summary, "wrote ", csv.string(), " (", rows.size(), " rows), ", report.string(),
                  plotted);
  // Only a plain name (a results.csv is a file a user can edit: "../x" must not reach outside),
  // and only where its gnuplot script shows bench drew it (a `prism render` preview of the same
  // name in the same directory is not bench's).
  for (const std::string& stem : earlier_scenes) {
    if (absl::c_linear_search(stems, stem)) continue;
    if (stem.empty() || stem.front() == '.' || stem.find_first_of("/\\") != std::string::npos) {
      continue;
    }
    std::error_code ignored;
    if (!fs::is_regular_file(options.output / (stem + ".gp"), ignored)) continue;
    for (const char* ext : {".dat", ".svg", ".png", ".gp"}) {
      fs::remove(options.output / (stem + ext), ignored);
    }
  }
  return absl::StrCat(summary, "\n");
}

}  // namespace prism::client
