// An eye path's caustic offset (path_differential.h's receiver_offset) against finite
// differences of the light path it replays: light from a point through a dispersive glass
// sphere onto a floor, traced with Embree at λ ± 4 nm, and the chain given in eye order.
#include "worker/path_differential.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"
#include "tests/testing/test_dir.h"
#include "worker/embree_device.h"
#include "worker/render_scene.h"

namespace prism::worker {
namespace {

constexpr char kScene[] = R"(LookAt 0 6 -3  0 0 0  0 1 0
Camera "perspective" "float fov" 40
Film "spectral" "integer xresolution" 16 "integer yresolution" 16 "integer nbuckets" 16
WorldBegin
LightSource "point" "point3 from" [0 5 0] "blackbody I" 3000
Material "diffuse"
Shape "trianglemesh" "point3 P" [-20 0 -20  20 0 -20  20 0 20  -20 0 20]
  "integer indices" [0 1 2 0 2 3]
AttributeBegin
  Material "dielectric" "spectrum eta" "glass-SF11"
  Translate 0 2 0
  Shape "sphere" "float radius" 0.6
AttributeEnd
)";

// Snell's law for unit d through unit n (either side) with η = n_incident/n_transmitted.
std::optional<Vec3f> snell(const Vec3f& d, Vec3f n, double eta) {
  if (dot(d, n) > 0) n = -n;
  const double c = -dot(d, n), k = 1 - eta * eta * (1 - c * c);
  if (k < 0) return std::nullopt;
  return normalize(d * float(eta) + n * float(eta * c - std::sqrt(k)));
}

class PathDifferentialTest : public ::testing::Test {
 protected:
  void SetUp() override {
    library_ =
        std::make_unique<spectral::SpectrumLibrary>(*spectral::SpectrumLibrary::load_builtin());
    const std::filesystem::path file = prism::testing::test_dir() / "sphere.pbrt";
    std::ofstream(file) << kScene;
    auto loaded = scene::load_scene(file, scene::with_library_names(*library_));
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    job::RenderOptions options;
    options.bins = 16;
    auto built = RenderScene::build(device_, loaded->description, *library_, options, 16, 16);
    ASSERT_TRUE(built.ok()) << built.status();
    scene_ = std::move(*built);
  }

  struct Traced {
    SurfaceHit entry, exit, floor;
    Vec3f inside, outside;  // the directions inside the glass and after it
  };
  // The light path from o along d0 through the sphere onto the floor at wavelength λ.
  std::optional<Traced> trace(const Vec3f& o, const Vec3f& d0, double lambda) const {
    const Geometry& g = scene_->geometry();
    Traced t;
    auto entry = g.intersect({o, d0}, kInfinity);
    if (!entry || entry->shape != glass_shape()) return std::nullopt;
    const double n = spectral::eta(ior(), lambda);
    auto inside = snell(d0, entry->ns, 1 / n);
    if (!inside) return std::nullopt;
    auto exit = g.intersect({g.offset_origin(entry->p, entry->ng, *inside), *inside}, kInfinity);
    if (!exit || exit->shape != glass_shape()) return std::nullopt;
    auto outside = snell(*inside, exit->ns, n);
    if (!outside) return std::nullopt;
    auto floor = g.intersect({g.offset_origin(exit->p, exit->ng, *outside), *outside}, kInfinity);
    if (!floor || floor->shape == glass_shape()) return std::nullopt;
    t.entry = *entry;
    t.exit = *exit;
    t.floor = *floor;
    t.inside = *inside;
    t.outside = *outside;
    return t;
  }
  int glass_shape() const {
    for (int i = 0; i < scene_->shape_count(); ++i) {
      if (std::holds_alternative<DielectricMaterial>(material(i))) return i;
    }
    return -1;
  }
  const Material& material(int shape) const {
    return scene_->materials()[std::size_t(scene_->shape(shape).material)];
  }
  const spectral::Ior& ior() const {
    return std::get<DielectricMaterial>(material(glass_shape())).eta;
  }

  EmbreeDevice device_;
  std::unique_ptr<spectral::SpectrumLibrary> library_;
  std::unique_ptr<RenderScene> scene_;
};

TEST_F(PathDifferentialTest, ACausticsOffsetMatchesFiniteDifferencesOfItsLightPath) {
  const Vec3f o{0, 5, 0};
  int checked = 0;
  for (double lambda : {450.0, 600.0}) {
    for (float x : {0.05f, 0.15f, 0.3f, 0.45f}) {
      SCOPED_TRACE(::testing::Message() << lambda << " nm, x " << x);
      const Vec3f d0 = normalize(Vec3f{x, 2.0f, 0.6f * x} - o);
      auto at = trace(o, d0, lambda);
      // Central differences over ±4 nm: float positions make smaller steps noisy.
      auto plus = trace(o, d0, lambda + 4), minus = trace(o, d0, lambda - 4);
      ASSERT_TRUE(at && plus && minus);
      const Vec3f fd = (plus->floor.p - minus->floor.p) * 0.125f;
      // The eye path: floor → exit → entry → the light, each vertex with its eye directions.
      const Material& glass = material(glass_shape());
      const ChainVertex chain[2] = {{at->exit, &glass, -at->outside, -at->inside, true},
                                    {at->entry, &glass, -at->inside, -d0, true}};
      auto offset = receiver_offset(scene_->geometry(), at->floor, chain, o, float(lambda));
      ASSERT_TRUE(offset.has_value());
      EXPECT_NEAR(offset->y, 0.0f, 1e-6f);  // it stays on the floor
      EXPECT_GT(length(fd), 1e-5f);
      EXPECT_LT(length(*offset - fd), 0.02f * length(fd) + 2e-7f)
          << "offset " << offset->x << "," << offset->z << " fd " << fd.x << "," << fd.z;
      ++checked;
    }
  }
  EXPECT_EQ(checked, 8);
}

// Without a dispersive vertex there is nothing to replay: no offset.
TEST_F(PathDifferentialTest, NoOffsetWithoutDispersion) {
  auto at = trace({0, 5, 0}, normalize(Vec3f{0.2f, 2.0f, 0.1f} - Vec3f{0, 5, 0}), 550);
  ASSERT_TRUE(at);
  EXPECT_FALSE(receiver_offset(scene_->geometry(), at->floor, {}, {0, 5, 0}, 550.0f).has_value());
}

}  // namespace
}  // namespace prism::worker
