#pragma once
// What is under the cursor: rays through pixels, ray-surface intersection (polygons fanned
// into triangles, Moller-Trumbore), the nearest vertex to a ray (curves and point clouds),
// and the plane a dragged vertex moves in. Plain geometry, no GL: the window and the tests
// use the same functions.

#include <Eigen/Core>
#include <optional>

#include "zsculpt/core/types.h"
#include "zsculpt/render/camera.h"

namespace zsculpt::app {

struct Ray {
  Vec3 origin = Vec3::Zero();
  Vec3 direction = Vec3::UnitZ();  ///< unit length
};

/// The ray from the eye through pixel (x, y) of a width x height view (x right, y down, pixel
/// centres at +0.5), for the camera's perspective at that aspect ratio.
Ray rayThroughPixel(const render::Camera& camera, int width, int height, double x, double y);
/// Where a point projects (x right, y down, pixels); absent behind the eye.
std::optional<Eigen::Vector2d> projectToPixel(const render::Camera& camera, int width, int height,
                                              const Vec3& point);
/// Scene units per pixel at the depth of `point` (for brush radii given in pixels).
double worldPerPixel(const render::Camera& camera, int height, const Vec3& point);

struct SurfaceHit {
  Index face = -1;              ///< the polygon hit
  Vec3 point = Vec3::Zero();    ///< on the surface
  double distance = 0.0;        ///< along the ray
  Index nearestCorner = -1;     ///< the polygon's corner closest to the point
  Vec3 normal = Vec3::UnitZ();  ///< unit normal of the triangle hit (facing the ray's origin)
};

/// The first polygon of `faces` (positions: one row per vertex) the ray hits, from either
/// side. O(total corners); absent when the ray misses every face.
std::optional<SurfaceHit> pickSurface(const CsrIndex& faces, const Points& positions,
                                      const Ray& ray);

/// The vertex closest to the ray among those within `maxDistance` of it (perpendicular
/// distance), nearest to the eye on ties; -1 if none.
Index pickNearestVertex(const Points& positions, const Ray& ray, double maxDistance);

/// The vertex of `positions` nearest to `point` (O(N)); -1 for no vertices.
Index nearestVertex(const Points& positions, const Vec3& point);

/// Where the ray meets the plane through `through` facing the camera (the drag plane);
/// `through` itself when the ray runs parallel to it.
Vec3 onViewPlane(const render::Camera& camera, const Ray& ray, const Vec3& through);

}  // namespace zsculpt::app
