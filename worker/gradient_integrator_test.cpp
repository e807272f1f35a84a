#include "worker/gradient_integrator.h"

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "worker/fresnel.h"
#include "worker/gradient_shift.h"
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

struct ShiftCase {
  Vec3f wo;
  float eta, eta_offset;
  bool transmission;
};

// Random rough configurations in which base and offset both succeed.
std::vector<std::pair<BaseScatter, DirectionShift>> rough_cases(bool transmission, int count,
                                                                Vec3f* offset_wo_out = nullptr) {
  std::mt19937 rng(transmission ? 7 : 8);
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<std::pair<BaseScatter, DirectionShift>> out;
  (void)offset_wo_out;
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
    out.push_back({base, {}});
  }
  return out;
}

TEST(GradientShiftTest, HalfVectorJacobiansMatchFiniteDifferences) {
  for (bool transmission : {true, false}) {
    int checked = 0;
    for (auto& [base, unused] : rough_cases(transmission, 200)) {
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
          << (transmission ? "refraction" : "reflection") << " wo " << base.wo.x << ","
          << base.wo.y << "," << base.wo.z << " analytic " << shift->jacobian << " fd " << fd;
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
      for (auto& [base, unused] : rough_cases(transmission, 200)) {
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

class GradientIntegratorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    library_ = new spectral::SpectrumLibrary(*spectral::SpectrumLibrary::load_builtin());
    device_ = new EmbreeDevice();
  }
  static void TearDownTestSuite() {
    delete device_;
    delete library_;
  }

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
    const fs::path file = fs::path(::testing::TempDir()) / name;
    std::ofstream(file) << text;
    return load_file(file);
  }

  static std::unique_ptr<RenderScene> build(const scene::SceneDescription& desc,
                                            const RenderOptions& options) {
    auto built = RenderScene::build(*device_, desc, *library_, options, desc.film.x_resolution,
                                    desc.film.y_resolution);
    EXPECT_TRUE(built.ok()) << built.status();
    return built.ok() ? std::move(*built) : nullptr;
  }

  static RenderOptions gradient_options(std::uint64_t seed, float tau = 0) {
    RenderOptions options;
    options.integrator = IntegratorKind::kGradient;
    options.sampler = SamplerKind::kIndependent;
    options.bins = 16;
    options.gradient_offset_bins = 3;
    options.gradient_tau = tau;
    options.max_depth = 6;
    options.seed = seed;
    return options;
  }

  static spectral::SpectrumLibrary* library_;
  static EmbreeDevice* device_;
};

spectral::SpectrumLibrary* GradientIntegratorTest::library_ = nullptr;
EmbreeDevice* GradientIntegratorTest::device_ = nullptr;

// Per-sample statistics of d[b] = G[b] − (I[b+k] − I[b]) (expected 0 for every bin) and of G.
struct Consistency {
  std::vector<double> mean_d, se_d, mean_g, se_g;
  TraceCounters counters;
  bool all_finite = true;
};

Consistency consistency(const RenderScene& scene, int spp) {
  GradientIntegrator integrator(scene);
  const int bins = scene.grid().bins();
  const int k = scene.options().gradient_offset_bins;
  std::vector<double> sum_d(bins), sq_d(bins), sum_g(bins), sq_g(bins);
  std::vector<double> g(bins), i(bins);
  Consistency out;
  const int width = scene.camera().width(), height = scene.camera().height();
  for (int py = 0; py < height; ++py) {
    for (int px = 0; px < width; ++px) {
      for (int s = 0; s < spp; ++s) {
        GradientSample r = integrator.trace(px, py, 0, std::uint32_t(s), scene.wavelength_pdf(),
                                            out.counters);
        out.all_finite = out.all_finite && std::isfinite(r.primal) &&
                         std::isfinite(r.gradient) && std::isfinite(r.gradient_below);
        std::fill(g.begin(), g.end(), 0.0);
        std::fill(i.begin(), i.end(), 0.0);
        i[r.bin] += r.primal;
        g[r.bin] += r.gradient;
        g[r.bin_below] += r.gradient_below;
        for (int b = 0; b < bins; ++b) {
          double d = g[b] - (i[(b + k) % bins] - i[b]);
          sum_d[b] += d;
          sq_d[b] += d * d;
          sum_g[b] += g[b];
          sq_g[b] += g[b] * g[b];
        }
      }
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

void expect_consistent(const Consistency& c, const std::string& what) {
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
  EXPECT_GT(c.counters.gradient_shifted_paths, 0u) << what;
  if (std::getenv("PRISM_GRADIENT_DEBUG")) {
    double max_z = 0;
    for (std::size_t b = 0; b < c.mean_d.size(); ++b) {
      max_z = std::max(max_z, std::abs(c.mean_d[b]) / c.se_d[b]);
    }
    std::printf("%s: max z %.2f significant %d paths %lu shifted %lu events %lu shifts %lu failed %lu wasted %lu\n",
                what.c_str(), max_z, significant, (unsigned long)c.counters.camera_rays,
                (unsigned long)c.counters.gradient_shifted_paths,
                (unsigned long)c.counters.gradient_events, (unsigned long)c.counters.gradient_shifts,
                (unsigned long)c.counters.gradient_shifts_failed,
                (unsigned long)c.counters.gradient_shifts_wasted);
    for (std::size_t b = 0; b < c.mean_d.size(); ++b) {
      std::printf("  bin %zu G %.4g ± %.2g  d %.3g ± %.2g\n", b, c.mean_g[b], c.se_g[b], c.mean_d[b], c.se_d[b]);
    }
  }
}

// E[G[b]] = E[I[b+k]] − E[I[b]] for every bin on the dispersive scenes, with τ = 0 and τ > 0.
TEST_F(GradientIntegratorTest, GradientIsConsistentWithPrimalOnDispersiveScenes) {
  std::uint64_t seed = 10;
  for (const char* name : {"gradient_prism.pbrt", "gradient_glass_diffuse.pbrt",
                           "gradient_rough_glass.pbrt", "unbiased.pbrt"}) {
    auto desc = load(name);
    for (float tau : {0.0f, 0.5f}) {
      auto scene = build(desc, gradient_options(seed++, tau));
      ASSERT_TRUE(scene);
      Consistency c = consistency(*scene, 1536);
      expect_consistent(c, std::string(name) + " tau " + std::to_string(tau));
      if (tau > 0) {
        EXPECT_GT(c.counters.gradient_shifts_wasted, 0u) << name;
      }
    }
  }
}

}  // namespace
}  // namespace prism::worker
