// The spectral path tracers: `uniform` (one wavelength per path, C = 1, the unbiased baseline)
// and `hero` (C = 4 lanes with CMIS rotation), both with next-event estimation, multiple
// importance sampling over (technique, lane), Russian roulette and homogeneous media
// (docs/estimators.md §2–§3).
//
// Estimator. A pixel sample draws u and lanes λ_s = P⁻¹((u + s/C) mod 1) from the wavelength
// distribution; the path is sampled with the hero λ_0. Lane s adds to bin(λ_s)
//     f(x̄, λ_s) / ( p(λ_s) · Σ_k p(x̄ | λ_k) ),
// where p(x̄|λ_k) is the density of sampling x̄ with λ_k as hero, including which of NEE or BSDF
// sampling produced the last vertex (balance heuristic over lanes and techniques). The tracer
// carries, per lane, β_s = f_s / p_0 and r_k = p_k / p_0 (ratios to the hero's density), which
// stay finite over long paths. Contributions are per-bin radiance averages (W·m⁻²·sr⁻¹·nm⁻¹).
//
// Prepass tracing (docs/estimators.md §4): a trace can force the lane count (prepass tasks use C =
// 4 whatever the job's integrator) and stop early. A *wavelength-dependent event* is a point of the
// path where what is evaluated or sampled differs between wavelengths, decided from flags
// precomputed when the RenderScene is built (one load per vertex, no spectrum evaluated):
//  - a surface vertex whose material depends_on_wavelength (material.h): a dispersive
//    dielectric, a diffuse reflectance or a conductor η/k that is not constant;
//  - a segment through a chromatic medium (σ_a or σ_s not constant), including scattering in it;
//  - an emitter found by the sampled direction (or the camera ray) whose emission spectrum is not
//    constant (ShapeInfo::wavelength_dependent covers both a surface's material and its light).
// Next-event estimation is not an event: it runs at every non-specular vertex, so counting it
// would keep every path of a scene with a coloured light. With early stop a path that has met no
// event when it reaches its vertex after kEarlyStopBounces scattering events ends there, as if
// max_depth were kEarlyStopBounces: the emission found at that vertex still counts, nothing is
// sampled from it. Such paths only carry the emitters' spectra through grey scattering, which
// the default distribution (and the defensive term of the tables built from a prepass) already
// covers; stopping them biases the prepass estimate, which only shapes a pdf.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "services/spectral/pixel_tables.h"
#include "services/spectral/sampled.h"
#include "worker/render_scene.h"
#include "worker/sampler.h"

namespace prism::worker {

// What one camera sample contributes: per lane, the wavelength bin and the value to add to it.
struct SampleContribution {
  int lanes = 0;
  int bin[spectral::kMaxLanes] = {};
  float value[spectral::kMaxLanes] = {};
  // The sample's linear sRGB from its lanes' exact wavelengths, Σ_lanes r̄(λ)·L(λ)·w/p(λ) with
  // r̄ the sRGB matching functions (pbrt-v4's cie1931 sensor, no division by the Y integral): what
  // the RGB outputs average, so that they do not depend on the bins. 0 when not finite.
  double rgb[3] = {0, 0, 0};
  // Gathering (RenderOptions::gather_width_nm): the caustic events' spectral offsets on the
  // film, d(raster)/dλ in pixels per nm, as the sums of TileBuffers::offsets (Σw, Σw·dx, Σw·dy,
  // Σw·dx², Σw·dy², Σw·dx·dy) with w the event's contribution over its lanes, times |filter
  // weight|. A caustic event: the camera's first vertex y is not a delta, every later one is, one
  // of them refracts dispersively, and the path finds an area light's emission; its offset is how
  // y would move per nm for the same light point (path_differential.h's receiver_offset).
  double offset[6] = {0, 0, 0, 0, 0, 0};
};

// Adds a sample's lanes into a pixel's per-bin sums and squares: lanes that land in the same bin
// form one value of this sample for that bin, so the squares are those of per-sample bin values.
// `scratch` holds one zero per bin and is left so.
inline void fold_lanes(const SampleContribution& c, std::span<double> scratch, double* sums,
                       double* squares) {
  for (int lane = 0; lane < c.lanes; ++lane) scratch[c.bin[lane]] += c.value[lane];
  for (int lane = 0; lane < c.lanes; ++lane) {
    double& v = scratch[c.bin[lane]];
    if (v != 0.0) {
      sums[c.bin[lane]] += v;
      squares[c.bin[lane]] += v * v;
      v = 0.0;
    }
  }
}

// Event counts for reports (rays traced, paths terminated by Russian roulette, ...); summed
// per thread and merged, never atomics in the hot path.
struct TraceCounters {
  std::uint64_t camera_rays = 0;
  std::uint64_t rays = 0;         // every intersect or occlusion query
  std::uint64_t lane_splits = 0;  // paths whose secondary lanes were terminated
  std::uint64_t non_finite = 0;   // contributions dropped because they were NaN or infinite
  std::uint64_t early_stops = 0;  // prepass paths ended by early stop (see the header comment)
  // Gradient sampling (gradient/integrator.h; the paper's Table 1): base events whose
  // contribution passed c > τ, base paths with at least one shifted event, offsets evaluated
  // (one per side of such an event), and of those the shifts that failed (no valid offset path)
  // and the ones wasted because the offset's own contribution was <= τ.
  std::uint64_t gradient_events = 0;
  std::uint64_t gradient_shifted_paths = 0;
  std::uint64_t gradient_shifts = 0;
  std::uint64_t gradient_shifts_failed = 0;
  std::uint64_t gradient_shifts_wasted = 0;
  // How the offsets moved on the steps that events used (offsets follow lazily): left the base
  // at a dispersive vertex, reconnected to it, and left it again after a reconnection.
  std::uint64_t gradient_divergences = 0;
  std::uint64_t gradient_reconnections = 0;
  std::uint64_t gradient_repeated_divergences = 0;
  // Gradient samples traced, and the sum of their hero lanes C (GradientIntegrator).
  std::uint64_t gradient_samples = 0;
  std::uint64_t gradient_lanes = 0;
  // Light paths (light_tracer.h): their splats on the film, and of those the ones differential
  // splatting drew as lines (differential_splat.h).
  std::uint64_t light_splats = 0;
  std::uint64_t splat_lines = 0;

  TraceCounters& operator+=(const TraceCounters& o) {
    camera_rays += o.camera_rays;
    rays += o.rays;
    lane_splits += o.lane_splits;
    non_finite += o.non_finite;
    early_stops += o.early_stops;
    gradient_events += o.gradient_events;
    gradient_shifted_paths += o.gradient_shifted_paths;
    gradient_shifts += o.gradient_shifts;
    gradient_shifts_failed += o.gradient_shifts_failed;
    gradient_shifts_wasted += o.gradient_shifts_wasted;
    gradient_divergences += o.gradient_divergences;
    gradient_reconnections += o.gradient_reconnections;
    gradient_repeated_divergences += o.gradient_repeated_divergences;
    gradient_samples += o.gradient_samples;
    gradient_lanes += o.gradient_lanes;
    light_splats += o.light_splats;
    splat_lines += o.splat_lines;
    return *this;
  }
};

// Counter names and values for reports and task results, in a fixed order (the names are the
// JSON report's and the ResultUpload's).
std::vector<std::pair<std::string, std::uint64_t>> counter_list(const TraceCounters& c);

// Optional first-hit guide values (prepass guide buffers): distance along the camera ray
// divided by the distance from the camera to the far side of the scene's bounding sphere (so in
// [0, 1], 1 for a miss), shading normal, albedo (mean over the lanes of a diffuse reflectance,
// 1 for specular materials).
struct GuideValues {
  float depth = 0;
  Vec3f normal;
  float albedo = 0;
};

// Scattering events after which a prepass path with no wavelength-dependent event stops (§4).
inline constexpr int kEarlyStopBounces = 3;

// How one trace differs from the job's options (prepass tasks); the defaults trace exactly as
// the job says.
struct TraceOptions {
  int lanes = 0;            // C in 1..kMaxLanes; 0: the job's (job::RenderOptions::lanes())
  bool early_stop = false;  // stop paths without wavelength-dependent events (header comment)
};

class PathIntegrator {
 public:
  explicit PathIntegrator(const RenderScene& scene) : scene_(scene) {}

  // Traces pixel (px, py)'s sample `sample_index` of pass `pass`, drawing the lanes from and
  // weighting them by `lambda_pdf` (the scene's distribution, or the pixel's table). `trace`
  // lanes outside 0..kMaxLanes are a bug (PRISM_CHECK). Pure function of its arguments; never
  // allocates.
  SampleContribution trace(int px, int py, std::uint32_t pass, std::uint32_t sample_index,
                           spectral::WavelengthPdfView lambda_pdf, TraceCounters& counters,
                           GuideValues* guides = nullptr, TraceOptions trace = {}) const;

 private:
  const RenderScene& scene_;
};

}  // namespace prism::worker
