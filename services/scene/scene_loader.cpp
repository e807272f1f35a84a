#include "services/scene/scene_loader.h"

#include <system_error>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/status.h"
#include "services/scene/mesh_obj.h"
#include "services/scene/mesh_ply.h"
#include "services/scene/path_guard.h"

namespace prism::scene {

namespace fs = std::filesystem;

absl::StatusOr<LoadedScene> load_scene(const fs::path& scene_file, const LoadOptions& options) {
  std::error_code ec;
  if (!fs::exists(scene_file, ec))
    return absl::NotFoundError(
        absl::StrCat("scene file \"", scene_file.string(), "\" does not exist"));
  if (fs::is_directory(scene_file, ec))
    return absl::InvalidArgumentError(
        absl::StrCat("scene file \"", scene_file.string(), "\" is a directory; name a .pbrt file"));
  if (!fs::is_regular_file(scene_file, ec))
    return absl::InvalidArgumentError(
        absl::StrCat("scene file \"", scene_file.string(),
                     "\" is not a regular file (a device, pipe or socket)"));
  fs::path dir = scene_file.parent_path();
  if (dir.empty()) dir = ".";
  PRISM_ASSIGN_OR_RETURN(PathGuard guard, PathGuard::create(dir));
  std::string scene_relpath = scene_file.filename().string();
  PRISM_ASSIGN_OR_RETURN(fs::path real_scene, guard.resolve(scene_relpath));

  // Resolves a normalised reference; a missing file gets a message that names it plainly.
  auto real_path = [&guard](const std::string& relpath) -> absl::StatusOr<fs::path> {
    absl::StatusOr<fs::path> p = guard.resolve(relpath);
    if (!p.ok() && absl::IsNotFound(p.status()))
      return absl::NotFoundError(absl::StrCat("file \"", relpath, "\" does not exist"));
    return p;
  };
  SceneFiles files;
  files.read = [real_path](const std::string& relpath,
                           std::uint64_t max_bytes) -> absl::StatusOr<std::string> {
    PRISM_ASSIGN_OR_RETURN(fs::path p, real_path(relpath));
    return base::read_file(p, max_bytes);
  };
  files.load_mesh = [real_path](const std::string& relpath, MeshFormat format,
                                const MeshLimits& limits) -> absl::StatusOr<TriangleMeshData> {
    PRISM_ASSIGN_OR_RETURN(fs::path p, real_path(relpath));
    return format == MeshFormat::kPly ? load_ply(p, limits) : load_obj(p, limits);
  };

  PRISM_ASSIGN_OR_RETURN(std::string text,
                         base::read_file(real_scene, options.max_scene_file_bytes));
  PRISM_ASSIGN_OR_RETURN(SceneDescription description,
                         parse_scene(text, scene_relpath, options, files));
  return LoadedScene{std::move(description), guard.root(), scene_relpath};
}

}  // namespace prism::scene
