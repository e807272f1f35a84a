#include "services/job/job_spec.h"

#include <gtest/gtest.h>

#include <string>
#include <utility>

#include "google/protobuf/util/message_differencer.h"

namespace prism::job {
namespace {

const std::string kHash(64, 'a');

scene::SceneDescription test_scene() {
  scene::SceneDescription scene;
  scene.film.x_resolution = 320;
  scene.film.y_resolution = 200;
  scene.film.bins = 32;
  scene.sampler.samples_per_pixel = 48;
  scene.integrator.max_depth = 7;
  return scene;
}

prism::v1::JobSpec minimal_spec() {
  prism::v1::JobSpec spec;
  spec.set_bundle_hash(kHash);
  spec.set_scene_path("scene.pbrt");
  return spec;
}

TEST(JobSpecTest, DefaultsComeFromTheSceneAsPrismRenderTakesThem) {
  auto p = job_parameters(minimal_spec(), test_scene());
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(p->width, 320);
  EXPECT_EQ(p->height, 200);
  EXPECT_EQ(p->spp, 48u);
  EXPECT_EQ(p->render.bins, 32);
  EXPECT_EQ(p->render.max_depth, 7);
  EXPECT_EQ(p->tile_size, kDefaultTileSize);
  EXPECT_EQ(p->samples_per_task, 0u);
  EXPECT_EQ(p->render.integrator, IntegratorKind::kHero);
  EXPECT_EQ(p->render.spectral_pdf, SpectralPdfKind::kFlat);
  EXPECT_EQ(p->render.emitter_pdf, EmitterPdfKind::kEmitters);
  EXPECT_EQ(p->render.light_selection, LightSelectionKind::kPower);
  EXPECT_TRUE(p->render.spectral_light_selection);
  EXPECT_TRUE(p->outputs.spectral_exr && p->outputs.rgb_exr && p->outputs.png);

  scene::SceneDescription no_buckets = test_scene();
  no_buckets.film.bins.reset();
  auto q = job_parameters(minimal_spec(), no_buckets);
  ASSERT_TRUE(q.ok()) << q.status();
  EXPECT_EQ(q->render.bins, 64);
}

TEST(JobSpecTest, ExplicitValuesRoundTripIndependentlyOfTheScene) {
  prism::v1::JobSpec spec = minimal_spec();
  spec.set_name("cornell");
  spec.set_integrator(prism::v1::INTEGRATOR_UNIFORM);
  spec.set_spectral_pdf(prism::v1::SPECTRAL_PDF_VISIBLE);
  spec.set_emitter_pdf(prism::v1::EMITTER_PDF_UNIFORM);
  spec.set_light_selection(prism::v1::LIGHT_SELECTION_SPATIAL);
  spec.set_spectral_light_selection(false);
  spec.set_spp(9);
  spec.set_width(17);
  spec.set_height(5);
  spec.set_bins(4);
  spec.set_tile_size(8);
  spec.set_seed(0xfeedfacecafebeefULL);
  spec.set_max_depth(0);  // a depth, not "the scene's"
  spec.set_samples_per_task(3);
  spec.set_light_caustics(true);
  spec.set_caustic_paths(0.125f);
  spec.set_splat_width(12.5f);
  spec.mutable_outputs()->set_png(true);
  spec.mutable_outputs()->set_png_exposure(-1.5f);
  spec.mutable_outputs()->set_exr_compression(prism::v1::EXR_COMPRESSION_PIZ);

  auto p = job_parameters(spec, test_scene());
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(p->render.max_depth, 0);
  EXPECT_FALSE(p->render.spectral_light_selection);
  EXPECT_FALSE(p->outputs.spectral_exr);
  EXPECT_TRUE(p->outputs.png);
  EXPECT_EQ(p->outputs.exr_compression, image::ExrCompression::kPiz);
  EXPECT_EQ(p->render.seed, 0xfeedfacecafebeefULL);

  const prism::v1::JobSpec wire = to_proto(*p);
  // Decoding the explicit spec against a different scene gives the same parameters.
  auto again = job_parameters(wire, scene::SceneDescription{});
  ASSERT_TRUE(again.ok()) << again.status();
  const prism::v1::JobSpec wire2 = to_proto(*again);
  EXPECT_TRUE(google::protobuf::util::MessageDifferencer::Equals(wire, wire2))
      << wire.DebugString() << "\nvs\n"
      << wire2.DebugString();
  EXPECT_EQ(again->width, 17);
  EXPECT_EQ(again->height, 5);
  EXPECT_EQ(again->spp, 9u);
  EXPECT_EQ(again->render.bins, 4);
  EXPECT_EQ(again->render.max_depth, 0);
  EXPECT_EQ(again->tile_size, 8);
  EXPECT_EQ(again->samples_per_task, 3u);
  EXPECT_EQ(again->outputs.exr_compression, image::ExrCompression::kPiz);
  EXPECT_TRUE(again->render.light_caustics);
  EXPECT_EQ(again->render.caustic_paths, 0.125f);
  EXPECT_EQ(again->render.light_paths_per_batch(17 * 5), 11);  // round(10.625)
  EXPECT_EQ(again->render.splat_width_nm, 12.5f);
  EXPECT_EQ(again->render.integrator, IntegratorKind::kUniform);
  EXPECT_EQ(again->render.spectral_pdf, SpectralPdfKind::kVisible);
  EXPECT_EQ(again->render.emitter_pdf, EmitterPdfKind::kUniform);
  EXPECT_EQ(again->render.light_selection, LightSelectionKind::kSpatial);
  EXPECT_FALSE(again->render.spectral_light_selection);
  EXPECT_EQ(again->outputs, p->outputs);
  EXPECT_EQ(again->name, "cornell");

  // And through the bytes.
  prism::v1::JobSpec parsed;
  ASSERT_TRUE(parsed.ParseFromString(wire.SerializeAsString()));
  EXPECT_TRUE(google::protobuf::util::MessageDifferencer::Equals(wire, parsed));
}

struct BadCase {
  const char* name;
  void (*mutate)(prism::v1::JobSpec&);
  const char* message;
};

TEST(JobSpecTest, BadFieldsAreRefusedNamingTheField) {
  const BadCase cases[] = {
      {"hash", [](prism::v1::JobSpec& s) { s.set_bundle_hash("ABC"); }, "bundle_hash 'ABC'"},
      {"scene", [](prism::v1::JobSpec& s) { s.clear_scene_path(); }, "scene_path"},
      {"spp", [](prism::v1::JobSpec& s) { s.set_spp(20'000'000); },
       "spp 20000000 is out of range: want 1..16777216"},
      {"bins_low", [](prism::v1::JobSpec& s) { s.set_bins(3); },
       "bins 3 is out of range: want 4..256"},
      {"bins_high", [](prism::v1::JobSpec& s) { s.set_bins(257); },
       "bins 257 is out of range: want 4..256"},
      {"tile", [](prism::v1::JobSpec& s) { s.set_tile_size(2); },
       "tile_size 2 is out of range: want 4..1024"},
      // All three outputs set false was read as none given, and wrote all three.
      {"no_outputs",
       [](prism::v1::JobSpec& s) {
         s.mutable_outputs()->set_spectral_exr(false);
         s.mutable_outputs()->set_rgb_exr(false);
         s.mutable_outputs()->set_png(false);
       },
       "outputs: spectral_exr, rgb_exr and png are all false"},
      {"depth", [](prism::v1::JobSpec& s) { s.set_max_depth(1025); },
       "max_depth 1025 is out of range: want 0..1024"},
      {"width_only", [](prism::v1::JobSpec& s) { s.set_width(10); }, "resolution 10x0"},
      {"huge",
       [](prism::v1::JobSpec& s) {
         s.set_width(16385);
         s.set_height(2);
       },
       "resolution 16385x2: want WxH with 1 <= W, H <= 16384"},
      {"gradient_options_without_gradient",
       [](prism::v1::JobSpec& s) { s.mutable_gradient()->set_tau(0.5f); },
       "gradient options (delta, tau, alpha, norm, lanes) need the gradient integrator, not hero"},
      {"delta",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->set_delta(0.7f);
       },
       "gradient.delta 0.7"},
      {"delta_rounds_to_zero_bins",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->set_delta(0.001f);
       },
       "rounds to 0 bins"},
      {"negative_tau",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->set_tau(-1.0f);
       },
       "gradient.tau -1 is out of range"},
      {"lanes_without_gradient", [](prism::v1::JobSpec& s) { s.mutable_gradient()->set_lanes(4); },
       "gradient options (delta, tau, alpha, norm, lanes) need the gradient integrator"},
      {"lanes",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->set_lanes(7);
       },
       "gradient.lanes 7 is out of range: want 1..6 (0: by the scene)"},
      {"tau_pilot_without_gradient",
       [](prism::v1::JobSpec& s) { s.mutable_gradient()->mutable_tau_pilot()->set_epsilon(0.1f); },
       "gradient options (delta, tau, alpha, norm, lanes) need the gradient integrator"},
      {"tau_pilot_epsilon",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->mutable_tau_pilot()->set_epsilon(0.0f);
       },
       "gradient.tau_pilot.epsilon 0 is out of range: want (0, 1]"},
      {"tau_pilot_fraction",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->mutable_tau_pilot()->set_epsilon(0.1f);
         s.mutable_gradient()->mutable_tau_pilot()->set_offset_vertex_fraction(1.5f);
       },
       "gradient.tau_pilot.offset_vertex_fraction 1.5 is out of range: want [0, 1]"},
      {"tau_pilot_lost_benefit",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->mutable_tau_pilot()->set_epsilon(0.1f);
         s.mutable_gradient()->mutable_tau_pilot()->set_lost_benefit_fraction(0.2f);
       },
       "gradient.tau_pilot.lost_benefit_fraction 0.2 is out of range: want [0, epsilon 0.1]"},
      {"tau_pilot_rise",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->mutable_tau_pilot()->set_epsilon(0.1f);
         s.mutable_gradient()->mutable_tau_pilot()->set_second_moment_rise(INFINITY);
       },
       "gradient.tau_pilot.second_moment_rise inf is out of range"},
      {"negative_alpha",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->set_alpha(-0.2f);
       },
       "gradient.alpha -0.2 is out of range"},
      {"nan_alpha",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->set_alpha(std::nanf(""));
       },
       "gradient.alpha nan is out of range"},
      {"norm",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.mutable_gradient()->set_norm(static_cast<prism::v1::PoissonNorm>(7));
       },
       "gradient.norm 7: want l2, l1 or weighted"},
      {"primal_without_gradient",
       [](prism::v1::JobSpec& s) { s.mutable_outputs()->set_primal_and_gradients(true); },
       "outputs.primal_and_gradients needs the gradient integrator"},
      {"integrator_enum",
       [](prism::v1::JobSpec& s) { s.set_integrator(static_cast<prism::v1::Integrator>(42)); },
       "integrator 42: want uniform, hero, gradient or light"},
      {"light_too_large",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_LIGHT);
         s.set_width(4096);
         s.set_height(4096);
         s.set_bins(64);
       },
       "returns 17280 MiB per task, over the limit of 1024 MiB"},
      {"splat_without_light_paths", [](prism::v1::JobSpec& s) { s.set_splat_width(20.0f); },
       "splat_width splats light paths: it needs the light integrator or light_caustics"},
      {"splat_width_range",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_LIGHT);
         s.set_splat_width(500.0f);
       },
       "splat_width 500 nm is out of range: want 0.1..470"},
      {"splat_width_nan",
       [](prism::v1::JobSpec& s) {
         s.set_light_caustics(true);
         s.set_splat_width(std::nanf(""));
       },
       "splat_width nan nm is out of range"},
      {"gather_with_light",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_LIGHT);
         s.set_gather_width(50.0f);
       },
       "gathering (--gather, gather_width) filters eye-traced images: it needs the hero or "
       "the uniform integrator"},
      {"gather_with_caustics",
       [](prism::v1::JobSpec& s) {
         s.set_light_caustics(true);
         s.set_gather_width(50.0f);
       },
       "without light-traced caustics"},
      {"gather_with_target_error",
       [](prism::v1::JobSpec& s) {
         s.set_gather_width(50.0f);
         s.set_target_error(0.05f);
       },
       "gathering (--gather, gather_width) does not combine with a target error"},
      {"gather_width_range", [](prism::v1::JobSpec& s) { s.set_gather_width(-3.0f); },
       "gather_width -3 nm is out of range: want 0.1..470"},
      {"caustics_with_gradient",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
         s.set_light_caustics(true);
       },
       "light-traced caustics (--caustics light, light_caustics) need the hero or the uniform "
       "integrator, not gradient"},
      {"caustic_paths_without_caustics", [](prism::v1::JobSpec& s) { s.set_caustic_paths(0.5f); },
       "caustic_paths is the share of light paths of light_caustics: set light_caustics"},
      {"caustic_paths_range",
       [](prism::v1::JobSpec& s) {
         s.set_light_caustics(true);
         s.set_caustic_paths(1.5f);
       },
       "caustic_paths 1.5 is out of range: want light paths per pixel and sample in 0.00390625..1"},
      {"caustic_paths_nan",
       [](prism::v1::JobSpec& s) {
         s.set_light_caustics(true);
         s.set_caustic_paths(std::nanf(""));
       },
       "caustic_paths nan is out of range"},
      {"caustics_with_prepass",
       [](prism::v1::JobSpec& s) {
         s.set_light_caustics(true);
         s.mutable_prepass()->set_enabled(true);
       },
       "light-traced caustics (--caustics light, light_caustics) do not combine with the "
       "prepass"},
      {"light_with_prepass",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_LIGHT);
         s.mutable_prepass()->set_enabled(true);
       },
       "the light integrator has no use for it"},
      {"light_with_target_error",
       [](prism::v1::JobSpec& s) {
         s.set_integrator(prism::v1::INTEGRATOR_LIGHT);
         s.set_target_error(0.05f);
       },
       "a target error (--target-error, target_error) is not available with the light "
       "integrator yet"},
      {"spectral_pdf",
       [](prism::v1::JobSpec& s) { s.set_spectral_pdf(static_cast<prism::v1::SpectralPdf>(9)); },
       "spectral_pdf 9: want flat or visible"},
      {"emitter_pdf",
       [](prism::v1::JobSpec& s) { s.set_emitter_pdf(static_cast<prism::v1::EmitterPdf>(9)); },
       "emitter_pdf 9: want uniform or emitters"},
      {"light_selection",
       [](prism::v1::JobSpec& s) {
         s.set_light_selection(static_cast<prism::v1::LightSelection>(9));
       },
       "light_selection 9: want uniform, power or spatial"},
      {"prepass_passes",
       [](prism::v1::JobSpec& s) {
         s.mutable_prepass()->set_enabled(true);
         s.mutable_prepass()->set_passes(9);
       },
       "prepass.passes 9 is out of range: want 1..8"},
      {"prepass_epsilon",
       [](prism::v1::JobSpec& s) {
         s.mutable_prepass()->set_enabled(true);
         s.mutable_prepass()->set_epsilon(1.5f);
       },
       "prepass epsilon is 1.5; it must be in (0, 1)"},
      {"prepass_sigma",
       [](prism::v1::JobSpec& s) {
         s.mutable_prepass()->set_enabled(true);
         s.mutable_prepass()->set_sigma_s(-1.0f);
       },
       "prepass sigma_s is -1"},
      {"prepass_options_when_off",
       [](prism::v1::JobSpec& s) {
         s.mutable_prepass()->set_enabled(false);
         s.mutable_prepass()->set_spp(64);
       },
       "prepass options are set but the prepass is off"},
      {"exposure", [](prism::v1::JobSpec& s) { s.mutable_outputs()->set_png_exposure(65.0f); },
       "outputs.png_exposure 65 is out of range"},
      {"exr_compression",
       [](prism::v1::JobSpec& s) {
         s.mutable_outputs()->set_exr_compression(static_cast<prism::v1::ExrCompression>(9));
       },
       "outputs.exr_compression 9: want none, rle, zips, zip or piz"},
      {"name", [](prism::v1::JobSpec& s) { s.set_name(std::string(300, 'n')); }, "name is 300"},
  };
  for (const BadCase& c : cases) {
    prism::v1::JobSpec spec = minimal_spec();
    c.mutate(spec);
    auto p = job_parameters(spec, test_scene());
    ASSERT_FALSE(p.ok()) << c.name;
    EXPECT_EQ(p.status().code(), absl::StatusCode::kInvalidArgument) << c.name;
    EXPECT_NE(std::string(p.status().message()).find(c.message), std::string::npos)
        << c.name << ": " << p.status().message();
  }
}

// Unset gradient and prepass fields take the defaults rounded as the wire keeps them, so the
// submitted spec and its explicit form (what workers and a restarted coordinator see) give the
// same parameters: the farm's reconstruction uses exactly the embedded render's α.
TEST(JobSpecTest, GradientAndPrepassDefaultsSurviveTheExplicitForm) {
  prism::v1::JobSpec spec = minimal_spec();
  spec.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
  spec.set_spp(4096);
  spec.mutable_prepass()->set_enabled(true);
  auto p = job_parameters(spec, test_scene());
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(p->render.gradient_offset_bins, 5);  // round(0.15 * 32)
  EXPECT_EQ(p->gradient.alpha, double(float(kDefaultPoissonAlpha)));
  EXPECT_EQ(p->gradient.norm, PoissonNorm::kL2);
  ASSERT_TRUE(p->prepass.has_value());
  EXPECT_EQ(p->prepass->passes, 2);
  EXPECT_EQ(p->prepass->spp, 128u);  // the budget's cap
  auto again = job_parameters(to_proto(*p), scene::SceneDescription{});
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->gradient, p->gradient);
  EXPECT_EQ(again->render.gradient_offset_bins, p->render.gradient_offset_bins);
  EXPECT_EQ(again->render.gradient_tau, p->render.gradient_tau);
  ASSERT_TRUE(again->prepass.has_value());
  EXPECT_EQ(again->prepass->epsilon, p->prepass->epsilon);
  EXPECT_EQ(again->prepass->fallback, p->prepass->fallback);
  EXPECT_EQ(again->prepass->sigma_s, p->prepass->sigma_s);
  EXPECT_EQ(again->prepass->sigma_r, p->prepass->sigma_r);
}

// The pilot's figures ride with the τ it chose through the explicit form.
TEST(JobSpecTest, TheTauPilotSurvivesTheExplicitForm) {
  prism::v1::JobSpec spec = minimal_spec();
  spec.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
  spec.mutable_gradient()->set_tau(0.125f);
  auto* t = spec.mutable_gradient()->mutable_tau_pilot();
  t->set_epsilon(0.1f);
  t->set_pixels(1200);
  t->set_spp(8);
  t->set_events(10736);
  t->set_shifted_event_fraction(0.08f);
  t->set_shifted_square_fraction(0.99f);
  t->set_lost_benefit_fraction(0.09f);
  t->set_second_moment_rise(-0.01f);
  t->set_offset_vertex_fraction(0.07f);
  auto p = job_parameters(spec, test_scene());
  ASSERT_TRUE(p.ok()) << p.status();
  ASSERT_TRUE(p->gradient.tau_pilot.has_value());
  EXPECT_EQ(p->gradient.tau_pilot->events, 10736u);
  EXPECT_EQ(p->render.gradient_tau, 0.125f);
  EXPECT_EQ(to_proto(*p).gradient().tau_pilot().SerializeAsString(), t->SerializeAsString());
  auto again = job_parameters(to_proto(*p), scene::SceneDescription{});
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->gradient, p->gradient);
}

// How `auto` chose survives the explicit form; a choice that is not the
// job's integrator is refused. A target error survives with its scope and max spp, and its
// ranges are checked.
TEST(JobSpecTest, TheAutoChoiceAndTheTargetErrorSurviveTheExplicitForm) {
  prism::v1::JobSpec spec = minimal_spec();
  spec.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
  auto* a = spec.mutable_auto_choice();
  a->set_choice("gradient");
  a->set_reason("predicted 0.75 of hero's relMSE at equal time");
  a->set_seconds(0.25);
  for (const char* m : {"hero", "gradient", "hero+caustics"}) {
    auto* c = a->add_candidates();
    c->set_method(m);
    c->set_rel_mse_per_sample(0.02);
    c->set_rays_per_sample(1e-6);
    c->set_relative_efficiency(std::string(m) == "hero" ? 1.0 : 0.75);
    c->set_ray_cost(std::string(m) == "gradient" ? 1.18 : 1.16);
    if (std::string(m) == "hero+caustics") c->set_caustic_paths(0.0625);
  }
  spec.set_target_error(0.02f);
  spec.set_target_error_image(true);
  spec.set_max_spp(512);
  auto p = job_parameters(spec, test_scene());
  ASSERT_TRUE(p.ok()) << p.status();
  ASSERT_TRUE(p->auto_choice.has_value());
  ASSERT_EQ(p->auto_choice->candidates.size(), 3u);
  EXPECT_EQ(p->auto_choice->candidates[2].caustic_paths, 0.0625);
  ASSERT_TRUE(p->target_error.has_value());
  EXPECT_TRUE(p->target_error->image_scope);
  EXPECT_EQ(p->target_error->max_spp, 512u);
  EXPECT_EQ(to_proto(*p).auto_choice().SerializeAsString(), a->SerializeAsString());
  auto again = job_parameters(to_proto(*p), scene::SceneDescription{});
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->auto_choice, p->auto_choice);
  EXPECT_EQ(again->target_error->relative, p->target_error->relative);

  // The limits themselves are taken, though the float field holds 1e-4 as 9.99999975e-05.
  for (float limit : {1e-4f, 1.0f}) {
    prism::v1::JobSpec at = spec;
    at.set_target_error(limit);
    EXPECT_TRUE(job_parameters(at, test_scene()).ok()) << limit;
  }
  prism::v1::JobSpec below = spec;
  below.set_target_error(9e-5f);
  EXPECT_FALSE(job_parameters(below, test_scene()).ok());

  prism::v1::JobSpec wrong = spec;
  wrong.mutable_auto_choice()->set_choice("uniform");
  EXPECT_NE(job_parameters(wrong, test_scene())
                .status()
                .message()
                .find("auto_choice says 'uniform' but the integrator is gradient"),
            std::string_view::npos);

  // hero+prepass is hero with a prepass that runs: a job whose spp leaves the prepass no budget
  // runs hero alone, and says so.
  prism::v1::JobSpec prepass = minimal_spec();
  prepass.set_integrator(prism::v1::INTEGRATOR_HERO);
  prepass.mutable_prepass()->set_enabled(true);
  prepass.set_spp(1024);
  prepass.mutable_auto_choice()->set_choice("hero+prepass");
  auto with_prepass = job_parameters(prepass, test_scene());
  ASSERT_TRUE(with_prepass.ok()) << with_prepass.status();
  EXPECT_TRUE(with_prepass->prepass.has_value());
  prepass.mutable_auto_choice()->set_choice("hero");
  EXPECT_NE(job_parameters(prepass, test_scene())
                .status()
                .message()
                .find("auto_choice says 'hero' but the integrator is hero+prepass"),
            std::string_view::npos);
  prepass.set_spp(16);
  auto unbudgeted = job_parameters(prepass, test_scene());
  ASSERT_TRUE(unbudgeted.ok()) << unbudgeted.status();
  EXPECT_FALSE(unbudgeted->prepass.has_value());
  for (float bad : {1e-5f, 1.5f, -0.1f}) {
    prism::v1::JobSpec t = minimal_spec();
    t.set_target_error(bad);
    EXPECT_NE(job_parameters(t, test_scene()).status().message().find("target_error"),
              std::string_view::npos)
        << bad;
  }
  prism::v1::JobSpec low = minimal_spec();
  low.set_spp(64);
  low.set_target_error(0.01f);
  low.set_max_spp(32);
  EXPECT_NE(job_parameters(low, test_scene())
                .status()
                .message()
                .find("(max_spp, --max-spp) 32 is out of range"),
            std::string_view::npos);
  prism::v1::JobSpec stray = minimal_spec();
  stray.set_max_spp(32);
  EXPECT_NE(job_parameters(stray, test_scene()).status().message().find("without a target_error"),
            std::string_view::npos);
}

// The variance-weighted norm survives the wire and makes the workers sum the squares of G; the
// other norms do not ask for them.
TEST(JobSpecTest, WeightedNormAsksForGradientSquares) {
  for (auto [wire, norm] : {std::pair{prism::v1::POISSON_NORM_WEIGHTED, PoissonNorm::kWeighted},
                            std::pair{prism::v1::POISSON_NORM_L1, PoissonNorm::kL1},
                            std::pair{prism::v1::POISSON_NORM_L2, PoissonNorm::kL2}}) {
    prism::v1::JobSpec spec = minimal_spec();
    spec.set_integrator(prism::v1::INTEGRATOR_GRADIENT);
    spec.mutable_gradient()->set_norm(wire);
    auto p = job_parameters(spec, test_scene());
    ASSERT_TRUE(p.ok()) << p.status();
    EXPECT_EQ(p->gradient.norm, norm);
    EXPECT_EQ(p->render.gradient_variances, norm == PoissonNorm::kWeighted);
    EXPECT_EQ(to_proto(*p).gradient().norm(), wire);
    auto again = job_parameters(to_proto(*p), scene::SceneDescription{});
    ASSERT_TRUE(again.ok()) << again.status();
    EXPECT_EQ(again->gradient.norm, norm);
    EXPECT_EQ(again->render.gradient_variances, p->render.gradient_variances);
  }
}

// The prepass is off unless the spec asks for it, whatever the scene needs; an explicit
// PrepassOptions decides.
TEST(JobSpecTest, PrepassDefaultFollowsTheScene) {
  scene::SceneDescription plain = test_scene();
  scene::Light light;
  light.kind = scene::PointLight{};
  plain.lights.push_back(light);
  auto p = job_parameters(minimal_spec(), plain);
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_FALSE(p->prepass.has_value()) << "one emitter spectrum, nothing dispersive: no prepass";

  scene::SceneDescription fog = plain;
  fog.media.push_back(scene::Medium{"fog", scene::HomogeneousMedium{}, {}});
  fog.camera.medium = 0;
  EXPECT_FALSE(prepass_by_default(IntegratorKind::kHero, fog));
  auto f = job_parameters(minimal_spec(), fog);
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_FALSE(f->prepass.has_value());
  prism::v1::JobSpec on = minimal_spec();
  on.set_spp(1024);
  on.mutable_prepass()->set_enabled(true);
  auto g = job_parameters(on, fog);
  ASSERT_TRUE(g.ok()) << g.status();
  EXPECT_TRUE(g->prepass.has_value());

  prism::v1::JobSpec off = minimal_spec();
  off.mutable_prepass()->set_enabled(false);
  auto q = job_parameters(off, fog);
  ASSERT_TRUE(q.ok()) << q.status();
  EXPECT_FALSE(q->prepass.has_value());
}

// Left open, Ñ follows the job's spp so the passes' samples stay under kBudgetShare of the final
// pass's (K = 2: Ñ·(1 + 1/8), image-scaled Ñ·(1 + 1/4)); a job too small to learn from, or whose
// first sample-scaled pass would decide from fewer than 8 spp, runs without a prepass; an
// explicit Ñ is kept whatever the spp.
TEST(JobSpecTest, PrepassSamplesFollowTheBudget) {
  EXPECT_EQ(budgeted_prepass_spp(1024, 2), 72u);        // ⌊0.08·1024/1.125⌋, first pass 9 spp
  EXPECT_EQ(budgeted_prepass_spp(1024, 2, true), 65u);  // ⌊0.08·1024/1.25⌋
  EXPECT_EQ(budgeted_prepass_spp(4096, 1), 128u);       // the cap
  EXPECT_EQ(budgeted_prepass_spp(900, 2), 64u);         // first pass 8 spp
  EXPECT_EQ(budgeted_prepass_spp(899, 2), 0u);          // Ñ = 63: first pass 7 spp
  EXPECT_EQ(budgeted_prepass_spp(225, 2), 0u);          // Ñ = 16: first pass 2 spp
  EXPECT_EQ(budgeted_prepass_spp(225, 1), 18u);         // one pass: it is the last
  EXPECT_EQ(budgeted_prepass_spp(222, 1), 17u);
  EXPECT_EQ(budgeted_prepass_spp(199, 1), 0u);         // Ñ = 15
  EXPECT_EQ(budgeted_prepass_spp(281, 2, true), 17u);  // image-scaled: Ñ spp on a smaller film
  EXPECT_EQ(budgeted_prepass_spp(249, 2, true), 0u);   // Ñ = 15
  EXPECT_EQ(budgeted_prepass_spp(4096, 3), 0u);        // first pass ⌊128/64⌋ = 2 spp
  EXPECT_EQ(budgeted_prepass_spp(1000000, 3), 0u);     // the cap first: ⌊128/64⌋ = 2 spp
  EXPECT_EQ(budgeted_prepass_spp(1000000, 2), 128u);   // first pass 16 spp
  for (std::uint64_t spp : {64u, 1024u, 100000u}) {
    const std::uint32_t n = budgeted_prepass_spp(spp, 2);
    if (n != 0) {
      EXPECT_LE(double(n) * 1.125, kBudgetShare * double(spp)) << spp;
    }
  }
  prism::v1::JobSpec spec = minimal_spec();
  spec.mutable_prepass()->set_enabled(true);
  spec.set_spp(1024);
  auto p = job_parameters(spec, test_scene());
  ASSERT_TRUE(p.ok()) << p.status();
  ASSERT_TRUE(p->prepass.has_value());
  EXPECT_EQ(p->prepass->spp, 72u);
  spec.set_spp(128);
  p = job_parameters(spec, test_scene());
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_FALSE(p->prepass.has_value());
  auto again = job_parameters(to_proto(*p), scene::SceneDescription{});
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_FALSE(again->prepass.has_value());
  spec.mutable_prepass()->set_spp(32);
  p = job_parameters(spec, test_scene());
  ASSERT_TRUE(p.ok()) << p.status();
  ASSERT_TRUE(p->prepass.has_value());
  EXPECT_EQ(p->prepass->spp, 32u);
}

}  // namespace
}  // namespace prism::job
