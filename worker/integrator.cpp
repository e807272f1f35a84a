#include "worker/integrator.h"

#include <cmath>
#include <limits>

#include "services/base/check.h"
#include "services/spectral/color.h"
#include "worker/bsdf.h"
#include "worker/light.h"
#include "worker/material.h"
#include "worker/medium.h"
#include "worker/path_differential.h"
#include "worker/sample_layout.h"
#include "worker/shadow_ray.h"

namespace prism::worker {
namespace {

using namespace layout;  // the sample dimensions (sample_layout.h)

Point2f to_point(const Point2& p) {
  return {p.u0, p.u1};
}

float lane_sum(const SampledSpectrum& s, int lanes) {
  float sum = 0;
  for (int i = 0; i < lanes; ++i) sum += s[i];
  return sum;
}

SampledSpectrum ones(int lanes) {
  SampledSpectrum s;
  for (int i = 0; i < lanes; ++i) s[i] = 1.0f;
  return s;
}

// Per-lane division by the hero's value, so ratios stay O(1) along the path.
SampledSpectrum over_hero(const SampledSpectrum& s) {
  return s[0] != 0.0f ? s / s[0] : SampledSpectrum();
}

// The path's running state (see integrator.h for the estimator).
struct PathState {
  SampledWavelengths lambda;
  SampledSpectrum beta;      // f_s / p_0 of the path so far
  SampledSpectrum r;         // p_k / p_0 of the path so far (unidirectional technique)
  SampledSpectrum radiance;  // Σ over events of beta·Le / denominator, per lane
  // At the last scattering vertex, for MIS when the next emitter is found by the sampled
  // direction: the ratios before scattering, the hero's density of everything sampled since
  // (direction times free-flight passes), the lanes and the shading point.
  SampledSpectrum r_prev;
  float pdf_since_prev = 1;
  SampledWavelengths lambda_prev;
  LightContext prev_ctx;
  bool prev_specular = true;
  float eta_scale = 1;
  int medium = -1;
  // Where the path stands against the caustic class of `--caustics light` (light → delta chain
  // → the first, non-delta vertex → camera), by each vertex's BSDF (is_specular): 0 before the
  // first scattering, 1 after a non-delta first vertex, 2 once a delta vertex followed it (and
  // only delta ones since), −1 outside it.
  int caustic_chain = 0;
  // Gathering: the first vertex (the caustic's receiver) and the delta vertices after it while
  // the path is in that class (a vector, empty and unallocated unless the job gathers); more
  // than kMaxChain of them: too long to replay.
  static constexpr std::size_t kMaxChain = 8;
  SurfaceHit receiver;
  std::vector<ChainVertex> chain;
  bool chain_too_long = false;
  // The caustic events' offset sums (SampleContribution::offset), before the filter's weight.
  double offset[6] = {0, 0, 0, 0, 0, 0};

  explicit PathState(const SampledWavelengths& l) : lambda(l), lambda_prev(l) {}
};

// One camera path of PathIntegrator::trace, its state and the estimator's steps by name
// (docs/estimators.md §2–3): the emission a vertex finds, next-event estimation, a flight
// through a medium, a scattering at a surface, Russian roulette, and the sample's contribution
// per lane. It lives for one sample; every step reads its numbers from the sample layout.
class CameraPath {
 public:
  CameraPath(const RenderScene& scene, TraceCounters& counters, const Sampler& sampler,
             const SampledWavelengths& lambda, int lanes, bool early_stop)
      : scene_(scene),
        counters_(counters),
        sampler_(sampler),
        lanes_(lanes),
        early_stop_(early_stop),
        state(lambda) {
    state.beta = ones(lanes);
    state.r = ones(lanes);
    state.r_prev = state.r;
    state.medium = scene.camera_medium();
  }

  // Adds an emitter's radiance found by the unidirectional technique (camera or sampled
  // direction), weighted against NEE having produced the same vertex.
  void add_emission(const SampledSpectrum& le, int light, const SurfaceHit* hit,
                    const Vec3f& direction) {
    if (le.is_zero()) return;
    // With --caustics light the light tracer renders this path (light_tracer.h).
    if (state.caustic_chain == 2 && scene_.options().light_caustics) return;
    float denominator = lane_sum(state.r, lanes_);
    if (!state.prev_specular) {
      float p_light = scene_.light_sampler().pmf(state.prev_ctx.p, state.lambda_prev, light);
      const Light& l = scene_.lights()[light];
      if (const auto* area = std::get_if<AreaLight>(&l)) {
        p_light *= area->pdf(state.prev_ctx, direction, *hit);
      } else if (const auto* inf = std::get_if<InfiniteLight>(&l)) {
        p_light *= inf->pdf(state.prev_ctx.p, direction);
      }
      for (int k = 0; k < lanes_; ++k) {
        denominator += state.r_prev[k] * p_light / state.pdf_since_prev;
      }
    }
    if (!(denominator > 0)) return;
    const SampledSpectrum added = state.beta * le / denominator;
    state.radiance += added;
    if (state.caustic_chain == 2 && gathers_ && hit != nullptr) record_offset(added, hit->p);
  }

  // Gathering: the caustic event's offset on the film, weighted by what it added over its lanes.
  void record_offset(const SampledSpectrum& added, const Vec3f& emitter) {
    if (state.chain.empty() || state.chain_too_long) return;
    double w = 0;
    for (int s = 0; s < lanes_; ++s) {
      const float pdf = state.lambda.pdf(s);
      if (pdf > 0) w += double(added[s]) / pdf;
    }
    if (!(w > 0) || !std::isfinite(w)) return;
    auto dp = receiver_offset(scene_.geometry(), state.receiver, state.chain, emitter,
                              state.lambda.lambda(0));
    if (!dp) return;
    const Point2f d = scene_.camera().raster_differential(state.receiver.p, *dp);
    if (!std::isfinite(d.x) || !std::isfinite(d.y)) return;
    const double dx = d.x, dy = d.y;
    const double terms[6] = {w, w * dx, w * dy, w * dx * dx, w * dy * dy, w * dx * dy};
    for (int i = 0; i < 6; ++i) state.offset[i] += terms[i];
  }

  // The environment seen along an escaping ray.
  void add_environment(const Ray& ray) {
    const int infinite = scene_.infinite_light();
    if (infinite < 0) return;
    const auto& inf = std::get<InfiniteLight>(scene_.lights()[infinite]);
    add_emission(inf.radiance(ray.origin, ray.direction, state.lambda), infinite, nullptr,
                 ray.direction);
  }

  // Next-event estimation from a scattering vertex: `f_and_pdf` gives the per-lane scattering
  // value (BSDF·|cos| or phase) and its per-lane density for a direction.
  template <typename FAndPdf>
  void sample_direct(const LightContext& ctx, const Vec3f& origin_normal, std::uint32_t dim,
                     FAndPdf&& f_and_pdf) {
    const Geometry& geometry = scene_.geometry();
    const Point2 choice_u = sampler_.at2(dim + kLightChoice);  // choice and extra: one pair
    auto choice = scene_.light_sampler().sample(ctx.p, state.lambda, choice_u.u0);
    if (!choice) return;
    const Light& light = scene_.lights()[choice->light];
    auto ls = sample_light(light, ctx, to_point(sampler_.at2(dim + kLightPosition)), choice_u.u1,
                           state.lambda);
    if (!ls || !(ls->pdf > 0) || ls->radiance.is_zero()) return;
    SampledSpectrum f, scatter_pdf;
    f_and_pdf(ls->wi, &f, &scatter_pdf);
    if (f.is_zero()) return;
    Vec3f origin =
        origin_normal == Vec3f() ? ctx.p : geometry.offset_origin(ctx.p, origin_normal, ls->wi);
    // Both ends leave their surfaces (pbrt-v4's SpawnRayTo): the segment stops just in front of
    // an area light, on the side facing the shading point, so the light cannot occlude itself.
    Vec3f target = ls->n_light == Vec3f()
                       ? ls->p_light
                       : geometry.offset_origin(ls->p_light, ls->n_light, -ls->wi);
    const Shadow shadow = trace_shadow(scene_, origin, ls->wi, target, std::isinf(ls->distance),
                                       state.medium, state.lambda, lanes_, counters_);
    if (shadow.transmittance.is_zero()) return;
    float p_light = choice->pmf * ls->pdf;
    float denominator = 0;
    for (int k = 0; k < lanes_; ++k) {
      float p_unidirectional = ls->delta ? 0.0f : scatter_pdf[k] * shadow.pass[k];
      denominator += state.r[k] * (p_light + p_unidirectional);
    }
    if (denominator > 0) {
      state.radiance += state.beta * f * ls->radiance * shadow.transmittance / denominator;
    }
  }

  // Early stop (integrator.h): whether a path without a wavelength-dependent event so far ends
  // at the vertex from which it would scatter at `depth`.
  bool stops_early(int depth) {
    if (!early_stop_ || spectral_event || depth < kEarlyStopBounces) return false;
    ++counters_.early_stops;
    return true;
  }

  // The lanes other than the hero end here (an event only the hero wavelength follows).
  void terminate_secondary() {
    if (state.lambda.live_count() <= 1) return;
    state.lambda.terminate_secondary();
    for (int k = 1; k < spectral::kMaxLanes; ++k) state.beta[k] = state.r[k] = 0;
    ++counters_.lane_splits;
  }

  // The segment of `ray` up to `hit` (or infinity) through the current medium: passed (go on to
  // the surface), scattered inside the medium (NEE done, `ray` is the new direction from the
  // medium vertex), or ended.
  enum class Flight { kPassed, kScattered, kEnded };
  Flight fly_through_medium(Ray& ray, const std::optional<SurfaceHit>& hit, int depth,
                            std::uint32_t dim, std::uint32_t flight_dim) {
    if (state.medium < 0) return Flight::kPassed;
    const HomogeneousMedium& m = scene_.media()[state.medium];
    if (m.chromatic()) spectral_event = true;
    if (!m.scattering()) {
      // A purely absorbing medium: nothing to sample, the segment's transmittance is the
      // weight (the same density, 1, for every lane).
      SampledSpectrum sigma_a = m.sigma_a(state.lambda);
      if (hit) {
        state.beta *= spectral::exp(-sigma_a * hit->t);
      } else {
        for (int i = 0; i < lanes_; ++i) {
          if (sigma_a[i] > 0) state.beta[i] = 0;
        }
      }
      return state.beta.is_zero() ? Flight::kEnded : Flight::kPassed;
    }
    SampledSpectrum sigma_s = m.sigma_s(state.lambda);
    SampledSpectrum sigma_t = m.sigma_a(state.lambda) + sigma_s;
    FreeFlight flight =
        sample_free_flight(sigma_t, hit ? hit->t : kInfinity, sampler_.at(flight_dim), lanes_);
    if (!(flight.pdf[0] > 0)) return Flight::kEnded;
    if (!flight.scattered) {
      state.beta *= flight.transmittance / flight.pdf[0];
      state.r *= over_hero(flight.pdf);
      state.pdf_since_prev *= flight.pdf[0];
      return state.beta.is_zero() ? Flight::kEnded : Flight::kPassed;
    }
    state.beta *= flight.transmittance * sigma_s / flight.pdf[0];
    state.r *= over_hero(flight.pdf);
    if (state.beta.is_zero() || depth == scene_.options().max_depth || stops_early(depth)) {
      return Flight::kEnded;
    }
    // A real scattering event inside the medium.
    Vec3f p = ray.origin + ray.direction * flight.t;
    Vec3f wo = -ray.direction;
    const HenyeyGreenstein& phase = m.phase();
    LightContext ctx{p, Vec3f()};
    sample_direct(ctx, Vec3f(), dim,
                  [&](const Vec3f& wi, SampledSpectrum* f, SampledSpectrum* pdf) {
                    float value = phase.p(wo, wi);
                    *f = ones(lanes_) * value * state.lambda.live_mask();
                    *pdf = *f;
                  });
    float phase_pdf = 0;
    Vec3f wi = phase.sample(wo, to_point(sampler_.at2(dim + kScatterDirection)), &phase_pdf);
    if (!(phase_pdf > 0)) return Flight::kEnded;
    state.r_prev = state.r;
    state.lambda_prev = state.lambda;
    state.prev_ctx = ctx;
    state.prev_specular = false;
    state.caustic_chain = -1;
    state.pdf_since_prev = phase_pdf;
    ray = {p, wi};
    return Flight::kScattered;
  }

  // Scattering at a surface vertex: NEE (unless the BSDF is specular), then the BSDF's sampled
  // direction becomes `ray`. False when the path ends here. `roulette_u` receives the number
  // Russian roulette reads after this vertex (it shares its pair with the lobe choice), if
  // `roulette_follows`.
  bool scatter_at_surface(const Bsdf& bsdf, const Material& material, const SurfaceHit& hit,
                          const ShapeInfo& info, std::uint32_t dim, bool roulette_follows, Ray& ray,
                          float* roulette_u) {
    const Geometry& geometry = scene_.geometry();
    Frame frame = Frame::from_xz(hit.dpdu, hit.ns);
    Vec3f wo = frame.to_local(-ray.direction);
    LightContext ctx{hit.p, hit.ns};
    if (!is_specular(bsdf)) {
      sample_direct(ctx, hit.ng, dim,
                    [&](const Vec3f& wi, SampledSpectrum* f, SampledSpectrum* pdf) {
                      Vec3f wi_local = frame.to_local(wi);
                      *f = eval(bsdf, wo, wi_local) * abs_cos_theta(wi_local);
                      *pdf = worker::pdf(bsdf, wo, wi_local);
                    });
    }
    // A diffuse BSDF has one lobe and ignores the lobe number; where no roulette follows either,
    // nothing reads the pair, so it is not drawn (the same numbers everywhere else).
    const bool pair_read = roulette_follows || !std::holds_alternative<DiffuseBsdf>(bsdf);
    const Point2 lobe_and_roulette =
        pair_read ? sampler_.at2(dim + kScatterLobe) : Point2{0.5f, 0.5f};
    *roulette_u = lobe_and_roulette.u1;
    auto bs =
        sample(bsdf, wo, lobe_and_roulette.u0, to_point(sampler_.at2(dim + kScatterDirection)));
    if (!bs || !(bs->pdf[0] > 0)) return false;
    state.r_prev = state.r;
    state.lambda_prev = state.lambda;
    state.prev_ctx = ctx;
    state.prev_specular = bs->specular;
    state.pdf_since_prev = bs->pdf[0];
    // By the vertex's BSDF, not the sample: the light tracer decides by is_specular too, and a
    // coated BSDF (not a delta) samples its smooth coat's reflection as a delta event.
    const bool delta_vertex = is_specular(bsdf);
    if (state.caustic_chain == 0) {
      state.caustic_chain = delta_vertex ? -1 : 1;
      if (gathers_ && !delta_vertex) {
        state.receiver = hit;
        state.chain.clear();
        state.chain_too_long = false;
      }
    } else if (state.caustic_chain > 0) {
      state.caustic_chain = delta_vertex ? 2 : -1;
    }
    const bool in_chain = gathers_ && state.caustic_chain == 2;
    state.beta *= bs->f * (abs_cos_theta(bs->wi) / bs->pdf[0]);
    state.r *= over_hero(bs->pdf);
    if (bs->hero_only) terminate_secondary();
    if (state.beta.is_zero()) return false;
    Vec3f wi = frame.from_local(bs->wi);
    if (in_chain) {
      if (state.chain.size() < PathState::kMaxChain) {
        state.chain.push_back(ChainVertex{hit, &material, ray.direction, wi, bs->transmission});
      } else {
        state.chain_too_long = true;
      }
    }
    if (bs->transmission) {
      state.eta_scale *= bs->etap * bs->etap;
      if (info.medium_transition) {
        state.medium = dot(wi, hit.ng) < 0 ? info.medium_inside : info.medium_outside;
      }
    }
    ray = {geometry.offset_origin(hit.p, hit.ng, wi), wi};
    return true;
  }

  // Russian roulette on the path's throughput: false when it ends. The roulette weight
  // f_s / Σ_k p_k is the same whichever lane is the hero, so the survival probability is too,
  // and the lane MIS stays consistent.
  bool survives_roulette(float u) {
    float r_sum = lane_sum(state.r, lanes_);
    float weight =
        r_sum > 0 ? state.beta.max_value(lanes_) * float(state.lambda.live_count()) / r_sum : 0;
    weight *= state.eta_scale;
    if (weight < 1.0f) {
      float q = std::max(0.0f, 1.0f - weight);
      if (u < q) return false;
      state.beta /= 1.0f - q;
    }
    return true;
  }

  // The first vertex's guide features (prepass tasks), normalised so that every point of the
  // scene's bounding sphere lies in [0, 1] and a miss (1) is never nearer than a hit.
  GuideValues guides_at(const SurfaceHit& hit, const Material& material) const {
    const Bounds3f& b = scene_.geometry().bounds();
    const float far = length(scene_.camera().position() - b.centre()) + b.radius();
    GuideValues g;
    g.depth = std::min(1.0f, hit.t / std::max(1e-6f, far));
    g.normal = hit.ns;
    if (const auto* diffuse = std::get_if<DiffuseMaterial>(&material)) {
      g.albedo = diffuse->reflectance.at(texture_context(hit), state.lambda).average(lanes_);
    } else {
      g.albedo = 1.0f;
    }
    return g;
  }

  // The sample's value per lane: its bin and radiance / (p(λ)·bin width), times the pixel
  // filter's weight, and its exact-wavelength linear sRGB; nothing for a non-finite radiance.
  SampleContribution contribution(float filter_weight) {
    SampleContribution out;
    out.lanes = lanes_;
    const spectral::WavelengthGrid& grid = scene_.grid();
    const float inverse_width = 1.0f / float(grid.bin_width());
    bool finite = !state.radiance.has_non_finite();
    const spectral::ColorMatching& cmf = scene_.cmf();
    for (int s = 0; s < lanes_; ++s) {
      float pdf = state.lambda.pdf(s);
      out.bin[s] = grid.bin_of(state.lambda.lambda(s));
      const bool counted = finite && pdf > 0 && out.bin[s] >= 0;
      out.value[s] = counted ? state.radiance[s] / pdf * inverse_width * filter_weight : 0.0f;
      if (counted && state.radiance[s] != 0.0f) {
        const double estimate = double(state.radiance[s]) / pdf * filter_weight;
        const spectral::Rgb bar = cmf.srgb(state.lambda.lambda(s));
        out.rgb[0] += bar.r * estimate;
        out.rgb[1] += bar.g * estimate;
        out.rgb[2] += bar.b * estimate;
      }
      if (out.bin[s] < 0) out.bin[s] = 0;
    }
    if (!finite) ++counters_.non_finite;
    if (finite && state.offset[0] > 0) {
      for (int i = 0; i < 6; ++i) out.offset[i] = state.offset[i] * std::abs(filter_weight);
    }
    return out;
  }

 private:
  const RenderScene& scene_;
  TraceCounters& counters_;
  const Sampler& sampler_;
  const int lanes_;
  const bool early_stop_;
  // Gathering: record the caustic events' spectral offsets (RenderOptions::gathers; never with
  // --caustics light, whose light paths take those events).
  const bool gathers_ = scene_.options().gathers() && !scene_.options().light_caustics;

 public:
  PathState state;
  bool spectral_event = false;  // the path has met a wavelength-dependent event
};

}  // namespace

std::vector<std::pair<std::string, std::uint64_t>> counter_list(const TraceCounters& c) {
  return {{"camera_rays", c.camera_rays},
          {"rays", c.rays},
          {"lane_splits", c.lane_splits},
          {"non_finite", c.non_finite},
          {"early_stops", c.early_stops},
          {"gradient_events", c.gradient_events},
          {"gradient_shifted_paths", c.gradient_shifted_paths},
          {"gradient_shifts", c.gradient_shifts},
          {"gradient_shifts_failed", c.gradient_shifts_failed},
          {"gradient_shifts_wasted", c.gradient_shifts_wasted},
          {"gradient_divergences", c.gradient_divergences},
          {"gradient_reconnections", c.gradient_reconnections},
          {"gradient_repeated_divergences", c.gradient_repeated_divergences},
          {"gradient_samples", c.gradient_samples},
          {"gradient_lanes", c.gradient_lanes},
          {"light_splats", c.light_splats},
          {"splat_lines", c.splat_lines}};
}

SampleContribution PathIntegrator::trace(int px, int py, std::uint32_t pass,
                                         std::uint32_t sample_index,
                                         spectral::WavelengthPdfView lambda_pdf,
                                         TraceCounters& counters, GuideValues* guides,
                                         TraceOptions trace) const {
  const job::RenderOptions& options = scene_.options();
  const Geometry& geometry = scene_.geometry();
  PRISM_CHECK(trace.lanes >= 0 && trace.lanes <= spectral::kMaxLanes);
  const int lanes = trace.lanes > 0 ? trace.lanes : options.lanes();
  Sampler sampler(options.sampler, SampleKey{options.seed, pass, std::uint32_t(px),
                                             std::uint32_t(py), sample_index});
  CameraPath path(scene_, counters, sampler,
                  lambda_pdf.sample_lanes(sampler.at(kDimWavelength), lanes), lanes,
                  trace.early_stop);

  auto [ray, filter_weight] = scene_.camera_sample(px, py, sampler);
  ++counters.camera_rays;
  if (guides) *guides = GuideValues{1.0f, {}, 0.0f};

  std::uint32_t crossings = 0;  // medium boundaries crossed since the last scattering vertex
  for (int depth = 0;;) {
    const std::uint32_t dim = kDimBounce + kDimsPerBounce * std::uint32_t(depth);
    const std::uint32_t flight_dim =
        crossings == 0 ? dim + kFreeFlight
                       : kDimCrossings + kCrossingsPerBounce * std::uint32_t(depth) + crossings;
    ++counters.rays;
    auto hit = geometry.intersect(ray, kInfinity);

    const CameraPath::Flight flight = path.fly_through_medium(ray, hit, depth, dim, flight_dim);
    if (flight == CameraPath::Flight::kEnded) break;
    if (flight == CameraPath::Flight::kScattered) {
      ++depth;
      crossings = 0;
      continue;
    }

    if (!hit) {
      path.add_environment(ray);
      break;
    }

    const ShapeInfo& info = scene_.shape(hit->shape);
    const Material& material = scene_.material_at(info.material, *hit, -ray.direction);
    if (info.wavelength_dependent) path.spectral_event = true;
    if (depth == 0 && guides && !std::holds_alternative<InterfaceMaterial>(material)) {
      *guides = path.guides_at(*hit, material);
    }
    if (info.area_light >= 0) {
      const auto& area = std::get<AreaLight>(scene_.lights()[info.area_light]);
      path.add_emission(area.radiance(hit->ng, -ray.direction, path.state.lambda), info.area_light,
                        &*hit, ray.direction);
    }

    auto bsdf = make_bsdf(material, path.state.lambda, texture_context(*hit));
    if (!bsdf) {
      // A pure medium boundary: continue in the medium on the other side, same path vertex.
      if (info.medium_transition) {
        path.state.medium =
            dot(ray.direction, hit->ng) < 0 ? info.medium_inside : info.medium_outside;
      }
      ray.origin = geometry.offset_origin(hit->p, hit->ng, ray.direction);
      if (++crossings == kCrossingsPerBounce) break;
      continue;
    }
    if (depth == options.max_depth || path.stops_early(depth)) break;
    // A coat of wavelength-dependent index was made for the hero wavelength alone (pbrt-v4
    // terminates the others when it makes the BSDF, before next-event estimation).
    if (terminates_secondary(material)) path.terminate_secondary();
    float roulette_u = 0;
    if (!path.scatter_at_surface(*bsdf, material, *hit, info, dim,
                                 depth + 1 >= options.rr_min_depth, ray, &roulette_u)) {
      break;
    }
    ++depth;
    crossings = 0;
    if (depth >= options.rr_min_depth && !path.survives_roulette(roulette_u)) break;
  }
  return path.contribution(filter_weight);
}

}  // namespace prism::worker
