// Scene objects built from a directive's type name and parameter list, each reading its own
// parameters (pbrt-v4's per-type Create()): cameras, films, samplers, integrators, materials,
// lights, area lights, media and shape geometry. Each maker reads what it knows, refuses
// unsupported parameters by name, checks ranges, and finally calls check_all_used(), so a
// misspelt parameter is an error at its position. Unknown types are refused by name with the
// list of supported ones. Every use is recorded through the parameter list's FeatureRecorder
// (scene_features.h); when it allows unsupported input, a refusal is recorded instead, the
// maker returns its substitution (a default, or nullopt for a dropped light or shape).
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "services/scene/parameters.h"
#include "services/scene/parser.h"
#include "services/scene/scene_description.h"

namespace prism::scene {

// A directive's type string ("perspective", "diffuse", ...) and where it was written.
struct TypeName {
  std::string name;
  SourceLocation where;
};

struct EntityContext {
  SpectrumSources spectra;
  MeshLimits mesh_limits;
  // The index of an earlier named material (MakeNamedMaterial), or nullopt.
  std::function<std::optional<int>(const std::string& name)> find_material;
  // Loads the mesh file `reference` (as written, at `where`) and returns it with its
  // root-relative path.
  std::function<absl::StatusOr<TriangleMeshShape>(const std::string& reference, MeshFormat format,
                                                  const SourceLocation& where)>
      load_mesh;
  // The index of the texture of that kind (spectrum or float) called `name`, used at `where`, or
  // nullopt. Materials and shapes may name a texture defined further on (pbrt-v4 resolves them
  // once the whole scene is read); a texture names only earlier ones.
  std::function<std::optional<int>(const std::string& name, bool spectrum,
                                   const SourceLocation& where)>
      find_texture;
  // Decodes the image file `reference` (PNG or OpenEXR); values as in the file (8-bit samples
  // still in the file's encoding, eight_bit set), with the root-relative path.
  struct LoadedImage {
    std::shared_ptr<const TextureImage> image;
    bool eight_bit = false;
    std::string relpath;
  };
  std::function<absl::StatusOr<LoadedImage>(const std::string& reference,
                                            const SourceLocation& where)>
      load_image;
};

absl::StatusOr<Camera> make_camera(const TypeName& type, const ParameterList& params);
// Parameters that only change how pbrt-v4 stores its output (`savefp16`) are accepted with a
// warning: Prism always writes float32.
absl::StatusOr<Film> make_film(const TypeName& type, const ParameterList& params);
absl::StatusOr<SamplerSpec> make_sampler(const TypeName& type, const ParameterList& params);
absl::StatusOr<IntegratorSpec> make_integrator(const TypeName& type, const ParameterList& params);
// box, gaussian, triangle, mitchell and lanczos with pbrt-v4's parameters and defaults.
absl::StatusOr<PixelFilterSpec> make_pixel_filter(const TypeName& type,
                                                  const ParameterList& params);
absl::StatusOr<MaterialKind> make_material(const TypeName& type, const ParameterList& params,
                                           const EntityContext& ctx);
// `ctm` is the current transform at the directive (pbrt-v4 renderFromLight starts from it).
// nullopt: an unsupported light dropped because the load allows unsupported input.
absl::StatusOr<std::optional<Light>> make_light(const TypeName& type, const ParameterList& params,
                                                const Transform& ctm, const EntityContext& ctx);
// nullopt: an unsupported area light dropped (the shapes do not emit).
absl::StatusOr<std::optional<AreaLight>> make_area_light(const TypeName& type,
                                                         const ParameterList& params,
                                                         const EntityContext& ctx);
// `Texture "name" "float"|"spectrum" "class" ...`: constant, checkerboard, imagemap, scale, mix,
// directionmix (texture_description.h). `ctm` transforms directionmix's `dir`.
absl::StatusOr<TextureKind> make_texture(const TypeName& type, bool spectrum,
                                         const ParameterList& params, const Transform& ctm,
                                         const EntityContext& ctx);
absl::StatusOr<Medium> make_medium(const TypeName& type, const ParameterList& params,
                                   const EntityContext& ctx);
// A shape's `alpha` (float in [0, 1] or a float texture); leaves the defaults when absent.
absl::Status read_shape_alpha(const ParameterList& params, const EntityContext& ctx, double* alpha,
                              int* alpha_texture);
// nullopt: an unsupported shape dropped because the load allows unsupported input.
absl::StatusOr<std::optional<ShapeGeometry>> make_shape_geometry(const TypeName& type,
                                                                 const ParameterList& params,
                                                                 const EntityContext& ctx);

}  // namespace prism::scene
