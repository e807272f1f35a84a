#include "coordinator/active_job.h"

#include <gtest/gtest.h>

#include <set>

#include "services/job/job_spec.h"
#include "services/scene/parser.h"
#include "services/scene/scene_loader.h"

namespace prism::coordinator {
namespace {

constexpr char kScene[] = R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 30
Film "spectral" "integer xresolution" 24 "integer yresolution" 16 "integer nbuckets" 8
Sampler "zsobol" "integer pixelsamples" 16
WorldBegin
LightSource "point" "spectrum I" "stdillum-F11" "point3 from" [0 2 -2]
AttributeBegin
  Material "diffuse" "float reflectance" 0.5
  Shape "sphere" "float radius" 0.8
AttributeEnd
)";

class ActiveJobTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    library_ = new spectral::SpectrumLibrary(*spectral::SpectrumLibrary::load_builtin());
  }
  static void TearDownTestSuite() { delete library_; }

  std::unique_ptr<ActiveJob> make(const prism::v1::JobSpec& edits) {
    auto scene =
        scene::parse_scene_string(kScene, "scene.pbrt", scene::with_library_names(*library_));
    EXPECT_TRUE(scene.ok()) << scene.status();
    prism::v1::JobSpec spec = edits;
    spec.set_bundle_hash(std::string(64, 'a'));
    spec.set_scene_path("scene.pbrt");
    spec.set_tile_size(8);
    auto params = job::job_parameters(spec, *scene);
    EXPECT_TRUE(params.ok()) << params.status();
    auto job = ActiveJob::create(*params, job::to_proto(*params), *scene, *library_, cmf_);
    EXPECT_TRUE(job.ok()) << job.status();
    return job.ok() ? std::move(*job) : nullptr;
  }

  // The stage arithmetic agrees with the task list: every task index lies in its stage and in
  // the task range of its tile, its rect is that tile's, and the stages tile the index space.
  static void expect_consistent(const ActiveJob& job) {
    const std::vector<TaskSpec> tasks = job.task_specs();
    ASSERT_EQ(job.stage_first.front(), 0);
    ASSERT_EQ(job.stage_first.back(), static_cast<int>(tasks.size()));
    std::set<int> seen;
    for (int stage = 0; stage <= job.final_stage(); ++stage) {
      const std::vector<TaskSpec> part = job.stage_specs(stage);
      ASSERT_EQ(static_cast<int>(part.size()),
                job.stage_first[std::size_t(stage) + 1] - job.stage_first[std::size_t(stage)]);
    }
    for (int i = 0; i < static_cast<int>(tasks.size()); ++i) {
      const int stage = job.stage_of(i);
      ASSERT_GE(i, job.stage_first[std::size_t(stage)]);
      ASSERT_LT(i, job.stage_first[std::size_t(stage) + 1]);
      const auto [first, last] = job.tile_tasks(stage, job.tile_of(i));
      ASSERT_GE(i, first);
      ASSERT_LT(i, last);
      for (int j = first; j < last; ++j) {
        EXPECT_EQ(tasks[std::size_t(j)].tile, tasks[std::size_t(i)].tile);
        seen.insert(j);
      }
      EXPECT_EQ(tasks[std::size_t(i)].pass,
                stage < job.first_final_stage() ? Pass::kPrepass : Pass::kFinal);
    }
    EXPECT_EQ(seen.size(), tasks.size());
  }

  static spectral::SpectrumLibrary* library_;
  spectral::ColorMatching cmf_ = spectral::ColorMatching::cie1931();
};
spectral::SpectrumLibrary* ActiveJobTest::library_ = nullptr;

// 24x16 in 8-pixel tiles is 6 tiles; 16 spp in ranges of 5 is 4 ranges per tile.
TEST_F(ActiveJobTest, AFinalPassInSampleRangesIsOneStageOfTileMajorTasks) {
  prism::v1::JobSpec spec;
  spec.set_samples_per_task(5);
  const auto job = make(spec);
  ASSERT_NE(job, nullptr);
  EXPECT_EQ(job->first_final_stage(), 0);
  EXPECT_EQ(job->final_stage(), 0);
  EXPECT_EQ(job->stage_first, (std::vector<int>{0, 24}));
  EXPECT_EQ(job->tile_of(0), 0);
  EXPECT_EQ(job->tile_of(3), 0);
  EXPECT_EQ(job->tile_of(4), 1);
  EXPECT_EQ(job->tile_tasks(0, 5), (std::pair<int, int>{20, 24}));
  expect_consistent(*job);
}

// Two prepasses (one task per tile each) come before the final pass.
TEST_F(ActiveJobTest, PrepassesAreStagesBeforeTheFinalPass) {
  prism::v1::JobSpec spec;
  spec.mutable_prepass()->set_enabled(true);
  spec.mutable_prepass()->set_passes(2);
  spec.mutable_prepass()->set_spp(8);
  const auto job = make(spec);
  ASSERT_NE(job, nullptr);
  EXPECT_EQ(job->first_final_stage(), 2);
  EXPECT_EQ(job->final_stage(), 2);
  EXPECT_EQ(job->stage_first, (std::vector<int>{0, 6, 12, 18}));
  EXPECT_EQ(job->stage_of(5), 0);
  EXPECT_EQ(job->stage_of(6), 1);
  EXPECT_EQ(job->stage_of(17), 2);
  EXPECT_EQ(job->tile_of(13), 1);
  expect_consistent(*job);
}

// A target error turns the final pass into rounds of doubling spp (4, 8, 16, 32 at a max of
// 32), each a stage with every tile.
TEST_F(ActiveJobTest, ATargetErrorRendersTheFinalPassAsRounds) {
  prism::v1::JobSpec spec;
  spec.set_spp(4);
  spec.set_target_error(0.05f);
  spec.set_max_spp(32);
  const auto job = make(spec);
  ASSERT_NE(job, nullptr);
  EXPECT_EQ(job->round_plans.size(), 4u);
  EXPECT_EQ(job->final_stage(), 3);
  EXPECT_EQ(job->stage_first, (std::vector<int>{0, 6, 12, 18, 24}));
  const std::vector<TaskSpec> round3 = job->stage_specs(2);
  ASSERT_EQ(round3.size(), 6u);
  EXPECT_EQ(round3[0].samples.s0, 8u);
  EXPECT_EQ(round3[0].samples.s1, 16u);
  expect_consistent(*job);
}

}  // namespace
}  // namespace prism::coordinator
