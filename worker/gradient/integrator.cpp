#include "worker/gradient/integrator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>
#include <type_traits>

#include "services/base/check.h"
#include "services/spectral/color.h"
#include "worker/bsdf.h"
#include "worker/gradient/offset.h"
#include "worker/gradient/shift.h"
#include "worker/light.h"
#include "worker/material.h"
#include "worker/medium.h"
#include "worker/sample_layout.h"

namespace prism::worker {
namespace {

// The base path reads PathIntegrator's sample dimensions (sample_layout.h), so it is drawn
// exactly like a `uniform` path.
using namespace layout;

using gradient::BaseEvent;
using gradient::DivergedNee;
using gradient::EventValue;
using gradient::Offset;
using gradient::OffsetState;
using gradient::VertexKind;

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

// Adds a sample's values to one bin: its entry for the bin, new or the one it has.
void add_entry(GradientSample& out, int bin, float primal, float gradient) {
  for (int e = 0; e < out.entries; ++e) {
    if (out.entry[e].bin == bin) {
      out.entry[e].primal += primal;
      out.entry[e].gradient += gradient;
      return;
    }
  }
  out.entry[out.entries++] = {bin, primal, gradient};
}

// Adds a lane's value v in `bin` unshifted: v to I[bin], and its finite difference to G
// (G[bin] −= v, G[bin − k] += v).
void add_unshifted_lane(GradientSample& out, const spectral::WavelengthGrid& grid, int k, int bin,
                        float v) {
  add_entry(out, bin, v, -v);
  add_entry(out, grid.wrap(bin - k), 0.0f, v);
}

// One gradient sample's base path and its two offsets (docs/estimators.md §5), the estimator's
// steps by name: the events' accumulation with their shifts, emission found by the sampled
// direction, a flight through a medium, next-event estimation at a surface, scattering and
// roulette, and the final values. The offsets follow the base lazily through a log of its steps
// (record, catch_up). It lives for one sample.
class BasePath {
 public:
  // `lanes` holds the C hero lanes (C = 1: the base wavelength alone); lane 0 is the base.
  BasePath(const RenderScene& scene, const Sampler& sampler, TraceCounters& counters,
           GradientEventSink* events, float tau, const SampledWavelengths& lanes)
      : scene_(scene),
        sampler(sampler),
        counters(counters),
        events(events),
        tau_(tau),
        hero_lanes(lanes.count()),
        base_lambda(single(lanes.lambda(0), lanes.pdf(0))),
        hero_lambda(lanes),
        shared(kLanes + lanes.count() - 1),
        tracer(scene, counters) {
    for (int s = 0; s < hero_lanes; ++s) {
      lane_lambda[s] = single(lanes.lambda(s), lanes.pdf(s));
      hero.beta[s] = hero.r[s] = hero.r_prev[s] = 1.0f;
    }
  }

  bool has_hero() const { return hero_lanes > 1; }
  // The wavelengths the base's spectral evaluations (BSDF, emission, light samples) are made
  // for: lane 0 is the base's.
  const SampledWavelengths& eval_lambda() const { return has_hero() ? hero_lambda : base_lambda; }
  // Hero lane s's index in `shared`.
  static int shared_lane(int s) { return s == 0 ? kBase : kLanes + s - 1; }

  // Places the base wavelength and the offsets at λ ± δ (δ = `offset_bins` bins); false when the
  // base's λ falls in no bin or has no density.
  bool start(spectral::WavelengthPdfView lambda_pdf, int offset_bins) {
    const spectral::WavelengthGrid& grid = scene_.grid();
    lambda = base_lambda.lambda(0);
    const float lambda_density = base_lambda.pdf(0);
    const int bin = grid.bin_of(lambda);
    if (bin < 0 || !(lambda_density > 0)) return false;
    out.lambda = lambda;
    out.bin = bin;
    out.bin_below = grid.wrap(bin - offset_bins);
    offset_bins_ = offset_bins;

    // Offsets at λ ± δ, placed from the base's position inside its bin so that they land in bins
    // i ± k exactly (λ ± k·w wrapped can round into a neighbouring bin).
    shared.set(kBase, lambda, lambda_density);
    for (int s = 1; s < hero_lanes; ++s) {
      shared.set(shared_lane(s), hero_lambda.lambda(s), hero_lambda.pdf(s));
    }
    for (int side = 0; side < 2; ++side) {
      const int target = grid.wrap(bin + (side == 0 ? offset_bins : -offset_bins));
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
    scale = 1.0f / (lambda_density * grid.bin_width());

    medium = scene_.camera_medium();
    for (Offset& o : offsets) o.medium = medium;
    return true;
  }

  // Whether any lane still carries light: the base's throughput, or with hero lanes any of theirs
  // (the path goes on for them; the base's events then add 0).
  bool alive() const {
    if (beta != 0.0f) return true;
    for (int s = 1; s < hero_lanes; ++s) {
      if (hero.beta[s] != 0.0f) return true;
    }
    return false;
  }
  // Whether a light's radiance reaches a hero lane other than the base's.
  bool hero_lit(const SampledSpectrum& radiance) const {
    for (int s = 1; s < hero_lanes; ++s) {
      if (radiance[s] > 0) return true;
    }
    return false;
  }

  float hero_r_sum() const {
    float sum = 0;
    for (int k = 0; k < hero_lanes; ++k) sum += hero.r[k];
    return sum;
  }

  // An emitter found by the sampled direction, for the hero lanes: `le` per lane (eval_lambda())
  // and `light_density(l)`, the density next-event estimation with the single wavelength l as the
  // base's would have given this point (read only after a non-specular event).
  template <typename LightDensity>
  void hero_emission(const SampledSpectrum& le, LightDensity&& light_density) {
    if (!has_hero() || le.is_zero()) return;
    float denominator = hero_r_sum();
    if (!prev_specular) {
      for (int k = 0; k < hero_lanes; ++k) {
        if (hero.r_prev[k] > 0) {
          denominator += hero.r_prev[k] * light_density(lane_lambda[k]) / pdf_since_prev;
        }
      }
    }
    if (!(denominator > 0)) return;
    for (int s = 0; s < hero_lanes; ++s) hero.radiance[s] += hero.beta[s] * le[s] / denominator;
  }

  // Next-event estimation for the hero lanes: light `light` at `p` through the light sample `ls`
  // (radiance per lane), the scattering value and density per lane towards it, its shadow.
  void hero_direct(const Vec3f& p, int light, const LightSample& ls, const SampledSpectrum& f,
                   const SampledSpectrum& scatter_pdf, const Shadow& shadow) {
    if (!has_hero()) return;
    float denominator = 0;
    for (int k = 0; k < hero_lanes; ++k) {
      if (!(hero.r[k] > 0)) continue;
      const float p_light = scene_.light_sampler().pmf(p, lane_lambda[k], light) * ls.pdf;
      const float p_unidirectional = ls.delta ? 0.0f : scatter_pdf[k] * shadow.pass[shared_lane(k)];
      denominator += hero.r[k] * (p_light + p_unidirectional);
    }
    if (!(denominator > 0)) return;
    for (int s = 0; s < hero_lanes; ++s) {
      hero.radiance[s] +=
          hero.beta[s] * f[s] * ls.radiance[s] * shadow.transmittance[shared_lane(s)] / denominator;
    }
  }

  // The hero lanes other than the base's end here (an event only the base's wavelength follows).
  void hero_terminate_secondary() {
    if (!has_hero() || !hero.secondary) return;
    hero.secondary = false;
    for (int s = 1; s < hero_lanes; ++s) hero.beta[s] = hero.r[s] = 0;
    ++counters.lane_splits;
  }

  // The base reached its next vertex (or escaped) after scattering at a surface: the offsets
  // resolve theirs when they catch up.
  void resolve_arrival(const Ray& ray, const std::optional<SurfaceHit>& hit) {
    gradient::OffsetStep& step = record();
    step.kind = StepKind::kResolve;
    step.has_next = hit.has_value();
    if (hit) step.hit = *hit;
    step.direction = ray.direction;
    step.base = base_event;
    resolve_due = false;
  }

  void catch_up() {
    for (int i = 0; i < step_count; ++i) {
      for (Offset& o : offsets) {
        if (o.live()) tracer.apply(o, steps[i].step);
      }
    }
    step_count = 0;
  }
  // Default-initialised, not value-initialised: the step's default member initialisers hold and
  // the rest (points, frames, the hit) is left for the recorder of each kind to set, instead of
  // zeroing the whole step first (a tenth of the path loop's own time on scenes that never shift).
  gradient::OffsetStep& record() {
    if (step_count == kMaxSteps) catch_up();
    return *new (&steps[step_count++].step) gradient::OffsetStep;
  }

  template <typename OffsetEventFn>
  void accumulate(float c, OffsetEventFn&& offset_event) {
    if (c == 0.0f) return;
    out.primal += c;
    // Roulette-free values for the threshold (both sides of a pair compute the same numbers).
    const float c_free = c * survival;
    float up = -c, down = c;  // unshifted
    float own_values[2] = {0, 0};
    if (c_free > tau_ && shiftable) {
      catch_up();
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
        own_values[side] = own;
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
    if (events != nullptr) {
      events->record(
          {c_free, c * c, {up * up, down * down}, {own_values[0], own_values[1]}, depth + 1});
    }
  }

  template <typename OffsetEmissionFn>
  void emission_event(float le_x, float p_light_x, OffsetEmissionFn&& offset_emission) {
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
  }

  // The segment of `ray` up to `hit` (or infinity) through the base's medium, recorded for the
  // offsets: passed (go on to the surface), scattered inside the medium (NEE with the offsets
  // done, `ray` is the new direction from the medium vertex, depth counted), or ended.
  enum class Flight { kPassed, kScattered, kEnded };
  Flight fly_through_medium(Ray& ray, const std::optional<SurfaceHit>& hit, std::uint32_t dim,
                            std::uint32_t flight_dim) {
    if (medium >= 0) {
      const HomogeneousMedium& m = scene_.media()[medium];
      if (!m.scattering()) {
        SampledSpectrum sigma_a = m.sigma_a(shared);
        auto absorb = [&](float sa) {
          return hit ? std::exp(-sa * hit->t) : (sa > 0 ? 0.0f : 1.0f);
        };
        beta *= absorb(sigma_a[kBase]);
        for (int s = 0; s < hero_lanes && has_hero(); ++s) {
          hero.beta[s] *= absorb(sigma_a[shared_lane(s)]);
        }
        gradient::OffsetStep& step = record();
        step.kind = StepKind::kSegment;
        for (const Offset& o : offsets) step.factor[o.lane - 1] = absorb(sigma_a[o.lane]);
        if (!alive()) return Flight::kEnded;
      } else {
        SampledSpectrum sigma_s = m.sigma_s(shared);
        SampledSpectrum sigma_t = m.sigma_a(shared) + sigma_s;
        FreeFlight flight = sample_free_flight(sigma_t, hit ? hit->t : kInfinity,
                                               sampler.at(flight_dim), shared.count());
        const float p_x = flight.pdf[kBase];
        if (!(p_x > 0)) return Flight::kEnded;
        if (has_hero()) {
          for (int s = 0; s < hero_lanes; ++s) {
            const int l = shared_lane(s);
            hero.beta[s] *= flight.transmittance[l] * (flight.scattered ? sigma_s[l] : 1.0f) / p_x;
            hero.r[s] *= flight.pdf[l] / p_x;
          }
        }
        {
          gradient::OffsetStep& step = record();
          step.kind = StepKind::kSegment;
          step.scattering = true;
          step.p_x = p_x;
          for (const Offset& o : offsets) {
            step.factor[o.lane - 1] =
                flight.transmittance[o.lane] * (flight.scattered ? sigma_s[o.lane] : 1.0f);
            step.pdf[o.lane - 1] = flight.pdf[o.lane];
          }
        }
        if (flight.scattered) {
          beta *= flight.transmittance[kBase] * sigma_s[kBase] / p_x;
          if (!alive() || depth == scene_.options().max_depth) return Flight::kEnded;
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
            auto ls = sample_light(light, ctx, to_point(light_u), choice_u.u1, eval_lambda());
            if (ls && ls->pdf > 0 && (ls->radiance[0] > 0 || hero_lit(ls->radiance))) {
              const float f = phase.p(wo, ls->wi);
              Shadow s = trace_shadow(scene_, p, ls->wi, ls->p_light, std::isinf(ls->distance),
                                      medium, shared, shared.count(), counters);
              if (has_hero()) {
                SampledSpectrum fs;
                for (int l = 0; l < hero_lanes; ++l) fs[l] = f;
                hero_direct(p, choice->light, *ls, fs, fs, s);
              }
              const float p_light_x = choice->pmf * ls->pdf;
              const float denominator_x = p_light_x + (ls->delta ? 0.0f : f * s.pass[kBase]);
              const float c = ls->radiance[0] > 0 ? scale * beta * f * ls->radiance[0] *
                                                        s.transmittance[kBase] / denominator_x
                                                  : 0.0f;
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
          if (!(phase_pdf > 0)) return Flight::kEnded;
          for (int k = 0; k < hero_lanes; ++k) hero.r_prev[k] = hero.r[k];
          gradient::OffsetStep& step = record();
          step.kind = StepKind::kMediumVertex;
          step.phase_pdf = phase_pdf;
          step.ctx = ctx;
          prev_ctx = ctx;
          prev_specular = false;
          pdf_since_prev = phase_pdf;
          ray = {p, wi};
          ++depth;
          return Flight::kScattered;
        }
        beta *= flight.transmittance[kBase] / p_x;
        pdf_since_prev *= p_x;
        if (!alive()) return Flight::kEnded;
      }
    }
    return Flight::kPassed;
  }

  // The environment seen along an escaping ray, with what each offset's own ray sees.
  void add_environment(const Ray& ray) {
    const int infinite = scene_.infinite_light();
    if (infinite >= 0) {
      const auto& inf = std::get<InfiniteLight>(scene_.lights()[infinite]);
      auto light_density = [&](const LightContext& ctx, const SampledWavelengths& l,
                               const Vec3f& dir) {
        return scene_.light_sampler().pmf(ctx.p, l, infinite) * inf.pdf(ctx.p, dir);
      };
      const float p_light_x =
          prev_specular ? 0.0f : light_density(prev_ctx, base_lambda, ray.direction);
      const SampledSpectrum le = inf.radiance(ray.origin, ray.direction, eval_lambda());
      hero_emission(le, [&](const SampledWavelengths& l) {
        return light_density(prev_ctx, l, ray.direction);
      });
      emission_event(le[0], p_light_x, [&](Offset& o) -> std::optional<std::pair<float, float>> {
        Vec3f origin = ray.origin, dir = ray.direction;
        if (o.state == OffsetState::kDiverged) {
          if (o.has_hit) return std::pair{0.0f, 0.0f};
          origin = o.prev_ctx.p;
          dir = o.direction;
        }
        return std::pair{inf.radiance(origin, dir, o.lambda)[0],
                         prev_specular ? 0.0f : light_density(o.prev_ctx, o.lambda, dir)};
      });
    }
  }

  // The first vertex's guide features (prepass tasks).
  void record_guides(const std::optional<SurfaceHit>& hit, const Material* material,
                     GuideValues* guides) const {
    const Geometry& geometry = scene_.geometry();
    const Bounds3f& b = geometry.bounds();
    float far = length(scene_.camera().position() - b.centre()) + b.radius();
    guides->depth = std::min(1.0f, hit->t / std::max(1e-6f, far));
    guides->normal = hit->ns;
    if (const auto* diffuse = std::get_if<DiffuseMaterial>(material)) {
      guides->albedo = diffuse->reflectance.at(texture_context(*hit), base_lambda)[0];
    } else {
      guides->albedo = 1.0f;
    }
  }

  // An area emitter the base hit, with what each offset hits or sees there.
  void add_area_emission(const Ray& ray, const std::optional<SurfaceHit>& hit,
                         const ShapeInfo* info, bool at_vertex) {
    if (info->area_light >= 0) {
      const auto& area = std::get<AreaLight>(scene_.lights()[info->area_light]);
      auto light_density = [&](const LightContext& ctx, const SampledWavelengths& l, int light,
                               const AreaLight& a, const Vec3f& dir, const SurfaceHit& h) {
        return scene_.light_sampler().pmf(ctx.p, l, light) * a.pdf(ctx, dir, h);
      };
      const float p_light_x = prev_specular ? 0.0f
                                            : light_density(prev_ctx, base_lambda, info->area_light,
                                                            area, ray.direction, *hit);
      const SampledSpectrum le = area.radiance(hit->ng, -ray.direction, eval_lambda());
      hero_emission(le, [&](const SampledWavelengths& l) {
        return light_density(prev_ctx, l, info->area_light, area, ray.direction, *hit);
      });
      emission_event(le[0], p_light_x, [&](Offset& o) -> std::optional<std::pair<float, float>> {
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
  }

  // Arriving at a surface vertex: the offsets' arrival is recorded, and next-event estimation
  // from the base's vertex is weighed against the offsets' (at the base's vertex, or from their
  // own vertices to the base's light point). Returns what scattering there needs.
  struct SurfaceVertex {
    std::optional<Bsdf> bsdf;
    VertexKind kind;
    Frame frame;
    Vec3f wo;
    LightContext ctx;
  };
  SurfaceVertex direct_at_surface(const Ray& ray, const std::optional<SurfaceHit>& hit,
                                  const Material* material, std::uint32_t dim) {
    const Geometry& geometry = scene_.geometry();
    // A coat of wavelength-dependent index was made for the base's wavelength alone (as `hero`).
    if (has_hero() && terminates_secondary(*material)) hero_terminate_secondary();
    auto bsdf = make_bsdf(*material, eval_lambda(), texture_context(*hit));
    const VertexKind kind = gradient::kind_of(*bsdf);
    const Frame frame = Frame::from_xz(hit->dpdu, hit->ns);
    const Vec3f wo = frame.to_local(-ray.direction);
    const LightContext ctx{hit->p, hit->ns};

    {
      // Diverged offsets must have reached a vertex of the same kind.
      gradient::OffsetStep& step = record();
      step.kind = StepKind::kArrive;
      step.vertex_kind = kind;
    }
    // An offset's BSDF, frame and incoming direction at this vertex (its own vertex when
    // diverged), once it has caught up.
    struct OffsetVertex {
      std::optional<Bsdf> bsdf;
      Frame frame;
      Vec3f wo;
    };
    auto offset_vertex = [&](const Offset& o) {
      OffsetVertex v;
      if (o.state == OffsetState::kDiverged) {
        v.bsdf =
            make_bsdf(scene_.material_at(scene_.shape(o.hit.shape).material, o.hit, -o.direction),
                      o.lambda, texture_context(o.hit));
        v.frame = Frame::from_xz(o.hit.dpdu, o.hit.ns);
        v.wo = v.frame.to_local(-o.direction);
      } else {
        v.bsdf = make_bsdf(*material, o.lambda, texture_context(*hit));
        v.frame = frame;
        v.wo = o.state == OffsetState::kReconnected ? frame.to_local(-o.direction) : wo;
      }
      return v;
    };

    if (!kind.specular) {
      const Point2 choice_u = sampler.at2(dim + kLightChoice);
      const Point2 light_u = sampler.at2(dim + kLightPosition);
      auto choice = scene_.light_sampler().sample(ctx.p, base_lambda, choice_u.u0);
      std::optional<LightSample> ls;
      if (choice) {
        ls = sample_light(scene_.lights()[choice->light], ctx, to_point(light_u), choice_u.u1,
                          eval_lambda());
      }
      if (ls && ls->pdf > 0 && (ls->radiance[0] > 0 || hero_lit(ls->radiance))) {
        const Light& light = scene_.lights()[choice->light];
        const Vec3f wi_local = frame.to_local(ls->wi);
        const SampledSpectrum f = eval(*bsdf, wo, wi_local) * abs_cos_theta(wi_local);
        const float f_x = ls->radiance[0] > 0 ? f[0] : 0.0f;
        if (f_x > 0 || hero_lit(f * ls->radiance)) {
          const SampledSpectrum bsdf_pdf = pdf(*bsdf, wo, wi_local);
          const float bsdf_pdf_x = bsdf_pdf[0];
          const Vec3f target = ls->n_light == Vec3f()
                                   ? ls->p_light
                                   : geometry.offset_origin(ls->p_light, ls->n_light, -ls->wi);
          Shadow s =
              trace_shadow(scene_, geometry.offset_origin(ctx.p, hit->ng, ls->wi), ls->wi, target,
                           std::isinf(ls->distance), medium, shared, shared.count(), counters);
          hero_direct(ctx.p, choice->light, *ls, f, bsdf_pdf, s);
          const float p_light_x = choice->pmf * ls->pdf;
          const float denominator_x = p_light_x + (ls->delta ? 0.0f : bsdf_pdf_x * s.pass[kBase]);
          const float c = f_x > 0 ? scale * beta * f_x * ls->radiance[0] * s.transmittance[kBase] /
                                        denominator_x
                                  : 0.0f;
          accumulate(c, [&](Offset& o) -> OffsetEvent {
            const OffsetVertex y = offset_vertex(o);
            const Bsdf& b = *y.bsdf;
            if (o.state != OffsetState::kDiverged) {
              // At the base's vertex: the same light point along the same direction (J = 1).
              auto ls_y = sample_light(light, ctx, to_point(light_u), choice_u.u1, o.lambda);
              if (!ls_y) return {};
              const float f_y = eval(b, y.wo, wi_local)[0] * abs_cos_theta(wi_local);
              const float p_y = pdf(b, y.wo, wi_local)[0];
              const float p_light_y =
                  scene_.light_sampler().pmf(ctx.p, o.lambda, choice->light) * ls->pdf;
              const float denominator_y = p_light_y + (ls->delta ? 0.0f : p_y * s.pass[o.lane]);
              return {true,
                      scale * o.beta * f_y * ls_y->radiance[0] * s.transmittance[o.lane] /
                          denominator_x,
                      o.rho * denominator_y / denominator_x};
            }
            // From the offset's own vertex to the base's light point.
            DivergedNee n = tracer.diverged_nee(o, b, y.frame, y.wo, choice->light, *ls, ctx.p,
                                                to_point(light_u), choice_u.u1);
            if (!n.valid) return {};
            if (!(n.f > 0) || !(n.le > 0)) return {true, 0.0f, 0.0f};
            const float denominator_y = n.p_light + (ls->delta ? 0.0f : n.p_bsdf * n.pass);
            return {true,
                    scale * o.beta * n.f * n.le * n.transmittance * n.jacobian / denominator_x,
                    o.rho * denominator_y * n.jacobian / denominator_x};
          });
        }
      }
    }
    return SurfaceVertex{std::move(bsdf), kind, frame, wo, ctx};
  }

  // The base scatters at its surface vertex (recorded for the offsets, which follow when they
  // catch up; depth counted), then Russian roulette on its throughput. False when the path ends.
  bool scatter_at_surface(Ray& ray, const std::optional<SurfaceHit>& hit, const ShapeInfo* info,
                          const Material* material, const SurfaceVertex& vertex,
                          std::uint32_t dim) {
    const Geometry& geometry = scene_.geometry();
    const std::optional<Bsdf>& bsdf = vertex.bsdf;
    const VertexKind kind = vertex.kind;
    const Frame& frame = vertex.frame;
    const Vec3f wo = vertex.wo;
    const LightContext ctx = vertex.ctx;
    // As in PathIntegrator: a diffuse BSDF ignores the lobe number, and before rr_min_depth no
    // roulette reads the pair's other number, so then the pair is not drawn.
    const bool pair_read =
        depth + 1 >= scene_.options().rr_min_depth || !std::holds_alternative<DiffuseBsdf>(*bsdf);
    const Point2 lobe_and_roulette =
        pair_read ? sampler.at2(dim + kScatterLobe) : Point2{0.5f, 0.5f};
    auto bs =
        sample(*bsdf, wo, lobe_and_roulette.u0, to_point(sampler.at2(dim + kScatterDirection)));
    if (!bs || !(bs->pdf[0] > 0)) return false;
    const float p_x = bs->pdf[0];
    const Vec3f wi = frame.from_local(bs->wi);
    const int medium_before = medium;
    base_event.scatter = {wo, bs->wi, bs->transmission, bs->specular,
                          gradient::relative_eta(*bsdf)};
    base_event.position = hit->p;
    base_event.pdf = p_x;
    {
      gradient::OffsetStep& step = record();
      step.kind = StepKind::kScatter;
      step.p_x = p_x;
      step.ctx = ctx;
      step.hit = *hit;
      step.base = base_event;
      step.vertex_kind = kind;
      step.material = material;
      step.info = info;
      step.frame = frame;
      step.wo = wo;
      step.medium_before = medium_before;
      step.medium_after = bs->transmission && info->medium_transition
                              ? (dot(wi, hit->ng) < 0 ? info->medium_inside : info->medium_outside)
                              : medium;
      resolve_due = true;
    }
    prev_ctx = ctx;
    prev_specular = bs->specular;
    pdf_since_prev = p_x;
    beta *= bs->f[0] * abs_cos_theta(bs->wi) / p_x;
    if (has_hero()) {
      for (int s = 0; s < hero_lanes; ++s) {
        hero.r_prev[s] = hero.r[s];
        hero.beta[s] *= bs->f[s] * abs_cos_theta(bs->wi) / p_x;
        hero.r[s] *= bs->pdf[s] / p_x;
      }
      if (bs->hero_only) {
        hero_terminate_secondary();
        shiftable = true;
      }
    }
    if (!alive()) return false;
    if (bs->transmission) {
      eta_scale *= bs->etap * bs->etap;
      if (info->medium_transition) {
        medium = dot(wi, hit->ng) < 0 ? info->medium_inside : info->medium_outside;
      }
    }
    ray = {geometry.offset_origin(hit->p, hit->ng, wi), wi};
    ++depth;

    if (depth >= scene_.options().rr_min_depth) {
      // With hero lanes, PathIntegrator's weight f_s / Σ_k p_k: the same whichever lane is the
      // base, as the lanes' MIS needs.
      float weight = beta * eta_scale;
      if (has_hero()) {
        float most = 0;
        for (int s = 0; s < hero_lanes; ++s) most = std::max(most, hero.beta[s]);
        const float r_sum = hero_r_sum();
        weight =
            r_sum > 0 ? most * float(hero.secondary ? hero_lanes : 1) / r_sum * eta_scale : 0.0f;
      }
      if (weight < 1.0f) {
        const float q = std::max(0.0f, 1.0f - weight);
        if (lobe_and_roulette.u1 < q) return false;
        beta /= 1.0f - q;
        for (int s = 0; s < hero_lanes && has_hero(); ++s) hero.beta[s] /= 1.0f - q;
        survival *= 1.0f - q;
        gradient::OffsetStep& step = record();
        step.kind = StepKind::kRoulette;
        step.survival = 1.0f - q;
      }
    }
    return true;
  }

  // The sample's values times the pixel filter's weight (nothing for a non-finite one) and the
  // added primal's exact-wavelength linear sRGB. With hero lanes the tile gets the lanes' primal
  // values, and the gradient rebuilt around them: G = D·I_hero + Σ (shifted − unshifted), the
  // single-wavelength G with its unshifted part D·I replaced by the hero primal's finite
  // difference (docs/estimators.md §5.1).
  GradientSample finish(float filter_weight) {
    const spectral::WavelengthGrid& grid = scene_.grid();
    if (any_shifted) ++counters.gradient_shifted_paths;
    bool finite = std::isfinite(out.primal) && std::isfinite(out.gradient) &&
                  std::isfinite(out.gradient_below);
    for (int s = 0; s < hero_lanes && has_hero(); ++s) {
      finite = finite && std::isfinite(hero.radiance[s]);
    }
    if (!finite) {
      ++counters.non_finite;
      out.primal = out.gradient = out.gradient_below = 0;
      return out;
    }
    if (filter_weight != 1.0f) {
      out.primal *= filter_weight;
      out.gradient *= filter_weight;
      out.gradient_below *= filter_weight;
    }
    auto add = [&](int bin, float primal, float gradient) {
      add_entry(out, bin, primal, gradient);
    };
    auto add_rgb = [&](float lambda_nm, double estimate) {
      const spectral::Rgb bar = scene_.cmf().srgb(lambda_nm);
      out.rgb[0] += bar.r * estimate;
      out.rgb[1] += bar.g * estimate;
      out.rgb[2] += bar.b * estimate;
    };
    if (!has_hero()) {
      add(out.bin, out.primal, out.gradient);
      add(out.bin_below, 0.0f, out.gradient_below);
      // primal is a per-bin average: times the bin width it is f/p at λ.
      if (out.primal != 0.0f) add_rgb(lambda, double(out.primal) * grid.bin_width());
      return out;
    }
    add(out.bin, 0.0f, out.gradient + out.primal);
    add(out.bin_below, 0.0f, out.gradient_below - out.primal);
    const float inverse_width = 1.0f / float(grid.bin_width());
    for (int s = 0; s < hero_lanes; ++s) {
      const float pdf = hero_lambda.pdf(s);
      const int bin = grid.bin_of(hero_lambda.lambda(s));
      if (!(pdf > 0) || bin < 0 || hero.radiance[s] == 0.0f) continue;
      const float v = hero.radiance[s] / pdf * inverse_width * filter_weight;
      add_unshifted_lane(out, grid, offset_bins_, bin, v);
      add_rgb(hero_lambda.lambda(s), double(hero.radiance[s]) / pdf * filter_weight);
    }
    return out;
  }

 private:
  using StepKind = gradient::OffsetStep::Kind;
  // An offset's value for one base event: {valid, c_y = f(y)|J|/Σp(x̄), ratio = Σp(y)|J| / Σp(x̄)}.
  struct OffsetEvent {
    bool valid = false;
    float contribution = 0;
    float ratio = 0;
  };

  const RenderScene& scene_;
  const Sampler& sampler;
  TraceCounters& counters;
  GradientEventSink* events;
  const float tau_;

 public:
  const int hero_lanes;
  const SampledWavelengths base_lambda;
  const SampledWavelengths hero_lambda;                 // the C hero lanes, lane 0 the base's
  SampledWavelengths lane_lambda[spectral::kMaxLanes];  // each hero lane alone
  // The hero lanes' estimator (C > 1), PathIntegrator's (integrator.h) with each lane's own
  // light selection: β_s = f_s / p_0, r_k = p_k / p_0 (the density of x̄ with λ_k as the base's
  // wavelength), r_prev before the last scattering, and the radiance found per lane.
  struct HeroLanes {
    float beta[spectral::kMaxLanes] = {};
    float r[spectral::kMaxLanes] = {};
    float r_prev[spectral::kMaxLanes] = {};
    float radiance[spectral::kMaxLanes] = {};
    bool secondary = true;  // the lanes other than the base still follow the path
  } hero;
  float lambda = 0;
  GradientSample out;
  Offset offsets[2];
  SampledWavelengths shared;  // the base and the offsets, for the shared evaluations
  float scale = 0;            // contributions are per-bin averages: f / (p(λ) p(x̄|λ)) / w
  float beta = 1;             // f / p(x̄|λ) of the base prefix, with roulette
  float survival = 1;         // product of the roulette survival probabilities
  float pdf_since_prev = 1;
  LightContext prev_ctx;
  bool prev_specular = true;
  float eta_scale = 1;
  int medium = -1;
  bool any_shifted = false;
  // Whether this path's events may be shifted: always with C = 1; with hero lanes only after a
  // smooth dispersive refraction (BsdfSample::hero_only), where the other lanes have ended
  // (docs/estimators.md §5.1).
  bool shiftable = hero_lanes == 1;
  int offset_bins_ = 0;
  int depth = 0;
  bool resolve_due = false;  // the base scattered at a surface and has not reached its next vertex

 private:
  const gradient::OffsetTracer tracer;
  BaseEvent base_event;
  // The base's steps the offsets have not followed yet; they catch up when an event needs them
  // (or when the log is full), so τ > 0 saves the offsets' rays as well as their events. A
  // surface vertex records about four steps; 64 hold a path of depth 15 without a forced catch-up
  // (at 24, the offsets of deep paths traced rays no event used). The slots are left
  // uninitialised (zeroing 24 steps of 288 bytes per sample cost a tenth of a sample's time) and
  // each step is constructed when it is recorded.
  static constexpr int kMaxSteps = 64;
  union StepSlot {
    StepSlot() {}
    gradient::OffsetStep step;
  };
  static_assert(std::is_trivially_destructible_v<gradient::OffsetStep>);
  StepSlot steps[kMaxSteps];
  int step_count = 0;
};

// A hero sample as a gradient sample: its lanes' values into I, and their finite differences
// into G (G[b] −= v, G[b − k] += v), so that the reconstruction returns I.
GradientSample from_lanes(const RenderScene& scene, int offset_bins, const SampleContribution& c) {
  GradientSample out;
  for (int s = 0; s < c.lanes; ++s) {
    if (c.value[s] != 0.0f)
      add_unshifted_lane(out, scene.grid(), offset_bins, c.bin[s], c.value[s]);
  }
  for (int i = 0; i < 3; ++i) out.rgb[i] = c.rgb[i];
  return out;
}

}  // namespace

bool has_smooth_dispersive_refraction(const RenderScene& scene) {
  return std::any_of(scene.materials().begin(), scene.materials().end(),
                     may_refract_smooth_dispersive);
}

GradientIntegrator::GradientIntegrator(const RenderScene& scene)
    : scene_(scene),
      offset_bins_(scene.options().gradient_offset_bins),
      tau_(scene.options().gradient_tau),
      hero_(scene) {
  const bool smooth_dispersive = has_smooth_dispersive_refraction(scene);
  hero_lanes_ = scene.options().gradient_lanes;
  if (hero_lanes_ == 0) hero_lanes_ = smooth_dispersive ? 1 : job::kSceneGradientLanes;
  shifts_possible_ = hero_lanes_ == 1 || smooth_dispersive;
  PRISM_CHECK(offset_bins_ >= 1 && offset_bins_ < scene.grid().bins());
  PRISM_CHECK(tau_ >= 0.0f);
  PRISM_CHECK(hero_lanes_ >= 1 && hero_lanes_ <= job::kMaxGradientLanes);
}

GradientSample GradientIntegrator::trace(int px, int py, std::uint32_t pass,
                                         std::uint32_t sample_index,
                                         spectral::WavelengthPdfView lambda_pdf,
                                         TraceCounters& counters, GuideValues* guides,
                                         GradientEventSink* events) const {
  ++counters.gradient_samples;
  counters.gradient_lanes += std::uint64_t(hero_lanes_);
  if (!shifts_possible_) {
    // Nothing can be shifted: the sample is `hero`'s with C lanes, and G its finite difference.
    return from_lanes(scene_, offset_bins_,
                      hero_.trace(px, py, pass, sample_index, lambda_pdf, counters, guides,
                                  {hero_lanes_, false}));
  }
  const job::RenderOptions& options = scene_.options();
  const Geometry& geometry = scene_.geometry();
  Sampler sampler(options.sampler, SampleKey{options.seed, pass, std::uint32_t(px),
                                             std::uint32_t(py), sample_index});
  BasePath path(scene_, sampler, counters, events, tau_,
                lambda_pdf.sample_lanes(sampler.at(kDimWavelength), hero_lanes_));
  if (!path.start(lambda_pdf, offset_bins_)) return path.out;

  auto [ray, filter_weight] = scene_.camera_sample(px, py, sampler);
  ++counters.camera_rays;
  if (guides) *guides = GuideValues{1.0f, {}, 0.0f};

  std::uint32_t crossings = 0;
  for (;;) {
    const std::uint32_t dim = kDimBounce + kDimsPerBounce * std::uint32_t(path.depth);
    const std::uint32_t flight_dim =
        crossings == 0
            ? dim + kFreeFlight
            : kDimCrossings + kCrossingsPerBounce * std::uint32_t(path.depth) + crossings;
    ++counters.rays;
    auto hit = geometry.intersect(ray, kInfinity);

    const BasePath::Flight flight = path.fly_through_medium(ray, hit, dim, flight_dim);
    if (flight == BasePath::Flight::kEnded) break;
    if (flight == BasePath::Flight::kScattered) {
      crossings = 0;
      continue;
    }

    const ShapeInfo* info = hit ? &scene_.shape(hit->shape) : nullptr;
    const Material* material =
        hit ? &scene_.material_at(info->material, *hit, -ray.direction) : nullptr;
    const bool at_vertex = !hit || !std::holds_alternative<InterfaceMaterial>(*material);
    if (path.resolve_due && at_vertex) path.resolve_arrival(ray, hit);
    if (!hit) {
      path.add_environment(ray);
      break;
    }
    if (path.depth == 0 && guides && at_vertex) path.record_guides(hit, material, guides);
    path.add_area_emission(ray, hit, info, at_vertex);

    if (!at_vertex) {
      // A pure medium boundary: the base continues on the other side, same path vertex; a
      // diverged offset met an emitter the base counted without a vertex of its own.
      if (info->area_light >= 0) path.record().kind = gradient::OffsetStep::Kind::kInterfaceEmitter;
      if (info->medium_transition) {
        path.medium = dot(ray.direction, hit->ng) < 0 ? info->medium_inside : info->medium_outside;
      }
      ray.origin = geometry.offset_origin(hit->p, hit->ng, ray.direction);
      if (++crossings == kCrossingsPerBounce) break;
      continue;
    }
    if (path.depth == options.max_depth) break;

    const BasePath::SurfaceVertex vertex = path.direct_at_surface(ray, hit, material, dim);
    if (!path.scatter_at_surface(ray, hit, info, material, vertex, dim)) break;
    crossings = 0;
  }
  return path.finish(filter_weight);
}

}  // namespace prism::worker
