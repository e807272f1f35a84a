// The offset paths of spectral gradient sampling (integrator.h describes the shift):
// an offset's state relative to the base path, and the steps that move a diverged offset on its
// own: its own rays, the decision at its vertex between reconnecting to the base's next vertex
// and copying the base's half-vector, and next-event estimation to the base's light point.
// Internal to the gradient integrator. Nothing here allocates.
#pragma once

#include <optional>

#include "services/spectral/sampled.h"
#include "worker/bsdf.h"
#include "worker/gradient/shift.h"
#include "worker/integrator.h"
#include "worker/light.h"
#include "worker/material.h"
#include "worker/render_scene.h"
#include "worker/shadow_ray.h"

namespace prism::worker::gradient {

// A vertex's kind for the shift: vertices must match in all three to be shifted onto each
// other, and "connectable" means rough and not dispersive.
// `stochastic`: a BSDF whose value and density are random-walk estimates (LayeredBsdf). Its
// sample()'s pdf is an estimate, not the density the direction was drawn with, so an offset
// weighted by it (f(λ')/p_x) or reconnected through it (p_x in the Jacobian) would be biased;
// offsets fail there instead, which the base's MIS weight then covers (weight 1).
struct VertexKind {
  std::size_t bsdf = 0;
  bool specular = false;
  bool dispersive = false;
  bool stochastic = false;
  bool connectable() const { return !specular && !dispersive && !stochastic; }
  friend bool operator==(const VertexKind&, const VertexKind&) = default;
};

VertexKind kind_of(const Bsdf& bsdf);
// The dielectric's relative index at lane 0 (1 for the other BSDFs).
float relative_eta(const Bsdf& bsdf);

// f·|cos θ_i| and the density of a given event at lane 0: for a smooth vertex the discrete
// probability of the same event (reflect / refract) and its value; for a rough one eval and pdf.
struct EventValue {
  float f_cos = 0;
  float pdf = 0;
};
EventValue event_value(const Bsdf& bsdf, const Vec3f& wo, const Vec3f& wi, bool transmission);

enum class OffsetState { kSame, kReconnected, kDiverged, kFailed };

// One offset path, stored relative to the base.
struct Offset {
  OffsetState state = OffsetState::kSame;
  int lane = 1;  // its lane in the evaluations shared with the base
  SampledWavelengths lambda{1};
  float beta = 1;  // f(y)|J| / p(x̄|λ) of the prefix, with the base's roulette
  float rho = 1;   // p̃(y,λ')|J| / p̃(x̄,λ) of the prefix, roulette-free
  // For MIS at an emitter found by the sampled direction: ρ before the last direction, the
  // offset's own density of everything sampled since (direction times free-flight passes), the
  // last step's Jacobian and its own previous scattering vertex.
  float rho_prev = 1;
  float pdf_since_prev = 1;
  float jacobian_last = 1;
  LightContext prev_ctx;
  // kReconnected / kDiverged: the own direction of arrival (unit, pointing along the ray).
  Vec3f direction;
  // kDiverged: the own vertex (if the own ray hit something), its medium, and whether its next
  // direction waits for the base's next vertex.
  SurfaceHit hit;
  bool has_hit = false;
  int medium = -1;
  bool pending = false;
  bool reconnected_before = false;

  bool live() const { return state != OffsetState::kFailed; }
  void fail() { state = OffsetState::kFailed; }
};

// The offset's step through a scattering vertex: its event value and Jacobian against the
// base's density p_x of the same step; ctx is the offset's vertex.
void take_step(Offset& o, const EventValue& v, float jacobian, float p_x, const LightContext& ctx);

// What the base did at its last scattering vertex, for the diverged offsets' next step.
struct BaseEvent {
  BaseScatter scatter;
  Vec3f position;
  float pdf = 0;
};

// The factors of a diverged offset's NEE to the base's light sample, in its own measure: BSDF
// value·|cos|, emitted radiance, transmittance, Jacobian to the base's measure, and the light
// and BSDF densities of the connection (pass: free-flight pass probability). `valid` false when
// the connection does not exist (the shift fails for this event); f or le 0 for a connection
// that carries no light.
struct DivergedNee {
  bool valid = false;
  float f = 0, le = 0, transmittance = 0, jacobian = 1;
  float p_light = 0, p_bsdf = 0, pass = 0;
};

// One step of the base path that moves the offsets, recorded so that they can follow lazily:
// they are brought up to date only when an event passes the threshold τ (the paper's §3.3:
// shifts should cost time only where a contribution uses them). Applied in order, the steps
// give exactly the offsets that following the base eagerly would.
struct OffsetStep {
  enum class Kind {
    kSegment,           // the base's segment through a medium
    kMediumVertex,      // the base scattered in a medium
    kResolve,           // the base reached its next vertex: pending diverged offsets decide
    kInterfaceEmitter,  // the base counted an emitter on an interface (no vertex)
    kArrive,            // the base reached a scattering surface: kinds must match
    kScatter,           // the base sampled its next direction at a surface
    kRoulette,          // the base survived Russian roulette
  };
  Kind kind = Kind::kSegment;
  // kSegment. Absorbing: factor[s] is the transmittance at offset s's wavelength. Scattering:
  // factor[s] its free-flight value (T·σ_s, or T when passed), pdf[s] its free-flight density,
  // p_x the base's. kScatter: p_x is the base's BSDF density.
  bool scattering = false;
  float factor[2] = {};
  float pdf[2] = {};
  float p_x = 1;
  // kMediumVertex, kScatter: the base's vertex; kMediumVertex: the phase function's density.
  LightContext ctx;
  float phase_pdf = 0;
  // kResolve: the base's next vertex (has_next false when it escaped), its direction of
  // arrival and the base's event before it. kScatter: the base's hit and event.
  SurfaceHit hit;
  bool has_next = false;
  Vec3f direction;
  BaseEvent base;
  // kArrive, kScatter: the base vertex's kind; kScatter: its material, shape, frame, incoming
  // direction (local), and the base's medium before and after the event.
  VertexKind vertex_kind;
  const Material* material = nullptr;
  const ShapeInfo* info = nullptr;
  Frame frame;
  Vec3f wo;
  int medium_before = -1;
  int medium_after = -1;
  // kRoulette: the survival probability the base's weights were divided by.
  float survival = 1;
};

class OffsetTracer {
 public:
  // Rays are counted in `counters`.
  OffsetTracer(const RenderScene& scene, TraceCounters& counters)
      : scene_(scene), counters_(counters) {}

  // A diverged offset's own ray: crosses interfaces (absorbing media on the way), stops at its
  // next scattering surface or escapes. A scattering medium, or an emitter on an interface
  // (which the base would count as an event without a vertex), fails it.
  void trace_own(Offset& o, Ray own) const;

  // A diverged offset's next step, once the base's next vertex is known (`next`: its surface
  // hit, or null when the base escaped): reconnection when the offset's vertex and `next` are
  // both connectable, else the half-vector copy of `base` and a ray of its own.
  void resolve_pending(Offset& o, const BaseEvent& base, const SurfaceHit* next,
                       const Vec3f& base_direction) const;

  // Moves a live offset through one recorded step of the base.
  void apply(Offset& o, const OffsetStep& step) const;

  // NEE from a diverged offset's vertex (BSDF b, frame, incoming wo in that frame) to the light
  // point the base sampled from base_p (the environment: the base's direction; a delta light:
  // its position, sampled again from the offset's vertex with the same numbers).
  DivergedNee diverged_nee(const Offset& o, const Bsdf& b, const Frame& frame, const Vec3f& wo,
                           int light_index, const LightSample& ls, const Vec3f& base_p,
                           Point2f light_u, float u_extra) const;

 private:
  void scatter(Offset& o, const OffsetStep& step) const;

  const RenderScene& scene_;
  TraceCounters& counters_;
};

}  // namespace prism::worker::gradient
