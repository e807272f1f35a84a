#include "coordinator/job_report.h"

#include <gtest/gtest.h>

#include "services/scene/scene_description.h"

namespace prism::coordinator {
namespace {

job::JobParameters gradient_job() {
  job::JobParameters p;
  p.width = 64;
  p.height = 48;
  p.spp = 16;
  p.render.integrator = job::IntegratorKind::kGradient;
  p.render.gradient_offset_bins = 5;
  p.render.gradient_tau = 0.125f;
  p.gradient.delta = 0.15;
  p.gradient.norm = job::PoissonNorm::kL1;
  job::TauPilotReport pilot;
  pilot.epsilon = 0.05f;
  pilot.events = 10736;
  p.gradient.tau_pilot = pilot;
  job::AutoReport choice;
  choice.choice = "gradient";
  choice.reason = "predicted 0.75 of hero";
  p.auto_choice = choice;
  return p;
}

// What the job chose reaches the report: the gradient settings with the pilot that chose τ, and
// auto's choice; a job without a prepass has no prepass section.
TEST(JobReportTest, TheGradientSettingsAndAutosChoiceReachTheReport) {
  const job::JobParameters p = gradient_job();
  RenderReport report;
  add_job_sections(p, report);
  ASSERT_TRUE(report.gradient.has_value());
  EXPECT_EQ(report.gradient->offset_bins, 5);
  EXPECT_EQ(report.gradient->tau, 0.125f);
  EXPECT_EQ(report.gradient->norm, "l1");
  EXPECT_EQ(report.gradient->tau_pilot, p.gradient.tau_pilot);
  EXPECT_EQ(report.auto_choice, p.auto_choice);
  EXPECT_FALSE(report.prepass.has_value());
}

// A prepass section lists each pass's spp and film as the coordinator schedules them.
TEST(JobReportTest, APrepassSectionListsThePassesAsScheduled) {
  job::JobParameters p = gradient_job();
  p.render.integrator = job::IntegratorKind::kHero;
  p.prepass = job::PrepassParameters{};
  p.prepass->passes = 2;
  p.prepass->spp = 64;
  RenderReport report;
  add_job_sections(p, report);
  EXPECT_FALSE(report.gradient.has_value());
  ASSERT_TRUE(report.prepass.has_value());
  EXPECT_EQ(report.prepass->passes, 2);
  EXPECT_EQ(report.prepass->pass_spp, (std::vector<std::uint64_t>{8, 64}));
  EXPECT_EQ(report.prepass->pass_resolution, (std::vector<std::string>{"64x48", "64x48"}));
}

// Only the features not rendered exactly as pbrt-v4 would are reported, with where they are.
TEST(JobReportTest, OnlyFeaturesThatAreNotSupportedExactlyAreReported) {
  scene::SceneDescription scene;
  scene::FeatureUse supported;
  supported.feature = "Shape \"trianglemesh\"";
  scene.features.push_back(supported);
  scene::FeatureUse ignored;
  ignored.feature = "Option \"disablepixeljitter\"";
  ignored.status = scene::FeatureStatus::kIgnored;
  ignored.uses = 2;
  scene.features.push_back(ignored);
  const std::vector<SceneFeatureNote> notes = reported_features(scene);
  ASSERT_EQ(notes.size(), 1u);
  EXPECT_EQ(notes[0].feature, ignored.feature);
  EXPECT_EQ(notes[0].status, "ignored");
  EXPECT_EQ(notes[0].uses, 2);
}

}  // namespace
}  // namespace prism::coordinator
