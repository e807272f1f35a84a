// Spectral gradient sampling on the worker (docs/estimators.md §5, spectral gradient paper §3): a
// path tracer whose every base path x̄ at λ (bin i) is shifted to offset paths y₊ at λ + δ and y₋
// at λ − δ (δ = k bin widths, cyclic), returning the primal contribution to I[i] and the
// gradient contributions to G[i] and G[i − k], with E[G[b]] = I[b + k] − I[b].
//
// Hero lanes (docs/estimators.md §5.1). With C > 1 the base also carries C − 1 rotated lanes
// with PathIntegrator's estimator (each lane's light density its own single-wavelength
// selection's, the lane-symmetric roulette weight), and its events split in two classes by
// whether the path went through a smooth dispersive refraction (BsdfSample::hero_only; a shift
// keeps the class). Those after one are this single-wavelength estimator's (the other lanes have
// ended there); the others are never shifted, their lanes' values go to I and their finite
// differences to G. Where no material can refract so (shifts_possible), a sample is
// PathIntegrator's with C lanes and G its finite difference. The sections below describe the
// single-wavelength estimator.
//
// Contributions. Every event that adds light (an emitter found by the sampled direction, or
// next-event estimation) ends its own path prefix x̄, weighted against the other technique by
// the balance heuristic as in PathIntegrator, so its primal value is c = f(x̄)/Σ_t p_t(x̄): the
// sum runs over the techniques (NEE, BSDF sampling) that could have produced the last vertex.
// The pair (x̄, y) can be produced by either technique from either wavelength, so the symmetric
// weight is one balance heuristic over all four (as Mitsuba's gradient-domain path tracer does):
//     w₊ = Σ_t p_t(x̄,λ) / (Σ_t p_t(x̄,λ) + Σ_t p_t(y₊,λ+δ)·|J₊|),
//     c₊ = f(y₊,λ+δ)·|J₊| / Σ_t p_t(x̄,λ),
// p(·,λ) including the wavelength density p(λ) of `lambda_pdf` at the base's and at the offset's
// wavelength. Accumulation per event (§5): shifted, G[i] += w₊(c₊ − c), G[i−k] += w₋(c − c₋);
// unshifted, G[i] −= c, G[i−k] += c. An event is shifted on one side when the mapping succeeds
// and min(c, f(y)/Σ_t p_t(y)) > τ (paper Eq. 16 made symmetric; c is tested first and nothing of
// the offset is computed when it fails). With τ = 0 an event with c = 0 is unshifted, so only
// events that carry base light need offsets; the pairs whose base carries none are estimated by
// standard sampling from the other wavelength, whose unshifted rule adds exactly that term.
//
// Laziness. The offsets follow the base through a log of the base's steps and catch up only
// when an event passes c > τ (or the log fills), so with τ > 0 an event below the threshold
// costs no offset rays at all, and steps after a path's last such event are never followed.
// Catching up applies exactly the steps eager following would, so the output does not depend on
// it.
//
// Roulette. Contributions divide by the base's survival probabilities (they are part of the
// base's true density, so c₊ = f(y)|J|/p(x̄) divides by them too), but the MIS weights and the
// threshold use roulette-free densities: any pair of positive functions that both sides of a
// pair compute identically gives weights that sum to 1, and the offset's own roulette would
// depend on a throughput the base cannot know.
//
// The shift (shift.h: the local mappings; offset.h: the offsets' own
// steps), per offset state:
//  - same: the offset is at the base's vertex with the base's incoming direction. It copies the
//    sampled direction (J = 1) at every vertex whose sampling does not depend on λ (diffuse,
//    conductors, non-dispersive dielectrics, medium scattering, and reflection off a dispersive
//    dielectric, whose half-vector copy with the same ω_o is the same direction); only its
//    values change (reflectance, Fresnel, η'², emission, σ(λ'), free-flight densities). At a
//    refraction through a dispersive dielectric it copies the half-vector (smooth: the same event
//    with its own η; TIR fails the shift) and becomes diverged.
//  - diverged: the offset has its own vertex, reached by its own ray. Its vertex must be of the
//    same kind as the base's (BSDF type, smooth or rough, dispersive or not), else the shift
//    fails. When its vertex and the base's next vertex are both connectable (rough and not
//    dispersive), it reconnects to that vertex (visibility, arrival on the same side, Jacobian
//    cosθ'·d²/(cosθ·d'²)) and becomes reconnected; otherwise it copies the half-vector and traces
//    its own ray. NEE from a diverged vertex connects to the base's light sample point (for the
//    environment: the base's direction, J = 1; for point and spot lights: the light's position).
//  - reconnected: at the base's vertex with its own incoming direction: NEE and the next
//    direction are the base's (J = 1), evaluated with its own ω_o; then same again.
//  - failed: every later event is unshifted.
// The shift fails (offset contribution 0, base weight 1, i.e. the unshifted rule) on: total
// internal reflection of the offset where the base refracted; a copied half-vector the offset
// sees from the wrong side, or a direction on the wrong side of the surface for the event; an
// offset vertex of another kind than the base's, or an offset ray that escapes while the base
// scatters again; a blocked reconnection, or one arriving on the other side of the target; a
// diverged offset meeting a scattering medium or an emitting interface; an event value of 0
// probability at λ'. Each of these decisions depends only on the pair (x̄, y), so the reverse
// shift from y fails exactly when the forward one does, which the symmetric weights need.
// Media: an offset at the base's position keeps the base's distances and directions and
// evaluates σ, transmittance and free-flight densities at λ' (Henyey–Greenstein does not depend
// on λ). A diverged offset crosses absorbing media on its own; meeting a scattering medium while
// diverged fails the shift (its free flight has no base distance to copy).
#pragma once

#include <cstdint>

#include "services/spectral/pixel_tables.h"
#include "worker/integrator.h"
#include "worker/render_scene.h"

namespace prism::worker {

// What one sample adds to one bin of I and of G.
struct GradientBinValue {
  int bin = 0;
  float primal = 0;
  float gradient = 0;
};

// One camera sample's output. The single-wavelength estimator: the base bin i, its primal value
// for I[i] and the gradient contributions to G[i] and G[(i − k) mod B]. What the tile adds is
// `entry`: with C = 1 exactly those values, {i: primal, gradient} and {i − k: 0,
// gradient_below}; with hero lanes (C > 1) the lanes' primal values and the gradient rebuilt
// around them (GradientIntegrator). Per-bin averages (W·m⁻²·sr⁻¹·nm⁻¹), as SampleContribution
// values; all finite (a non-finite sample contributes zeros and is counted).
struct GradientSample {
  float lambda = 0;  // the base wavelength (nm); 0 when the sample drew none
  int bin = 0;
  int bin_below = 0;  // (bin − k) mod B
  float primal = 0;
  float gradient = 0;        // to G[bin]
  float gradient_below = 0;  // to G[bin_below]
  // The values the tile adds, one entry per bin (distinct bins, at most 2C).
  int entries = 0;
  GradientBinValue entry[2 * spectral::kMaxLanes];
  // The added primal's linear sRGB at the lanes' exact wavelengths (SampleContribution::rgb).
  double rgb[3] = {0, 0, 0};
};

// One base event of a traced sample, for the τ pilot (pilot.h): the roulette-free value
// c the threshold compares, the square c² each side adds unshifted (G[i] −= c, G[i−k] += c), the
// squares the sides added as traced (up to G[i], down to G[i−k]), the offsets' own roulette-free
// values (0 where the shift failed or was not tried; a side is shifted at τ when c > τ and its
// own value > τ), and the base's vertex count at the event (how far the offsets had to follow).
struct GradientEvent {
  float threshold_value = 0;
  float unshifted_square = 0;
  float side_square[2] = {0, 0};
  float offset_value[2] = {0, 0};
  int vertices = 0;
};

// Receives a sample's events in path order.
class GradientEventSink {
 public:
  virtual ~GradientEventSink() = default;
  virtual void record(const GradientEvent& event) = 0;
};

// Whether some material of the scene may refract through a smooth dispersive interface
// (may_refract_smooth_dispersive): the one event a shift follows when the base path carries hero
// lanes. Without one, a gradient job with its lanes chosen by the scene is hero's render with an
// identity reconstruction (`auto` then leaves it out of its candidates).
bool has_smooth_dispersive_refraction(const RenderScene& scene);

class GradientIntegrator {
 public:
  // The scene's options give k (gradient_offset_bins, 1 <= k < bins), τ, the hero lanes C
  // (gradient_lanes), depth and roulette.
  explicit GradientIntegrator(const RenderScene& scene);

  // Traces pixel (px, py)'s sample `sample_index` of pass `pass`: the base wavelength is drawn
  // from `lambda_pdf` (the scene's distribution or the pixel's table; lane 0 of
  // sample_lanes(u, 1)) and the offsets' MIS densities are that same density's pdf at λ ± δ, so
  // a pixel's table enters both sides of every pair alike. Pure function of its arguments;
  // never allocates (an event sink may).
  GradientSample trace(int px, int py, std::uint32_t pass, std::uint32_t sample_index,
                       spectral::WavelengthPdfView lambda_pdf, TraceCounters& counters,
                       GuideValues* guides = nullptr, GradientEventSink* events = nullptr) const;

  // Whether any event can be shifted: always with C = 1; with hero lanes only when some material
  // may refract through a smooth dispersive interface (may_refract_smooth_dispersive). Without,
  // the offsets are never traced and the sample is the hero lanes' alone (G = D·I).
  bool shifts_possible() const { return shifts_possible_; }

 private:
  const RenderScene& scene_;
  int offset_bins_;
  float tau_;
  int hero_lanes_;
  PathIntegrator hero_;  // the sample when nothing can be shifted
  bool shifts_possible_;
};

}  // namespace prism::worker
