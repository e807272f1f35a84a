// Clarberg's (2008) octahedral equal-area map between the unit square and the unit sphere, as
// pbrt-v4 uses it for its spherical camera and its environment maps: the square folds onto the
// octahedron, each diamond |u| + |v| = r about the centre onto the circle of latitude with
// z = ±(1 − r²), and the position along a diamond's edge onto φ linearly. Area is preserved:
// a unit of square area covers 4π sr. The centre is +z, the corners −z.
#pragma once

#include "worker/vecmath.h"

namespace prism::worker {

Vec3f equal_area_square_to_sphere(Point2f p);
// The inverse, for unit d.
Point2f equal_area_sphere_to_square(const Vec3f& d);

}  // namespace prism::worker
