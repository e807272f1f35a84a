// A job's parameters: the wire JobSpec (proto/prism/v1/types.proto) turned into the typed values
// the worker and the coordinator use, and back. The rules are those of `prism render`'s flags
// (client/render_command.cpp): the same ranges and the same defaults taken from the scene (spp
// from its Sampler, resolution from its Film, bins from the Film's nbuckets else 64, max depth
// from its Integrator), so a job submitted to the farm renders exactly what the embedded render
// would with the same options.
//
// Invariant: a JobParameters returned by job_parameters() is fully validated, and
// job_parameters(to_proto(p), any scene) == p: to_proto() writes every value explicitly, so
// the result no longer depends on the scene's defaults.
//
// The prepass (docs/estimators.md §4) is off unless a spec's PrepassOptions turns it on
// (prepass_by_default says why).
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "prism/v1/types.pb.h"
#include "services/job/job_parameters.h"
#include "services/job/render_options.h"
#include "services/scene/scene_description.h"

namespace prism::job {

// Validates every field of `spec` and fills the unset ones from `scene`. INVALID_ARGUMENT naming
// the field and the accepted values, e.g. "spp 0 is out of range: want 1..16777216".
absl::StatusOr<JobParameters> job_parameters(const prism::v1::JobSpec& spec,
                                             const scene::SceneDescription& scene);

// Whether a job with this integrator runs a prepass when its spec does not say (the rule above).
bool prepass_by_default(IntegratorKind integrator, const scene::SceneDescription& scene);

// The wire values of the option enums (both to_proto and `prism`'s flags use these).
prism::v1::Integrator to_proto(IntegratorKind kind);
prism::v1::LightSelection to_proto(LightSelectionKind kind);
prism::v1::PoissonNorm to_proto(PoissonNorm norm);
prism::v1::ExrCompression to_proto(image::ExrCompression compression);
prism::v1::GradientTauPilot to_proto(const TauPilotReport& pilot);
prism::v1::AutoChoice to_proto(const AutoReport& report);

// Every value explicit (see the invariant above).
prism::v1::JobSpec to_proto(const JobParameters& parameters);

// What identifies a submission (the client's default token, the coordinator's check that a
// token comes back with the same request): the spec's bytes without what merely measured the
// client's run, auto's pilot time. Resubmitting a scene with `auto` is then the same request.
std::string request_identity(const prism::v1::JobSpec& spec);

// Short names of the option values: name() in render_options.h.

}  // namespace prism::job
