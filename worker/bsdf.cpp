#include "worker/bsdf.h"

#include "worker/fresnel.h"

namespace prism::worker {
namespace {

SampledSpectrum lanes_of(float value, int lanes) {
  SampledSpectrum s;
  for (int i = 0; i < lanes; ++i) s[i] = value;
  return s;
}

}  // namespace

std::optional<BsdfSample> DiffuseBsdf::sample(const Vec3f& wo, float, Point2f u) const {
  if (wo.z == 0.0f) return std::nullopt;
  Vec3f wi = sample_cosine_hemisphere(u);
  if (wo.z < 0.0f) wi.z = -wi.z;
  float p = abs_cos_theta(wi) * kInvPi;
  if (p == 0.0f) return std::nullopt;
  return BsdfSample{wi, r_ * kInvPi, lanes_of(p, lanes_)};
}

SampledSpectrum DiffuseBsdf::eval(const Vec3f& wo, const Vec3f& wi) const {
  if (!same_hemisphere(wo, wi)) return {};
  return r_ * kInvPi;
}

SampledSpectrum DiffuseBsdf::pdf(const Vec3f& wo, const Vec3f& wi) const {
  if (!same_hemisphere(wo, wi)) return {};
  return lanes_of(abs_cos_theta(wi) * kInvPi, lanes_);
}

SampledSpectrum DiffuseTransmissionBsdf::eval(const Vec3f& wo, const Vec3f& wi) const {
  if (wo.z == 0.0f || wi.z == 0.0f) return {};
  return (same_hemisphere(wo, wi) ? r_ : t_) * kInvPi;
}

SampledSpectrum DiffuseTransmissionBsdf::pdf(const Vec3f& wo, const Vec3f& wi) const {
  SampledSpectrum p;
  if (wo.z == 0.0f || wi.z == 0.0f) return p;
  const bool reflect = same_hemisphere(wo, wi);
  for (int s = 0; s < lanes_; ++s) {
    const float total = r_[s] + t_[s];
    if (total > 0) p[s] = (reflect ? r_[s] : t_[s]) / total * abs_cos_theta(wi) * kInvPi;
  }
  return p;
}

std::optional<BsdfSample> DiffuseTransmissionBsdf::sample(const Vec3f& wo, float uc,
                                                          Point2f u) const {
  if (wo.z == 0.0f) return std::nullopt;
  const float total = r_[0] + t_[0];
  if (!(total > 0)) return std::nullopt;
  const bool reflect = uc < r_[0] / total;
  Vec3f wi = sample_cosine_hemisphere(u);
  // Cosine-sampled directions have z >= 0: on wo's side for reflection, the other for
  // transmission.
  if ((wo.z < 0.0f) == reflect) wi.z = -wi.z;
  if (wi.z == 0.0f) return std::nullopt;
  BsdfSample s{wi, eval(wo, wi), pdf(wo, wi)};
  if (!(s.pdf[0] > 0)) return std::nullopt;
  s.transmission = !reflect;
  return s;
}

float ThinDielectricBsdf::reflectance(int lane, float cos_theta_o) const {
  float r = fresnel_dielectric(std::abs(cos_theta_o), eta_[lane]);
  const float t = 1.0f - r;
  if (r < 1.0f) r += t * t * r / (1.0f - r * r);
  return r;
}

std::optional<BsdfSample> ThinDielectricBsdf::sample(const Vec3f& wo, float uc, Point2f) const {
  if (wo.z == 0.0f) return std::nullopt;
  const bool reflect = uc < reflectance(0, wo.z);
  BsdfSample s;
  s.wi = reflect ? Vec3f(-wo.x, -wo.y, wo.z) : -wo;
  s.specular = true;
  s.transmission = !reflect;
  for (int i = 0; i < lanes_; ++i) {
    const float r = reflectance(i, wo.z);
    const float p = reflect ? r : 1.0f - r;
    s.f[i] = p / abs_cos_theta(s.wi);
    s.pdf[i] = p;
  }
  if (!(s.pdf[0] > 0)) return std::nullopt;
  return s;
}

std::optional<BsdfSample> DielectricBsdf::sample(const Vec3f& wo, float uc, Point2f u) const {
  if (wo.z == 0.0f) return std::nullopt;
  if (specular()) return sample_smooth(wo, uc);
  return sample_rough(wo, uc, u);
}

std::optional<BsdfSample> DielectricBsdf::sample_smooth(const Vec3f& wo, float uc) const {
  if (index_matched()) {
    // No boundary at all: the ray passes straight through with weight 1.
    return BsdfSample{
        -wo, lanes_of(1.0f / abs_cos_theta(wo), lanes_), lanes_of(1.0f, lanes_), true, true, false,
        1.0f};
  }
  float r0 = fresnel_dielectric(cos_theta(wo), eta_[0]);
  if (uc < r0) {
    // Reflection leaves in the same direction at every wavelength: every lane follows, each
    // with its own Fresnel probability.
    Vec3f wi(-wo.x, -wo.y, wo.z);
    BsdfSample s{wi, {}, {}, true, false, false, 1.0f};
    for (int i = 0; i < lanes_; ++i) {
      float r = fresnel_dielectric(cos_theta(wo), eta_[i]);
      s.f[i] = r / abs_cos_theta(wi);
      s.pdf[i] = r;
    }
    return s;
  }
  auto refraction = refract(wo, Vec3f(0, 0, 1), eta_[0]);
  if (!refraction || refraction->wt.z == 0.0f) return std::nullopt;
  Vec3f wi = refraction->wt;
  BsdfSample s{wi, {}, {}, true, true, dispersive_, refraction->etap};
  int follow = dispersive_ ? 1 : lanes_;
  for (int i = 0; i < follow; ++i) {
    float t = 1.0f - fresnel_dielectric(cos_theta(wo), eta_[i]);
    float etap = cos_theta(wo) > 0 ? eta_[i] : 1.0f / eta_[i];
    s.f[i] = t / abs_cos_theta(wi) / (etap * etap);
    s.pdf[i] = t;
  }
  return s;
}

std::optional<BsdfSample> DielectricBsdf::sample_rough(const Vec3f& wo, float uc, Point2f u) const {
  Vec3f wm = distrib_.sample_wm(wo, u);
  float r0 = fresnel_dielectric(dot(wo, wm), eta_[0]);
  BsdfSample s;
  s.specular = false;
  if (uc < r0) {
    s.wi = reflect(wo, wm);
    if (!same_hemisphere(wo, s.wi) || s.wi.z == 0.0f) return std::nullopt;
  } else {
    auto refraction = refract(wo, wm, eta_[0]);
    if (!refraction) return std::nullopt;
    s.wi = refraction->wt;
    if (same_hemisphere(wo, s.wi) || s.wi.z == 0.0f) return std::nullopt;
    s.transmission = true;
    s.etap = refraction->etap;
  }
  eval_rough(wo, s.wi, &s.f, &s.pdf);
  if (s.pdf[0] == 0.0f) return std::nullopt;
  return s;
}

void DielectricBsdf::eval_rough(const Vec3f& wo, const Vec3f& wi, SampledSpectrum* f,
                                SampledSpectrum* pdf) const {
  *f = {};
  *pdf = {};
  float cos_o = cos_theta(wo), cos_i = cos_theta(wi);
  if (cos_o == 0.0f || cos_i == 0.0f) return;
  bool reflection = cos_o * cos_i > 0.0f;
  if (reflection) {
    Vec3f wm = wo + wi;
    if (length_squared(wm) == 0.0f) return;
    wm = face_forward(normalize(wm), Vec3f(0, 0, 1));
    if (dot(wm, wi) * cos_i < 0.0f || dot(wm, wo) * cos_o < 0.0f) return;
    float d = distrib_.d(wm), g = distrib_.g(wo, wi);
    float pdf_wm = distrib_.d_visible(wo, wm) / (4.0f * abs_dot(wo, wm));
    for (int i = 0; i < lanes_; ++i) {
      float r = fresnel_dielectric(dot(wo, wm), eta_[i]);
      (*f)[i] = d * g * r / std::abs(4.0f * cos_i * cos_o);
      (*pdf)[i] = pdf_wm * r;
    }
    return;
  }
  // Transmission: each lane has its own generalised half-vector wm = normalize(wo + η' wi)
  // (paper Eq. 12 of the spectral gradient paper; Walter et al. 2007 Eq. 16).
  float g = distrib_.g(wo, wi);
  for (int i = 0; i < lanes_; ++i) {
    float etap = cos_o > 0.0f ? eta_[i] : 1.0f / eta_[i];
    Vec3f wm = wi * etap + wo;
    if (length_squared(wm) == 0.0f) continue;
    wm = face_forward(normalize(wm), Vec3f(0, 0, 1));
    if (dot(wm, wi) * cos_i < 0.0f || dot(wm, wo) * cos_o < 0.0f) continue;
    float t = 1.0f - fresnel_dielectric(dot(wo, wm), eta_[i]);
    float denom = dot(wi, wm) + dot(wo, wm) / etap;
    denom *= denom;
    if (denom == 0.0f) continue;
    float dwm_dwi = abs_dot(wi, wm) / denom;
    (*pdf)[i] = distrib_.d_visible(wo, wm) * dwm_dwi * t;
    (*f)[i] = t * distrib_.d(wm) * g *
              std::abs(dot(wi, wm) * dot(wo, wm) / (cos_i * cos_o * denom)) / (etap * etap);
  }
}

SampledSpectrum DielectricBsdf::eval(const Vec3f& wo, const Vec3f& wi) const {
  if (specular()) return {};
  SampledSpectrum f, p;
  eval_rough(wo, wi, &f, &p);
  return f;
}

SampledSpectrum DielectricBsdf::pdf(const Vec3f& wo, const Vec3f& wi) const {
  if (specular()) return {};
  SampledSpectrum f, p;
  eval_rough(wo, wi, &f, &p);
  return p;
}

SampledSpectrum ConductorBsdf::fresnel(float cos_theta) const {
  SampledSpectrum r;
  for (int i = 0; i < lanes_; ++i) r[i] = fresnel_complex(cos_theta, eta_[i], k_[i]);
  return r;
}

std::optional<BsdfSample> ConductorBsdf::sample(const Vec3f& wo, float, Point2f u) const {
  if (wo.z == 0.0f) return std::nullopt;
  if (specular()) {
    Vec3f wi(-wo.x, -wo.y, wo.z);
    return BsdfSample{wi,
                      fresnel(abs_cos_theta(wi)) / abs_cos_theta(wi),
                      lanes_of(1.0f, lanes_),
                      true,
                      false,
                      false,
                      1.0f};
  }
  Vec3f wm = distrib_.sample_wm(wo, u);
  Vec3f wi = reflect(wo, wm);
  if (!same_hemisphere(wo, wi) || wi.z == 0.0f) return std::nullopt;
  float p = distrib_.d_visible(wo, wm) / (4.0f * abs_dot(wo, wm));
  if (!(p > 0.0f)) return std::nullopt;
  return BsdfSample{wi, eval(wo, wi), lanes_of(p, lanes_), false, false, false, 1.0f};
}

SampledSpectrum ConductorBsdf::eval(const Vec3f& wo, const Vec3f& wi) const {
  if (specular() || !same_hemisphere(wo, wi)) return {};
  float cos_o = abs_cos_theta(wo), cos_i = abs_cos_theta(wi);
  if (cos_i == 0.0f || cos_o == 0.0f) return {};
  Vec3f wm = wi + wo;
  if (length_squared(wm) == 0.0f) return {};
  wm = normalize(wm);
  return fresnel(abs_dot(wo, wm)) * (distrib_.d(wm) * distrib_.g(wo, wi) / (4.0f * cos_i * cos_o));
}

SampledSpectrum ConductorBsdf::pdf(const Vec3f& wo, const Vec3f& wi) const {
  if (specular() || !same_hemisphere(wo, wi)) return {};
  Vec3f wm = wo + wi;
  if (length_squared(wm) == 0.0f) return {};
  wm = face_forward(normalize(wm), Vec3f(0, 0, 1));
  return lanes_of(distrib_.d_visible(wo, wm) / (4.0f * abs_dot(wo, wm)), lanes_);
}

}  // namespace prism::worker
