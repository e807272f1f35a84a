#include "worker/light_tracer.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/scene/source_location.h"
#include "services/spectral/color.h"
#include "worker/bsdf.h"
#include "worker/light.h"
#include "worker/material.h"
#include "worker/path_differential.h"
#include "worker/sample_layout.h"
#include "worker/shadow_ray.h"

namespace prism::worker {
namespace {

using namespace layout::light;  // the light path's sample dimensions (sample_layout.h)

// Share of a light's selection weight that ignores its spectrum, so that a light whose spectrum
// is only a mean (an image's, a projection's) keeps a positive probability at every λ.
constexpr double kDefensiveShare = 0.1;
constexpr int kMaxPassthroughs = 64;

Point2f to_point(const Point2& p) {
  return {p.u0, p.u1};
}

}  // namespace

absl::Status check_light_tracing(const RenderScene& scene) {
  if (!scene.camera().is_perspective()) {
    return absl::InvalidArgumentError(
        "light paths (--integrator light, --caustics light) connect to a perspective camera "
        "(a pinhole or a thin lens): render this camera without them");
  }
  if (scene.infinite_light() >= 0) {
    const auto& inf = std::get<InfiniteLight>(scene.lights()[scene.infinite_light()]);
    if (inf.portal()) {
      return scene::location_error(
          inf.where(),
          "light paths (--integrator light, --caustics light) cannot emit through an environment "
          "light's portal; render this scene without them");
    }
  }
  if (scene.lights().empty()) {
    return absl::InvalidArgumentError(
        "light paths (--integrator light, --caustics light) need at least one light in the scene");
  }
  return absl::OkStatus();
}

std::vector<CausticTarget> caustic_targets(const RenderScene& scene) {
  std::vector<CausticTarget> targets;
  for (int i = 0; i < scene.shape_count(); ++i) {
    const Material& m = scene.materials()[std::size_t(scene.shape(i).material)];
    if (std::holds_alternative<DiffuseMaterial>(m) ||
        std::holds_alternative<DiffuseTransmissionMaterial>(m) ||
        std::holds_alternative<InterfaceMaterial>(m)) {
      continue;
    }
    const Bounds3f& b = scene.geometry().shape_bounds(i);
    if (!(b.hi.x >= b.lo.x)) continue;  // empty
    targets.push_back({b.centre(), b.radius() * 1.001f + 1e-4f});
  }
  return targets;
}

LightTracer::LightTracer(const RenderScene& scene) : scene_(scene) {
  for (const Light& light : scene.lights()) {
    power_.push_back(light_power(light));
    mean_value_.push_back(
        spectral::integrate(light_spectrum(light), spectral::kLambdaMin, spectral::kLambdaMax) /
        (spectral::kLambdaMax - spectral::kLambdaMin));
  }
  const PixelFilter& filter = scene.pixel_filter();
  filter_radius_ = float(std::max(filter.radius(0), filter.radius(1)));
  if (scene.options().light_caustics) targets_ = caustic_targets(scene);
}

namespace {

// One light path: the emission, the walk, and the splats.
class LightPath {
 public:
  LightPath(const RenderScene& scene, const Sampler& sampler, std::vector<LightSplat>& out,
            TraceCounters& counters, float filter_radius, const std::vector<CausticTarget>& targets)
      : scene_(scene),
        sampler_(sampler),
        out_(out),
        counters_(counters),
        margin_(std::max(0.0f, filter_radius - 0.5f)),
        caustics_only_(scene.options().light_caustics),
        eye_moments_(scene.options().caustic_probe ==
                     job::RenderOptions::CausticProbe::kEyeMoments),
        targets_(targets) {}

  SampledWavelengths lambda;
  float beta = 0;  // the path's weight: f / p of everything sampled so far, importance-mode
  SpectralDifferential diff;
  int light = -1;                  // the emitting light's index
  int medium = -1;                 // the medium the path is in (RenderScene::media()), -1 vacuum
  std::uint32_t connections_ = 0;  // camera connections so far (their lens dimensions)
  // RenderOptions::CausticProbe::kEyeMoments: what an eye path that found this caustic path would
  // carry, in parts: the radiance it finds at the light (0 for a point, spot or distant light,
  // which no eye path finds), the chain's factors as the eye path weighs them (the delta
  // scatterings' f·|cos|/p with the radiance's 1/η'² of the eye's direction, transmittances),
  // and whether a scattering was dispersive (the eye path's secondary lanes end there).
  float eye_radiance = 0;
  float eye_chain = 1;
  std::vector<float> chain_factors;  // the chain's factors in light order (the roulette's weights)
  bool dispersive = false;

  // The contribution C of a vertex at p (geometric normal ng) that sends
  // `value_towards(to_camera)` towards the camera, per unit area of p: value · |ng·ω|/d² · W;
  // a medium vertex (ng = 0) per unit volume: value/d² · W. The connection starts in `inside`
  // when it leaves against ng, else in `outside` (the same medium twice where p is no medium
  // boundary).
  template <typename ValueTowards>
  void connect(const Vec3f& p, const Vec3f& ng, int inside, int outside,
               ValueTowards&& value_towards) {
    const Camera& camera = scene_.camera();
    // A thin lens: each connection its own lens point, from dimensions of their own.
    const Point2f lens =
        camera.has_lens() ? to_point(sampler_.at2(kLensConnect + 2 * connections_++)) : Point2f{};
    auto c = camera.connect(p, margin_, lens);
    if (!c) return;
    const float cos_p = ng == Vec3f() ? 1.0f : std::abs(dot(ng, c->to_camera));
    const float value = value_towards(c->to_camera);
    if (!(value > 0.0f) || !(cos_p > 0.0f)) return;
    const float contribution = value * cos_p * c->importance / (c->distance * c->distance);
    if (!std::isfinite(contribution)) {
      ++counters_.non_finite;
      return;
    }
    const Vec3f origin = ng == Vec3f() ? p : scene_.geometry().offset_origin(p, ng, c->to_camera);
    const int start = dot(c->to_camera, ng) < 0 ? inside : outside;
    const Shadow shadow = trace_shadow(scene_, origin, c->to_camera, c->lens_point, false, start,
                                       lambda, 1, counters_);
    if (!(shadow.transmittance[0] > 0.0f)) return;
    const float visible = contribution * shadow.transmittance[0];
    const spectral::WavelengthGrid& grid = scene_.grid();
    const int bin = grid.bin_of(lambda.lambda(0));
    if (bin < 0) return;
    LightSplat s;
    s.raster = c->raster;
    s.bin = bin;
    s.lambda = lambda.lambda(0);
    s.value = visible / float(grid.bin_width());
    const spectral::Rgb bar = scene_.cmf().srgb(lambda.lambda(0));
    s.rgb[0] = float(bar.r * visible);
    s.rgb[1] = float(bar.g * visible);
    s.rgb[2] = float(bar.b * visible);
    s.position = p;
    s.normal = ng;
    s.light = light;
    if (diff.tracked) {
      s.has_differential = true;
      s.raster_per_nm = camera.raster_differential(p, diff.dp);
      s.position_per_nm = diff.dp;
    }
    out_.push_back(s);
  }

  // A direction from p towards the caustic targets and its density (the mixture of their
  // cones, each chosen with 1/T; a target around p covers the whole sphere); false for none.
  bool towards_targets(const Vec3f& p, Vec3f* w, float* pdf) const {
    const auto count = targets_.size();
    const float pick = sampler_.at(kSide) * float(count);
    const std::size_t j = std::min(count - 1, std::size_t(pick));
    const Point2f u = to_point(sampler_.at2(kEmission));
    const CausticTarget& t = targets_[j];
    const Vec3f to = t.centre - p;
    const float d2 = length_squared(to);
    if (d2 <= t.radius * t.radius) {
      *w = sample_uniform_sphere(u);
    } else {
      const float cos_max = std::sqrt(std::max(0.0f, 1.0f - t.radius * t.radius / d2));
      const float cos_theta = 1.0f - u.x * (1.0f - cos_max);
      const float sin_theta = std::sqrt(std::max(0.0f, 1.0f - cos_theta * cos_theta));
      const float phi = 2.0f * kPi * u.y;
      *w = Frame::from_z(to / std::sqrt(d2))
               .from_local({sin_theta * std::cos(phi), sin_theta * std::sin(phi), cos_theta});
    }
    float sum = 0.0f;
    for (const CausticTarget& c : targets_) {
      const Vec3f a = c.centre - p;
      const float a2 = length_squared(a);
      if (a2 <= c.radius * c.radius) {
        sum += 1.0f / (4.0f * kPi);
        continue;
      }
      const float cos_max = std::sqrt(std::max(0.0f, 1.0f - c.radius * c.radius / a2));
      if (dot(*w, a) >= cos_max * std::sqrt(a2)) sum += 1.0f / (2.0f * kPi * (1.0f - cos_max));
    }
    *pdf = sum / float(count);
    return *pdf > 0.0f && std::isfinite(*pdf);
  }

  // For light along w from infinitely far: a point of the beam's cross-section on the disk of a
  // target across w, from outside the scene, and its density per unit area (the mixture).
  bool beam_towards_targets(const Vec3f& w, Vec3f* origin, float* pdf) const {
    const auto count = targets_.size();
    const std::size_t j = std::min(count - 1, std::size_t(sampler_.at(kSide) * float(count)));
    const Frame frame = Frame::from_z(w);
    const Point2f d = sample_uniform_disk_concentric(to_point(sampler_.at2(kPosition)));
    const CausticTarget& t = targets_[j];
    const Bounds3f& bounds = scene_.geometry().bounds();
    const float back = length(t.centre - bounds.centre()) + bounds.radius() * 1.01f + 1e-3f;
    *origin = t.centre - w * back + (frame.s * d.x + frame.t * d.y) * t.radius;
    float sum = 0.0f;
    for (const CausticTarget& c : targets_) {
      const Vec3f off = c.centre - *origin;
      const Vec3f across = off - w * dot(off, w);
      if (length_squared(across) <= c.radius * c.radius) sum += 1.0f / (kPi * c.radius * c.radius);
    }
    *pdf = sum / float(count);
    return *pdf > 0.0f && std::isfinite(*pdf);
  }

  // The emitted ray, with beta set; false when this light emits nothing here.
  bool emit(const Light& light, int light_index, float selection, Ray* ray) {
    const float density = selection * lambda.pdf(0);
    if (!(density > 0.0f)) return false;
    const Bounds3f& bounds = scene_.geometry().bounds();
    if (const auto* area = std::get_if<AreaLight>(&light)) {
      auto point = area->sample_point(to_point(sampler_.at2(kPosition)), sampler_.at(kTriangle));
      if (!point) return false;
      const float pdf_area = 1.0f / float(area->area());
      // The emitter seen by the camera: L_e · |n·ω|/d² · W / (p_A · p(e, λ)) (the eye paths'
      // with --caustics light).
      const ShapeInfo& info = scene_.shape(area->shape());
      if (!caustics_only_) {
        connect(point->p, point->n, info.medium_inside, info.medium_outside,
                [&](const Vec3f& to_camera) {
                  return area->radiance(point->n, to_camera, lambda)[0] / (pdf_area * density);
                });
      }
      // The medium on the side it emits into (a shape that is no boundary has one medium).
      auto emits_into = [&](const Vec3f& w) {
        return dot(w, point->n) < 0 ? info.medium_inside : info.medium_outside;
      };
      if (caustics_only_) {
        Vec3f w;
        float pdf_w = 0.0f;
        if (!towards_targets(point->p, &w, &pdf_w)) return false;
        const float le = area->radiance(point->n, w, lambda)[0];
        eye_radiance = le;
        beta = le * std::abs(dot(point->n, w)) / (pdf_area * pdf_w * density);
        medium = emits_into(w);
        *ray = {scene_.geometry().offset_origin(point->p, point->n, w), w};
        return beta > 0.0f;
      }
      Vec3f n = point->n;
      float side = 1.0f;
      if (area->two_sided()) {
        if (sampler_.at(kSide) < 0.5f) n = -n;
        side = 0.5f;
      }
      const Vec3f local = sample_cosine_hemisphere(to_point(sampler_.at2(kEmission)));
      if (!(local.z > 0.0f)) return false;
      const Vec3f w = Frame::from_z(n).from_local(local);
      const float le = area->radiance(point->n, w, lambda)[0];
      // L_e·|cos| / (p_A · side · cos/π · p(e, λ)).
      beta = le * kPi / (pdf_area * side * density);
      medium = emits_into(w);
      *ray = {scene_.geometry().offset_origin(point->p, point->n, w), w};
      return beta > 0.0f;
    }
    if (std::holds_alternative<PointLight>(light) || std::holds_alternative<SpotLight>(light)) {
      const Vec3f position = std::holds_alternative<PointLight>(light)
                                 ? std::get<PointLight>(light).position()
                                 : std::get<SpotLight>(light).position();
      // The intensity towards w: the light's own sample from one unit away along w.
      auto intensity = [&](const Vec3f& w) {
        auto s = sample_light(light, LightContext{position + w, Vec3f()}, {}, 0.0f, lambda);
        return s ? s->radiance[0] : 0.0f;
      };
      // No connection of the light itself: a point has no area for a camera ray to hit, and an
      // eye tracer (pbrt-v4's too) never sees one; the image would differ at one pixel.
      Vec3f w;
      float pdf_w = 1.0f / (4.0f * kPi);
      const auto* spot = std::get_if<SpotLight>(&light);
      if (caustics_only_) {
        if (!towards_targets(position, &w, &pdf_w)) return false;
      } else if (spot != nullptr && spot->cos_falloff_end() > -1.0f &&
                 1.0f - spot->cos_falloff_end() > 1e-6f) {
        // A spot emits only inside its cone: directions uniform in the cone.
        const float cos_max = spot->cos_falloff_end();
        const Point2f u = to_point(sampler_.at2(kEmission));
        const float cos_theta = 1.0f - u.x * (1.0f - cos_max);
        const float sin_theta = std::sqrt(std::max(0.0f, 1.0f - cos_theta * cos_theta));
        const float phi = 2.0f * kPi * u.y;
        w = Frame::from_z(spot->direction())
                .from_local({sin_theta * std::cos(phi), sin_theta * std::sin(phi), cos_theta});
        pdf_w = 1.0f / (2.0f * kPi * (1.0f - cos_max));
      } else {
        w = sample_uniform_sphere(to_point(sampler_.at2(kEmission)));
      }
      beta = intensity(w) / (pdf_w * density);
      medium = scene_.light_medium(light_index);
      *ray = {position, w};
      return beta > 0.0f;
    }
    // Light from infinitely far: a direction, then a point on the disk of the scene's bounding
    // sphere across it, from outside the sphere (density 1/πR²). Declared in a medium that
    // attenuates at λ, it reaches nothing, as an eye path escaping through that medium finds
    // (an infinite flight).
    medium = scene_.light_medium(light_index);
    if (medium >= 0) {
      const HomogeneousMedium& m = scene_.media()[std::size_t(medium)];
      if ((m.sigma_a(lambda) + m.sigma_s(lambda))[0] > 0.0f) return false;
    }
    const float radius = bounds.radius() * 1.01f + 1e-3f;
    Vec3f w;
    float value = 0.0f;
    if (const auto* distant = std::get_if<DistantLight>(&light)) {
      w = -distant->direction();
      auto s = sample_light(light, LightContext{bounds.centre(), Vec3f()}, {}, 0.0f, lambda);
      value = s ? s->radiance[0] : 0.0f;  // irradiance across the beam
    } else {
      const auto& inf = std::get<InfiniteLight>(light);
      w = sample_uniform_sphere(to_point(sampler_.at2(kEmission)));
      eye_radiance = inf.radiance(bounds.centre(), -w, lambda)[0];
      value = eye_radiance * (4.0f * kPi);
    }
    if (caustics_only_) {
      Vec3f origin;
      float pdf_beam = 0.0f;
      if (!beam_towards_targets(w, &origin, &pdf_beam)) return false;
      beta = value / (pdf_beam * density);
      *ray = {origin, w};
      return beta > 0.0f;
    }
    const Point2f d = sample_uniform_disk_concentric(to_point(sampler_.at2(kPosition)));
    const Frame frame = Frame::from_z(w);
    const Vec3f origin = bounds.centre() - w * radius + (frame.s * d.x + frame.t * d.y) * radius;
    beta = value * (kPi * radius * radius) / density;
    *ray = {origin, w};
    return beta > 0.0f;
  }

  // Follows the path from the emitted ray: connects every non-delta vertex to the camera and
  // scatters by the adjoint BSDF.
  void walk(Ray ray) {
    const job::RenderOptions& options = scene_.options();
    const Geometry& geometry = scene_.geometry();
    const float beta_emitted = beta;
    int passthroughs = 0;
    std::uint32_t segments = 0;  // free flights so far (their sample dimensions)
    // Russian roulette on the weight relative to the emitted one; false: the path ends.
    auto survives = [&](int depth, float u) {
      if (depth < options.rr_min_depth) return true;
      const float survive = std::min(1.0f, beta / beta_emitted);
      if (u >= survive) return false;
      beta /= survive;
      return true;
    };
    for (int depth = 0;;) {
      ++counters_.rays;
      auto hit = geometry.intersect(ray, kInfinity);
      if (medium >= 0) {
        const HomogeneousMedium& m = scene_.media()[std::size_t(medium)];
        const float sigma_s = m.sigma_s(lambda)[0];
        const float sigma_t = m.sigma_a(lambda)[0] + sigma_s;
        const std::uint32_t flight_dim = kFreeFlight + segments++;
        if (caustics_only_ || !m.scattering()) {
          // A caustic path does not scatter in a medium (the eye paths take those that do),
          // and an absorbing medium is not sampled: the segment's transmittance is the weight.
          if (!hit) return;
          const float transmittance = std::exp(-sigma_t * hit->t);
          beta *= transmittance;
          if (eye_moments_) eye_chain *= transmittance;
          if (!(beta > 0.0f)) return;
        } else if (sigma_t > 0.0f) {
          // Free flight with density σ_t·T(t): scattering at t weighs σ_s/σ_t, passing the
          // segment (probability T) weighs 1.
          const float t = -std::log1p(-sampler_.at(flight_dim)) / sigma_t;
          if (!hit || t < hit->t) {
            beta *= sigma_s / sigma_t;
            // A vertex at depth d is the eye path's d-th bounce: none past max_depth (at 0 the
            // light paths connected their first vertex, lighting what an eye path does not).
            if (++depth > options.max_depth) return;
            const Vec3f p = ray.origin + ray.direction * t;
            const Vec3f back = -ray.direction;
            const HenyeyGreenstein& phase = m.phase();
            diff.tracked = false;  // a medium vertex receives: no differential beyond it
            connect(p, Vec3f(), medium, medium,
                    [&](const Vec3f& to_camera) { return beta * phase.p(back, to_camera); });
            if (depth >= options.max_depth) return;
            const std::uint32_t dim = kBounce + kDimsPerBounce * std::uint32_t(depth - 1);
            float phase_pdf = 0.0f;
            const Vec3f next = phase.sample(back, to_point(sampler_.at2(dim)), &phase_pdf);
            if (!(phase_pdf > 0.0f) || !(beta > 0.0f) || !std::isfinite(beta)) return;
            // The phase function is sampled exactly: p/pdf = 1.
            if (!survives(depth, sampler_.at2(dim + 2).u1)) return;
            ray = {p, next};
            passthroughs = 0;
            continue;
          }
        }
      }
      if (!hit) return;
      transfer(diff, ray.direction, hit->t, hit->ng);
      const ShapeInfo& info = scene_.shape(hit->shape);
      const Material& material = scene_.material_at(info.material, *hit, -ray.direction);
      auto bsdf = make_bsdf(material, lambda, texture_context(*hit));
      // The medium on each side of this surface: its own two where it is a boundary, else the
      // path's.
      const int inside = info.medium_transition ? info.medium_inside : medium;
      const int outside = info.medium_transition ? info.medium_outside : medium;
      if (!bsdf) {
        // An interface: pass through, into the medium on its other side.
        medium = dot(ray.direction, hit->ng) < 0 ? inside : outside;
        ray.origin = geometry.offset_origin(hit->p, hit->ng, ray.direction);
        if (++passthroughs == kMaxPassthroughs) return;
        continue;
      }
      passthroughs = 0;
      const Vec3f back = -ray.direction;
      const float cos_geometric = std::abs(dot(hit->ng, back));
      if (!(cos_geometric > 1e-7f)) return;
      // pbrt-v4's shading-normal correction for importance, the arrival half of it.
      beta *= std::abs(dot(hit->ns, back)) / cos_geometric;
      const Frame frame = Frame::from_xz(hit->dpdu, hit->ns);
      const Vec3f back_local = frame.to_local(back);
      if (++depth > options.max_depth) return;  // as at a medium vertex
      if (!is_specular(*bsdf)) {
        // With --caustics light only a first non-delta vertex after a delta chain connects, and
        // nothing after it can: the path ends there.
        if (!caustics_only_ || depth >= 2) {
          connect(hit->p, hit->ng, inside, outside, [&](const Vec3f& to_camera) {
            const Vec3f camera_local = frame.to_local(to_camera);
            const float f = eval(*bsdf, camera_local, back_local)[0];
            if (!eye_moments_) return beta * f;
            return beta * f * eye_value(*bsdf, camera_local, back_local, f);
          });
        }
        if (caustics_only_) return;
      }
      if (depth >= options.max_depth) return;
      const std::uint32_t dim = kBounce + kDimsPerBounce * std::uint32_t(depth - 1);
      const Point2 lobe_and_roulette = sampler_.at2(dim + 2);
      auto bs = sample(*bsdf, back_local, lobe_and_roulette.u0, to_point(sampler_.at2(dim)));
      if (!bs || !(bs->pdf[0] > 0.0f)) return;
      const Vec3f next = frame.from_local(bs->wi);
      const float cos_next_geometric = std::abs(dot(hit->ng, next));
      float ratio;
      if (bs->specular) {
        // The radiance-mode ratio f·|cos|/p, without its 1/η'² (importance is not compressed
        // by a refraction), and the departure half of the shading-normal correction.
        ratio = bs->f[0] * abs_cos_theta(bs->wi) / bs->pdf[0];
        if (bs->transmission) ratio *= bs->etap * bs->etap;
        // The eye path crosses the other way, in radiance mode: its f·|cos|/p is 1/η'_eye² =
        // this η'² times the ratio; its roulette weight (times its η-scale η'_eye²) is the ratio.
        if (eye_moments_) {
          eye_chain *= bs->transmission ? ratio * bs->etap * bs->etap : ratio;
          chain_factors.push_back(ratio);
          dispersive = dispersive || bs->hero_only;
        }
        const float cos_next_shading = abs_cos_theta(bs->wi);
        ratio = cos_next_shading > 0.0f ? ratio * cos_next_geometric / cos_next_shading : 0.0f;
      } else {
        ratio = eval(*bsdf, bs->wi, back_local)[0] * cos_next_geometric / bs->pdf[0];
      }
      beta *= ratio;
      if (!(beta > 0.0f) || !std::isfinite(beta)) return;
      follow_differential(material, *hit, ray.direction, next, *bs);
      if (!survives(depth, lobe_and_roulette.u1)) return;
      medium = dot(next, hit->ng) < 0 ? inside : outside;
      ray = {geometry.offset_origin(hit->p, hit->ng, next), next};
    }
  }

 private:
  // CausticProbe::kEyeMoments: the value an eye path of the job's lanes adds to the bin of λ when
  // it reaches this caustic path's light from the receiver (eye direction `camera_local`, BSDF
  // value f towards the chain `chain_local`): its BSDF sample's f·|cos|/p, the chain, the
  // light's radiance, over p(λ)·bin width and, where every lane stays live, over the lanes
  // (integrator.h: a lane carries 1/C of a path no scattering told apart). A splat times it
  // estimates, in expectation over the light paths, the eye tracer's second moment of the
  // caustic paths per sample: E_light[(f/p_light)·(f/p_eye)] = ∫ f²/p_eye. The eye path's
  // Russian roulette is in p_eye: from rr_min_depth on, after each scattering, it survives with
  // min(1, throughput) (integrator.cpp; here the throughput at λ alone), which divides its value.
  float eye_value(const Bsdf& bsdf, const Vec3f& camera_local, const Vec3f& chain_local,
                  float f) const {
    const float p = worker::pdf(bsdf, camera_local, chain_local)[0];
    const float wavelength_pdf = lambda.pdf(0);
    if (!(p > 0.0f) || !(wavelength_pdf > 0.0f)) return 0.0f;
    const job::RenderOptions& options = scene_.options();
    const int live = dispersive ? 1 : options.lanes();
    const float receiver = f * abs_cos_theta(chain_local) / p;
    // The eye path scatters at the receiver (depth 1), then along the chain from its end.
    float throughput = receiver, survival = 1;
    int depth = 1;
    for (std::size_t k = chain_factors.size();; --k) {
      if (depth >= options.rr_min_depth) survival *= std::min(1.0f, throughput);
      if (k == 0) break;
      throughput *= chain_factors[k - 1];
      ++depth;
    }
    const float value =
        receiver * eye_chain * eye_radiance /
        (float(live) * wavelength_pdf * float(scene_.grid().bin_width()) * survival);
    return std::isfinite(value) ? value : 0.0f;
  }

  // The spectral differential through the scattering from direction `in` to `out` at `hit`.
  void follow_differential(const Material& material, const SurfaceHit& hit, const Vec3f& in,
                           const Vec3f& out, const BsdfSample& bs) {
    scatter_differential(diff, scene_.geometry(), material, hit, in, out, bs.specular,
                         bs.transmission, lambda.lambda(0));
  }

  const RenderScene& scene_;
  const Sampler& sampler_;
  std::vector<LightSplat>& out_;
  TraceCounters& counters_;
  const float margin_;
  // --caustics light: only light → delta chain → first non-delta vertex paths connect.
  const bool caustics_only_;
  const bool eye_moments_;  // RenderOptions::CausticProbe::kEyeMoments
  const std::vector<CausticTarget>& targets_;
};

}  // namespace

void LightTracer::trace(int x, int y, std::uint32_t sample_index, std::vector<LightSplat>& out,
                        TraceCounters& counters) const {
  const job::RenderOptions& options = scene_.options();
  Sampler sampler(options.sampler, SampleKey{options.seed, kLightPathPass, std::uint32_t(x),
                                             std::uint32_t(y), sample_index});
  if (options.light_caustics && targets_.empty()) return;  // no caustic path in this scene
  LightPath path(scene_, sampler, out, counters, filter_radius_, targets_);
  path.lambda =
      spectral::WavelengthPdfView(scene_.wavelength_pdf()).sample_lanes(sampler.at(kWavelength), 1);
  if (!(path.lambda.pdf(0) > 0.0f)) return;
  // A light with probability ∝ its spectral power at λ (mixed with its total power).
  const float l = path.lambda.lambda(0);
  const auto& lights = scene_.lights();
  auto weight = [&](std::size_t i) {
    if (!(mean_value_[i] > 0.0)) return 0.0;
    const double shape =
        std::max(0.0f, spectral::eval(light_spectrum(lights[i]), l)) / mean_value_[i];
    return power_[i] * ((1.0 - kDefensiveShare) * shape + kDefensiveShare);
  };
  double total = 0.0;
  for (std::size_t i = 0; i < lights.size(); ++i) total += weight(i);
  if (!(total > 0.0)) return;
  const double target = double(sampler.at(kChoice)) * total;
  double cumulative = 0.0;
  std::size_t chosen = lights.size() - 1;
  for (std::size_t i = 0; i < lights.size(); ++i) {
    cumulative += weight(i);
    if (target < cumulative) {
      chosen = i;
      break;
    }
  }
  const double selection = weight(chosen) / total;
  if (!(selection > 0.0)) return;
  Ray ray;
  path.light = int(chosen);
  if (!path.emit(lights[chosen], int(chosen), float(selection), &ray)) return;
  path.walk(ray);
}

}  // namespace prism::worker
