#include "worker/gradient/pilot.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"

namespace prism::worker {
namespace {

// Collects one pixel's events under the sample index the caller sets.
class PixelEvents final : public GradientEventSink {
 public:
  void record(const GradientEvent& event) override {
    events.push_back(event);
    sample_of.push_back(sample);
  }

  std::vector<GradientEvent> events;
  std::vector<std::uint32_t> sample_of;
  std::uint32_t sample = 0;  // pixel-local
};

}  // namespace

GradientPilotEvents::GradientPilotEvents(std::vector<GradientEvent> events,
                                         std::vector<std::uint32_t> sample_of,
                                         std::uint64_t samples)
    : events_(std::move(events)), sample_of_(std::move(sample_of)), samples_(samples) {
  PRISM_CHECK(events_.size() == sample_of_.size());
  // A side stays shifted while τ is below both the base's value and the offset's own value.
  transitions_.reserve(2 * events_.size());
  for (const GradientEvent& e : events_) {
    for (int side = 0; side < 2; ++side) {
      second_moment_ += e.side_square[side];
      const double rise = double(e.unshifted_square) - double(e.side_square[side]);
      transitions_.push_back(
          {std::min(e.threshold_value, e.offset_value[side]), rise, std::max(0.0, rise)});
      benefit_ += std::max(0.0, rise);
    }
    unshifted_total_ += e.unshifted_square;
  }
  std::stable_sort(transitions_.begin(), transitions_.end(),
                   [](const Transition& a, const Transition& b) { return a.tau < b.tau; });
}

double GradientPilotEvents::second_moment_rise(float tau) const {
  if (!(second_moment_ > 0)) return 0;
  double rise = 0;
  for (const Transition& t : transitions_) {
    if (!(t.tau <= tau)) break;
    rise += t.rise;
  }
  return rise / second_moment_;
}

double GradientPilotEvents::lost_benefit_fraction(float tau) const {
  if (!(benefit_ > 0)) return 0;
  double lost = 0;
  for (const Transition& t : transitions_) {
    if (!(t.tau <= tau)) break;
    lost += t.benefit;
  }
  return lost / benefit_;
}

double GradientPilotEvents::shifted_event_fraction(float tau) const {
  if (events_.empty()) return 0;
  std::size_t shifted = 0;
  for (const GradientEvent& e : events_) shifted += e.threshold_value > tau ? 1 : 0;
  return double(shifted) / double(events_.size());
}

double GradientPilotEvents::shifted_square_fraction(float tau) const {
  if (!(unshifted_total_ > 0)) return 0;
  double shifted = 0;
  for (const GradientEvent& e : events_) {
    if (e.threshold_value > tau) shifted += e.unshifted_square;
  }
  return shifted / unshifted_total_;
}

double GradientPilotEvents::offset_vertex_fraction(float tau) const {
  // Per sample, the offsets catch up to the deepest event above τ (events are in path order).
  auto catch_up = [&](float t) {
    double total = 0;
    for (std::size_t e = 0; e < events_.size();) {
      int deepest = 0;
      const std::uint32_t sample = sample_of_[e];
      for (; e < events_.size() && sample_of_[e] == sample; ++e) {
        if (events_[e].threshold_value > t) deepest = std::max(deepest, events_[e].vertices);
      }
      total += deepest;
    }
    return total;
  };
  const double at_zero = catch_up(0.0f);
  return at_zero > 0 ? catch_up(tau) / at_zero : 0.0;
}

float GradientPilotEvents::choose_tau(double epsilon) const {
  const double allowed = epsilon * benefit_;
  double lost = 0;
  float tau = 0;
  for (std::size_t k = 0; k < transitions_.size();) {
    // Transitions at one value happen together: any τ from v up to the next value unshifts them.
    const float value = transitions_[k].tau;
    for (; k < transitions_.size() && transitions_[k].tau == value; ++k) {
      lost += transitions_[k].benefit;
    }
    if (!(lost <= allowed) || !std::isfinite(value)) break;  // `lost` only grows
    if (!(value > 0)) continue;                              // τ = 0 unshifts these already
    // τ goes into a clean gap above the value (pilot.h), never onto a value.
    const float next =
        k < transitions_.size() ? transitions_[k].tau : std::numeric_limits<float>::infinity();
    if (!(double(next) > double(value) * (1 + kTauGap))) continue;
    tau = float(double(value) * (1 + kTauGap / 2));
  }
  return tau;
}

absl::StatusOr<GradientPilot> run_gradient_pilot(const RenderScene& scene, int width, int height,
                                                 const GradientPilotOptions& options) {
  if (options.max_pixels < 1 || options.samples < 1 || options.samples > 1 << 24 ||
      !(options.epsilon > 0.0 && options.epsilon <= 1.0) || options.threads < 0 || width < 1 ||
      height < 1) {
    return absl::InvalidArgumentError(absl::StrCat(
        "gradient pilot: ", options.samples, " samples over at most ", options.max_pixels,
        " pixels, epsilon ", options.epsilon, " on ", width, "x", height,
        "; want >= 1 pixel, 1..2^24 samples, epsilon in (0, 1], a non-empty image"));
  }
  if (scene.options().integrator != job::IntegratorKind::kGradient ||
      scene.options().gradient_tau != 0.0f) {
    return absl::InvalidArgumentError(
        "gradient pilot: the scene must be built for the gradient integrator with tau 0");
  }
  const auto start = std::chrono::steady_clock::now();
  // A regular stride over the image, centred in its cells.
  const double area = double(width) * double(height);
  const int stride = std::max(1, int(std::ceil(std::sqrt(area / options.max_pixels))));
  const int columns = (width + stride - 1) / stride, rows = (height + stride - 1) / stride;
  const int pixels = columns * rows;
  const int spp = int(std::min<std::int64_t>(
      1 << 16, std::max<std::int64_t>(1, (options.samples + pixels - 1) / pixels)));

  const GradientIntegrator integrator(scene);
  if (!integrator.shifts_possible()) {
    // Nothing can be shifted (hero lanes and no smooth dispersive material): τ does not matter.
    GradientPilot none;
    none.epsilon = options.epsilon;
    return none;
  }
  const spectral::WavelengthPdfView lambda_pdf(scene.wavelength_pdf());
  std::vector<PixelEvents> per_pixel(static_cast<std::size_t>(pixels));
  auto trace = [&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, pixels, 16),
                      [&](const tbb::blocked_range<int>& range) {
                        TraceCounters counters;
                        for (int p = range.begin(); p != range.end(); ++p) {
                          const int x = std::min(width - 1, (p % columns) * stride + stride / 2);
                          const int y = std::min(height - 1, (p / columns) * stride + stride / 2);
                          PixelEvents& sink = per_pixel[std::size_t(p)];
                          for (int s = 0; s < spp; ++s) {
                            sink.sample = std::uint32_t(s);
                            integrator.trace(x, y, kPilotPass, std::uint32_t(s), lambda_pdf,
                                             counters, nullptr, &sink);
                          }
                        }
                      });
  };
  if (options.threads > 0) {
    tbb::task_arena arena(options.threads);
    arena.execute(trace);
  } else {
    trace();
  }

  // Joined in pixel order: the same events, in the same order, for any thread count.
  std::vector<GradientEvent> events;
  std::vector<std::uint32_t> sample_of;
  std::uint32_t first_sample = 0;
  for (PixelEvents& p : per_pixel) {
    events.insert(events.end(), p.events.begin(), p.events.end());
    for (std::uint32_t s : p.sample_of) sample_of.push_back(first_sample + s);
    first_sample += std::uint32_t(spp);
  }
  const GradientPilotEvents pilot(std::move(events), std::move(sample_of),
                                  std::uint64_t(pixels) * std::uint64_t(spp));

  GradientPilot out;
  out.tau = pilot.choose_tau(options.epsilon);
  out.epsilon = options.epsilon;
  out.pixels = pixels;
  out.spp = spp;
  out.samples = pilot.samples();
  out.events = pilot.events();
  out.shifted_event_fraction = pilot.shifted_event_fraction(out.tau);
  out.shifted_square_fraction = pilot.shifted_square_fraction(out.tau);
  out.lost_benefit_fraction = pilot.lost_benefit_fraction(out.tau);
  out.second_moment_rise = pilot.second_moment_rise(out.tau);
  out.offset_vertex_fraction = pilot.offset_vertex_fraction(out.tau);
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

}  // namespace prism::worker
