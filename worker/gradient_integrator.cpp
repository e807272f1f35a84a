#include "worker/gradient_integrator.h"

#include <cmath>
#include <limits>

#include "services/base/check.h"
#include "worker/bsdf.h"
#include "worker/fresnel.h"
#include "worker/gradient_shift.h"
#include "worker/light.h"
#include "worker/material.h"
#include "worker/medium.h"

namespace prism::worker {
namespace {

constexpr float kInfinity = std::numeric_limits<float>::infinity();

// The sample-dimension layout of PathIntegrator (integrator.cpp), so that the base path is drawn
// exactly like a `uniform` path: offsets consume no numbers of their own.
constexpr std::uint32_t kDimFilm = 0;
constexpr std::uint32_t kDimLens = 2;
constexpr std::uint32_t kDimWavelength = 4;
constexpr std::uint32_t kDimBounce = 6;
constexpr std::uint32_t kDimsPerBounce = 12;
constexpr std::uint32_t kLightPosition = 0;
constexpr std::uint32_t kLightChoice = 2;
constexpr std::uint32_t kScatterDirection = 4;
constexpr std::uint32_t kScatterLobe = 6;
constexpr std::uint32_t kFreeFlight = 8;
constexpr std::uint32_t kDimCrossings = 1u << 16;
constexpr std::uint32_t kCrossingsPerBounce = 64;

// Lanes of the shared evaluations: the base and the two offsets.
constexpr int kBase = 0;
constexpr int kLanes = 3;

Point2f to_point(const Point2& p) {
  return {p.u0, p.u1};
}

SampledWavelengths single(float lambda, float pdf) {
  SampledWavelengths w(1);
  w.set(0, lambda, pdf);
  return w;
}

// A vertex's kind for the shift: vertices must match in all three to be shifted onto each
// other, and "connectable" means rough and not dispersive.
struct VertexKind {
  std::size_t bsdf = 0;
  bool specular = false;
  bool dispersive = false;
  bool connectable() const { return !specular && !dispersive; }
  friend bool operator==(const VertexKind&, const VertexKind&) = default;
};

VertexKind kind_of(const Bsdf& bsdf) {
  return {bsdf.index(), is_specular(bsdf), is_dispersive(bsdf)};
}

float relative_eta(const Bsdf& bsdf) {
  const auto* d = std::get_if<DielectricBsdf>(&bsdf);
  return d != nullptr ? d->eta(0) : 1.0f;
}

// f·|cos θ_i| and the density of a given event at lane 0: for a smooth vertex the discrete
// probability of the same event (reflect / refract) and its value; for a rough one eval and pdf.
struct EventValue {
  float f_cos = 0;
  float pdf = 0;
};

EventValue event_value(const Bsdf& bsdf, const Vec3f& wo, const Vec3f& wi, bool transmission) {
  if (!is_specular(bsdf)) {
    return {eval(bsdf, wo, wi)[0] * abs_cos_theta(wi), pdf(bsdf, wo, wi)[0]};
  }
  if (const auto* d = std::get_if<DielectricBsdf>(&bsdf)) {
    const float f = fresnel_dielectric(cos_theta(wo), d->eta(0));
    if (!transmission) return {f, f};
    const float etap = cos_theta(wo) > 0 ? d->eta(0) : 1.0f / d->eta(0);
    return {(1.0f - f) / (etap * etap), 1.0f - f};
  }
  // A smooth conductor reflects with probability 1; its sample() ignores the numbers.
  auto s = sample(bsdf, wo, 0.0f, {0.5f, 0.5f});
  if (!s || transmission) return {};
  return {s->f[0] * abs_cos_theta(s->wi), s->pdf[0]};
}

enum class OffsetState { kSame, kReconnected, kDiverged, kFailed };

// One offset path, stored relative to the base (see gradient_integrator.h).
struct Offset {
  OffsetState state = OffsetState::kSame;
  int lane = 1;  // its lane in the shared evaluations
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
};

// Transmittance along a shadow segment for up to kLanes lanes (as PathIntegrator's shadow_ray):
// the transmittance, the probability that free flights would pass, and whether any part ran
// through a scattering medium. Both spectra are 0 when something opaque blocks the segment.
struct Shadow {
  SampledSpectrum transmittance;
  SampledSpectrum pass;
  bool scattering = false;
};

}  // namespace

GradientIntegrator::GradientIntegrator(const RenderScene& scene)
    : scene_(scene),
      offset_bins_(scene.options().gradient_offset_bins),
      tau_(scene.options().gradient_tau) {
  PRISM_CHECK(offset_bins_ >= 1 && offset_bins_ < scene.grid().bins());
  PRISM_CHECK(tau_ >= 0.0f);
}

GradientSample GradientIntegrator::trace(int px, int py, std::uint32_t pass,
                                         std::uint32_t sample_index,
                                         const spectral::WavelengthDistribution& lambda_pdf,
                                         TraceCounters& counters, GuideValues* guides) const {
  const RenderOptions& options = scene_.options();
  const Geometry& geometry = scene_.geometry();
  const spectral::WavelengthGrid& grid = scene_.grid();
  Sampler sampler(options.sampler, SampleKey{options.seed, pass, std::uint32_t(px),
                                             std::uint32_t(py), sample_index});

  GradientSample out;
  const SampledWavelengths base_lambda = lambda_pdf.sample_lanes(sampler.at(kDimWavelength), 1);
  const float lambda = base_lambda.lambda(0);
  const float lambda_density = base_lambda.pdf(0);
  const int bin = grid.bin_of(lambda);
  if (bin < 0 || !(lambda_density > 0)) return out;
  out.lambda = lambda;
  out.bin = bin;
  out.bin_below = grid.wrap(bin - offset_bins_);

  // Offsets at λ ± δ, placed from the base's position inside its bin so that they land in bins
  // i ± k exactly (λ ± k·w wrapped can round into a neighbouring bin).
  Offset offsets[2];
  SampledWavelengths shared(kLanes);
  shared.set(kBase, lambda, lambda_density);
  for (int side = 0; side < 2; ++side) {
    const int target = grid.wrap(bin + (side == 0 ? offset_bins_ : -offset_bins_));
    float l = grid.lower(target) + (lambda - grid.lower(bin));
    l = std::clamp(l, grid.lower(target), std::nextafter(grid.upper(target), 0.0f));
    const float density = lambda_pdf.pdf(l);
    Offset& o = offsets[side];
    o.lane = 1 + side;
    o.lambda = single(l, density);
    o.rho = density / lambda_density;
    o.rho_prev = o.rho;
    shared.set(o.lane, l, density);
  }
  // Contributions are per-bin averages: f / (p(λ) p(x̄|λ)) / w.
  const float scale = 1.0f / (lambda_density * grid.bin_width());

  float beta = 1;      // f / p(x̄|λ) of the base prefix, with roulette
  float survival = 1;  // product of the roulette survival probabilities
  float pdf_since_prev = 1;
  LightContext prev_ctx;
  bool prev_specular = true;
  float eta_scale = 1;
  int medium = scene_.camera_medium();
  bool any_shifted = false;
  for (Offset& o : offsets) o.medium = medium;

  const Point2 film = sampler.at2(kDimFilm), lens = sampler.at2(kDimLens);
  Ray ray =
      scene_.camera().generate_ray({float(px) + film.u0, float(py) + film.u1}, {lens.u0, lens.u1});
  ++counters.camera_rays;
  if (guides) *guides = GuideValues{1.0f, {}, 0.0f};

  auto fail = [&](Offset& o) { o.state = OffsetState::kFailed; };

  // Accumulates one base event of value c (output units) whose offsets `offset_event(o)`
  // evaluates on demand as {valid, c_y = f(y)|J|/Σp(x̄), ratio = Σp(y)|J| / Σp(x̄)}.
  struct OffsetEvent {
    bool valid = false;
    float contribution = 0;
    float ratio = 0;
  };
  auto accumulate = [&](float c, auto&& offset_event) {
    if (c == 0.0f) return;
    out.primal += c;
    // Roulette-free values for the threshold (both sides of a pair compute the same numbers).
    const float c_free = c * survival;
    float up = -c, down = c;  // unshifted
    if (c_free > tau_) {
      ++counters.gradient_events;
      for (int side = 0; side < 2; ++side) {
        ++counters.gradient_shifts;
        Offset& o = offsets[side];
        OffsetEvent e = o.live() ? offset_event(o) : OffsetEvent{};
        if (!e.valid || !std::isfinite(e.ratio) || !(e.ratio >= 0) ||
            !std::isfinite(e.contribution)) {
          ++counters.gradient_shifts_failed;
          continue;
        }
        const float own = e.ratio > 0 ? e.contribution * survival / e.ratio
                                      : (e.contribution > 0 ? kInfinity : 0.0f);
        if (!(own > tau_)) {
          ++counters.gradient_shifts_wasted;
          continue;
        }
        const float w = 1.0f / (1.0f + e.ratio);
        if (side == 0) {
          up = w * (e.contribution - c);
        } else {
          down = w * (c - e.contribution);
        }
        any_shifted = true;
      }
    }
    out.gradient += up;
    out.gradient_below += down;
  };

  auto shadow_ray = [&](Vec3f origin, Vec3f direction, const Vec3f& target, bool to_infinity,
                        int medium_index, const SampledWavelengths& lambdas, int lanes) -> Shadow {
    Shadow shadow;
    for (int i = 0; i < lanes; ++i) shadow.transmittance[i] = shadow.pass[i] = 1.0f;
    for (int crossings = 0; crossings < 64; ++crossings) {
      float distance = kInfinity;
      if (!to_infinity) {
        Vec3f to_target = target - origin;
        float length_to_target = length(to_target);
        if (!(length_to_target > 0) || dot(to_target, direction) <= 0) return shadow;
        direction = to_target / length_to_target;
        distance = length_to_target * (1.0f - 1e-4f);
      }
      ++counters.rays;
      auto hit = geometry.intersect({origin, direction}, distance);
      float segment = hit ? hit->t : distance;
      if (medium_index >= 0) {
        const HomogeneousMedium& m = scene_.media()[medium_index];
        SampledSpectrum sigma_t = m.sigma_a(lambdas) + m.sigma_s(lambdas);
        SampledSpectrum t;
        for (int i = 0; i < lanes; ++i) {
          t[i] = std::isinf(segment) ? (sigma_t[i] > 0 ? 0.0f : 1.0f)
                                     : std::exp(-sigma_t[i] * segment);
        }
        shadow.transmittance *= t;
        if (m.scattering()) {
          shadow.pass *= t;
          shadow.scattering = true;
        }
      }
      if (!hit) return shadow;
      const ShapeInfo& info = scene_.shape(hit->shape);
      if (!std::holds_alternative<InterfaceMaterial>(scene_.materials()[info.material])) {
        return Shadow{};
      }
      if (info.medium_transition) {
        medium_index = dot(direction, hit->ng) < 0 ? info.medium_inside : info.medium_outside;
      }
      origin = geometry.offset_origin(hit->p, hit->ng, direction);
    }
    return Shadow{};
  };

  // A diverged offset's own ray from its vertex: crosses interfaces (absorbing media on the
  // way), stops at its next scattering surface or escapes. A scattering medium, or an emitter
  // on an interface (which the base would count as an event without a vertex), fails it.
  auto trace_own = [&](Offset& o, Ray own) {
    o.has_hit = false;
    o.pending = false;
    for (int crossings = 0; crossings < 64; ++crossings) {
      ++counters.rays;
      auto hit = geometry.intersect(own, kInfinity);
      if (o.medium >= 0) {
        const HomogeneousMedium& m = scene_.media()[o.medium];
        if (m.scattering()) return fail(o);
        const float sigma_a = m.sigma_a(o.lambda)[0];
        if (hit) {
          o.beta *= std::exp(-sigma_a * hit->t);
        } else if (sigma_a > 0) {
          o.beta = 0;
        }
      }
      if (!hit) return;
      const ShapeInfo& info = scene_.shape(hit->shape);
      if (std::holds_alternative<InterfaceMaterial>(scene_.materials()[info.material])) {
        if (info.area_light >= 0) return fail(o);
        if (info.medium_transition) {
          o.medium = dot(own.direction, hit->ng) < 0 ? info.medium_inside : info.medium_outside;
        }
        own.origin = geometry.offset_origin(hit->p, hit->ng, own.direction);
        continue;
      }
      o.hit = *hit;
      o.has_hit = true;
      return;
    }
    fail(o);
  };

  // The offset's step through a scattering vertex: its event value and Jacobian against the
  // base's density p_x of the same step.
  auto take_step = [&](Offset& o, const EventValue& v, float jacobian, float p_x,
                       const LightContext& ctx) {
    o.rho_prev = o.rho;
    o.beta *= v.f_cos * jacobian / p_x;
    o.rho *= v.pdf * jacobian / p_x;
    o.pdf_since_prev = v.pdf;
    o.jacobian_last = jacobian;
    o.prev_ctx = ctx;
  };

  // What the base did at its last scattering vertex, for the diverged offsets' next step.
  struct BaseEvent {
    BaseScatter scatter;
    Vec3f position;
    float pdf = 0;
  } base_event;

  // A diverged offset's next step, once the base's next vertex is known (`next`: its surface
  // hit, or null when the base escaped or met no surface vertex).
  auto resolve_pending = [&](Offset& o, const SurfaceHit* next, const Vec3f& base_direction) {
    const ShapeInfo& info_y = scene_.shape(o.hit.shape);
    auto bsdf_y = make_bsdf(scene_.materials()[info_y.material], o.lambda);
    PRISM_CHECK(bsdf_y.has_value());
    const Frame frame_y = Frame::from_xz(o.hit.dpdu, o.hit.ns);
    const Vec3f wo_y = frame_y.to_local(-o.direction);
    const LightContext ctx_y{o.hit.p, o.hit.ns};
    o.pending = false;
    bool target_connectable = false;
    if (next != nullptr) {
      const Material& m = scene_.materials()[scene_.shape(next->shape).material];
      auto bsdf_next = make_bsdf(m, base_lambda);
      target_connectable = bsdf_next && kind_of(*bsdf_next).connectable();
    }
    if (kind_of(*bsdf_y).connectable() && target_connectable) {
      Vec3f to = next->p - o.hit.p;
      const float distance = length(to);
      if (!(distance > 0)) return fail(o);
      const Vec3f dir = to / distance;
      // Arrive on the side the base arrived on, so the vertex, its BSDF side and the media
      // after it are the base's.
      if ((dot(dir, next->ng) < 0) != (dot(base_direction, next->ng) < 0)) return fail(o);
      const Vec3f wi_y = frame_y.to_local(dir);
      EventValue v{eval(*bsdf_y, wo_y, wi_y)[0] * abs_cos_theta(wi_y), pdf(*bsdf_y, wo_y, wi_y)[0]};
      if (!(v.f_cos > 0) || !(v.pdf > 0)) return fail(o);
      int own_medium = o.medium;
      if (info_y.medium_transition && cos_theta(wi_y) * cos_theta(wo_y) < 0) {
        own_medium = dot(dir, o.hit.ng) < 0 ? info_y.medium_inside : info_y.medium_outside;
      }
      Shadow s = shadow_ray(geometry.offset_origin(o.hit.p, o.hit.ng, dir), dir,
                            geometry.offset_origin(next->p, next->ng, -dir), false, own_medium,
                            o.lambda, 1);
      if (s.scattering || !(s.transmittance[0] > 0)) return fail(o);
      const float jacobian = reconnection_jacobian(base_event.position, o.hit.p, next->p, next->ng);
      if (!(jacobian > 0)) return fail(o);
      v.f_cos *= s.transmittance[0];
      take_step(o, v, jacobian, base_event.pdf, ctx_y);
      o.state = OffsetState::kReconnected;
      o.reconnected_before = true;
      ++counters.gradient_reconnections;
      o.direction = dir;
      return;
    }
    auto shift = shift_direction(base_event.scatter, wo_y, relative_eta(*bsdf_y));
    if (!shift) return fail(o);
    EventValue v = event_value(*bsdf_y, wo_y, shift->wi, base_event.scatter.transmission);
    if (!(v.pdf > 0)) return fail(o);
    take_step(o, v, shift->jacobian, base_event.pdf, ctx_y);
    const Vec3f dir = frame_y.from_local(shift->wi);
    if (info_y.medium_transition && base_event.scatter.transmission) {
      o.medium = dot(dir, o.hit.ng) < 0 ? info_y.medium_inside : info_y.medium_outside;
    }
    o.direction = dir;
    trace_own(o, {geometry.offset_origin(o.hit.p, o.hit.ng, dir), dir});
  };

  // An emitter found by the sampled direction: the base's event, with the offsets' emitters
  // found by their own rays (or the same one). `offset_emission` gives an offset's emitted
  // radiance and its light-sampling density from its previous vertex, or nullopt when the
  // offset has no vertex to compare.
  auto emission_event = [&](float le_x, float p_light_x, auto&& offset_emission) {
    if (!(le_x > 0)) return;
    const float denominator_x = prev_specular ? pdf_since_prev : pdf_since_prev + p_light_x;
    const float c = scale * beta * le_x * pdf_since_prev / denominator_x;
    accumulate(c, [&](Offset& o) -> OffsetEvent {
      if (o.state == OffsetState::kDiverged && o.pending) return {};
      std::optional<std::pair<float, float>> e = offset_emission(o);
      if (!e) return {};
      auto [le_y, p_light_y] = *e;
      const float denominator_y = prev_specular ? o.pdf_since_prev : o.pdf_since_prev + p_light_y;
      return {true, scale * o.beta * le_y * pdf_since_prev / denominator_x,
              o.rho_prev * o.jacobian_last * denominator_y / denominator_x};
    });
  };

  std::uint32_t crossings = 0;
  bool event_pending = false;  // a diverged offset waits for the base's next vertex
  for (int depth = 0;;) {
    const std::uint32_t dim = kDimBounce + kDimsPerBounce * std::uint32_t(depth);
    const std::uint32_t flight_dim =
        crossings == 0 ? dim + kFreeFlight
                       : kDimCrossings + kCrossingsPerBounce * std::uint32_t(depth) + crossings;
    ++counters.rays;
    auto hit = geometry.intersect(ray, kInfinity);

    if (medium >= 0) {
      const HomogeneousMedium& m = scene_.media()[medium];
      if (!m.scattering()) {
        SampledSpectrum sigma_a = m.sigma_a(shared);
        auto absorb = [&](float sa) {
          return hit ? std::exp(-sa * hit->t) : (sa > 0 ? 0.0f : 1.0f);
        };
        beta *= absorb(sigma_a[kBase]);
        for (Offset& o : offsets) {
          if (o.state == OffsetState::kSame) o.beta *= absorb(sigma_a[o.lane]);
        }
        if (beta == 0.0f) break;
      } else {
        // A diverged offset has no base distance to copy (see the header).
        for (Offset& o : offsets) {
          if (o.state == OffsetState::kDiverged) fail(o);
        }
        SampledSpectrum sigma_s = m.sigma_s(shared);
        SampledSpectrum sigma_t = m.sigma_a(shared) + sigma_s;
        FreeFlight flight =
            sample_free_flight(sigma_t, hit ? hit->t : kInfinity, sampler.at(flight_dim), kLanes);
        const float p_x = flight.pdf[kBase];
        if (!(p_x > 0)) break;
        for (Offset& o : offsets) {
          if (o.state != OffsetState::kSame) continue;
          const float f_y =
              flight.transmittance[o.lane] * (flight.scattered ? sigma_s[o.lane] : 1.0f);
          o.beta *= f_y / p_x;
          o.rho *= flight.pdf[o.lane] / p_x;
          o.pdf_since_prev *= flight.pdf[o.lane];
        }
        if (flight.scattered) {
          beta *= flight.transmittance[kBase] * sigma_s[kBase] / p_x;
          if (beta == 0.0f || depth == options.max_depth) break;
          const Vec3f p = ray.origin + ray.direction * flight.t;
          const Vec3f wo = -ray.direction;
          const HenyeyGreenstein& phase = m.phase();
          const LightContext ctx{p, Vec3f()};
          // NEE from the medium vertex: every live offset is at this vertex (same state), and
          // Henyey–Greenstein is the same at every wavelength.
          const Point2 choice_u = sampler.at2(dim + kLightChoice);
          const Point2 light_u = sampler.at2(dim + kLightPosition);
          auto choice = scene_.light_sampler().sample(p, base_lambda, choice_u.u0);
          if (choice) {
            const Light& light = scene_.lights()[choice->light];
            auto ls = sample_light(light, ctx, to_point(light_u), choice_u.u1, base_lambda);
            if (ls && ls->pdf > 0 && ls->radiance[0] > 0) {
              const float f = phase.p(wo, ls->wi);
              Shadow s = shadow_ray(p, ls->wi, ls->p_light, std::isinf(ls->distance), medium,
                                    shared, kLanes);
              const float p_light_x = choice->pmf * ls->pdf;
              const float denominator_x = p_light_x + (ls->delta ? 0.0f : f * s.pass[kBase]);
              const float c =
                  scale * beta * f * ls->radiance[0] * s.transmittance[kBase] / denominator_x;
              accumulate(c, [&](Offset& o) -> OffsetEvent {
                if (o.state != OffsetState::kSame) return {};
                auto ls_y = sample_light(light, ctx, to_point(light_u), choice_u.u1, o.lambda);
                if (!ls_y) return {};
                const float p_light_y =
                    scene_.light_sampler().pmf(p, o.lambda, choice->light) * ls->pdf;
                const float denominator_y = p_light_y + (ls->delta ? 0.0f : f * s.pass[o.lane]);
                return {true,
                        scale * o.beta * f * ls_y->radiance[0] * s.transmittance[o.lane] /
                            denominator_x,
                        o.rho * denominator_y / denominator_x};
              });
            }
          }
          float phase_pdf = 0;
          const Vec3f wi =
              phase.sample(wo, to_point(sampler.at2(dim + kScatterDirection)), &phase_pdf);
          if (!(phase_pdf > 0)) break;
          for (Offset& o : offsets) {
            if (o.state == OffsetState::kSame)
              take_step(o, {phase_pdf, phase_pdf}, 1.0f, phase_pdf, ctx);
          }
          prev_ctx = ctx;
          prev_specular = false;
          pdf_since_prev = phase_pdf;
          ray = {p, wi};
          ++depth;
          crossings = 0;
          continue;
        }
        beta *= flight.transmittance[kBase] / p_x;
        pdf_since_prev *= p_x;
        if (beta == 0.0f) break;
      }
    }

    const ShapeInfo* info = hit ? &scene_.shape(hit->shape) : nullptr;
    const Material* material = hit ? &scene_.materials()[info->material] : nullptr;
    const bool at_vertex = !hit || !std::holds_alternative<InterfaceMaterial>(*material);
    if (event_pending && at_vertex) {
      for (Offset& o : offsets) {
        if (o.state == OffsetState::kDiverged && o.pending) {
          resolve_pending(o, hit ? &*hit : nullptr, ray.direction);
        }
      }
      event_pending = false;
    }

    if (!hit) {
      const int infinite = scene_.infinite_light();
      if (infinite >= 0) {
        const auto& inf = std::get<InfiniteLight>(scene_.lights()[infinite]);
        auto light_density = [&](const LightContext& ctx, const SampledWavelengths& l,
                                 const Vec3f& dir) {
          return scene_.light_sampler().pmf(ctx.p, l, infinite) * inf.pdf(dir);
        };
        const float p_light_x =
            prev_specular ? 0.0f : light_density(prev_ctx, base_lambda, ray.direction);
        emission_event(inf.radiance(base_lambda)[0], p_light_x,
                       [&](Offset& o) -> std::optional<std::pair<float, float>> {
                         Vec3f dir = ray.direction;
                         if (o.state == OffsetState::kDiverged) {
                           if (o.has_hit) return std::pair{0.0f, 0.0f};
                           dir = o.direction;
                         }
                         return std::pair{
                             inf.radiance(o.lambda)[0],
                             prev_specular ? 0.0f : light_density(o.prev_ctx, o.lambda, dir)};
                       });
      }
      break;
    }

    if (depth == 0 && guides && at_vertex) {
      const Bounds3f& b = geometry.bounds();
      float far = length(scene_.camera().position() - b.centre()) + b.radius();
      guides->depth = std::min(1.0f, hit->t / std::max(1e-6f, far));
      guides->normal = hit->ns;
      if (const auto* diffuse = std::get_if<DiffuseMaterial>(material)) {
        guides->albedo = spectral::sample(diffuse->reflectance, base_lambda)[0];
      } else {
        guides->albedo = 1.0f;
      }
    }

    if (info->area_light >= 0) {
      const auto& area = std::get<AreaLight>(scene_.lights()[info->area_light]);
      auto light_density = [&](const LightContext& ctx, const SampledWavelengths& l, int light,
                               const AreaLight& a, const Vec3f& dir, const SurfaceHit& h) {
        return scene_.light_sampler().pmf(ctx.p, l, light) * a.pdf(ctx, dir, h);
      };
      const float p_light_x = prev_specular ? 0.0f
                                            : light_density(prev_ctx, base_lambda, info->area_light,
                                                            area, ray.direction, *hit);
      emission_event(
          area.radiance(hit->ng, -ray.direction, base_lambda)[0], p_light_x,
          [&](Offset& o) -> std::optional<std::pair<float, float>> {
            if (!at_vertex && o.state != OffsetState::kSame) return std::nullopt;
            const SurfaceHit* h = &*hit;
            Vec3f dir = ray.direction;
            if (o.state == OffsetState::kReconnected) dir = o.direction;
            if (o.state == OffsetState::kDiverged) {
              if (!o.has_hit) return std::pair{0.0f, 0.0f};
              h = &o.hit;
              dir = o.direction;
            }
            const int light = scene_.shape(h->shape).area_light;
            if (light < 0) return std::pair{0.0f, 0.0f};
            const auto& a = std::get<AreaLight>(scene_.lights()[light]);
            return std::pair{
                a.radiance(h->ng, -dir, o.lambda)[0],
                prev_specular ? 0.0f : light_density(o.prev_ctx, o.lambda, light, a, dir, *h)};
          });
    }

    if (!at_vertex) {
      // A pure medium boundary: the base continues on the other side, same path vertex; a
      // diverged offset met an emitter the base counted without a vertex of its own.
      for (Offset& o : offsets) {
        if (o.state != OffsetState::kSame && info->area_light >= 0) fail(o);
      }
      if (info->medium_transition) {
        medium = dot(ray.direction, hit->ng) < 0 ? info->medium_inside : info->medium_outside;
      }
      ray.origin = geometry.offset_origin(hit->p, hit->ng, ray.direction);
      if (++crossings == kCrossingsPerBounce) break;
      continue;
    }
    if (depth == options.max_depth) break;

    auto bsdf = make_bsdf(*material, base_lambda);
    const VertexKind kind = kind_of(*bsdf);
    const Frame frame = Frame::from_xz(hit->dpdu, hit->ns);
    const Vec3f wo = frame.to_local(-ray.direction);
    const LightContext ctx{hit->p, hit->ns};

    // The offsets' BSDFs at this vertex (their own vertex when diverged), of the same kind.
    std::optional<Bsdf> bsdf_y[2];
    Frame frame_y[2];
    Vec3f wo_y[2];
    for (int side = 0; side < 2; ++side) {
      Offset& o = offsets[side];
      if (!o.live()) continue;
      if (o.state == OffsetState::kDiverged) {
        if (!o.has_hit) {
          fail(o);
          continue;
        }
        bsdf_y[side] = make_bsdf(scene_.materials()[scene_.shape(o.hit.shape).material], o.lambda);
        if (!bsdf_y[side] || !(kind_of(*bsdf_y[side]) == kind)) {
          fail(o);
          continue;
        }
        frame_y[side] = Frame::from_xz(o.hit.dpdu, o.hit.ns);
        wo_y[side] = frame_y[side].to_local(-o.direction);
      } else {
        bsdf_y[side] = make_bsdf(*material, o.lambda);
        frame_y[side] = frame;
        wo_y[side] = o.state == OffsetState::kReconnected ? frame.to_local(-o.direction) : wo;
      }
    }

    if (!kind.specular) {
      const Point2 choice_u = sampler.at2(dim + kLightChoice);
      const Point2 light_u = sampler.at2(dim + kLightPosition);
      auto choice = scene_.light_sampler().sample(ctx.p, base_lambda, choice_u.u0);
      std::optional<LightSample> ls;
      if (choice) {
        ls = sample_light(scene_.lights()[choice->light], ctx, to_point(light_u), choice_u.u1,
                          base_lambda);
      }
      if (ls && ls->pdf > 0 && ls->radiance[0] > 0) {
        const Light& light = scene_.lights()[choice->light];
        const Vec3f wi_local = frame.to_local(ls->wi);
        const float f_x = eval(*bsdf, wo, wi_local)[0] * abs_cos_theta(wi_local);
        const float bsdf_pdf_x = pdf(*bsdf, wo, wi_local)[0];
        if (f_x > 0) {
          const Vec3f target = ls->n_light == Vec3f()
                                   ? ls->p_light
                                   : geometry.offset_origin(ls->p_light, ls->n_light, -ls->wi);
          Shadow s = shadow_ray(geometry.offset_origin(ctx.p, hit->ng, ls->wi), ls->wi, target,
                                std::isinf(ls->distance), medium, shared, kLanes);
          const float p_light_x = choice->pmf * ls->pdf;
          const float denominator_x = p_light_x + (ls->delta ? 0.0f : bsdf_pdf_x * s.pass[kBase]);
          const float c =
              scale * beta * f_x * ls->radiance[0] * s.transmittance[kBase] / denominator_x;
          accumulate(c, [&](Offset& o) -> OffsetEvent {
            const int side = o.lane - 1;
            const Bsdf& b = *bsdf_y[side];
            if (o.state != OffsetState::kDiverged) {
              // At the base's vertex: the same light point along the same direction (J = 1).
              auto ls_y = sample_light(light, ctx, to_point(light_u), choice_u.u1, o.lambda);
              if (!ls_y) return {};
              const float f_y = eval(b, wo_y[side], wi_local)[0] * abs_cos_theta(wi_local);
              const float p_y = pdf(b, wo_y[side], wi_local)[0];
              const float p_light_y =
                  scene_.light_sampler().pmf(ctx.p, o.lambda, choice->light) * ls->pdf;
              const float denominator_y = p_light_y + (ls->delta ? 0.0f : p_y * s.pass[o.lane]);
              return {true,
                      scale * o.beta * f_y * ls_y->radiance[0] * s.transmittance[o.lane] /
                          denominator_x,
                      o.rho * denominator_y / denominator_x};
            }
            // From the offset's own vertex to the base's light point.
            const LightContext ctx_y{o.hit.p, o.hit.ns};
            Vec3f wi_y;
            float le_y = 0, solid_angle_pdf_y = 0, jacobian = 1;
            bool to_infinity = std::isinf(ls->distance);
            Vec3f target_y = ls->p_light;
            if (std::holds_alternative<InfiniteLight>(light)) {
              wi_y = ls->wi;  // the environment's point is a direction: J = 1
              le_y = std::get<InfiniteLight>(light).radiance(o.lambda)[0];
              solid_angle_pdf_y = ls->pdf;
            } else if (ls->delta) {
              auto ls_y = sample_light(light, ctx_y, to_point(light_u), choice_u.u1, o.lambda);
              if (!ls_y) return {};
              wi_y = ls_y->wi;
              le_y = ls_y->radiance[0];
              solid_angle_pdf_y = ls_y->pdf;
            } else {
              const auto& area = std::get<AreaLight>(light);
              Vec3f to = ls->p_light - o.hit.p;
              const float d = length(to);
              if (!(d > 0)) return {};
              wi_y = to / d;
              le_y = area.radiance(ls->n_light, -wi_y, o.lambda)[0];
              SurfaceHit light_point;
              light_point.p = ls->p_light;
              light_point.ng = ls->n_light;
              solid_angle_pdf_y = area.pdf(ctx_y, wi_y, light_point);
              jacobian = reconnection_jacobian(ctx.p, o.hit.p, ls->p_light, ls->n_light);
              if (!(jacobian > 0)) return {};
              target_y = geometry.offset_origin(ls->p_light, ls->n_light, -wi_y);
            }
            const Vec3f wi_y_local = frame_y[side].to_local(wi_y);
            const float f_y = eval(b, wo_y[side], wi_y_local)[0] * abs_cos_theta(wi_y_local);
            if (!(f_y > 0) || !(le_y > 0)) return {true, 0.0f, 0.0f};
            const float p_y = pdf(b, wo_y[side], wi_y_local)[0];
            Shadow s_y = shadow_ray(geometry.offset_origin(o.hit.p, o.hit.ng, wi_y), wi_y, target_y,
                                    to_infinity, o.medium, o.lambda, 1);
            const float p_light_y =
                scene_.light_sampler().pmf(o.hit.p, o.lambda, choice->light) * solid_angle_pdf_y;
            const float denominator_y = p_light_y + (ls->delta ? 0.0f : p_y * s_y.pass[0]);
            return {true,
                    scale * o.beta * f_y * le_y * s_y.transmittance[0] * jacobian / denominator_x,
                    o.rho * denominator_y * jacobian / denominator_x};
          });
        }
      }
    }

    const Point2 lobe_and_roulette = sampler.at2(dim + kScatterLobe);
    auto bs =
        sample(*bsdf, wo, lobe_and_roulette.u0, to_point(sampler.at2(dim + kScatterDirection)));
    if (!bs || !(bs->pdf[0] > 0)) break;
    const float p_x = bs->pdf[0];
    const Vec3f wi = frame.from_local(bs->wi);
    const int medium_before = medium;
    base_event.scatter = {wo, bs->wi, bs->transmission, bs->specular, relative_eta(*bsdf)};
    base_event.position = hit->p;
    base_event.pdf = p_x;
    for (int side = 0; side < 2; ++side) {
      Offset& o = offsets[side];
      if (!o.live()) continue;
      if (o.state == OffsetState::kDiverged) {
        o.pending = true;
        event_pending = true;
        continue;
      }
      const Bsdf& b = *bsdf_y[side];
      if (o.state == OffsetState::kSame && kind.dispersive && bs->transmission) {
        // The first wavelength-dependent vertex: copy the half-vector (the event for a smooth
        // one) with the offset's own η, and leave the base.
        auto shift = shift_direction(base_event.scatter, wo, relative_eta(b));
        if (!shift) {
          fail(o);
          continue;
        }
        EventValue v = event_value(b, wo, shift->wi, true);
        if (!(v.pdf > 0)) {
          fail(o);
          continue;
        }
        take_step(o, v, shift->jacobian, p_x, ctx);
        const Vec3f dir = frame.from_local(shift->wi);
        o.state = OffsetState::kDiverged;
        ++counters.gradient_divergences;
        if (o.reconnected_before) ++counters.gradient_repeated_divergences;
        o.direction = dir;
        o.medium = medium_before;
        if (info->medium_transition) {
          o.medium = dot(dir, hit->ng) < 0 ? info->medium_inside : info->medium_outside;
        }
        trace_own(o, {geometry.offset_origin(hit->p, hit->ng, dir), dir});
        continue;
      }
      // The base's direction (J = 1): nothing about it depends on λ here, or the offset has
      // just reconnected to this (connectable) vertex.
      EventValue v = event_value(b, wo_y[side], bs->wi, bs->transmission);
      take_step(o, v, 1.0f, p_x, ctx);
      o.state = OffsetState::kSame;
    }
    prev_ctx = ctx;
    prev_specular = bs->specular;
    pdf_since_prev = p_x;
    beta *= bs->f[0] * abs_cos_theta(bs->wi) / p_x;
    if (beta == 0.0f) break;
    if (bs->transmission) {
      eta_scale *= bs->etap * bs->etap;
      if (info->medium_transition) {
        medium = dot(wi, hit->ng) < 0 ? info->medium_inside : info->medium_outside;
      }
    }
    for (Offset& o : offsets) {
      if (o.state == OffsetState::kSame) o.medium = medium;
    }
    ray = {geometry.offset_origin(hit->p, hit->ng, wi), wi};
    ++depth;
    crossings = 0;

    if (depth >= options.rr_min_depth) {
      const float weight = beta * eta_scale;
      if (weight < 1.0f) {
        const float q = std::max(0.0f, 1.0f - weight);
        if (lobe_and_roulette.u1 < q) break;
        beta /= 1.0f - q;
        survival *= 1.0f - q;
        for (Offset& o : offsets) o.beta /= 1.0f - q;
      }
    }
  }

  if (any_shifted) ++counters.gradient_shifted_paths;
  if (!std::isfinite(out.primal) || !std::isfinite(out.gradient) ||
      !std::isfinite(out.gradient_below)) {
    ++counters.non_finite;
    out.primal = out.gradient = out.gradient_below = 0;
  }
  return out;
}

}  // namespace prism::worker
