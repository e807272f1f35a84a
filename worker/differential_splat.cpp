#include "worker/differential_splat.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "services/spectral/color.h"
#include "worker/light.h"
#include "worker/material.h"

namespace prism::worker {
namespace {

constexpr int kMaxPassthroughs = 64;
// |n·n_g|^32: 0.72 at 2.3°, 0.2 at 10°, 0.01 at 17°.
constexpr int kNormalExponent = 32;

double normal_weight(const Vec3f& a, const Vec3f& b) {
  double c = std::abs(double(dot(a, b)));
  for (int k = 0; k < 5; ++k) c *= c;  // c^32
  static_assert(kNormalExponent == 32);
  return c;
}

}  // namespace

ReceiverImage::ReceiverImage(const RenderScene& scene)
    : width_(scene.camera().width()),
      height_(scene.camera().height()),
      pixels_(std::size_t(width_) * height_) {
  const Camera& camera = scene.camera();
  const Geometry& geometry = scene.geometry();
  tbb::parallel_for(tbb::blocked_range<int>(0, height_), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y != rows.end(); ++y) {
      for (int x = 0; x < width_; ++x) {
        Ray ray = camera.generate_ray({float(x) + 0.5f, float(y) + 0.5f}, {0.5f, 0.5f});
        for (int pass = 0; pass < kMaxPassthroughs; ++pass) {
          auto hit = geometry.intersect(ray, kInfinity);
          if (!hit) break;
          const Material& m = scene.materials()[std::size_t(scene.shape(hit->shape).material)];
          if (std::holds_alternative<InterfaceMaterial>(m)) {
            ray.origin = geometry.offset_origin(hit->p, hit->ng, ray.direction);
            continue;
          }
          Pixel& out = pixels_[std::size_t(y) * width_ + x];
          out.position = hit->p;
          out.normal = hit->ng;
          out.footprint = camera.pixel_footprint(hit->p);
          out.valid = out.footprint > 0.0f;
          break;
        }
      }
    }
  });
}

DifferentialSplatter::DifferentialSplatter(const RenderScene& scene, const ReceiverImage& receivers)
    : scene_(scene), receivers_(receivers) {}

void DifferentialSplatter::point(const LightSplat& s, double scale, FilteredSums& out) const {
  for_each_filter_pixel(scene_.pixel_filter(), s.raster, scale, out.width, out.height,
                        [&](int x, int y, double w) {
                          const std::size_t p = std::size_t(y) * out.width + x;
                          out.values[p * out.bins + s.bin] += s.value * w;
                          for (int c = 0; c < 3; ++c) out.rgb[p * 3 + c] += s.rgb[c] * w;
                        });
}

bool DifferentialSplatter::splat(const LightSplat& s, double width_nm, double scale,
                                 FilteredSums& out) {
  if (!s.has_differential || !(width_nm > 0.0)) {
    point(s, scale, out);
    return false;
  }
  const spectral::WavelengthGrid& grid = scene_.grid();
  // t ∈ [t0, t1] ⊂ [−1, 1] keeps λ + t·Δλ inside the grid.
  const double lambda = s.lambda;
  const double t0 = std::max(-1.0, (spectral::kLambdaMin - lambda) / width_nm);
  const double t1 = std::min(1.0, (spectral::kLambdaMax - lambda) / width_nm);
  const double dx = double(s.raster_per_nm.x) * width_nm, dy = double(s.raster_per_nm.y) * width_nm;
  const double pixels = (t1 - t0) * std::sqrt(dx * dx + dy * dy);
  if (!(t1 > t0) || !std::isfinite(pixels)) {
    point(s, scale, out);
    return false;
  }
  const int fragments = int(std::clamp(std::ceil(2.0 * pixels), 1.0, double(kMaxSplatFragments)));
  // The emitter's spectrum, when the splat knows its light: fragments share the splat's energy in
  // proportion to it (with the bilateral weights), so that the caustic keeps its lamp's spectral
  // shape along the line and only the rest of the path's throughput is taken as constant.
  const spectral::Spectrum* emitted = nullptr;
  if (s.light >= 0 && std::size_t(s.light) < scene_.lights().size()) {
    emitted = &light_spectrum(scene_.lights()[std::size_t(s.light)]);
  }
  weights_.assign(std::size_t(fragments), 0.0);
  double total = 0.0;
  for (int k = 0; k < fragments; ++k) {
    const double t = t0 + (t1 - t0) * (k + 0.5) / fragments;
    const double rx = s.raster.x + t * dx, ry = s.raster.y + t * dy;
    const int x = int(std::floor(rx)), y = int(std::floor(ry));
    double w = 1.0;  // off the film: nothing to compare with, and nothing lands there
    if (x >= 0 && x < out.width && y >= 0 && y < out.height) {
      const ReceiverImage::Pixel& g = receivers_.at(x, y);
      if (!g.valid) {
        w = 0.0;
      } else {
        const Vec3f q = s.position + s.position_per_nm * float(t * width_nm);
        const double off_plane = double(dot(g.position - q, s.normal)) / double(g.footprint);
        w = std::exp(-0.5 * off_plane * off_plane) * normal_weight(g.normal, s.normal);
      }
    }
    if (emitted != nullptr && w > 0.0) {
      w *= std::max(0.0f, spectral::eval(*emitted, float(lambda + t * width_nm)));
    }
    weights_[std::size_t(k)] = w;
    total += w;
  }
  if (!(total > 0.0) || !std::isfinite(total)) {
    point(s, scale, out);
    return false;
  }
  const double energy = double(s.value) * grid.bin_width();  // the splat's value at λ
  for (int k = 0; k < fragments; ++k) {
    const double w = weights_[std::size_t(k)];
    if (w == 0.0) continue;
    const double t = t0 + (t1 - t0) * (k + 0.5) / fragments;
    const float l = float(lambda + t * width_nm);
    const int bin = grid.bin_of(l);
    if (bin < 0) continue;
    const spectral::Rgb bar = scene_.cmf().srgb(l);
    const double share = scale * w / total;
    const double value = double(s.value) * share;
    const double rgb[3] = {bar.r * energy * share, bar.g * energy * share, bar.b * energy * share};
    const Point2f raster{float(s.raster.x + t * dx), float(s.raster.y + t * dy)};
    for_each_filter_pixel(scene_.pixel_filter(), raster, 1.0, out.width, out.height,
                          [&](int x, int y, double f) {
                            const std::size_t p = std::size_t(y) * out.width + x;
                            out.values[p * out.bins + bin] += value * f;
                            for (int c = 0; c < 3; ++c) out.rgb[p * 3 + c] += rgb[c] * f;
                          });
  }
  return true;
}

}  // namespace prism::worker
