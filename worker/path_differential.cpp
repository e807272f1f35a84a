#include "worker/path_differential.h"

#include <cmath>

namespace prism::worker {

void scatter_differential(SpectralDifferential& diff, const Geometry& geometry,
                          const Material& material, const SurfaceHit& hit, const Vec3f& in,
                          const Vec3f& out, bool specular, bool transmission, float lambda) {
  const auto* dielectric = std::get_if<DielectricMaterial>(&material);
  if (!specular && dielectric == nullptr) {
    diff.tracked = false;  // a diffuse receiver, a rough conductor, a layer: it ends here
    return;
  }
  if (!diff.tracked && (dielectric == nullptr || !dielectric->dispersive || !transmission)) {
    return;  // nothing to carry, nothing to start
  }
  if (std::holds_alternative<ThinDielectricMaterial>(material) && transmission) return;
  const Vec3f dn = diff.tracked ? geometry.normal_differential(hit, diff.dp) : Vec3f();
  // The interface's normal: the shading normal, or the sampled microfacet normal held fixed in
  // the shading frame (rough dielectrics).
  Vec3f m = hit.ns, dm = dn;
  RelativeEta eta;
  if (transmission && dielectric != nullptr) {
    const double n = spectral::eta(dielectric->eta, lambda),
                 dn_dl = spectral::deta_dlambda(dielectric->eta, lambda);
    const bool entering = dot(in, hit.ng) < 0;
    eta = entering ? relative_eta(1, 0, n, dn_dl) : relative_eta(n, dn_dl, 1, 0);
    if (!specular) m = normalize(in * eta.eta - out);  // n_i·in − n_t·out, over n_t
  } else if (!specular) {
    m = normalize(out - in);
  }
  if (!specular) dm = microfacet_normal_differential(hit.ns, dn, m);
  if (transmission) {
    refract(diff, in, m, dm, eta);
  } else {
    reflect(diff, in, m, dm);
  }
}

std::optional<Vec3f> receiver_offset(const Geometry& geometry, const SurfaceHit& receiver,
                                     std::span<const ChainVertex> chain, const Vec3f& emitter,
                                     float lambda) {
  if (chain.empty()) return std::nullopt;
  SpectralDifferential diff;
  Vec3f at = emitter;
  for (std::size_t i = chain.size(); i-- > 0;) {
    const ChainVertex& v = chain[i];
    const Vec3f to = v.hit.p - at;
    const float t = length(to);
    if (!(t > 0.0f)) return std::nullopt;
    const Vec3f d = to / t;
    if (diff.tracked && !transfer(diff, d, t, v.hit.ng)) return std::nullopt;
    // Reversed: the light arrives along −out and leaves along −in.
    const bool was_tracked = diff.tracked;
    scatter_differential(diff, geometry, *v.material, v.hit, -v.out, -v.in, true, v.transmission,
                         lambda);
    if (was_tracked && !diff.tracked) return std::nullopt;  // ended (TIR, grazing)
    at = v.hit.p;
  }
  if (!diff.tracked) return std::nullopt;
  const Vec3f to = receiver.p - at;
  const float t = length(to);
  if (!(t > 0.0f) || !transfer(diff, to / t, t, receiver.ng)) return std::nullopt;
  return diff.dp;
}

}  // namespace prism::worker
