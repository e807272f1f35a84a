// The automatic shift threshold τ of a gradient job (`--tau auto`; spectral gradient paper
// §3.3). A short pilot traces a stride-sampled subset of the image's pixels at τ = 0 with its
// own sample streams (pass kPilotPass, independent of the job's passes) and records every base
// event: its roulette-free value c (what τ is compared with), the squares it adds to the
// gradients unshifted and shifted, and how deep the offsets had to follow the base to reach it.
//
// Raising τ leaves an event with c <= τ unshifted: it saves the offsets' work for it (and for the
// steps after a path's last shifted event) and gives up what its shift gained. Per side of an
// event, unshifted it adds c² to the gradients' sum of squares, shifted its square s as traced (a
// side is shifted while both c and the offset's own value exceed τ); the shift's benefit is
// b = max(0, c² − s). The pilot picks the largest τ that gives up at most ε of the whole benefit:
//     Σ_{sides with min(c, own) <= τ} b <= ε · Σ_sides b.
// Only the positive part counts: a shift that made a sample worse (s > c², a rare offset far
// brighter than its base) is noise that would otherwise cancel real losses; with the signed sum
// measured against Σ s, two seeds of scenes/torus-glass.pbrt chose τ = 0.26 and 5.9, the second
// shifting nothing and losing 3× at equal time. The pilot also reports the predicted rise of the
// gradients' sum of squares, Σ (c² − s) over the unshifted sides, as a fraction of Σ s; it is
// exact for the pilot's own samples (tracing them at τ gives that sum: the base path does not
// depend on τ), which the tests check.
// ε is a fraction, so τ follows the scene's brightness (c is in output units) and the job stays
// the same whatever the scene's scale. The choice is a pure function of the scene, the job's
// options and the seed: the pilot's events are collected per pixel and joined in pixel order,
// whatever the thread count, so the farm and `prism render` run the same τ (the job spec carries
// the number).
#pragma once

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "worker/gradient/integrator.h"
#include "worker/render_scene.h"

namespace prism::worker {

// The pilot's own pass number: sample streams no job pass uses (0 final, 1.. prepass).
inline constexpr std::uint32_t kPilotPass = 0x70696c74;  // "pilt"

struct GradientPilotOptions {
  int max_pixels = 4096;  // pixels traced, on a regular stride over the image
  // Samples in all, spread evenly over those pixels (at least one each). Rare bright events (a
  // caustic) carry most of the benefit, so the choice needs many samples: at 32768, two seeds'
  // τ agree within 1.8× on seven of the eight evaluation scenes; on the caustic they differ 9×
  // and the error by 4 % (docs/benchmarks.md).
  int samples = 32768;
  double epsilon = 0.05;  // share of the shifts' benefit τ may give up, in (0, 1]
  int threads = 0;        // 0: TBB's default
};

// What the pilot measured and chose (the job report's gradient.tau_pilot).
struct GradientPilot {
  float tau = 0;
  double epsilon = 0;
  int pixels = 0;
  int spp = 0;
  std::uint64_t samples = 0;
  std::uint64_t events = 0;  // base events with light (c > 0)
  // At the chosen τ: the fraction of events shifted, the fraction of Σc² they carry, the share
  // of the benefit given up (<= ε), the predicted rise of the gradients' sum of squares, and the
  // offsets' predicted catch-up vertices as a fraction of τ = 0's (the shift work that remains).
  double shifted_event_fraction = 0;
  double shifted_square_fraction = 0;
  double lost_benefit_fraction = 0;
  double second_moment_rise = 0;
  double offset_vertex_fraction = 0;
  double seconds = 0;  // wall clock (reports only; never part of the choice)
};

// The events of a pilot, and the predictions above for any τ. Built by run_gradient_pilot, or
// directly from events in tests.
class GradientPilotEvents {
 public:
  // `events` in sample order; `sample_of[e]` the sample (0..samples−1, nondecreasing) of event e.
  GradientPilotEvents(std::vector<GradientEvent> events, std::vector<std::uint32_t> sample_of,
                      std::uint64_t samples);

  std::uint64_t samples() const { return samples_; }
  std::size_t events() const { return events_.size(); }
  // Σ s over both sides of every event at τ = 0: the gradients' sum of squares.
  double second_moment() const { return second_moment_; }
  // Σ b over both sides of every event: what shifting gains.
  double benefit() const { return benefit_; }
  // Predicted relative rise of the gradients' sum of squares at τ (0 at τ = 0).
  double second_moment_rise(float tau) const;
  // The share of the benefit the sides unshifted at τ give up.
  double lost_benefit_fraction(float tau) const;
  double shifted_event_fraction(float tau) const;
  double shifted_square_fraction(float tau) const;
  double offset_vertex_fraction(float tau) const;
  // The largest τ with lost_benefit_fraction(τ) <= ε, placed in a clean gap of the pilot's
  // values: just above a value v (v·(1 + kTauGap/2)) where the next value is more than kTauGap
  // relative above v, or above the largest value (nothing of the pilot's shifted). Just above,
  // not mid-gap: a wide gap (the bright, sparse events) holds values the job will meet, and
  // they should stay shifted as the pilot predicted. 0 without events. A τ on one of the values
  // would be decided differently by the two sides of a pair where their own computations of a
  // path's value differ in the last bits, and where many paths share one value (in a white furnace
  // every path's value is the light over p(λ)) that one-sided decision biases the gradients; in a
  // gap no value the job meets is within rounding of it.
  float choose_tau(double epsilon) const;
  static constexpr double kTauGap = 1e-4;

 private:
  // Where one side of one event becomes unshifted (τ >= min(c, the offset's own value)) and what
  // that adds to the second moment; ascending τ.
  struct Transition {
    float tau;
    double rise;     // c² − s
    double benefit;  // max(0, c² − s)
  };
  std::vector<GradientEvent> events_;
  std::vector<std::uint32_t> sample_of_;
  std::vector<Transition> transitions_;
  std::uint64_t samples_ = 0;
  double second_moment_ = 0;
  double benefit_ = 0;
  double unshifted_total_ = 0;  // Σ c²
};

// Runs the pilot on `scene`, which must be built for the gradient integrator with τ = 0 (its
// options are the job's otherwise) and a width x height film. INVALID_ARGUMENT for options out of
// range.
absl::StatusOr<GradientPilot> run_gradient_pilot(const RenderScene& scene, int width, int height,
                                                 const GradientPilotOptions& options);

}  // namespace prism::worker
