// The pbrt-v4 scene parser (Prism's subset): runs the directives of a scene file, keeping
// pbrt-v4's graphics state (current transform, attribute stack, material, area light, media,
// ReverseOrientation, named coordinate systems, object instances), and builds a
// SceneDescription. Files it mentions (Include/Import, meshes, spectrum tables, textures) are
// named relative to the main scene file's directory, the scene root, from whichever file mentions
// them (as in pbrt-v4), normalised, and must stay inside the root;
// the parser reaches them only through SceneFiles, so the same code parses from disk
// (scene_loader.h) and from memory (tests, fuzzing).
//
// Every error is a Status whose message starts with `file:line:column: `. Nothing is silently
// dropped (scene_features.h): every feature the scene uses is recorded in
// SceneDescription::features as supported, approximated (textures without pbrt-v4's
// ray-differential filtering), ignored (cannot change the converged image: the sampler type,
// Accelerator, the film's `savefp16`, speed-only Options and integrator tuning) or refused.
// A refusal is an error naming the feature, unless LoadOptions::allow_unsupported: then its
// substitution is recorded and rendered (an unknown material becomes pbrt-v4's default diffuse,
// an unknown shape or light is dropped, a partial sphere is whole, ...).
//
// Deliberate differences from pbrt-v4:
// - Include/Import nesting deeper than kMaxIncludeDepth (16) is an error.
// - Names are resolved when their directive is read: MediumInterface, CoordSysTransform,
//   ObjectInstance and texture references must follow the definition they name. NamedMaterial
//   may precede its MakeNamedMaterial (as in pbrt-v4, which resolves material names when it
//   builds the scene); a name never defined is an error at the NamedMaterial.
// - Extensions: `objmesh` shapes (Wavefront OBJ); `float cauchy` / `float sellmeier` IORs on
//   dielectrics; a `float` where a spectrum is expected (a constant spectrum).
// - A spectrum given as a string is a file if it contains '/' or '.', else a named spectrum.
// - Refused (each by name): partial spheres, disks and cylinders, image area lights, motion
//   blur (ActiveTransform StartTime/EndTime), crop windows, non-default sensors,
//   lambdamin/lambdamax other than 360/830 nm, emissive and heterogeneous media, the measured,
//   hair and subsurface materials, textured coat indices (pbrt-v4 rejects them too), emitters
//   inside ObjectBegin, realistic cameras, Attribute, and the integrators that
//   render something other than light transport (ambientocclusion, aov, function).
// - The homogeneous medium's `g` is kept (Henyey-Greenstein, as pbrt-v4); `preset` and `Le`
//   are refused.
// - Unclosed AttributeBegin at the end is a warning (as pbrt-v4); unmatched AttributeEnd is
//   an error.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "services/scene/mesh.h"
#include "services/scene/scene_description.h"

namespace prism::scene {

struct LoadOptions {
  // Named spectra ("stdillum-F11") and named IORs ("glass-BK7", "metal-Cu-eta", also used for
  // conductor eta/k) are checked with these; unset accepts every name.
  std::function<bool(std::string_view)> is_known_spectrum;
  std::function<bool(std::string_view)> is_known_ior;
  // Limits for each mesh file and inline mesh.
  MeshLimits mesh_limits;
  std::uint64_t max_scene_file_bytes = std::uint64_t{256} << 20;  // each scene/include file
  std::uint64_t max_spectrum_file_bytes = std::uint64_t{16} << 20;
  std::uint64_t max_image_file_bytes = std::uint64_t{1} << 30;  // each texture image
  std::uint64_t max_total_triangles = 200'000'000;
  // Input that would change the image and that Prism does not render is an error naming it;
  // with this set it is recorded in SceneDescription::features with what Prism renders instead
  // (a dropped parameter or shape, a default material, ...), and loading goes on.
  bool allow_unsupported = false;
};

enum class MeshFormat { kPly, kObj };

// How the parser reads referenced files. Paths are normalised and relative to the scene root.
struct SceneFiles {
  std::function<absl::StatusOr<std::string>(const std::string& relpath, std::uint64_t max_bytes)>
      read;
  std::function<absl::StatusOr<TriangleMeshData>(const std::string& relpath, MeshFormat format,
                                                 const MeshLimits& limits)>
      load_mesh;
};

// Parses `text`, the contents of the scene file `file_relpath` (relative to the root).
absl::StatusOr<SceneDescription> parse_scene(std::string_view text, const std::string& file_relpath,
                                             const LoadOptions& options, const SceneFiles& files);

// Parses from memory. `files` maps normalised relative paths to contents (Include targets,
// meshes, spectrum tables); a reference to anything else is NOT_FOUND. `name` is the scene's
// file name in messages.
absl::StatusOr<SceneDescription> parse_scene_string(
    std::string_view text, const std::string& name, const LoadOptions& options = {},
    const std::map<std::string, std::string>& files = {});

}  // namespace prism::scene
