// Tests of spectral gradient sampling on the worker (docs/estimators.md §5): the local shift
// (Jacobians against finite differences of the mapping, invertibility of vertex and whole-path
// shifts, failure at TIR and grazing angles), and the integrator: E[G[b]] = E[I[b+k]] − E[I[b]]
// per bin on dispersive scenes with τ = 0 and τ > 0, I identical to `uniform`, exact gradients
// where nothing wavelength-dependent bends paths, numerical corners, deterministic tile bytes.
#include "worker/gradient/integrator.h"

#include <gtest/gtest.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/testing/chi_square.h"
#include "tests/testing/test_dir.h"
#include "worker/fresnel.h"
#include "worker/gradient/shift.h"
#include "worker/testing/bin_stats.h"
#include "worker/testing/skewed_tables.h"
#include "worker/testing/tracer_test.h"
#include "worker/tile_renderer.h"

namespace prism::worker {
namespace {

namespace fs = std::filesystem;

const fs::path kTestData = fs::path(PRISM_SOURCE_DIR) / "worker" / "testdata";

// ---------------------------------------------------------------------------------------------
// The local shift: Jacobians against finite differences of the mapping, and invertibility.

Vec3f spherical(float theta, float phi) {
  return {std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
}

// Solid-angle ratio of a direction map g at w: the area of the image of a small parallelogram
// of directions over its own area, by central differences in the tangent plane of w.
template <typename Map>
double finite_difference_jacobian(const Vec3f& w, Map&& g, double eps = 2e-4) {
  Frame f = Frame::from_z(w);
  auto image = [&](double a, double b) -> std::optional<Vec3f> {
    Vec3f d = normalize(w + f.s * float(a) + f.t * float(b));
    return g(d);
  };
  auto xp = image(eps, 0), xm = image(-eps, 0), yp = image(0, eps), ym = image(0, -eps);
  if (!xp || !xm || !yp || !ym) return -1;
  Vec3f dx = (*xp - *xm) / float(2 * eps), dy = (*yp - *ym) / float(2 * eps);
  return length(cross(dx, dy));
}

// Random rough base scatters (from either side, η about 1.45..1.65) whose half-vector is valid.
std::vector<BaseScatter> rough_cases(bool transmission, int count) {
  std::mt19937 rng(transmission ? 7 : 8);
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<BaseScatter> out;
  while (int(out.size()) < count) {
    const bool inside = u(rng) < 0.3f;
    Vec3f wo = spherical(std::acos(0.1f + 0.85f * u(rng)), 2 * kPi * u(rng));
    if (inside) wo.z = -wo.z;
    Vec3f h = spherical(std::acos(0.7f + 0.3f * u(rng)), 2 * kPi * u(rng));
    const float eta = 1.45f + 0.2f * u(rng);
    BaseScatter base{wo, {}, transmission, false, eta};
    if (transmission) {
      auto r = refract(wo, h, eta);
      if (!r) continue;
      base.wi = normalize(r->wt);
    } else {
      base.wi = reflect(wo, h);
      if (!same_hemisphere(wo, base.wi)) continue;
    }
    if (!generalized_half_vector(base)) continue;
    out.push_back(base);
  }
  return out;
}

TEST(GradientShiftTest, HalfVectorJacobiansMatchFiniteDifferences) {
  for (bool transmission : {true, false}) {
    int checked = 0;
    for (const BaseScatter& base : rough_cases(transmission, 200)) {
      // The offset arrives along a nearby direction with a different index (Eq. 13's setting).
      Vec3f wo_y = normalize(base.wo + Vec3f(0.05f, -0.03f, 0.02f));
      if (wo_y.z * base.wo.z <= 0) continue;
      const float eta_y = base.eta * 1.03f;
      auto shift = shift_direction(base, wo_y, eta_y);
      if (!shift) continue;
      // The mapping as a function of the base's direction wi: recover h from (wo, wi), copy it.
      auto map = [&](const Vec3f& wi) -> std::optional<Vec3f> {
        BaseScatter b = base;
        b.wi = wi;
        auto s = shift_direction(b, wo_y, eta_y);
        if (!s) return std::nullopt;
        return s->wi;
      };
      double fd = finite_difference_jacobian(base.wi, map);
      if (fd < 0) continue;
      EXPECT_NEAR(shift->jacobian / fd, 1.0, 0.02)
          << (transmission ? "refraction" : "reflection") << " wo " << base.wo.x << "," << base.wo.y
          << "," << base.wo.z << " analytic " << shift->jacobian << " fd " << fd;
      ++checked;
    }
    EXPECT_GT(checked, 100) << (transmission ? "refraction" : "reflection");
  }
}

TEST(GradientShiftTest, ReconnectionJacobianMatchesFiniteDifferences) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1, 1);
  for (int i = 0; i < 100; ++i) {
    // Target plane through z with normal n; base at x shoots along w and hits it at z; the
    // offset at y reconnects to the hit point.
    const Vec3f n = normalize(Vec3f(0.2f * u(rng), 1, 0.2f * u(rng)));
    const Vec3f plane_point(0, 0, 0);
    const Vec3f x(u(rng), 2 + u(rng), u(rng)), y(u(rng), 1.5f + u(rng), u(rng));
    const Vec3f z(0.5f * u(rng), 0, 0.5f * u(rng));
    auto hit = [&](const Vec3f& w) -> std::optional<Vec3f> {
      float t = dot(plane_point - x, n) / dot(w, n);
      if (!(t > 0)) return std::nullopt;
      return x + w * t;
    };
    const Vec3f z_on_plane = *hit(normalize(z - x));
    auto map = [&](const Vec3f& w) -> std::optional<Vec3f> {
      auto p = hit(w);
      if (!p) return std::nullopt;
      return normalize(*p - y);
    };
    double fd = finite_difference_jacobian(normalize(z_on_plane - x), map);
    double analytic = reconnection_jacobian(x, y, z_on_plane, n);
    EXPECT_NEAR(analytic / fd, 1.0, 0.02) << "case " << i;
  }
}

// Forward (λ → λ') then backward (λ' → λ, the offset as the base) returns the base direction,
// and the two Jacobians are reciprocal: the symmetric MIS weights of a pair agree.
TEST(GradientShiftTest, ShiftIsInvertible) {
  int checked = 0;
  for (bool transmission : {true, false}) {
    for (bool smooth : {true, false}) {
      for (const BaseScatter& base : rough_cases(transmission, 200)) {
        BaseScatter b = base;
        b.smooth = smooth;
        if (smooth) {
          auto r = refract(b.wo, Vec3f(0, 0, 1), b.eta);
          if (transmission && !r) continue;
          b.wi = transmission ? normalize(r->wt) : Vec3f(-b.wo.x, -b.wo.y, b.wo.z);
        }
        // η' → 1 through a rough interface maps every half-vector to nearly −ω_o (J ~ 1e-7): the
        // inverse is ill-conditioned in float, so it is only checked for smooth events here (the
        // stability test covers it).
        for (float eta_y : {b.eta * 0.98f, b.eta * 1.02f, smooth ? 1.0001f : b.eta * 1.05f}) {
          auto forward = shift_direction(b, b.wo, eta_y);
          if (!forward) continue;
          BaseScatter reverse{b.wo, forward->wi, transmission, smooth, eta_y};
          auto back = shift_direction(reverse, b.wo, b.eta);
          ASSERT_TRUE(back.has_value()) << "a successful shift must be invertible";
          EXPECT_LT(length(back->wi - b.wi), 2e-4f)
              << "eta " << b.eta << " eta_y " << eta_y << " smooth " << smooth << " transmission "
              << transmission << " wo " << b.wo.x << "," << b.wo.y << "," << b.wo.z << " wi "
              << b.wi.x << "," << b.wi.y << "," << b.wi.z << " J " << forward->jacobian;
          EXPECT_NEAR(forward->jacobian * back->jacobian, 1.0, 1e-3);
          ++checked;
        }
      }
    }
  }
  EXPECT_GT(checked, 1000);
}

// Path level: a camera ray through a slab (top y = 1.4, bottom y = 0.4, η(λ) inside) onto a
// floor (y = 0), with a rough or smooth refraction at each face. Shifting the whole path to λ'
// (half-vector copies, vertex by vertex, each offset vertex where its own ray meets the face)
// and shifting the offset path back to λ returns every base vertex, and the product of the
// forward and backward Jacobians along the path is 1.
struct SlabPath {
  Vec3f vertices[3];  // top, bottom, floor
  Vec3f directions[3];
  float jacobian = 1;
};

// Local frame of a horizontal face: z = +y (outside, up for the top face, down for the bottom
// face so that the normal points out of the glass).
Vec3f to_face(const Vec3f& w, bool top) {
  return top ? Vec3f(w.x, w.z, w.y) : Vec3f(w.x, -w.z, -w.y);
}
Vec3f from_face(const Vec3f& v, bool top) {
  return top ? Vec3f(v.x, v.z, v.y) : Vec3f(v.x, -v.z, -v.y);
}

std::optional<SlabPath> shift_slab_path(const SlabPath& base, float eta, float eta_offset,
                                        bool smooth, const Vec3f& camera) {
  SlabPath out;
  Vec3f origin = camera, direction = base.directions[0];
  out.directions[0] = direction;
  const float heights[3] = {1.4f, 0.4f, 0.0f};
  Vec3f base_in = base.directions[0];
  for (int v = 0; v < 3; ++v) {
    float t = (heights[v] - origin.y) / direction.y;
    if (!(t > 0)) return std::nullopt;
    origin = origin + direction * t;
    out.vertices[v] = origin;
    if (v == 2) break;
    const bool top = v == 0;
    BaseScatter b{to_face(-base_in, top), to_face(base.directions[v + 1], top), true, smooth, eta};
    auto shift = shift_direction(b, to_face(-direction, top), eta_offset);
    if (!shift) return std::nullopt;
    direction = from_face(shift->wi, top);
    out.directions[v + 1] = direction;
    out.jacobian *= shift->jacobian;
    base_in = base.directions[v + 1];
  }
  return out;
}

TEST(GradientShiftTest, PathShiftThroughASlabIsInvertible) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0, 1);
  const Vec3f camera(0, 3, -2);
  int checked = 0;
  for (bool smooth : {true, false}) {
    for (int i = 0; i < 300; ++i) {
      const float eta = 1.5f + 0.2f * u(rng);
      // The base path: a camera direction and half-vectors drawn near the face normals.
      SlabPath base;
      Vec3f d = normalize(Vec3f(u(rng) - 0.5f, -1.5f, 0.5f + u(rng)));
      base.directions[0] = d;
      Vec3f origin = camera;
      bool ok = true;
      const float heights[3] = {1.4f, 0.4f, 0.0f};
      for (int v = 0; v < 3 && ok; ++v) {
        float t = (heights[v] - origin.y) / d.y;
        origin = origin + d * t;
        base.vertices[v] = origin;
        if (v == 2) break;
        const bool top = v == 0;
        Vec3f h = smooth ? Vec3f(0, 0, 1)
                         : normalize(Vec3f(0.3f * (u(rng) - 0.5f), 0.3f * (u(rng) - 0.5f), 1));
        auto r = refract(to_face(-d, top), h, eta);
        if (!r) {
          ok = false;
          break;
        }
        d = from_face(normalize(r->wt), top);
        if (!(d.y < 0)) ok = false;
        base.directions[v + 1] = d;
      }
      if (!ok) continue;
      const float eta_offset = eta * (u(rng) < 0.5f ? 0.97f : 1.03f);
      auto forward = shift_slab_path(base, eta, eta_offset, smooth, camera);
      if (!forward) continue;
      auto back = shift_slab_path(*forward, eta_offset, eta, smooth, camera);
      ASSERT_TRUE(back.has_value());
      for (int v = 0; v < 3; ++v) {
        EXPECT_LT(length(back->vertices[v] - base.vertices[v]), 1e-4f) << "vertex " << v;
      }
      EXPECT_NEAR(forward->jacobian * back->jacobian, 1.0, 1e-3);
      // The offset really moved (dispersion), so the check is not vacuous.
      EXPECT_GT(length(forward->vertices[2] - base.vertices[2]), 1e-3f);
      ++checked;
    }
  }
  EXPECT_GT(checked, 400);
}

TEST(GradientShiftTest, FailsCleanlyAtTotalInternalReflectionAndGrazingAngles) {
  // From inside glass (wo.z < 0) at 40° the base (η = 1.5, critical angle 41.8°) refracts;
  // a denser offset (η' = 1.6, critical 38.7°) is totally reflected: the shift fails.
  Vec3f wo = spherical(kPi - 40.0f * kPi / 180.0f, 0.3f);
  BaseScatter smooth{wo, {}, true, true, 1.5f};
  auto r = refract(wo, Vec3f(0, 0, 1), 1.5f);
  ASSERT_TRUE(r.has_value());
  smooth.wi = normalize(r->wt);
  EXPECT_FALSE(shift_direction(smooth, wo, 1.6f).has_value());
  EXPECT_TRUE(shift_direction(smooth, wo, 1.45f).has_value());
  // η' → 1: the offset passes straight through, finite Jacobian.
  auto matched = shift_direction(smooth, wo, 1.0f);
  ASSERT_TRUE(matched.has_value());
  EXPECT_LT(length(matched->wi + wo), 1e-5f);
  // η' → 1 behind a rough interface: ill-conditioned but finite.
  {
    BaseScatter rough{normalize(Vec3f(0.3f, 0.2f, 0.9f)), {}, true, false, 1.5f};
    auto rr = refract(rough.wo, normalize(Vec3f(0.1f, 0, 1)), 1.5f);
    ASSERT_TRUE(rr.has_value());
    rough.wi = normalize(rr->wt);
    auto s = shift_direction(rough, rough.wo, 1.00001f);
    if (s) {
      EXPECT_TRUE(is_finite(s->wi));
      EXPECT_TRUE(std::isfinite(s->jacobian));
    }
  }
  // Grazing: every result is either a failure or finite.
  for (float z : {1e-7f, 1e-4f, 1e-2f}) {
    for (float eta_y : {1.0f, 1.3f, 1.7f}) {
      for (bool transmission : {true, false}) {
        for (bool is_smooth : {true, false}) {
          Vec3f w = normalize(Vec3f(1, 0.1f, z));
          BaseScatter b{w, {}, transmission, is_smooth, 1.5f};
          auto rr = refract(w, normalize(Vec3f(0.01f, 0, 1)), 1.5f);
          b.wi = transmission ? (rr ? normalize(rr->wt) : Vec3f(0, 0, -1))
                              : reflect(w, normalize(Vec3f(0.01f, 0, 1)));
          auto s = shift_direction(b, normalize(Vec3f(1, -0.1f, z)), eta_y);
          if (s) {
            EXPECT_TRUE(is_finite(s->wi));
            EXPECT_TRUE(std::isfinite(s->jacobian));
            EXPECT_GT(s->jacobian, 0.0f);
          }
        }
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------
// The integrator on scenes.

class GradientIntegratorTest : public testing::TracerTest {
 protected:
  static scene::SceneDescription load_file(const fs::path& file) {
    scene::LoadOptions options;
    auto loaded = scene::load_scene(file, options);
    EXPECT_TRUE(loaded.ok()) << loaded.status();
    return loaded.ok() ? loaded->description : scene::SceneDescription();
  }
  static scene::SceneDescription load(const std::string& name) {
    return load_file(kTestData / name);
  }
  static scene::SceneDescription load_text(const std::string& name, const std::string& text) {
    const fs::path file = prism::testing::test_dir() / name;
    std::ofstream(file) << text;
    return load_file(file);
  }

  static std::unique_ptr<RenderScene> build(const scene::SceneDescription& desc,
                                            const job::RenderOptions& options) {
    auto built = RenderScene::build(*device_, desc, *library_, options, desc.film.x_resolution,
                                    desc.film.y_resolution);
    EXPECT_TRUE(built.ok()) << built.status();
    return built.ok() ? std::move(*built) : nullptr;
  }

  static job::RenderOptions gradient_options(std::uint64_t seed, float tau = 0, int lanes = 1) {
    job::RenderOptions options;
    options.integrator = job::IntegratorKind::kGradient;
    options.gradient_lanes = lanes;
    options.sampler = job::SamplerKind::kIndependent;
    options.bins = 16;
    options.gradient_offset_bins = 4;
    options.gradient_tau = tau;
    options.max_depth = 6;
    options.seed = seed;
    return options;
  }
};

// Per-sample statistics of d[b] = G[b] − (I[b+k] − I[b]) (expected 0 for every bin) and of G.
struct Consistency {
  std::vector<double> mean_d, se_d, mean_g, se_g;
  TraceCounters counters;
  bool all_finite = true;
};

// With `tables` (the whole image's), each pixel samples from its own table.
Consistency consistency(const RenderScene& scene, int spp,
                        const spectral::PixelTables* tables = nullptr) {
  GradientIntegrator integrator(scene);
  const int bins = scene.grid().bins();
  const int k = scene.options().gradient_offset_bins;
  const int width = scene.camera().width(), height = scene.camera().height();
  // Per pixel (in parallel, merged in pixel order): Σd, Σd², ΣG, ΣG² per bin.
  struct PixelSums {
    std::vector<double> values;
    TraceCounters counters;
    bool all_finite = true;
  };
  std::vector<PixelSums> pixels(std::size_t(width) * height);
  tbb::parallel_for(0, width * height, [&](int index) {
    PixelSums& p = pixels[std::size_t(index)];
    p.values.assign(4 * std::size_t(bins), 0.0);
    std::vector<double> g(bins), i(bins);
    for (int s = 0; s < spp; ++s) {
      const int x = index % width, y = index / width;
      GradientSample r = integrator.trace(
          x, y, 0, std::uint32_t(s),
          tables != nullptr ? tables->view(x, y, scene.wavelength_pdf(), scene.binned_shape())
                            : spectral::WavelengthPdfView(scene.wavelength_pdf()),
          p.counters);
      p.all_finite = p.all_finite && std::isfinite(r.primal) && std::isfinite(r.gradient) &&
                     std::isfinite(r.gradient_below);
      std::fill(g.begin(), g.end(), 0.0);
      std::fill(i.begin(), i.end(), 0.0);
      // What the tile adds (with C = 1 the single-wavelength values themselves).
      for (int e = 0; e < r.entries; ++e) {
        i[r.entry[e].bin] += r.entry[e].primal;
        g[r.entry[e].bin] += r.entry[e].gradient;
        p.all_finite =
            p.all_finite && std::isfinite(r.entry[e].primal) && std::isfinite(r.entry[e].gradient);
      }
      for (int b = 0; b < bins; ++b) {
        double d = g[b] - (i[(b + k) % bins] - i[b]);
        p.values[4 * b] += d;
        p.values[4 * b + 1] += d * d;
        p.values[4 * b + 2] += g[b];
        p.values[4 * b + 3] += g[b] * g[b];
      }
    }
  });
  Consistency out;
  std::vector<double> sum_d(bins), sq_d(bins), sum_g(bins), sq_g(bins);
  for (const PixelSums& p : pixels) {
    out.counters += p.counters;
    out.all_finite = out.all_finite && p.all_finite;
    for (int b = 0; b < bins; ++b) {
      sum_d[b] += p.values[4 * b];
      sq_d[b] += p.values[4 * b + 1];
      sum_g[b] += p.values[4 * b + 2];
      sq_g[b] += p.values[4 * b + 3];
    }
  }
  const double n = double(width) * height * spp;
  for (int b = 0; b < bins; ++b) {
    auto stats = [&](double sum, double sq, std::vector<double>& mean, std::vector<double>& se) {
      double m = sum / n;
      mean.push_back(m);
      se.push_back(std::sqrt(std::max(0.0, sq / n - m * m) / (n - 1)));
    };
    stats(sum_d[b], sq_d[b], out.mean_d, out.se_d);
    stats(sum_g[b], sq_g[b], out.mean_g, out.se_g);
  }
  return out;
}

constexpr double kZ = 5.0;

// `shifts`: whether the scene's paths are shifted at all (with hero lanes only those after a smooth
// dispersive refraction are).
void expect_consistent(const Consistency& c, const std::string& what, bool shifts = true) {
  EXPECT_TRUE(c.all_finite) << what;
  EXPECT_EQ(c.counters.non_finite, 0u) << what;
  int significant = 0;
  for (std::size_t b = 0; b < c.mean_d.size(); ++b) {
    EXPECT_LT(std::abs(c.mean_d[b]), kZ * c.se_d[b] + 1e-12)
        << what << " bin " << b << " mean G − DI " << c.mean_d[b] << " se " << c.se_d[b]
        << " mean G " << c.mean_g[b];
    if (std::abs(c.mean_g[b]) > kZ * c.se_g[b]) ++significant;
  }
  // The check has power: the gradient itself is resolved in several bins.
  EXPECT_GE(significant, 3) << what;
  if (shifts) {
    EXPECT_GT(c.counters.gradient_shifted_paths, 0u) << what;
  } else {
    EXPECT_EQ(c.counters.gradient_shifted_paths, 0u) << what;
  }
  // PRISM_GRADIENT_DEBUG=1 prints the per-bin figures (what mutation runs compare).
  if (std::getenv("PRISM_GRADIENT_DEBUG")) {
    double max_z = 0;
    for (std::size_t b = 0; b < c.mean_d.size(); ++b) {
      max_z = std::max(max_z, std::abs(c.mean_d[b]) / c.se_d[b]);
    }
    std::printf("%s: diverged %lu reconnected %lu again %lu\n", what.c_str(),
                (unsigned long)c.counters.gradient_divergences,
                (unsigned long)c.counters.gradient_reconnections,
                (unsigned long)c.counters.gradient_repeated_divergences);
    std::printf(
        "%s: max z %.2f significant %d paths %lu shifted %lu events %lu shifts %lu failed %lu "
        "wasted %lu\n",
        what.c_str(), max_z, significant, (unsigned long)c.counters.camera_rays,
        (unsigned long)c.counters.gradient_shifted_paths, (unsigned long)c.counters.gradient_events,
        (unsigned long)c.counters.gradient_shifts, (unsigned long)c.counters.gradient_shifts_failed,
        (unsigned long)c.counters.gradient_shifts_wasted);
    for (std::size_t b = 0; b < c.mean_d.size(); ++b) {
      std::printf("  bin %zu G %.4g ± %.2g  d %.3g ± %.2g\n", b, c.mean_g[b], c.se_g[b],
                  c.mean_d[b], c.se_d[b]);
    }
  }
}

// E[G[b]] = E[I[b+k]] − E[I[b]] for every bin on the dispersive scenes, with τ = 0 and τ > 0.
TEST_F(GradientIntegratorTest, GradientIsConsistentWithPrimalOnDispersiveScenes) {
  std::uint64_t seed = 10;
  for (const char* name :
       {"gradient_prism.pbrt", "gradient_glass_diffuse.pbrt", "gradient_rough_glass.pbrt",
        "gradient_slab.pbrt", "gradient_mixed.pbrt", "gradient_media.pbrt", "gradient_room.pbrt",
        "unbiased.pbrt", "gradient_coated.pbrt"}) {
    auto desc = load(name);
    for (auto [tau, lanes] : {std::pair{0.0f, 1}, std::pair{0.5f, 1}, std::pair{0.0f, 4}}) {
      job::RenderOptions options = gradient_options(seed++, tau, lanes);
      options.max_depth = desc.integrator.max_depth;
      auto scene = build(desc, options);
      ASSERT_TRUE(scene);
      Consistency c = consistency(*scene, 1536);
      // With hero lanes, rough dispersive glass keeps every lane and nothing is shifted.
      const bool rough = std::string(name) == "gradient_rough_glass.pbrt";
      expect_consistent(
          c, std::string(name) + " tau " + std::to_string(tau) + " lanes " + std::to_string(lanes),
          !(rough && lanes > 1));
      if (lanes > 1) continue;
      if (tau > 0) {
        EXPECT_GT(c.counters.gradient_shifts_wasted, 0u) << name;
      }
      if (tau == 0.0f && std::string(name) != "unbiased.pbrt" &&
          std::string(name) != "gradient_media.pbrt" &&
          std::string(name) != "gradient_coated.pbrt") {
        // Every dispersive scene diverges offsets and reconnects them, on steps that events
        // used (offsets follow lazily, so steps no event needed are not counted).
        EXPECT_GT(c.counters.gradient_divergences, 1000u) << name;
        EXPECT_GT(c.counters.gradient_reconnections, 100u) << name;
      }
      if (std::string(name) == "gradient_room.pbrt") {
        EXPECT_GT(c.counters.gradient_repeated_divergences, 100u) << name;
      }
    }
  }
}

using testing::bin_stats;
using testing::BinStats;

image::TileResult render(const RenderScene& scene, std::uint64_t spp,
                         const spectral::PixelTables* tables = nullptr) {
  TileRenderer renderer(scene);
  RenderTask task{{0, 0, scene.camera().width(), scene.camera().height()}, {0, spp}, 0};
  task.tables = tables;
  auto result = renderer.render(task, nullptr);
  EXPECT_TRUE(result.ok()) << result.status();
  return std::move(*result);
}

// The primal I of `gradient` is the single-wavelength tracer (C = 1) or the hero lanes' estimator
// (C = 4): per bin it agrees with `uniform` (independent seeds, five standard errors per bin and
// the joint chi-square at p > 1e-4), for τ = 0 and τ > 0; and with the same seed τ changes G
// only, never I.
TEST_F(GradientIntegratorTest, PrimalAgreesWithUniformPerBin) {
  std::uint64_t seed = 40;
  for (const char* name :
       {"gradient_prism.pbrt", "gradient_glass_diffuse.pbrt", "gradient_rough_glass.pbrt",
        "gradient_media.pbrt", "gradient_coated.pbrt", "gradient_mixed.pbrt", "unbiased.pbrt"}) {
    for (int lanes : {1, 4}) {
      SCOPED_TRACE(std::string(name) + " lanes " + std::to_string(lanes));
      auto desc = load(name);
      job::RenderOptions uniform = gradient_options(seed++);
      uniform.integrator = job::IntegratorKind::kUniform;
      BinStats reference = bin_stats(render(*build(desc, uniform), 1024));
      image::TileResult tau_zero = render(*build(desc, gradient_options(seed, 0.0f, lanes)), 512);
      image::TileResult tau_positive =
          render(*build(desc, gradient_options(seed++, 0.5f, lanes)), 512);
      EXPECT_EQ(tau_zero.sums().size(), tau_positive.sums().size());
      EXPECT_TRUE(
          std::equal(tau_zero.sums().begin(), tau_zero.sums().end(), tau_positive.sums().begin()))
          << name << ": τ changed I";
      // With hero lanes nothing on rough glass is shifted, whatever τ.
      const bool shifts = lanes == 1 || std::string(name) != "gradient_rough_glass.pbrt";
      EXPECT_NE(std::equal(tau_zero.gradients().begin(), tau_zero.gradients().end(),
                           tau_positive.gradients().begin()),
                shifts)
          << name << ": τ = 0.5 shifted exactly what τ = 0 shifted, or shifted at all";
      BinStats gradient = bin_stats(tau_zero);
      double chi2 = 0;
      for (std::size_t b = 0; b < reference.mean.size(); ++b) {
        double se = std::hypot(reference.standard_error[b], gradient.standard_error[b]);
        double z = (gradient.mean[b] - reference.mean[b]) / se;
        EXPECT_LT(std::abs(z), kZ) << name << " bin " << b;
        EXPECT_GT(reference.mean[b], 0.0) << name << " bin " << b;
        chi2 += z * z;
      }
      EXPECT_GT(spectral::testing::chi_square_survival(chi2, int(reference.mean.size())), 1e-4)
          << name;
    }
  }
}

// With per-pixel tables deliberately unlike the default distribution (some pixels left on the
// default), the base wavelength comes from the pixel's table and the offsets' MIS densities are
// that table's pdf at λ ± δ: I still agrees with `uniform` per bin, and G with the differences
// of I.
TEST_F(GradientIntegratorTest, PerPixelTablesKeepPrimalAndGradientUnbiased) {
  std::uint64_t seed = 60;
  for (const char* name : {"gradient_prism.pbrt", "gradient_glass_diffuse.pbrt"}) {
    auto desc = load(name);
    const int width = desc.film.x_resolution, height = desc.film.y_resolution;
    const spectral::PixelTables tables = testing::skewed_tables(
        width, height, 16, [](int x, int y) { return (x + 3 * y) % 5 == 0; });
    job::RenderOptions uniform = gradient_options(seed++);
    uniform.integrator = job::IntegratorKind::kUniform;
    BinStats reference = bin_stats(render(*build(desc, uniform), 1024));
    auto scene = build(desc, gradient_options(seed++));
    ASSERT_TRUE(scene);
    BinStats gradient = bin_stats(render(*scene, 1024, &tables));
    double chi2 = 0;
    for (std::size_t b = 0; b < reference.mean.size(); ++b) {
      double se = std::hypot(reference.standard_error[b], gradient.standard_error[b]);
      double z = (gradient.mean[b] - reference.mean[b]) / se;
      EXPECT_LT(std::abs(z), kZ) << name << " bin " << b;
      chi2 += z * z;
    }
    EXPECT_GT(spectral::testing::chi_square_survival(chi2, int(reference.mean.size())), 1e-4)
        << name;
    expect_consistent(consistency(*scene, 1536, &tables), std::string(name) + " with tables");
  }
}

// With the same seed the base path is the `uniform` path sample for sample (same dimension
// layout), so per pixel and bin the sums agree up to float rounding of the event weights.
TEST_F(GradientIntegratorTest, PrimalIsTheUniformEstimatorSampleForSample) {
  auto desc = load("unbiased.pbrt");
  job::RenderOptions options = gradient_options(77);
  options.max_depth = 8;
  auto gradient = build(desc, options);
  options.integrator = job::IntegratorKind::kUniform;
  auto uniform = build(desc, options);
  image::TileResult a = render(*gradient, 16), b = render(*uniform, 16);
  double total = 0;
  for (std::size_t i = 0; i < a.sums().size(); ++i) {
    EXPECT_NEAR(a.sums()[i], b.sums()[i], 1e-4 * std::abs(b.sums()[i]) + 1e-9) << "value " << i;
    total += b.sums()[i];
  }
  EXPECT_GT(total, 0.0);
}

// An emitter seen directly (max_depth 0) with a flat wavelength pdf: the offsets are the same
// path at λ ± δ with equal densities, so per sample w = 1/2 and, exactly,
//   G[i] = (c(λ+δ) − c(λ)) / 2,   G[i−k] = (c(λ) − c(λ−δ)) / 2,   c(λ) ∝ Le(λ).
// With τ beyond every contribution nothing is shifted and G is the finite difference of the
// sample's I bit for bit. A unit box filter keeps every sample's filter weight exactly 1.
constexpr char kEmitterInView[] = R"(LookAt 0 0 -3  0 0 0  0 1 0
Camera "perspective" "float fov" 20
Film "spectral" "integer xresolution" 4 "integer yresolution" 4 "integer nbuckets" 16
PixelFilter "box"
WorldBegin
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" [360 0.5 450 2 520 1 600 3 700 0.7 830 1.5]
  Shape "trianglemesh" "point3 P" [-5 -5 0  5 -5 0  5 5 0  -5 5 0] "integer indices" [0 2 1 0 3 2]
AttributeEnd
)";

// kEmitterInView's emitter: its radiance at λ towards the camera (straight down its normal).
double radiance_towards_camera(const RenderScene& scene, float lambda) {
  const auto& light = std::get<AreaLight>(scene.lights()[0]);
  SampledWavelengths w(1);
  w.set(0, lambda, 1.0f);
  return double(light.radiance(Vec3f(0, 0, -1), Vec3f(0, 0, -1), w)[0]);
}

TEST_F(GradientIntegratorTest, DirectlySeenEmitterGivesExactGradients) {
  auto desc = load_text("emitter_in_view.pbrt", kEmitterInView);
  job::RenderOptions options = gradient_options(5);
  options.max_depth = 0;
  options.emitter_pdf = job::EmitterPdfKind::kUniform;
  auto scene = build(desc, options);
  ASSERT_TRUE(scene);
  ASSERT_EQ(scene->lights().size(), 1u);
  const auto& grid = scene->grid();
  const int k = options.gradient_offset_bins;
  auto radiance = [&](float l) { return radiance_towards_camera(*scene, l); };
  GradientIntegrator integrator(*scene);
  TraceCounters counters;
  int checked = 0;
  for (int s = 0; s < 400; ++s) {
    GradientSample g =
        integrator.trace(1, 2, 0, std::uint32_t(s), scene->wavelength_pdf(), counters);
    ASSERT_GT(g.primal, 0.0f);
    const int i = grid.bin_of(g.lambda);
    ASSERT_EQ(g.bin, i);
    ASSERT_EQ(g.bin_below, grid.wrap(i - k));
    const float up = grid.lower(grid.wrap(i + k)) + (g.lambda - grid.lower(i));
    const float down = grid.lower(grid.wrap(i - k)) + (g.lambda - grid.lower(i));
    const double c = g.primal, le = radiance(g.lambda);
    const double c_up = c * radiance(up) / le, c_down = c * radiance(down) / le;
    EXPECT_NEAR(g.gradient, 0.5 * (c_up - c), 1e-5 * c) << "λ " << g.lambda;
    EXPECT_NEAR(g.gradient_below, 0.5 * (c - c_down), 1e-5 * c) << "λ " << g.lambda;
    ++checked;
  }
  EXPECT_EQ(counters.gradient_shifts_failed, 0u);
  EXPECT_EQ(counters.gradient_events, 400u);

  options.gradient_tau = 1e30f;
  auto unshifted = build(desc, options);
  GradientIntegrator none(*unshifted);
  TraceCounters none_counters;
  for (int s = 0; s < 100; ++s) {
    GradientSample g =
        none.trace(2, 1, 0, std::uint32_t(s), unshifted->wavelength_pdf(), none_counters);
    EXPECT_EQ(g.gradient, -g.primal);
    EXPECT_EQ(g.gradient_below, g.primal);
  }
  EXPECT_EQ(none_counters.gradient_events, 0u);
  EXPECT_EQ(none_counters.gradient_shifted_paths, 0u);
}

// The same emitter with a pixel's table: the base wavelength comes from the table (c = Le(λ) /
// (p_T(λ)·w)) and the offsets' MIS densities are the table's too, so per sample, exactly,
//   G[i] = (c₊ − c) / (1 + p_T(λ+δ)/p_T(λ)),   G[i−k] = (c − c₋) / (1 + p_T(λ−δ)/p_T(λ)).
TEST_F(GradientIntegratorTest, DirectlySeenEmitterWeighsOffsetsByThePixelsTable) {
  auto desc = load_text("emitter_in_view_table.pbrt", kEmitterInView);
  job::RenderOptions options = gradient_options(6);
  options.max_depth = 0;
  auto scene = build(desc, options);
  ASSERT_TRUE(scene);
  const auto& grid = scene->grid();
  const int k = options.gradient_offset_bins;
  auto radiance = [&](float l) { return radiance_towards_camera(*scene, l); };
  const spectral::PixelTables tables = testing::skewed_tables(4, 4, 16);
  const spectral::WavelengthPdfView table =
      tables.view(1, 2, scene->wavelength_pdf(), scene->binned_shape());
  ASSERT_TRUE(table.is_pixel_table());
  GradientIntegrator integrator(*scene);
  TraceCounters counters;
  for (int s = 0; s < 400; ++s) {
    GradientSample g = integrator.trace(1, 2, 0, std::uint32_t(s), table, counters);
    ASSERT_GT(g.primal, 0.0f);
    const int i = grid.bin_of(g.lambda);
    const float up = grid.lower(grid.wrap(i + k)) + (g.lambda - grid.lower(i));
    const float down = grid.lower(grid.wrap(i - k)) + (g.lambda - grid.lower(i));
    const double p = table.pdf(g.lambda), le = radiance(g.lambda);
    const double c = le / (p * grid.bin_width());
    EXPECT_NEAR(g.primal, c, 1e-5 * c) << "λ " << g.lambda;
    const double c_up = c * radiance(up) / le, c_down = c * radiance(down) / le;
    EXPECT_NEAR(g.gradient, (c_up - c) / (1 + table.pdf(up) / p), 1e-5 * c) << "λ " << g.lambda;
    EXPECT_NEAR(g.gradient_below, (c - c_down) / (1 + table.pdf(down) / p), 1e-5 * c)
        << "λ " << g.lambda;
  }
  EXPECT_EQ(counters.gradient_shifts_failed, 0u);
}

// Nothing wavelength-dependent in the geometry (non-dispersive smooth and rough glass, coloured
// diffuse and conductor, an absorbing and a scattering medium, constant spectra): every offset
// is the base path at λ', no shift fails, and with constant spectra and a flat pdf every
// offset's value equals the base's, so G = 0 per sample (up to rounding).
constexpr char kNoDispersion[] = R"(LookAt 0 2 -4  0 0.5 0  0 1 0
Camera "perspective" "float fov" 45
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
WorldBegin
MakeNamedMedium "fog" "string type" "homogeneous"
  "spectrum sigma_a" [360 0.1 830 0.1] "spectrum sigma_s" [360 0.5 830 0.5]
AttributeBegin
  Material "diffuse" "float reflectance" 0.5
  Shape "trianglemesh" "point3 P" [-4 0 -4  4 0 -4  4 0 4  -4 0 4] "integer indices" [0 1 2 0 2 3]
AttributeEnd
AttributeBegin
  Material "dielectric" "float eta" 1.5
  Translate -0.8 0.5 0
  Shape "sphere" "float radius" 0.5
AttributeEnd
AttributeBegin
  Material "dielectric" "float eta" 1.33 "float roughness" 0.2
  Translate 0.8 0.5 0
  Shape "sphere" "float radius" 0.5
AttributeEnd
AttributeBegin
  Material "interface"
  MediumInterface "fog" ""
  Translate 0 0.4 -1.2
  Shape "sphere" "float radius" 0.4
AttributeEnd
AttributeBegin
  AreaLightSource "diffuse" "spectrum L" [360 1 830 1] "float scale" 2000
  Shape "trianglemesh" "point3 P" [-1 3 -1  1 3 -1  1 3 1  -1 3 1] "integer indices" [0 1 2 0 2 3]
AttributeEnd
)";

TEST_F(GradientIntegratorTest, WithoutWavelengthDependentGeometryOffsetsAreTheBasePath) {
  auto desc = load_text("no_dispersion.pbrt", kNoDispersion);
  job::RenderOptions options = gradient_options(9);
  options.emitter_pdf = job::EmitterPdfKind::kUniform;
  auto scene = build(desc, options);
  ASSERT_TRUE(scene);
  GradientIntegrator integrator(*scene);
  TraceCounters counters;
  double total = 0;
  for (int py = 0; py < 8; ++py) {
    for (int px = 0; px < 8; ++px) {
      for (int s = 0; s < 64; ++s) {
        GradientSample g =
            integrator.trace(px, py, 0, std::uint32_t(s), scene->wavelength_pdf(), counters);
        EXPECT_LE(std::abs(g.gradient), 1e-5f * g.primal) << px << "," << py << " sample " << s;
        EXPECT_LE(std::abs(g.gradient_below), 1e-5f * g.primal);
        total += g.primal;
      }
    }
  }
  EXPECT_GT(total, 0.0);
  EXPECT_GT(counters.gradient_events, 1000u);
  EXPECT_EQ(counters.gradient_shifts_failed, 0u);
  EXPECT_EQ(counters.gradient_shifts_wasted, 0u);
  EXPECT_EQ(counters.non_finite, 0u);
}

// The scene decides C when the job does not (gradient_lanes 0): single-wavelength base paths where
// a material can refract smooth-dispersively, hero lanes elsewhere. Without such a material
// nothing can be shifted and a sample is `hero`'s exactly: the tile's I is hero's to the bit and
// G is its finite difference, G[b] = I[b+k] − I[b] to float rounding, so the reconstruction
// returns I.
TEST_F(GradientIntegratorTest, TheSceneChoosesTheLanesAndWithoutSmoothDispersionASampleIsHeros) {
  for (auto [name, lanes] :
       {std::pair{"gradient_prism.pbrt", 1}, std::pair{"gradient_glass_diffuse.pbrt", 1},
        std::pair{"gradient_rough_glass.pbrt", job::kSceneGradientLanes}}) {
    SCOPED_TRACE(name);
    auto desc = load(name);
    job::RenderOptions options = gradient_options(51, 0.0f, 0);
    auto scene = build(desc, options);
    ASSERT_TRUE(scene);
    GradientIntegrator integrator(*scene);
    EXPECT_EQ(integrator.shifts_possible(), lanes == 1);
    TraceCounters counters;
    integrator.trace(3, 4, 0, 0, spectral::WavelengthPdfView(scene->wavelength_pdf()), counters);
    EXPECT_EQ(counters.gradient_samples, 1u);
    EXPECT_EQ(counters.gradient_lanes, std::uint64_t(lanes));
    if (lanes == 1) continue;

    const image::TileResult gradient = render(*scene, 64);
    job::RenderOptions hero_options = options;
    hero_options.integrator = job::IntegratorKind::kHero;
    const image::TileResult hero = render(*build(desc, hero_options), 64);
    ASSERT_EQ(gradient.sums().size(), hero.sums().size());
    EXPECT_TRUE(std::equal(gradient.sums().begin(), gradient.sums().end(), hero.sums().begin()));
    EXPECT_TRUE(std::equal(gradient.sum_squares().begin(), gradient.sum_squares().end(),
                           hero.sum_squares().begin()));
    const int bins = scene->grid().bins(), k = options.gradient_offset_bins;
    double largest = 0;
    for (std::size_t o = 0; o < gradient.sums().size(); o += std::size_t(bins)) {
      // G's per-sample values are floats: a bin's sum may round at float precision of the
      // pixel's largest values.
      double scale = 0;
      for (int b = 0; b < bins; ++b) scale = std::max(scale, std::abs(gradient.sums()[o + b]));
      for (int b = 0; b < bins; ++b) {
        const double di = gradient.sums()[o + std::size_t((b + k) % bins)] - gradient.sums()[o + b];
        EXPECT_NEAR(gradient.gradients()[o + b], di, 1e-6 * (1 + scale));
        largest = std::max(largest, std::abs(di));
      }
    }
    EXPECT_GT(largest, 0.0);
  }
}

// Numerical corners: grazing refraction into dispersive glass, η(λ') totally reflected where
// η(λ) refracts, η → 1, a line-spectrum emitter and a very bright one. No NaN or Inf may reach
// I or G, and none may be dropped either (non_finite counts drops).
std::string stability_scene(const std::string& glass, const std::string& emission) {
  return R"(LookAt 0 0.05 -4  0 0 0  0 1 0
Camera "perspective" "float fov" 50
Film "spectral" "integer xresolution" 8 "integer yresolution" 8 "integer nbuckets" 16
WorldBegin
AttributeBegin
  Material "diffuse" "float reflectance" 0.5
  Shape "trianglemesh" "point3 P" [-9 -1 -9  9 -1 -9  9 -1 9  -9 -1 9] "integer indices" [0 1 2 0 2 3]
AttributeEnd
AttributeBegin
  Material "dielectric" )" +
         glass + R"(
  Shape "trianglemesh" "point3 P" [-3 0 -3  3 0 -3  3 0 3  -3 0 3  -3 -0.3 -3  3 -0.3 -3  3 -0.3 3  -3 -0.3 3]
    "integer indices" [0 2 1  0 3 2  4 5 6  4 6 7  0 1 5  0 5 4  1 2 6  1 6 5  2 3 7  2 7 6  3 0 4  3 4 7]
AttributeEnd
AttributeBegin
  Material "dielectric" )" +
         glass + R"(
  Translate 0.8 0.6 0.5
  Shape "sphere" "float radius" 0.6
AttributeEnd
AttributeBegin
  AreaLightSource "diffuse" )" +
         emission + R"(
  Shape "trianglemesh" "point3 P" [-1 3 -1  1 3 -1  1 3 1  -1 3 1] "integer indices" [0 1 2 0 2 3]
AttributeEnd
)";
}

TEST_F(GradientIntegratorTest, NumericalCornersStayFinite) {
  const std::string smooth_dense = R"("float cauchy" [1.6 0.05])";
  const std::string plain = R"("spectrum L" [360 1 830 1] "float scale" 1000)";
  struct Case {
    std::string name, glass, emission;
  } cases[] = {
      {"grazing, strong dispersion", smooth_dense, plain},
      {"rough, strong dispersion", R"("float cauchy" [1.6 0.05] "float roughness" 0.05)", plain},
      {"eta near 1", R"("float cauchy" [1.0 0.0003])", plain},
      {"rough, eta near 1", R"("float cauchy" [1.0 0.0003] "float roughness" 0.3)", plain},
      {"index matched", R"("float eta" 1)", plain},
      {"line spectrum", smooth_dense,
       R"("spectrum L" [360 0 545 0 546 5000 547 0 610 0 611 3000 612 0 830 0])"},
      {"fluorescent", smooth_dense, R"("spectrum L" "stdillum-F11" "float scale" 1000)"},
      {"very bright", smooth_dense, R"("spectrum L" [360 1 830 1] "float scale" 1e20)"},
  };
  std::uint64_t seed = 60;
  for (const Case& c : cases) {
    auto desc = load_text("stability.pbrt", stability_scene(c.glass, c.emission));
    for (float tau : {0.0f, 1.0f}) {
      auto scene = build(desc, gradient_options(seed++, tau));
      ASSERT_TRUE(scene) << c.name;
      TileRenderer renderer(*scene);
      TileStats stats;
      auto result = renderer.render({{0, 0, 8, 8}, {0, 64}, 0}, &stats);
      ASSERT_TRUE(result.ok()) << c.name;
      double total = 0;
      for (double v : result->sums()) {
        EXPECT_TRUE(std::isfinite(v)) << c.name;
        total += v;
      }
      for (double v : result->sum_squares()) EXPECT_TRUE(std::isfinite(v)) << c.name;
      for (double v : result->gradients()) EXPECT_TRUE(std::isfinite(v)) << c.name;
      EXPECT_GT(total, 0.0) << c.name;
      EXPECT_EQ(stats.counters.non_finite, 0u) << c.name;
      if (tau == 0.0f) {
        EXPECT_GT(stats.counters.gradient_events, 0u) << c.name;
      }
    }
  }
}

// A gradient tile's bytes do not depend on the thread count or the tile split; the result
// carries the gradients buffer, other integrators' results do not.
TEST_F(GradientIntegratorTest, TileBytesDoNotDependOnThreadsOrTiles) {
  auto desc = load("gradient_glass_diffuse.pbrt");
  auto scene = build(desc, gradient_options(1));
  TileRenderer renderer(*scene);
  RenderTask whole{{0, 0, 12, 12}, {0, 8}, 0};
  auto one = tbb::task_arena(1).execute([&] { return *renderer.render(whole, nullptr); });
  auto two = tbb::task_arena(2).execute([&] { return *renderer.render(whole, nullptr); });
  ASSERT_TRUE(one.has_gradients());
  EXPECT_TRUE(one == two);
  double gradient_total = 0;
  for (double g : one.gradients()) gradient_total += std::abs(g);
  EXPECT_GT(gradient_total, 0.0);
  for (auto [x0, y0] : {std::pair{0, 0}, {6, 0}, {0, 6}, {6, 6}}) {
    auto part = *renderer.render({{x0, y0, x0 + 6, y0 + 6}, {0, 8}, 0}, nullptr);
    for (int y = y0; y < y0 + 6; ++y) {
      for (int x = x0; x < x0 + 6; ++x) {
        for (int b = 0; b < 16; ++b) {
          ASSERT_EQ(part.sum(x, y, b), one.sum(x, y, b));
          ASSERT_EQ(part.gradient(x, y, b), one.gradient(x, y, b));
        }
      }
    }
  }
  job::RenderOptions uniform = gradient_options(1);
  uniform.integrator = job::IntegratorKind::kUniform;
  auto uniform_scene = build(desc, uniform);
  EXPECT_FALSE(TileRenderer(*uniform_scene).render(whole, nullptr)->has_gradients());
}

TEST(GradientOffsetBinsTest, SnapsAndValidates) {
  EXPECT_EQ(*job::gradient_offset_bins(0.15, 64), 10);
  EXPECT_EQ(*job::gradient_offset_bins(0.15, 16), 2);
  EXPECT_EQ(*job::gradient_offset_bins(0.5, 4), 2);
  EXPECT_EQ(job::gradient_offset_bins(0.1, 4).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(job::gradient_offset_bins(0.0, 64).ok());
  EXPECT_FALSE(job::gradient_offset_bins(-0.1, 64).ok());
  EXPECT_FALSE(job::gradient_offset_bins(0.6, 64).ok());
  EXPECT_FALSE(job::gradient_offset_bins(std::nan(""), 64).ok());
}

}  // namespace
}  // namespace prism::worker
