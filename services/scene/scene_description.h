// The parsed scene: plain values describing a pbrt-v4 scene (the subset Prism renders), ready
// for a spectral path tracer and for the "what depends on wavelength" analysis. Nothing here
// is evaluated: spectra stay as written (spectrum_param.h), meshes stay in object space.
//
// Coordinate conventions (pbrt-v4; see docs/estimators.md §9):
// - The world is left-handed. Camera space: +z is the viewing direction, +y up, +x to the
//   right of the image. Raster x grows with camera +x, raster y grows with camera −y (down).
//   LookAt eye=(0,0,0) look=(0,0,1) up=(0,1,0) makes camera space equal world space, so world
//   +x appears on the RIGHT of the image (a right-handed renderer would show it on the left).
// - `fov` is the full angle spanned by the shorter image axis (pbrt-v4 perspective camera);
//   the default screen window is [-a,a]x[-1,1] (a = aspect >= 1) or [-1,1]x[-1/a,1/a].
// - Transforms: world_from_X matrices act on column vectors; shapes keep object-space data
//   plus object_to_world, which the tracer applies (to positions: apply_point; to vertex
//   normals: apply_normal). Spheres are centred at the object-space origin.
// - Triangle orientation: the geometric normal of triangle (p0, p1, p2), computed from the
//   WORLD-space positions, is n = normalize(cross(p0 − p2, p1 − p2)); it is negated when
//   reverse_orientation XOR transform_swaps_handedness. When the mesh has vertex normals, the
//   geometric normal is instead flipped to the side of the interpolated shading normal
//   (pbrt-v4 Triangle::InteractionFromIntersection), the vertex normals being negated under
//   reverse_orientation (as pbrt-v4's TriangleMesh does), so ReverseOrientation turns a mesh
//   with normals round too. Sphere, disk and cylinder normals are the
//   object-space normal (outward; +z on a disk) carried by the normal matrix, negated under
//   reverse_orientation alone: a mirroring transform keeps the outside outside, as for a mesh
//   (pbrt-v4 also negates them under a mirror when intersecting, not when sampling them as
//   lights; docs/conformance.md).
// - Area lights emit on the side the (final) geometric normal points to, unless two_sided.
// - Light spectra are normalised by pbrt-v4's rule before `scale` (docs/estimators.md §9); `power`
//   (or `illuminance`) then rescales to that target. The parser stores the inputs only.
// - Media: MediumInterface names are resolved when the directive is read; index -1 is vacuum.
//   A shape whose inside and outside media are equal is not a medium boundary (the ray keeps
//   its medium, as in pbrt-v4); an `interface` material marks a pure medium boundary.
//
// Invariants: every index (material, medium) is valid for its table or -1 where allowed;
// every number is finite; resolution is within [1, kMaxResolution]; meshes passed
// TriangleMeshData::validate().
#pragma once

#include <array>
#include <cstddef>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "services/scene/mesh.h"
#include "services/scene/scene_features.h"
#include "services/scene/source_location.h"
#include "services/scene/spectrum_param.h"
#include "services/scene/texture_description.h"
#include "services/scene/transform.h"

namespace prism::scene {

inline constexpr int kMaxResolution = 16384;
inline constexpr int kMinSpectralBins = 4;
inline constexpr int kMaxSpectralBins = 256;
inline constexpr double kLambdaMinNm = 360.0;
inline constexpr double kLambdaMaxNm = 830.0;
inline constexpr int kMaxIncludeDepth = 16;
// pbrt-v4's default illuminant for lights without a spectrum (the sRGB colour space's).
inline constexpr const char* kDefaultIlluminant = "stdillum-D65";

struct Camera {
  std::string type = "perspective";
  Transform world_from_camera;  // inverse of the CTM at the Camera directive
  double fov_deg = 90.0;
  double lens_radius = 0.0;
  double focal_distance = 1e6;
  std::optional<double> frame_aspect_ratio;
  std::optional<std::array<double, 4>> screen_window;  // xmin, xmax, ymin, ymax
  // spherical: "equalarea" (pbrt-v4's default, the equal-area octahedral square) or
  // "equirectangular".
  std::string mapping = "equalarea";
  int medium = -1;  // the outside medium current at the Camera directive
  SourceLocation where;
};

enum class FilmType { kRgb, kSpectral };

struct Film {
  FilmType type = FilmType::kRgb;
  int x_resolution = 1280;
  int y_resolution = 720;
  std::string filename = "pbrt.exr";
  // pbrt-v4's `nbuckets` of the spectral film: the number of wavelength bins over
  // [kLambdaMinNm, kLambdaMaxNm]; unset means the job's default.
  std::optional<int> bins;
  SourceLocation where;
};

// pbrt-v4's PixelFilter, with pbrt-v4's defaults: no directive means a gaussian of radius 1.5
// and sigma 0.5. Every filter pbrt-v4 has is separable: f(x, y) = f_x(x)·f_y(y).
enum class PixelFilterType { kBox, kGaussian, kTriangle, kMitchell, kLanczos };
struct PixelFilterSpec {
  PixelFilterType type = PixelFilterType::kGaussian;
  double x_radius = 1.5, y_radius = 1.5;  // pixels
  double sigma = 0.5;                     // gaussian
  double b = 1.0 / 3.0, c = 1.0 / 3.0;    // mitchell
  double tau = 3.0;                       // lanczos
  SourceLocation where;                   // unset: the default
};

struct SamplerSpec {
  std::string name = "zsobol";  // as written; Prism always uses its own sequence
  int samples_per_pixel = 16;
};

struct IntegratorSpec {
  std::string name = "volpath";  // as written
  int max_depth = 5;
};

// A spectrum slot of a material may instead name a spectrum texture: `*_texture` is then its
// index into SceneDescription::textures and the spectrum beside it is unused.
struct DiffuseMaterial {
  SpectrumParam reflectance = SpectrumConstant{0.5};
  int reflectance_texture = -1;
};

// Roughness as written; with remap_roughness the tracer maps it to the microfacet alpha
// with pbrt-v4's TrowbridgeReitzDistribution::RoughnessToAlpha (sqrt). Zero is smooth.
// A `texture roughness` (or uroughness, vroughness) gives the axis a float texture instead: its
// index into SceneDescription::textures, evaluated and remapped per hit.
struct Roughness {
  double u = 0.0;
  double v = 0.0;
  bool remap = true;
  int u_texture = -1;
  int v_texture = -1;
};

struct DielectricMaterial {
  IorParam eta = IorConstant{1.5};
  Roughness roughness;
};

// Either eta + k (complex IOR, default pbrt-v4's copper) or an artist reflectance (then eta
// and k are unused and pbrt-v4's reflectance-to-IOR mapping applies).
struct ConductorMaterial {
  SpectrumParam eta = SpectrumNamed{"metal-Cu-eta"};
  SpectrumParam k = SpectrumNamed{"metal-Cu-k"};
  std::optional<SpectrumParam> reflectance;
  Roughness roughness;
};

// No surface scattering: marks a boundary between media.
struct InterfaceMaterial {};

// pbrt-v4's `mix`: at each hit one of two earlier-defined materials (indices into
// SceneDescription::materials), the second with probability `amount`, chosen by a hash of the
// hit point and direction so that every query at one vertex agrees (pbrt-v4's ChooseMaterial).
struct MixMaterial {
  std::array<int, 2> materials{0, 0};
  double amount = 0.5;
  int amount_texture = -1;  // a float texture instead of `amount`
};

// pbrt-v4's `thindielectric`: a thin slab (two parallel interfaces, internal bounces summed).
struct ThinDielectricMaterial {
  IorParam eta = IorConstant{1.5};
};

// pbrt-v4's `diffusetransmission`: Lambertian reflection R and transmission T, both times
// `scale`.
struct DiffuseTransmissionMaterial {
  SpectrumParam reflectance = SpectrumConstant{0.25};
  SpectrumParam transmittance = SpectrumConstant{0.25};
  int reflectance_texture = -1;
  int transmittance_texture = -1;
  double scale = 1.0;
};

// pbrt-v4's layered materials: a dielectric coat (η, roughness) over a base, a slab of
// `thickness` between them holding an optional scattering medium (`albedo`, HG `g`; unit
// extinction per unit thickness), evaluated stochastically with `nsamples` random walks of at
// most `maxdepth` events (worker/layered_bsdf.h).
struct LayerSpec {
  double thickness = 0.01;
  int thickness_texture = -1;  // float textures replacing thickness and g per hit
  int g_texture = -1;
  SpectrumParam albedo = SpectrumConstant{0};
  int albedo_texture = -1;  // a spectrum texture replacing `albedo`
  double g = 0;
  int max_depth = 10;
  int samples = 1;
};

struct CoatedDiffuseMaterial {
  SpectrumParam reflectance = SpectrumConstant{0.5};
  int reflectance_texture = -1;
  IorParam eta = IorConstant{1.5};
  Roughness roughness;
  LayerSpec layer;
};

// The conductor's η and k (or reflectance) as written; pbrt-v4 divides them by the coat's η
// when it builds the BSDF (the base sits inside the coat).
struct CoatedConductorMaterial {
  IorParam interface_eta = IorConstant{1.5};
  Roughness interface_roughness;
  SpectrumParam conductor_eta = SpectrumNamed{"metal-Cu-eta"};
  SpectrumParam k = SpectrumNamed{"metal-Cu-k"};
  std::optional<SpectrumParam> reflectance;
  Roughness conductor_roughness;
  LayerSpec layer;
};

using MaterialKind =
    std::variant<DiffuseMaterial, DielectricMaterial, ConductorMaterial, InterfaceMaterial,
                 DiffuseTransmissionMaterial, ThinDielectricMaterial, MixMaterial,
                 CoatedDiffuseMaterial, CoatedConductorMaterial>;

struct Material {
  std::string name;  // empty for anonymous `Material` directives and the default material
  MaterialKind kind;
  SourceLocation where;
};

struct TriangleMeshShape {
  std::shared_ptr<const TriangleMeshData> mesh;  // object space; shared between instances
  // "trianglemesh", "bilinearmesh" (each patch kept as two triangles, (p00,p10,p11) and
  // (p00,p11,p01), listed in TriangleMeshData::patches; their facing is pbrt-v4's patch normal
  // cross(p10−p00, p01−p00)), or the mesh file's path relative to the scene root.
  std::string source;
};

struct SphereShape {
  double radius = 1.0;  // full sphere; partial spheres are refused
};

// pbrt-v4's disk: in the plane z = height, radius `radius`, a hole of `inner_radius`; its normal
// is +z in object space (carried by the orientation rule above). Partial disks are refused.
struct DiskShape {
  double height = 0.0;
  double radius = 1.0;
  double inner_radius = 0.0;
};

// pbrt-v4's cylinder: x² + y² = radius², z_min <= z <= z_max, open at both ends; its normal
// points outwards in object space. Partial cylinders (phimax < 360) are refused.
struct CylinderShape {
  double radius = 1.0;
  double z_min = -1.0;
  double z_max = 1.0;
};

using ShapeGeometry = std::variant<TriangleMeshShape, SphereShape, DiskShape, CylinderShape>;

struct AreaLight {
  SpectrumParam radiance = SpectrumNamed{kDefaultIlluminant};  // pbrt `L`
  double scale = 1.0;
  bool two_sided = false;
  std::optional<double> power;  // watts; rescales the emission to this total power
  SourceLocation where;
};

struct MediumInterface {
  int inside = -1;
  int outside = -1;
  bool is_transition() const { return inside != outside; }
};

struct Shape {
  ShapeGeometry geometry;
  Transform object_to_world;
  bool transform_swaps_handedness = false;
  bool reverse_orientation = false;
  int material = 0;  // index into SceneDescription::materials
  std::optional<AreaLight> area_light;
  MediumInterface media;
  // pbrt-v4's `alpha` cut-out: a constant (1: opaque) or a float texture (index into
  // SceneDescription::textures) at the hit's uv.
  double alpha = 1.0;
  int alpha_texture = -1;
  SourceLocation where;
};

// Also pbrt-v4's `goniometric` light: a point light whose intensity is modulated by a grey
// equal-area octahedral image over the directions of light space with y and z swapped (pbrt-v4
// maps the image's centre, +z of the square, to light-space +y); RGB images are averaged to grey.
struct PointLight {
  SpectrumParam intensity = SpectrumNamed{kDefaultIlluminant};  // pbrt `I`
  double scale = 1.0;
  std::optional<double> power;
  Vec3 position_world{};  // light_to_world applied to the origin
  std::shared_ptr<const TextureImage> goniometric;  // grey, square; null for a plain point
  std::string filename;
  // pbrt-v4's `projection` light: an RGB image projected through a perspective frustum of
  // `fov` degrees (the shorter image axis) along light-space +z; `intensity` is then unused.
  std::shared_ptr<const TextureImage> projection;  // linear RGB
  double fov_deg = 90.0;
};

struct SpotLight {
  SpectrumParam intensity = SpectrumNamed{kDefaultIlluminant};
  double scale = 1.0;
  std::optional<double> power;
  double cone_angle_deg = 30.0;
  double cone_delta_angle_deg = 5.0;
  Vec3 position_world{};
  Vec3 direction_world{0, 0, 1};  // unit vector, light space +z in world
};

// A constant environment, or with `image` an environment map: pbrt-v4's equal-area octahedral
// square image (RGB, linear after decoding), looked up at the nearest texel of the light-space
// direction's equal-area square coordinates; `radiance` is then unused.
// With a `portal` (image maps only, as pbrt-v4), the map lights the scene only through that
// rectangle: a ray escaping along w sees the map when it crosses the rectangle towards the
// portal's front (pbrt-v4: +z of the frame x = p3 − p0, y = p1 − p0), and nothing otherwise.
struct InfiniteLight {
  SpectrumParam radiance = SpectrumNamed{kDefaultIlluminant};  // pbrt `L`
  double scale = 1.0;
  std::optional<double> illuminance;
  std::shared_ptr<const TextureImage> image;
  std::string filename;  // the image's path relative to the scene root
  // The portal's corners p0..p3 in world space (pbrt-v4 does not apply the CTM to them).
  std::optional<std::array<Vec3, 4>> portal;
};

// pbrt-v4's `distant` light: radiance L arriving along one direction from infinitely far; the
// light shines from `from` towards `to` (defaults 0,0,0 → 0,0,1), in light space.
struct DistantLight {
  SpectrumParam radiance = SpectrumNamed{kDefaultIlluminant};  // pbrt `L`
  double scale = 1.0;
  std::optional<double> illuminance;  // on a surface facing the light
  Vec3 direction_world{0, 0, -1};     // unit, from the scene towards the light (from − to)
};

using LightKind = std::variant<PointLight, SpotLight, InfiniteLight, DistantLight>;

struct Light {
  LightKind kind;
  // pbrt-v4's renderFromLight: CTM * Translate(from) (* the spot's frame, light +z = to−from).
  Transform light_to_world;
  int medium = -1;  // the outside medium current at the directive
  SourceLocation where;
};

// Henyey-Greenstein phase function with asymmetry g (pbrt-v4's homogeneous medium); g = 0 is
// isotropic. Coefficients are per scene unit after multiplying by `scale`.
struct HomogeneousMedium {
  SpectrumParam sigma_a = SpectrumConstant{1.0};
  SpectrumParam sigma_s = SpectrumConstant{1.0};
  double scale = 1.0;
  double g = 0.0;  // in (-1, 1)
};

using MediumKind = std::variant<HomogeneousMedium>;

struct Medium {
  std::string name;
  MediumKind kind;
  SourceLocation where;
};

struct SceneDescription {
  Camera camera;
  Film film;
  PixelFilterSpec filter;
  SamplerSpec sampler;
  IntegratorSpec integrator;
  std::vector<Shape> shapes;
  std::vector<Material> materials;
  std::vector<Light> lights;
  std::vector<Medium> media;
  std::vector<Texture> textures;  // float and spectrum, in definition order
  // Each feature the scene uses and what Prism did with it (scene_features.h).
  std::vector<FeatureUse> features;
  // "file:line:column: warning: message" for what is not a feature (an AttributeBegin never
  // closed); feature_warnings(features) gives the features' notes in the same form.
  std::vector<std::string> warnings;
  // Every file the parse opened, relative to the scene root, in first-open order, scene file
  // first; what a bundle must contain.
  std::vector<std::string> files;

  std::size_t triangle_count() const;
  std::size_t area_light_count() const;
};

}  // namespace prism::scene
