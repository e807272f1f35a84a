#include "coordinator/job_report.h"

#include "absl/strings/str_cat.h"
#include "coordinator/gather.h"
#include "coordinator/prepass.h"

namespace prism::coordinator {

std::vector<SceneFeatureNote> reported_features(const scene::SceneDescription& scene) {
  std::vector<SceneFeatureNote> out;
  for (const scene::FeatureUse& f : scene.features) {
    if (f.status == scene::FeatureStatus::kSupported) continue;
    out.push_back(SceneFeatureNote{scene::feature_status_name(f.status), f.feature,
                                   f.where.to_string(), f.uses, f.note, f.substitution});
  }
  return out;
}

void add_job_sections(const job::JobParameters& p, RenderReport& report) {
  report.auto_choice = p.auto_choice;
  if (p.render.splats_differentials()) {
    FilteredReport f;
    f.width_nm = p.render.splat_width_nm;
    f.last_width_nm = job::splat_width_at(p.render.splat_width_nm, p.spp > 0 ? p.spp - 1 : 0);
    report.filtered = f;
  } else if (p.render.gathers()) {
    FilteredReport f;
    f.method = "gather";
    f.width_nm = p.render.gather_width_nm;
    f.last_width_nm = gather_width_at(p.render.gather_width_nm, p.spp);
    report.filtered = f;
  }
  if (p.render.integrator == job::IntegratorKind::kGradient) {
    GradientReport g;
    g.offset_bins = p.render.gradient_offset_bins;
    g.delta = static_cast<float>(p.gradient.delta);
    g.tau = p.render.gradient_tau;
    g.tau_pilot = p.gradient.tau_pilot;
    g.alpha = static_cast<float>(p.gradient.alpha);
    g.norm = std::string(to_string(p.gradient.norm));
    g.with_primal_and_gradients = p.outputs.primal_and_gradients;
    g.lanes_requested = p.render.gradient_lanes;
    report.gradient = g;
  }
  if (p.prepass.has_value()) {
    PrepassReport r;
    r.passes = p.prepass->passes;
    absl::StatusOr<std::vector<PrepassPass>> schedule =
        prepass_schedule(*p.prepass, p.width, p.height);
    if (schedule.ok()) {
      for (const PrepassPass& pass : *schedule) {
        r.pass_spp.push_back(pass.spp);
        r.pass_resolution.push_back(absl::StrCat(pass.width, "x", pass.height));
      }
    }
    r.image_scaled = p.prepass->image_scaled;
    r.epsilon = static_cast<float>(p.prepass->epsilon);
    r.fallback = static_cast<float>(p.prepass->fallback);
    r.sigma_s = static_cast<float>(p.prepass->sigma_s);
    r.sigma_r = static_cast<float>(p.prepass->sigma_r);
    report.prepass = r;
  }
}

}  // namespace prism::coordinator
