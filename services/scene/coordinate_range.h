// The coordinates a scene may reach. Embree takes rays whose origin and direction components are
// at most about 1.8e18 in magnitude (its FLT_LARGE) and aborts the process on any other, and it
// traces a ray through a shape's transform in the shape's own space: a shape placed at 1e30, or
// scaled by 1e-30 (which maps a camera 5 units away to 5e30 of object space), would bring down the
// renderer at the first ray near it. check_coordinate_range refuses such a scene when it is
// loaded, naming the shape, camera or light, with a margin of two orders of magnitude for the
// hit points and offsets that rays start from.
#pragma once

#include "absl/status/status.h"
#include "services/scene/scene_description.h"

namespace prism::scene {

inline constexpr double kMaxSceneCoordinate = 1e16;

// INVALID_ARGUMENT, at the offending directive's file:line:column, when a shape's world-space
// bounds, the camera's position or a point or spot light's position exceed kMaxSceneCoordinate
// in magnitude (or are not finite), or when a shape's transform maps the scene's world-space
// bounding box (shapes, camera and lights) beyond it in the shape's object space.
absl::Status check_coordinate_range(const SceneDescription& scene);

}  // namespace prism::scene
