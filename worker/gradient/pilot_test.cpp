// Tests of the automatic τ's pilot (pilot.h): the choice against hand-computed events,
// the prediction against a trace at the chosen τ on the same samples (it must be exact), the
// same choice on any thread count, and the refusals.
#include "worker/gradient/pilot.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <vector>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "worker/testing/tracer_test.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

const fs::path kTestData = fs::path(PRISM_SOURCE_DIR) / "worker" / "testdata";

GradientEvent event(float c, float up_square, float down_square, float own_up, float own_down,
                    int vertices) {
  return {c, c * c, {up_square, down_square}, {own_up, own_down}, vertices};
}

TEST(GradientPilotEvents, PredictsTheRiseAndChoosesTheLargestTauWithinIt) {
  // Sample 0: a dim event (c = 1) whose shifts cut its square 1 → 0.25 per side, then a bright
  // one (c = 10, squares 100 → 1 per side). Sample 1: c = 2 whose down side failed (own 0, its
  // square stays 4) and whose up side's offset is dim (own 0.5).
  std::vector<GradientEvent> events = {event(1, 0.25f, 0.25f, 3, 3, 2), event(10, 1, 1, 20, 20, 4),
                                       event(2, 1, 4, 0.5f, 0, 3)};
  const GradientPilotEvents pilot(events, {0, 0, 1}, 2);
  const double m0 = 0.25 + 0.25 + 1 + 1 + 1 + 4;  // 7.5
  EXPECT_DOUBLE_EQ(pilot.second_moment(), m0);
  // Transitions: (0, down of c=2: 4 − 4 = 0), (0.5, up of c=2: 4 − 1 = 3), (1, c=1 both sides:
  // 2 × 0.75), (10, c=10 both: 2 × 99).
  EXPECT_DOUBLE_EQ(pilot.second_moment_rise(0), 0.0);
  EXPECT_DOUBLE_EQ(pilot.second_moment_rise(0.4f), 0.0);
  EXPECT_DOUBLE_EQ(pilot.second_moment_rise(0.5f), 3 / m0);
  EXPECT_DOUBLE_EQ(pilot.second_moment_rise(1), 4.5 / m0);
  EXPECT_DOUBLE_EQ(pilot.second_moment_rise(10), 202.5 / m0);
  // Benefits: 3 at 0.5, 2 × 0.75 at 1, 2 × 99 at 10, none for the failed side: 202.5 in all.
  EXPECT_DOUBLE_EQ(pilot.benefit(), 202.5);
  EXPECT_DOUBLE_EQ(pilot.lost_benefit_fraction(0.5f), 3 / 202.5);
  EXPECT_DOUBLE_EQ(pilot.lost_benefit_fraction(1), 4.5 / 202.5);
  // τ sits just above the last value it may unshift, kTauGap/2 relative, in a clean gap.
  const float above = 1 + GradientPilotEvents::kTauGap / 2;
  EXPECT_EQ(pilot.choose_tau(0.01), 0.0f);  // 3/202.5 = 0.0148 already too much
  EXPECT_FLOAT_EQ(pilot.choose_tau(0.015), 0.5f * above);
  EXPECT_FLOAT_EQ(pilot.choose_tau(0.025), 1.0f * above);
  EXPECT_FLOAT_EQ(pilot.choose_tau(0.99), 1.0f * above);
  // Everything may go: just above the largest value, so nothing of the pilot's shifts.
  EXPECT_FLOAT_EQ(pilot.choose_tau(1.0), 10.0f * above);
  EXPECT_DOUBLE_EQ(pilot.shifted_event_fraction(1), 2.0 / 3);
  EXPECT_DOUBLE_EQ(pilot.shifted_square_fraction(1), 104.0 / 105);
  // Catch-up: at τ = 0 sample 0 follows to vertex 4, sample 1 to 3; at τ = 1 only the c = 10 event
  // of sample 0 (vertex 4) and c = 2 of sample 1 (vertex 3); at τ = 2 sample 1 none.
  EXPECT_DOUBLE_EQ(pilot.offset_vertex_fraction(1), 1.0);
  EXPECT_DOUBLE_EQ(pilot.offset_vertex_fraction(2), 4.0 / 7);
  EXPECT_DOUBLE_EQ(pilot.offset_vertex_fraction(10), 0.0);
}

// A shift that made its sample worse (s > c²) gains nothing, and its loss does not cancel the
// gains of others: the noisy bright offset cannot buy a large τ.
TEST(GradientPilotEvents, HarmfulShiftsDoNotCancelUsefulOnes) {
  std::vector<GradientEvent> events = {event(1, 0, 0, 5, 5, 1), event(2, 400, 400, 5, 5, 1),
                                       event(30, 100, 100, 50, 50, 1)};
  const GradientPilotEvents pilot(events, {0, 1, 2}, 3);
  EXPECT_DOUBLE_EQ(pilot.benefit(), 2 * 1.0 + 2 * 800.0);
  // Signed, unshifting everything would look cheap: (2 − 792 + 1600) / 1000 = 0.81 of Σ s.
  EXPECT_DOUBLE_EQ(pilot.second_moment_rise(30), 0.81);
  // But the bright event's gain is 1600 of 1602: τ stays below 30, just above 2.
  const float above = 1 + GradientPilotEvents::kTauGap / 2;
  EXPECT_FLOAT_EQ(pilot.choose_tau(0.9), 2.0f * above);
  EXPECT_FLOAT_EQ(pilot.choose_tau(0.002), 2.0f * above);  // the harmful shift costs nothing
  EXPECT_EQ(pilot.choose_tau(0.001), 0.0f);
}

// Nothing to shift for, or nothing gained by shifting.
TEST(GradientPilotEvents, NoLightMeansNoThreshold) {
  const GradientPilotEvents pilot({}, {}, 5);
  EXPECT_EQ(pilot.choose_tau(0.1), 0.0f);
  EXPECT_EQ(pilot.second_moment_rise(1), 0.0);
  const GradientPilotEvents useless({event(1, 1, 1, 2, 2, 1), event(3, 9, 9, 4, 4, 1)}, {0, 1}, 2);
  EXPECT_FLOAT_EQ(useless.choose_tau(0.1), 3.0f * (1 + GradientPilotEvents::kTauGap / 2));
}

// Where many paths share one value up to rounding (a white furnace: every path's value is the
// light over p(λ)), a τ among them would be decided differently by the two sides of one pair,
// which biases the gradients (a BK7 sphere in a white furnace came out 0.6 % blue). τ goes below
// the cluster, into the clean gap beneath it, never within rounding of a value.
TEST(GradientPilotEvents, TauStaysOutOfClustersOfEqualValues) {
  std::vector<GradientEvent> events = {event(0.2f, 0, 0, 5, 5, 1)};
  for (int k = 0; k < 1000; ++k) {
    const float c = 0.56f * (1 + 1e-7f * float(k % 37));  // rounding-level spread
    events.push_back(event(c, 0.25f * c * c, 0.25f * c * c, c, c, 1));
  }
  std::vector<std::uint32_t> sample_of(events.size());
  for (std::uint32_t i = 0; i < sample_of.size(); ++i) sample_of[i] = i;
  const GradientPilotEvents pilot(events, sample_of, sample_of.size());
  for (double epsilon : {0.001, 0.3, 0.5, 0.7, 0.999}) {
    const float tau = pilot.choose_tau(epsilon);
    SCOPED_TRACE(epsilon);
    for (const GradientEvent& e : events) {
      EXPECT_GT(std::abs(double(tau) / double(e.threshold_value) - 1),
                GradientPilotEvents::kTauGap / 4);
    }
    // Half the benefit inside the cluster may not go; all of it at epsilon 0.999 neither.
    EXPECT_LT(tau, 0.56f);
    EXPECT_LE(pilot.lost_benefit_fraction(tau), epsilon);
  }
  EXPECT_FLOAT_EQ(pilot.choose_tau(0.5), 0.2f * (1 + GradientPilotEvents::kTauGap / 2));
}

class GradientPilotTest : public testing::TracerTest {
 protected:
  static scene::SceneDescription load(const std::string& name) {
    auto loaded = scene::load_scene(kTestData / name, {});
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    return loaded.ok() ? loaded->description : scene::SceneDescription();
  }

  static std::unique_ptr<RenderScene> build(
      const scene::SceneDescription& desc, float tau,
      job::IntegratorKind integrator = job::IntegratorKind::kGradient, int lanes = 1) {
    job::RenderOptions options;
    options.integrator = integrator;
    options.bins = 16;
    options.gradient_offset_bins = 4;
    options.gradient_tau = tau;
    options.gradient_lanes = lanes;  // 1: single-wavelength base paths shift on every scene
    options.max_depth = 6;
    options.seed = 11;
    auto built = RenderScene::build(*device_, desc, *library_, options, desc.film.x_resolution,
                                    desc.film.y_resolution);
    EXPECT_TRUE(built.ok()) << built.status();
    return built.ok() ? std::move(*built) : nullptr;
  }

  // Every event of pixels (x, y) < 12 x 12, `spp` samples each, traced at the scene's τ.
  static std::vector<GradientEvent> trace(const RenderScene& scene, int spp,
                                          std::vector<std::uint32_t>* sample_of = nullptr) {
    struct Sink final : GradientEventSink {
      void record(const GradientEvent& e) override {
        events.push_back(e);
        samples.push_back(sample);
      }
      std::vector<GradientEvent> events;
      std::vector<std::uint32_t> samples;
      std::uint32_t sample = 0;
    } sink;
    const GradientIntegrator integrator(scene);
    TraceCounters counters;
    for (int y = 0; y < 12; ++y) {
      for (int x = 0; x < 12; ++x) {
        for (int s = 0; s < spp; ++s) {
          integrator.trace(x, y, kPilotPass, std::uint32_t(s), scene.wavelength_pdf(), counters,
                           nullptr, &sink);
          ++sink.sample;
        }
      }
    }
    if (sample_of != nullptr) *sample_of = sink.samples;
    return sink.events;
  }

  static double second_moment(const std::vector<GradientEvent>& events) {
    double m = 0;
    for (const GradientEvent& e : events) m += double(e.side_square[0]) + e.side_square[1];
    return m;
  }
};

// The base paths do not depend on τ, so tracing the pilot's samples at any τ must give exactly
// the predicted second moment: the prediction holds no model, only bookkeeping.
TEST_F(GradientPilotTest, PredictionIsExactOnThePilotsOwnSamples) {
  for (const char* name :
       {"gradient_prism.pbrt", "gradient_glass_diffuse.pbrt", "gradient_rough_glass.pbrt"}) {
    SCOPED_TRACE(name);
    const scene::SceneDescription desc = load(name);
    auto at_zero = build(desc, 0);
    ASSERT_TRUE(at_zero);
    std::vector<std::uint32_t> sample_of;
    std::vector<GradientEvent> events = trace(*at_zero, 16, &sample_of);
    ASSERT_GT(events.size(), 500u);
    const GradientPilotEvents pilot(events, sample_of, 12 * 12 * 16);
    ASSERT_GT(pilot.second_moment(), 0.0);

    std::vector<float> taus = {pilot.choose_tau(0.05), pilot.choose_tau(0.3),
                               pilot.choose_tau(1.0)};
    for (float tau : taus) {
      SCOPED_TRACE(tau);
      auto scene = build(desc, tau);
      ASSERT_TRUE(scene);
      std::vector<GradientEvent> traced = trace(*scene, 16);
      ASSERT_EQ(traced.size(), events.size());  // the same base events
      const double predicted = pilot.second_moment() * (1.0 + pilot.second_moment_rise(tau));
      EXPECT_NEAR(second_moment(traced), predicted, 1e-5 * predicted);
      std::size_t shifted = 0;
      for (const GradientEvent& e : traced) shifted += e.threshold_value > tau ? 1 : 0;
      EXPECT_DOUBLE_EQ(double(shifted) / double(traced.size()), pilot.shifted_event_fraction(tau));
    }
    EXPECT_LE(pilot.lost_benefit_fraction(taus[0]), 0.05);
    EXPECT_LE(pilot.lost_benefit_fraction(taus[1]), 0.3);
    EXPECT_LE(taus[0], taus[1]);
    EXPECT_LE(taus[1], taus[2]);
  }
}

TEST_F(GradientPilotTest, ChoosesTheSameTauOnAnyThreadCount) {
  const scene::SceneDescription desc = load("gradient_glass_diffuse.pbrt");
  auto scene = build(desc, 0);
  ASSERT_TRUE(scene);
  GradientPilotOptions options;
  options.max_pixels = 64;  // a stride of 2 over 12 x 12
  options.samples = 36 * 32;
  options.threads = 1;
  auto one = run_gradient_pilot(*scene, 12, 12, options);
  ASSERT_TRUE(one.ok()) << one.status();
  options.threads = 2;
  auto two = run_gradient_pilot(*scene, 12, 12, options);
  ASSERT_TRUE(two.ok()) << two.status();
  EXPECT_EQ(one->pixels, 36);
  EXPECT_EQ(one->samples, 36u * 32u);
  EXPECT_GT(one->events, 0u);
  EXPECT_GT(one->tau, 0.0f);
  EXPECT_LE(one->lost_benefit_fraction, options.epsilon);
  EXPECT_EQ(one->tau, two->tau);
  EXPECT_EQ(one->events, two->events);
  EXPECT_EQ(one->lost_benefit_fraction, two->lost_benefit_fraction);
  EXPECT_EQ(one->second_moment_rise, two->second_moment_rise);
  EXPECT_EQ(one->offset_vertex_fraction, two->offset_vertex_fraction);
}

// With hero lanes on a scene without a material that can refract smooth-dispersively nothing is
// ever shifted (GradientIntegrator::shifts_possible): the pilot traces nothing and τ stays 0.
TEST_F(GradientPilotTest, HasNothingToChooseWhereNothingCanBeShifted) {
  const scene::SceneDescription rough = load("gradient_rough_glass.pbrt");
  auto by_scene = build(rough, 0, job::IntegratorKind::kGradient, 0);
  ASSERT_TRUE(by_scene);
  auto pilot = run_gradient_pilot(*by_scene, 12, 12, {});
  ASSERT_TRUE(pilot.ok()) << pilot.status();
  EXPECT_EQ(pilot->events, 0u);
  EXPECT_EQ(pilot->samples, 0u);
  EXPECT_EQ(pilot->tau, 0.0f);
  // The same scene with single-wavelength base paths has events to choose from.
  auto single = build(rough, 0, job::IntegratorKind::kGradient, 1);
  ASSERT_TRUE(single);
  GradientPilotOptions small;
  small.samples = 2048;
  auto traced = run_gradient_pilot(*single, 12, 12, small);
  ASSERT_TRUE(traced.ok()) << traced.status();
  EXPECT_GT(traced->events, 0u);
}

TEST_F(GradientPilotTest, RefusesScenesAndOptionsItCannotUse) {
  const scene::SceneDescription desc = load("gradient_prism.pbrt");
  auto with_tau = build(desc, 0.5f);
  auto hero = build(desc, 0, job::IntegratorKind::kHero);
  auto good = build(desc, 0);
  ASSERT_TRUE(with_tau && hero && good);
  EXPECT_EQ(run_gradient_pilot(*with_tau, 12, 12, {}).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(run_gradient_pilot(*hero, 12, 12, {}).status().code(),
            absl::StatusCode::kInvalidArgument);
  for (auto bad :
       {GradientPilotOptions{0, 8, 0.1, 0}, GradientPilotOptions{64, 0, 0.1, 0},
        GradientPilotOptions{64, 8, 0.0, 0}, GradientPilotOptions{64, 8, 1.5, 0},
        GradientPilotOptions{64, 8, 0.1, -1}, GradientPilotOptions{64, 1 << 25, 0.1, 0}}) {
    absl::Status s = run_gradient_pilot(*good, 12, 12, bad).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(s.message().find("gradient pilot"), std::string::npos) << s;
  }
  EXPECT_FALSE(run_gradient_pilot(*good, 0, 12, {}).ok());
}

}  // namespace
}  // namespace prism::worker
