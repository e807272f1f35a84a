#include "worker/gradient/offset.h"

#include <cmath>
#include <limits>

#include "services/base/check.h"
#include "worker/fresnel.h"
#include "worker/material.h"
#include "worker/medium.h"

namespace prism::worker::gradient {

VertexKind kind_of(const Bsdf& bsdf) {
  return {bsdf.index(), is_specular(bsdf), is_dispersive(bsdf),
          std::holds_alternative<LayeredBsdf>(bsdf)};
}

float relative_eta(const Bsdf& bsdf) {
  const auto* d = std::get_if<DielectricBsdf>(&bsdf);
  return d != nullptr ? d->eta(0) : 1.0f;
}

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
  if (const auto* thin = std::get_if<ThinDielectricBsdf>(&bsdf)) {
    const float r = thin->reflectance(0, cos_theta(wo));
    return transmission ? EventValue{1.0f - r, 1.0f - r} : EventValue{r, r};
  }
  // A smooth conductor reflects with probability 1; its sample() ignores the numbers.
  auto s = sample(bsdf, wo, 0.0f, {0.5f, 0.5f});
  if (!s || transmission) return {};
  return {s->f[0] * abs_cos_theta(s->wi), s->pdf[0]};
}

void take_step(Offset& o, const EventValue& v, float jacobian, float p_x, const LightContext& ctx) {
  o.rho_prev = o.rho;
  o.beta *= v.f_cos * jacobian / p_x;
  o.rho *= v.pdf * jacobian / p_x;
  o.pdf_since_prev = v.pdf;
  o.jacobian_last = jacobian;
  o.prev_ctx = ctx;
}

void OffsetTracer::trace_own(Offset& o, Ray own) const {
  const Geometry& geometry = scene_.geometry();
  o.has_hit = false;
  o.pending = false;
  for (int crossings = 0; crossings < 64; ++crossings) {
    ++counters_.rays;
    auto hit = geometry.intersect(own, kInfinity);
    if (o.medium >= 0) {
      const HomogeneousMedium& m = scene_.media()[o.medium];
      if (m.scattering()) return o.fail();
      const float sigma_a = m.sigma_a(o.lambda)[0];
      if (hit) {
        o.beta *= std::exp(-sigma_a * hit->t);
      } else if (sigma_a > 0) {
        o.beta = 0;
      }
    }
    if (!hit) return;
    const ShapeInfo& info = scene_.shape(hit->shape);
    if (std::holds_alternative<InterfaceMaterial>(
            scene_.material_at(info.material, *hit, -own.direction))) {
      if (info.area_light >= 0) return o.fail();
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
  o.fail();
}

void OffsetTracer::resolve_pending(Offset& o, const BaseEvent& base, const SurfaceHit* next,
                                   const Vec3f& base_direction) const {
  const Geometry& geometry = scene_.geometry();
  const ShapeInfo& info_y = scene_.shape(o.hit.shape);
  auto bsdf_y = make_bsdf(scene_.material_at(info_y.material, o.hit, -o.direction), o.lambda,
                          texture_context(o.hit));
  PRISM_CHECK(bsdf_y.has_value());
  if (kind_of(*bsdf_y).stochastic) return o.fail();  // VertexKind
  const Frame frame_y = Frame::from_xz(o.hit.dpdu, o.hit.ns);
  const Vec3f wo_y = frame_y.to_local(-o.direction);
  const LightContext ctx_y{o.hit.p, o.hit.ns};
  o.pending = false;
  bool target_connectable = false;
  if (next != nullptr) {
    const Material& m =
        scene_.material_at(scene_.shape(next->shape).material, *next, -base_direction);
    auto bsdf_next = make_bsdf(m, o.lambda, texture_context(*next));
    target_connectable = bsdf_next && kind_of(*bsdf_next).connectable();
  }
  if (kind_of(*bsdf_y).connectable() && target_connectable) {
    Vec3f to = next->p - o.hit.p;
    const float distance = length(to);
    if (!(distance > 0)) return o.fail();
    const Vec3f dir = to / distance;
    // Arrive on the side the base arrived on, so the vertex, its BSDF side and the media
    // after it are the base's.
    if ((dot(dir, next->ng) < 0) != (dot(base_direction, next->ng) < 0)) return o.fail();
    const Vec3f wi_y = frame_y.to_local(dir);
    EventValue v{eval(*bsdf_y, wo_y, wi_y)[0] * abs_cos_theta(wi_y), pdf(*bsdf_y, wo_y, wi_y)[0]};
    if (!(v.f_cos > 0) || !(v.pdf > 0)) return o.fail();
    int own_medium = o.medium;
    if (info_y.medium_transition && cos_theta(wi_y) * cos_theta(wo_y) < 0) {
      own_medium = dot(dir, o.hit.ng) < 0 ? info_y.medium_inside : info_y.medium_outside;
    }
    Shadow s =
        trace_shadow(scene_, geometry.offset_origin(o.hit.p, o.hit.ng, dir), dir,
                   geometry.offset_origin(next->p, next->ng, -dir), false, own_medium, o.lambda, 1,
                   counters_);
    if (s.scattering || !(s.transmittance[0] > 0)) return o.fail();
    const float jacobian = reconnection_jacobian(base.position, o.hit.p, next->p, next->ng);
    if (!(jacobian > 0)) return o.fail();
    v.f_cos *= s.transmittance[0];
    take_step(o, v, jacobian, base.pdf, ctx_y);
    o.state = OffsetState::kReconnected;
    o.reconnected_before = true;
    ++counters_.gradient_reconnections;
    o.direction = dir;
    return;
  }
  auto shift = shift_direction(base.scatter, wo_y, relative_eta(*bsdf_y));
  if (!shift) return o.fail();
  EventValue v = event_value(*bsdf_y, wo_y, shift->wi, base.scatter.transmission);
  if (!(v.pdf > 0)) return o.fail();
  take_step(o, v, shift->jacobian, base.pdf, ctx_y);
  const Vec3f dir = frame_y.from_local(shift->wi);
  if (info_y.medium_transition && base.scatter.transmission) {
    o.medium = dot(dir, o.hit.ng) < 0 ? info_y.medium_inside : info_y.medium_outside;
  }
  o.direction = dir;
  trace_own(o, {geometry.offset_origin(o.hit.p, o.hit.ng, dir), dir});
}

void OffsetTracer::apply(Offset& o, const OffsetStep& step) const {
  using Kind = OffsetStep::Kind;
  const int side = o.lane - 1;
  switch (step.kind) {
    case Kind::kSegment:
      if (!step.scattering) {
        if (o.state == OffsetState::kSame) o.beta *= step.factor[side];
      } else if (o.state == OffsetState::kDiverged) {
        o.fail();  // no base distance to copy (integrator.h)
      } else if (o.state == OffsetState::kSame) {
        o.beta *= step.factor[side] / step.p_x;
        o.rho *= step.pdf[side] / step.p_x;
        o.pdf_since_prev *= step.pdf[side];
      }
      return;
    case Kind::kMediumVertex:
      if (o.state == OffsetState::kSame) {
        take_step(o, {step.phase_pdf, step.phase_pdf}, 1.0f, step.phase_pdf, step.ctx);
      }
      return;
    case Kind::kResolve:
      if (o.state == OffsetState::kDiverged && o.pending) {
        resolve_pending(o, step.base, step.has_next ? &step.hit : nullptr, step.direction);
      }
      return;
    case Kind::kInterfaceEmitter:
      if (o.state != OffsetState::kSame) o.fail();
      return;
    case Kind::kArrive:
      if (o.state == OffsetState::kDiverged) {
        if (!o.has_hit) return o.fail();
        auto bsdf_y =
            make_bsdf(scene_.material_at(scene_.shape(o.hit.shape).material, o.hit, -o.direction),
                      o.lambda, texture_context(o.hit));
        if (!bsdf_y || !(kind_of(*bsdf_y) == step.vertex_kind)) o.fail();
      }
      return;
    case Kind::kScatter:
      scatter(o, step);
      return;
    case Kind::kRoulette:
      o.beta /= step.survival;
      return;
  }
}

void OffsetTracer::scatter(Offset& o, const OffsetStep& step) const {
  if (step.vertex_kind.stochastic) return o.fail();  // VertexKind
  if (o.state == OffsetState::kDiverged) {
    o.pending = true;
    return;
  }
  const Geometry& geometry = scene_.geometry();
  const SurfaceHit& hit = step.hit;
  auto b = make_bsdf(*step.material, o.lambda, texture_context(step.hit));
  PRISM_CHECK(b.has_value());
  if (o.state == OffsetState::kSame && step.vertex_kind.dispersive &&
      step.base.scatter.transmission) {
    // The first wavelength-dependent vertex: copy the half-vector (the event for a smooth one)
    // with the offset's own η, and leave the base.
    auto shift = shift_direction(step.base.scatter, step.wo, relative_eta(*b));
    if (!shift) return o.fail();
    EventValue v = event_value(*b, step.wo, shift->wi, true);
    if (!(v.pdf > 0)) return o.fail();
    take_step(o, v, shift->jacobian, step.p_x, step.ctx);
    const Vec3f dir = step.frame.from_local(shift->wi);
    o.state = OffsetState::kDiverged;
    ++counters_.gradient_divergences;
    if (o.reconnected_before) ++counters_.gradient_repeated_divergences;
    o.direction = dir;
    o.medium = step.medium_before;
    if (step.info->medium_transition) {
      o.medium = dot(dir, hit.ng) < 0 ? step.info->medium_inside : step.info->medium_outside;
    }
    trace_own(o, {geometry.offset_origin(hit.p, hit.ng, dir), dir});
    return;
  }
  // The base's direction (J = 1): nothing about it depends on λ here, or the offset has just
  // reconnected to this (connectable) vertex.
  const Vec3f wo_y =
      o.state == OffsetState::kReconnected ? step.frame.to_local(-o.direction) : step.wo;
  EventValue v = event_value(*b, wo_y, step.base.scatter.wi, step.base.scatter.transmission);
  take_step(o, v, 1.0f, step.p_x, step.ctx);
  o.state = OffsetState::kSame;
  o.medium = step.medium_after;
}

DivergedNee OffsetTracer::diverged_nee(const Offset& o, const Bsdf& b, const Frame& frame,
                                       const Vec3f& wo, int light_index, const LightSample& ls,
                                       const Vec3f& base_p, Point2f light_u, float u_extra) const {
  const Geometry& geometry = scene_.geometry();
  const Light& light = scene_.lights()[light_index];
  const LightContext ctx_y{o.hit.p, o.hit.ns};
  DivergedNee out;
  Vec3f wi_y;
  float solid_angle_pdf_y = 0;
  const bool to_infinity = std::isinf(ls.distance);
  Vec3f target_y = ls.p_light;
  if (std::holds_alternative<InfiniteLight>(light)) {
    wi_y = ls.wi;  // the environment's point is a direction: J = 1
    const auto& inf = std::get<InfiniteLight>(light);
    out.le = inf.radiance(o.hit.p, wi_y, o.lambda)[0];
    solid_angle_pdf_y = inf.pdf(o.hit.p, wi_y);  // a portal's window depends on the point
  } else if (ls.delta) {
    auto ls_y = sample_light(light, ctx_y, light_u, u_extra, o.lambda);
    if (!ls_y) return out;
    wi_y = ls_y->wi;
    out.le = ls_y->radiance[0];
    solid_angle_pdf_y = ls_y->pdf;
  } else {
    const auto& area = std::get<AreaLight>(light);
    Vec3f to = ls.p_light - o.hit.p;
    const float d = length(to);
    if (!(d > 0)) return out;
    wi_y = to / d;
    out.le = area.radiance(ls.n_light, -wi_y, o.lambda)[0];
    SurfaceHit light_point;
    light_point.p = ls.p_light;
    light_point.ng = ls.n_light;
    solid_angle_pdf_y = area.pdf(ctx_y, wi_y, light_point);
    out.jacobian = reconnection_jacobian(base_p, o.hit.p, ls.p_light, ls.n_light);
    if (!(out.jacobian > 0)) return out;
    target_y = geometry.offset_origin(ls.p_light, ls.n_light, -wi_y);
  }
  out.valid = true;
  const Vec3f wi_y_local = frame.to_local(wi_y);
  out.f = eval(b, wo, wi_y_local)[0] * abs_cos_theta(wi_y_local);
  if (!(out.f > 0) || !(out.le > 0)) return out;
  out.p_bsdf = pdf(b, wo, wi_y_local)[0];
  Shadow s = trace_shadow(scene_, geometry.offset_origin(o.hit.p, o.hit.ng, wi_y), wi_y, target_y,
                        to_infinity, o.medium, o.lambda, 1, counters_);
  out.transmittance = s.transmittance[0];
  out.pass = s.pass[0];
  out.p_light = scene_.light_sampler().pmf(o.hit.p, o.lambda, light_index) * solid_angle_pdf_y;
  return out;
}

}  // namespace prism::worker::gradient
