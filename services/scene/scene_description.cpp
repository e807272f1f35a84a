#include "services/scene/scene_description.h"

namespace prism::scene {

std::size_t SceneDescription::triangle_count() const {
  std::size_t n = 0;
  for (const Shape& s : shapes)
    if (const auto* mesh = std::get_if<TriangleMeshShape>(&s.geometry)) n += mesh->mesh->triangles.size();
  return n;
}

std::size_t SceneDescription::area_light_count() const {
  std::size_t n = 0;
  for (const Shape& s : shapes)
    if (s.area_light) ++n;
  return n;
}

}  // namespace prism::scene
