#include "worker/layered_bsdf.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <initializer_list>

#include "worker/float_hash.h"
#include "worker/fresnel.h"
#include "worker/medium.h"

namespace prism::worker {
namespace {

constexpr float kInv4Pi = 0.25f * kInvPi;

// ---------------------------------------------------------------------------------------------
// Reproducible randomness: splitmix64 (Steele, Lea and Flood 2014) as a counter-based generator.
// A walk's numbers depend only on the call's arguments, never on a thread's history.

// Separate streams so eval() and pdf() of the same pair of directions draw unrelated numbers.
enum class Stream : std::uint64_t { kEval = 1, kPdf = 2, kSample = 3 };

std::uint64_t seed_of(Stream stream, std::initializer_list<float> values) {
  return hash_floats(static_cast<std::uint64_t>(stream), values);
}

class WalkRng {
 public:
  explicit WalkRng(std::uint64_t seed) : state_(seed) {}
  // 24 random bits: uniform on [0, 1 − 2⁻²⁴], exact in a float and never 1.
  float uniform() {
    state_ += kGoldenGamma;
    return unit_float(mix64(state_));
  }
  // Two numbers, drawn in a fixed order (argument evaluation order is unspecified in C++).
  Point2f uniform2() {
    const float x = uniform();
    return {x, uniform()};
  }

 private:
  std::uint64_t state_;
};

// ---------------------------------------------------------------------------------------------
// The two interfaces, with what pbrt's BxDFs offer and Prism's lobes do not: sampling restricted
// to reflection or to transmission (BxDFReflTransFlags) and the adjoint (importance) transport
// mode. Densities are scalars (the same in every lane); values are per lane.

enum Events : unsigned { kReflection = 1, kTransmission = 2, kBoth = 3 };
enum class Transport { kRadiance, kImportance };

struct Scatter {
  Vec3f wi;
  SampledSpectrum f;
  float pdf = 0;
  bool specular = false;
  bool transmission = false;
};

// pbrt's test for a sample worth continuing with.
bool usable(const std::optional<Scatter>& s) {
  return s && !s->f.is_zero() && s->pdf > 0 && s->wi.z != 0;
}

SampledSpectrum lanes_of(float value, int lanes) {
  SampledSpectrum s;
  for (int i = 0; i < lanes; ++i) s[i] = value;
  return s;
}

float power_heuristic(float p, float q) {
  // In double: a peaked microfacet density squared can overflow a float.
  const double p2 = double(p) * p, q2 = double(q) * q;
  if (!(p2 + q2 > 0)) return 0;
  return float(p2 / (p2 + q2));
}

// Transmittance of a slab of height |dz| crossed in direction w (unit extinction).
float transmittance(float dz, const Vec3f& w) {
  return std::exp(-std::abs(dz / w.z));
}

// The dielectric coat with one scalar index (η = η_coat/η_outside, normal pointing outside),
// following DielectricBsdf's conventions (bsdf.cpp): radiance transport scales a refraction by
// 1/η'², η' being the relative index crossed as seen from wo (η from outside, 1/η from inside).
//
// Adjoint transport: the walk connects to the exit direction wi by sampling the coat *from* wi
// (pbrt's `!mode`), and what it needs is the radiance BSDF of the reverse pair, f_rad(w, wi),
// with w inside. Write f_rad(a, b) = S(a, b)/η'(a)², S being the importance-mode value (no
// factor). The generalised half-vector form of a rough refraction gives
// f_rad(b, a) = η'(a)²·f_rad(a, b) = S(a, b), and a smooth one the same in the delta sense: so the
// importance-mode sample from wi, S(wi, w), is exactly the f_rad(w, wi) the connection needs, and
// it is the radiance-mode value times η'(wi)² (η² when wi is outside). Densities do not depend
// on the mode.
class Coat {
 public:
  Coat(float eta, const TrowbridgeReitz& distrib, int lanes)
      : eta_(eta), distrib_(distrib), lanes_(lanes) {}

  // Index-matched (η = 1: DielectricBsdf passes straight through, whatever its roughness) or
  // smooth: a delta, so f and pdf are 0.
  bool matched() const { return eta_ == 1.0f; }
  bool specular() const { return matched() || distrib_.effectively_smooth(); }

  SampledSpectrum f(const Vec3f& wo, const Vec3f& wi) const {
    Vec3f wm;
    if (specular() || !half_vector(wo, wi, &wm)) return {};
    return lanes_of(rough(wo, wi, wm, kBoth, Transport::kRadiance).f, lanes_);
  }

  // Density of wi when sampling only the `allowed` events (pbrt's restricted PDF: for one kind
  // of event alone, no Fresnel choice probability).
  float pdf(const Vec3f& wo, const Vec3f& wi, Events allowed) const {
    Vec3f wm;
    if (specular() || !half_vector(wo, wi, &wm)) return 0;
    return rough(wo, wi, wm, allowed, Transport::kRadiance).pdf;
  }

  // Samples an allowed event directly: at a microfacet with Fresnel reflectance R the event is
  // reflection with probability pr/(pr + pt), pr = R if reflection is allowed (else 0) and
  // pt = 1 − R likewise; the pdf carries that probability. With one kind allowed the event is
  // taken with probability 1. (Retrying until the wanted kind comes up would favour the
  // microfacets where it is likely, a density that is not the one pdf() reports.)
  std::optional<Scatter> sample(const Vec3f& wo, float uc, Point2f u, Events allowed,
                                Transport mode) const {
    if (wo.z == 0) return std::nullopt;
    if (matched()) {
      // No boundary at all: straight through with f·|cos|/pdf = 1 (η' = 1 in both modes).
      if (!(allowed & kTransmission)) return std::nullopt;
      return Scatter{-wo, lanes_of(1.0f / abs_cos_theta(wo), lanes_), 1.0f, true, true};
    }
    if (distrib_.effectively_smooth()) return sample_smooth(wo, uc, allowed, mode);
    const Vec3f wm = distrib_.sample_wm(wo, u);
    const float r = fresnel_dielectric(dot(wo, wm), eta_);
    const float pr = (allowed & kReflection) ? r : 0.0f;
    const float pt = (allowed & kTransmission) ? 1.0f - r : 0.0f;
    if (!(pr + pt > 0)) return std::nullopt;
    Vec3f wi;
    if (uc < pr / (pr + pt)) {
      wi = reflect(wo, wm);
      if (!same_hemisphere(wo, wi)) return std::nullopt;
    } else {
      const auto refraction = refract(wo, wm, eta_);
      if (!refraction) return std::nullopt;
      wi = refraction->wt;
      if (same_hemisphere(wo, wi) || wi.z == 0) return std::nullopt;
    }
    // Value and density at the sampled microfacet itself, so f/pdf is exactly the sample's.
    const Value v = rough(wo, wi, wm, allowed, mode);
    if (!(v.pdf > 0)) return std::nullopt;
    return Scatter{wi, lanes_of(v.f, lanes_), v.pdf, false, !same_hemisphere(wo, wi)};
  }

 private:
  struct Value {
    float f = 0;
    float pdf = 0;
  };

  std::optional<Scatter> sample_smooth(const Vec3f& wo, float uc, Events allowed,
                                       Transport mode) const {
    const float r = fresnel_dielectric(cos_theta(wo), eta_);
    const float pr = (allowed & kReflection) ? r : 0.0f;
    const float pt = (allowed & kTransmission) ? 1.0f - r : 0.0f;
    if (!(pr + pt > 0)) return std::nullopt;  // e.g. transmission only under total reflection
    // With both events allowed this is R itself, so the sample is DielectricBsdf's bit for bit.
    const float p_reflect = allowed == kBoth ? r : pr / (pr + pt);
    if (uc < p_reflect) {
      const Vec3f wi(-wo.x, -wo.y, wo.z);
      return Scatter{wi, lanes_of(r / abs_cos_theta(wi), lanes_), p_reflect, true, false};
    }
    const auto refraction = refract(wo, Vec3f(0, 0, 1), eta_);
    if (!refraction || refraction->wt.z == 0) return std::nullopt;
    const Vec3f wi = refraction->wt;
    float f = (1.0f - r) / abs_cos_theta(wi);
    if (mode == Transport::kRadiance) f /= refraction->etap * refraction->etap;
    return Scatter{wi, lanes_of(f, lanes_), 1.0f - p_reflect, true, true};
  }

  // The microfacet normal (upper hemisphere) that reflects or refracts wo into wi.
  bool half_vector(const Vec3f& wo, const Vec3f& wi, Vec3f* wm) const {
    if (wo.z == 0 || wi.z == 0) return false;
    Vec3f h = wo + wi;
    if (!same_hemisphere(wo, wi)) h = wi * (wo.z > 0 ? eta_ : 1.0f / eta_) + wo;
    if (length_squared(h) == 0) return false;
    *wm = face_forward(normalize(h), Vec3f(0, 0, 1));
    return true;
  }

  // Rough dielectric value and restricted density of (wo, wi) through the microfacet wm.
  Value rough(const Vec3f& wo, const Vec3f& wi, const Vec3f& wm, Events allowed,
              Transport mode) const {
    const float cos_o = cos_theta(wo), cos_i = cos_theta(wi);
    if (cos_o == 0 || cos_i == 0) return {};
    // Microfacets seen from behind by either direction contribute nothing.
    if (dot(wm, wi) * cos_i <= 0 || dot(wm, wo) * cos_o <= 0) return {};
    const float r = fresnel_dielectric(dot(wo, wm), eta_);
    const float pr = (allowed & kReflection) ? r : 0.0f;
    const float pt = (allowed & kTransmission) ? 1.0f - r : 0.0f;
    const float choice = pr + pt > 0 ? 1.0f / (pr + pt) : 0.0f;
    const float d = distrib_.d(wm), g = distrib_.g(wo, wi);
    const float visible = distrib_.d_visible(wo, wm);
    if (cos_o * cos_i > 0) {
      return {d * g * r / std::abs(4 * cos_i * cos_o),
              visible / (4 * abs_dot(wo, wm)) * pr * choice};
    }
    const float etap = cos_o > 0 ? eta_ : 1.0f / eta_;
    float denom = dot(wi, wm) + dot(wo, wm) / etap;
    denom *= denom;
    if (!(denom > 0)) return {};
    float f = (1 - r) * d * g * std::abs(dot(wi, wm) * dot(wo, wm) / (cos_i * cos_o * denom));
    if (mode == Transport::kRadiance) f /= etap * etap;
    return {f, visible * abs_dot(wi, wm) / denom * pt * choice};
  }

  float eta_;
  TrowbridgeReitz distrib_;
  int lanes_;
};

// The opaque base: reflection only, and reciprocal, so both transport modes are the same BSDF.
class BaseLayer {
 public:
  explicit BaseLayer(const LayeredBsdf::Base& base) : base_(base) {}

  bool specular() const {
    return std::visit([](const auto& b) { return b.specular(); }, base_);
  }
  SampledSpectrum f(const Vec3f& wo, const Vec3f& wi) const {
    return std::visit([&](const auto& b) { return b.eval(wo, wi); }, base_);
  }
  float pdf(const Vec3f& wo, const Vec3f& wi, Events allowed) const {
    if (!(allowed & kReflection)) return 0;
    return std::visit([&](const auto& b) { return b.pdf(wo, wi)[0]; }, base_);
  }
  std::optional<Scatter> sample(const Vec3f& wo, float uc, Point2f u, Events allowed,
                                Transport) const {
    if (!(allowed & kReflection)) return std::nullopt;
    const auto s = std::visit([&](const auto& b) { return b.sample(wo, uc, u); }, base_);
    if (!s) return std::nullopt;
    return Scatter{s->wi, s->f, s->pdf[0], s->specular, s->transmission};
  }

 private:
  const LayeredBsdf::Base& base_;
};

// One of the two, as the walk sees them (pbrt's TopOrBottomBxDF).
class Interface {
 public:
  explicit Interface(const Coat& coat) : coat_(&coat) {}
  explicit Interface(const BaseLayer& base) : base_(&base) {}

  bool specular() const { return coat_ ? coat_->specular() : base_->specular(); }
  SampledSpectrum f(const Vec3f& wo, const Vec3f& wi) const {
    return coat_ ? coat_->f(wo, wi) : base_->f(wo, wi);
  }
  float pdf(const Vec3f& wo, const Vec3f& wi, Events allowed) const {
    return coat_ ? coat_->pdf(wo, wi, allowed) : base_->pdf(wo, wi, allowed);
  }
  std::optional<Scatter> sample(const Vec3f& wo, float uc, Point2f u, Events allowed,
                                Transport mode) const {
    return coat_ ? coat_->sample(wo, uc, u, allowed, mode)
                 : base_->sample(wo, uc, u, allowed, mode);
  }

 private:
  const Coat* coat_ = nullptr;
  const BaseLayer* base_ = nullptr;
};

// A free-flight distance along z for unit extinction: the path length is exponential with rate
// 1, so its z extent is that times |cos θ|.
float free_flight_dz(float u, const Vec3f& w) {
  return -std::log1p(-u) * abs_cos_theta(w);
}

// Russian roulette after the first few events, when every lane's weight is small. Returns false
// when the walk ends; otherwise compensates `beta` (and, if given, the walk's pdf).
bool survives_roulette(int depth, int lanes, WalkRng& rng, SampledSpectrum* beta,
                       double* walk_pdf = nullptr) {
  if (depth <= 3) return true;
  const float m = beta->max_value(lanes);
  if (!(m < 0.25f)) return true;
  const float q = std::max(0.0f, 1.0f - m);
  if (rng.uniform() < q) return false;
  *beta /= 1.0f - q;
  if (walk_pdf != nullptr) *walk_pdf *= 1.0f - q;
  return true;
}

// The slab's two interfaces, the coat on top and the base below (an Interface points at its
// layer, so they live together).
struct Slab {
  Slab(float eta, const TrowbridgeReitz& distrib, int lanes, const LayeredBsdf::Base& base_layer)
      : coat(eta, distrib, lanes), base(base_layer), top(coat), bottom(base) {}
  Slab(const Slab&) = delete;
  Slab& operator=(const Slab&) = delete;
  const Coat coat;
  const BaseLayer base;
  const Interface top, bottom;
};

// The BSDF is two-sided: both directions mirrored so that wo is above the coat.
std::pair<Vec3f, Vec3f> above_the_coat(const Vec3f& wo, const Vec3f& wi) {
  return wo.z < 0 ? std::pair{-wo, -wi} : std::pair{wo, wi};
}

}  // namespace

LayeredBsdf::LayeredBsdf(const DielectricBsdf& top, const Base& bottom, const LayerParams& params,
                         int lanes)
    : eta_(top.eta(0)),
      distrib_(top.distribution()),
      bottom_(bottom),
      params_(params),
      lanes_(lanes),
      scattering_(false) {
  PRISM_CHECK(lanes >= 1 && lanes <= spectral::kMaxLanes);
  // pbrt-v4 keeps the slab from vanishing: z = 0 and z = thickness must stay distinct.
  params_.thickness = std::max(params.thickness, FLT_MIN);
  params_.samples = std::max(params.samples, 1);
  params_.max_depth = std::max(params.max_depth, 0);
  for (int i = lanes; i < spectral::kMaxLanes; ++i) params_.albedo[i] = 0;
  scattering_ = params_.albedo.max_value(lanes) > 0;
}

SampledSpectrum LayeredBsdf::eval(const Vec3f& wo_in, const Vec3f& wi_in) const {
  if (wo_in.z == 0 || wi_in.z == 0) return {};
  WalkRng rng(seed_of(Stream::kEval, {wo_in.x, wo_in.y, wo_in.z, wi_in.x, wi_in.y, wi_in.z}));
  const auto [wo, wi] = above_the_coat(wo_in, wi_in);
  const Slab slab(eta_, distrib_, lanes_, bottom_);
  const Interface &top = slab.top, &bottom = slab.bottom;
  // The walk enters through the coat; it leaves through the coat for a reflection and through
  // the base for a transmission (never, for an opaque base, but the logic stays general).
  const bool reflection = same_hemisphere(wo, wi);
  const Interface& exit = reflection ? top : bottom;
  const Interface& other = reflection ? bottom : top;
  const float thickness = params_.thickness;
  const float exit_z = reflection ? thickness : 0.0f;
  const SampledSpectrum& albedo = params_.albedo;
  const HenyeyGreenstein phase(params_.g);

  // Reflection at the coat itself, known exactly (0 for a smooth coat: a delta).
  SampledSpectrum f;
  if (reflection) f = slab.coat.f(wo, wi) * float(params_.samples);

  for (int s = 0; s < params_.samples; ++s) {
    // Into the slab through the coat, and, from the other end, the exit interface sampled from
    // wi in adjoint mode: the direction every next-event connection will use.
    const float uc_in = rng.uniform();
    const Point2f u_in = rng.uniform2();
    const auto wos = top.sample(wo, uc_in, u_in, kTransmission, Transport::kRadiance);
    if (!usable(wos)) continue;
    const float uc_out = rng.uniform();
    const Point2f u_out = rng.uniform2();
    const auto wis = exit.sample(wi, uc_out, u_out, kTransmission, Transport::kImportance);
    if (!usable(wis)) continue;
    const SampledSpectrum exit_weight = wis->f / wis->pdf;

    SampledSpectrum beta = wos->f * (abs_cos_theta(wos->wi) / wos->pdf);
    float z = thickness;
    Vec3f w = wos->wi;
    for (int depth = 0; depth < params_.max_depth; ++depth) {
      if (!survives_roulette(depth, lanes_, rng, &beta)) break;
      // A connection made at this event leaves at the next one. sample() counts that exit as
      // an event of its own, so connect only if it is within max_depth: both then sum the same
      // paths. (pbrt-v4 also connects at the last event, so its f includes paths its sampling
      // never produces: with a scattering medium ~0.1 % of the albedo at max_depth 10.)
      const bool connect = depth + 1 < params_.max_depth;

      if (!scattering_) {
        // Straight to the other interface, attenuated.
        z = (z == thickness) ? 0.0f : thickness;
        beta *= transmittance(thickness, w);
      } else {
        const float zp =
            w.z > 0 ? z + free_flight_dz(rng.uniform(), w) : z - free_flight_dz(rng.uniform(), w);
        // A flight too short to move z in float would leave the walk at an interface facing
        // the wrong way; it has probability ~2⁻²⁴ and is dropped (pbrt's sample() does too).
        if (zp == z) break;
        if (0 < zp && zp < thickness) {
          // Scattered in the medium. Next event through the exit along wis; the MIS partner is
          // the phase function sampling the same direction.
          if (connect) {
            const float p_exit = phase.p(-w, -wis->wi);
            const float wt = exit.specular() ? 1.0f : power_heuristic(wis->pdf, p_exit);
            f += beta * albedo * exit_weight * (p_exit * wt * transmittance(zp - exit_z, wis->wi));
          }

          float phase_pdf = 0;
          const Vec3f next = phase.sample(-w, rng.uniform2(), &phase_pdf);
          if (!(phase_pdf > 0) || next.z == 0) break;
          beta *= albedo;  // p/pdf = 1: the phase function is sampled exactly
          w = next;
          z = zp;
          // The phase sample, if it heads for the exit, connects there too, MIS-weighted
          // against the technique that drew wis: that one draws the direction given wi, so its
          // density is exit.pdf(wi, −w). (pbrt-v4 uses exit.pdf(−w, wi), the density of wi given
          // w; the weights then do not sum to 1 and f is biased: layered_bsdf_test.cpp.)
          if (connect && !exit.specular() && ((z < exit_z && w.z > 0) || (z > exit_z && w.z < 0))) {
            const SampledSpectrum f_exit = exit.f(-w, wi);
            if (!f_exit.is_zero()) {
              const float wt_phase = power_heuristic(phase_pdf, exit.pdf(wi, -w, kTransmission));
              f += beta * f_exit * (transmittance(zp - exit_z, w) * wt_phase);
            }
          }
          continue;
        }
        z = std::clamp(zp, 0.0f, thickness);
      }

      if (z == exit_z) {
        // At the exit interface: transmission there was counted by the next-event connections,
        // so only reflection continues the walk.
        const float uc = rng.uniform();
        const Point2f u = rng.uniform2();
        const auto bs = exit.sample(-w, uc, u, kReflection, Transport::kRadiance);
        if (!usable(bs)) break;
        beta *= bs->f * (abs_cos_theta(bs->wi) / bs->pdf);
        w = bs->wi;
        continue;
      }

      // At the other interface. Next event along wis (MIS against sampling this interface)...
      if (connect && !other.specular()) {
        const float wt =
            exit.specular() ? 1.0f : power_heuristic(wis->pdf, other.pdf(-w, -wis->wi, kBoth));
        f += beta * other.f(-w, -wis->wi) * exit_weight *
             (abs_cos_theta(wis->wi) * wt * transmittance(thickness, wis->wi));
      }
      // ...then scatter here, and connect the new direction to wi through the exit (MIS
      // against wis with its density exit.pdf(wi, −w), as in the medium above).
      const float uc = rng.uniform();
      const Point2f u = rng.uniform2();
      const auto bs = other.sample(-w, uc, u, kReflection, Transport::kRadiance);
      if (!usable(bs)) break;
      beta *= bs->f * (abs_cos_theta(bs->wi) / bs->pdf);
      w = bs->wi;
      if (connect && !exit.specular()) {
        const SampledSpectrum f_exit = exit.f(-w, wi);
        if (!f_exit.is_zero()) {
          const float wt =
              other.specular() ? 1.0f : power_heuristic(bs->pdf, exit.pdf(wi, -w, kTransmission));
          f += beta * f_exit * (transmittance(thickness, bs->wi) * wt);
        }
      }
    }
  }
  f /= float(params_.samples);
  for (int i = lanes_; i < spectral::kMaxLanes; ++i) f[i] = 0;
  return f;
}

SampledSpectrum LayeredBsdf::pdf(const Vec3f& wo_in, const Vec3f& wi_in) const {
  WalkRng rng(seed_of(Stream::kPdf, {wi_in.x, wi_in.y, wi_in.z, wo_in.x, wo_in.y, wo_in.z}));
  const auto [wo, wi] = above_the_coat(wo_in, wi_in);
  const Slab slab(eta_, distrib_, lanes_, bottom_);
  const Interface &top = slab.top, &bottom = slab.bottom;
  const bool reflection = same_hemisphere(wo, wi);

  // Reflection at the coat (pbrt-v4 uses the reflection-only density here).
  double sum = 0;
  if (reflection) sum += double(params_.samples) * slab.coat.pdf(wo, wi, kReflection);

  for (int s = 0; s < params_.samples; ++s) {
    if (reflection) {
      // Only the first term of the series, TRT (in through the coat, off the base, out through
      // the coat); longer walks are left to the uniform part of the mixture.
      const float uc_o = rng.uniform();
      const Point2f u_o = rng.uniform2();
      const float uc_i = rng.uniform();
      const Point2f u_i = rng.uniform2();
      const auto wos = top.sample(wo, uc_o, u_o, kTransmission, Transport::kRadiance);
      const auto wis = top.sample(wi, uc_i, u_i, kTransmission, Transport::kImportance);
      if (!usable(wos) || !usable(wis)) continue;
      if (top.specular()) {
        sum += bottom.pdf(-wos->wi, -wis->wi, kBoth);
        continue;
      }
      const float uc_r = rng.uniform();
      const Point2f u_r = rng.uniform2();
      const auto rs = bottom.sample(-wos->wi, uc_r, u_r, kBoth, Transport::kRadiance);
      if (!usable(rs)) continue;
      if (bottom.specular()) {
        sum += top.pdf(-rs->wi, wi, kBoth);
        continue;
      }
      // Two estimates of the base-then-coat density, combined with the power heuristic.
      const float r_pdf = bottom.pdf(-wos->wi, -wis->wi, kBoth);
      sum += power_heuristic(wis->pdf, r_pdf) * r_pdf;
      const float t_pdf = top.pdf(-rs->wi, wi, kBoth);
      sum += power_heuristic(rs->pdf, t_pdf) * t_pdf;
    } else {
      // TT: through the coat and through the base (0 for an opaque base).
      const float uc_o = rng.uniform();
      const Point2f u_o = rng.uniform2();
      const auto wos = top.sample(wo, uc_o, u_o, kBoth, Transport::kRadiance);
      if (!usable(wos) || !wos->transmission) continue;
      const float uc_i = rng.uniform();
      const Point2f u_i = rng.uniform2();
      const auto wis = bottom.sample(wi, uc_i, u_i, kBoth, Transport::kImportance);
      if (!usable(wis) || !wis->transmission) continue;
      if (top.specular()) {
        sum += bottom.pdf(-wos->wi, wi, kBoth);
      } else if (bottom.specular()) {
        sum += top.pdf(wo, -wis->wi, kBoth);
      } else {
        sum += 0.5 * (top.pdf(wo, -wis->wi, kBoth) + bottom.pdf(-wos->wi, wi, kBoth));
      }
    }
  }
  const float estimate = float(sum / params_.samples);
  return lanes_of(0.9f * estimate + 0.1f * kInv4Pi, lanes_);
}

std::optional<BsdfSample> LayeredBsdf::sample(const Vec3f& wo_in, float uc, Point2f u) const {
  if (wo_in.z == 0) return std::nullopt;
  const bool flip = wo_in.z < 0;
  const Vec3f wo = flip ? -wo_in : wo_in;
  auto outside = [&](const Vec3f& w) { return flip ? -w : w; };

  // The walk's f/pdf is kept, and the returned pdf is the estimate pdf(wo, wi) (header).
  auto proportional = [&](const Vec3f& wi, const SampledSpectrum& ratio,
                          bool transmission) -> std::optional<BsdfSample> {
    const SampledSpectrum p = pdf(wo_in, wi);
    return BsdfSample{wi, ratio * p[0], p, false, transmission, false, 1.0f};
  };

  const Slab slab(eta_, distrib_, lanes_, bottom_);
  const Interface &top = slab.top, &bottom = slab.bottom;
  const auto entry = slab.coat.sample(wo, uc, u, kBoth, Transport::kRadiance);
  if (!usable(entry)) return std::nullopt;
  if (!entry->transmission) {
    const Vec3f wi = outside(entry->wi);
    if (entry->specular) {
      return BsdfSample{wi, entry->f, lanes_of(entry->pdf, lanes_), true, false, false, 1.0f};
    }
    return proportional(wi, entry->f / entry->pdf, false);
  }

  WalkRng rng(seed_of(Stream::kSample, {wo_in.x, wo_in.y, wo_in.z, uc, u.x, u.y}));
  const float thickness = params_.thickness;
  const HenyeyGreenstein phase(params_.g);
  // beta = f/pdf of the walk so far; walk_pdf only matters for an all-specular walk, which is
  // returned with its own discrete probability like any specular sample.
  SampledSpectrum beta = entry->f * (abs_cos_theta(entry->wi) / entry->pdf);
  double walk_pdf = entry->pdf;
  bool specular_path = entry->specular;
  float z = thickness;
  Vec3f w = entry->wi;
  for (int depth = 0; depth < params_.max_depth; ++depth) {
    if (!survives_roulette(depth, lanes_, rng, &beta, &walk_pdf)) return std::nullopt;
    if (w.z == 0) return std::nullopt;

    if (scattering_) {
      const float zp =
          w.z > 0 ? z + free_flight_dz(rng.uniform(), w) : z - free_flight_dz(rng.uniform(), w);
      if (zp == z) return std::nullopt;
      if (0 < zp && zp < thickness) {
        float phase_pdf = 0;
        const Vec3f next = phase.sample(-w, rng.uniform2(), &phase_pdf);
        if (!(phase_pdf > 0) || next.z == 0) return std::nullopt;
        beta *= params_.albedo;
        walk_pdf *= phase_pdf;
        specular_path = false;
        w = next;
        z = zp;
        continue;
      }
      z = std::clamp(zp, 0.0f, thickness);
    } else {
      z = (z == thickness) ? 0.0f : thickness;
      beta *= transmittance(thickness, w);
    }

    const Interface& layer = (z == 0) ? bottom : top;
    const float uc_s = rng.uniform();
    const Point2f u_s = rng.uniform2();
    const auto bs = layer.sample(-w, uc_s, u_s, kBoth, Transport::kRadiance);
    if (!usable(bs)) return std::nullopt;
    beta *= bs->f / bs->pdf;
    walk_pdf *= bs->pdf;
    specular_path = specular_path && bs->specular;
    w = bs->wi;
    if (bs->transmission) {
      // Out of the slab: above the coat (a reflection of the layered BSDF) or below the base.
      const bool transmission = !same_hemisphere(wo, w);
      const Vec3f wi = outside(w);
      if (specular_path) {
        const float p = float(walk_pdf);
        if (!(p > 0)) return std::nullopt;
        return BsdfSample{wi, beta * p, lanes_of(p, lanes_), true, transmission, false, 1.0f};
      }
      return proportional(wi, beta, transmission);
    }
    beta *= abs_cos_theta(w);
  }
  return std::nullopt;
}

}  // namespace prism::worker
