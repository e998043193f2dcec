#pragma once
// Orbit (turntable) camera: plain values, so a view can be saved and restored as JSON.
// World z is up (the built-in torus has its axis along z and the grid lies in z = 0).

#include <Eigen/Core>
#include <nlohmann/json_fwd.hpp>

#include "zsculpt/core/types.h"
#include "zsculpt/mesh/mesh.h"

namespace zsculpt::render {

struct Camera {
  Vec3 target = Vec3::Zero();  ///< the point orbited and looked at
  double distance = 6.0;       ///< eye to target
  double yawDegrees = -55.0;   ///< azimuth about +z, from +x
  double pitchDegrees = 30.0;  ///< elevation above the xy plane, within (-90, 90)
  double fovYDegrees = 35.0;   ///< vertical field of view

  [[nodiscard]] Vec3 eye() const;
  /// World to view (right-handed, looking down -z).
  [[nodiscard]] Eigen::Matrix4d viewMatrix() const;
  /// Perspective projection with near and far planes proportional to `distance`.
  [[nodiscard]] Eigen::Matrix4d projectionMatrix(double aspect) const;

  /// Keeps the orientation, places the target at the centre of the points' box and sets
  /// the distance so that every point is in view at this aspect ratio (width / height);
  /// `margin` > 1 leaves room around the model (and its glyphs).
  void frame(const Points& points, double aspect, double margin = 1.2);
  /// The distance at which every point is in view from this target and orientation (at
  /// this aspect ratio and margin), the distance frame() sets for the box's centre.
  [[nodiscard]] double distanceToFit(const Points& points, double aspect,
                                     double margin = 1.2) const;
  /// The same for the eight corners of a box (looser for round models).
  void frame(const BoundingBox& box, double aspect, double margin = 1.2);
  /// Turntable rotation; pitch is clamped to +-89 degrees.
  void orbit(double deltaYawDegrees, double deltaPitchDegrees);
  /// Multiplies the distance (factor > 0), kept within [kNearest, kFarthest]: a wheel turned
  /// long enough reached 0 or infinity, which a saved scene cannot hold.
  void zoom(double factor);
  /// Moves the target in the view plane by fractions of the view height at the target; a
  /// move that would take a coordinate beyond kFarthest is not made.
  void pan(double dxFraction, double dyFraction);

  static constexpr double kNearest = 1e-9;
  static constexpr double kFarthest = 1e15;

  /// Pixel position (x right, y down, origin top left) of a world point in a width x height
  /// view; false when the point is behind the eye.
  bool project(const Vec3& point, int width, int height, Eigen::Vector2d& pixel) const;
  /// The ray from the eye through pixel (x, y) (e.g. the mouse, for the brush): unit
  /// `direction`.
  void ray(double x, double y, int width, int height, Vec3& origin, Vec3& direction) const;

  friend bool operator==(const Camera&, const Camera&) = default;
};

/// {"target": [x, y, z], "distance": d, "yaw": deg, "pitch": deg, "fov": deg}
void to_json(nlohmann::json& j, const Camera& camera);
/// Missing fields keep their defaults; throws InvalidInputError for a non-positive distance
/// or fov, or a pitch outside (-90, 90).
void from_json(const nlohmann::json& j, Camera& camera);

}  // namespace zsculpt::render
