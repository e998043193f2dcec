#include "zsculpt/app/picking.h"

#include <Eigen/LU>
#include <cmath>
#include <limits>

namespace zsculpt::app {

Ray rayThroughPixel(const render::Camera& camera, int width, int height, double x, double y) {
  const double aspect = static_cast<double>(width) / std::max(height, 1);
  const Eigen::Matrix4d inverse = (camera.projectionMatrix(aspect) * camera.viewMatrix()).inverse();
  const double nx = 2.0 * x / width - 1.0;
  const double ny = 1.0 - 2.0 * y / height;
  auto unproject = [&](double z) {
    const Eigen::Vector4d p = inverse * Eigen::Vector4d(nx, ny, z, 1.0);
    return Vec3(p.head<3>() / p.w());
  };
  const Vec3 nearPoint = unproject(-1.0);
  const Vec3 farPoint = unproject(1.0);
  Ray ray;
  ray.origin = camera.eye();
  ray.direction = (farPoint - nearPoint).normalized();
  return ray;
}

std::optional<Eigen::Vector2d> projectToPixel(const render::Camera& camera, int width, int height,
                                              const Vec3& point) {
  const double aspect = static_cast<double>(width) / std::max(height, 1);
  const Eigen::Vector4d clip = camera.projectionMatrix(aspect) * camera.viewMatrix() *
                               Eigen::Vector4d(point.x(), point.y(), point.z(), 1.0);
  if (!(clip.w() > 0.0)) return std::nullopt;
  const double nx = clip.x() / clip.w();
  const double ny = clip.y() / clip.w();
  return Eigen::Vector2d(0.5 * (nx + 1.0) * width, 0.5 * (1.0 - ny) * height);
}

double worldPerPixel(const render::Camera& camera, int height, const Vec3& point) {
  const Vec3 forward = (camera.target - camera.eye()).normalized();
  const double depth = std::max((point - camera.eye()).dot(forward), 1e-9 * camera.distance);
  const double halfHeight = depth * std::tan(0.5 * camera.fovYDegrees * M_PI / 180.0);
  return 2.0 * halfHeight / std::max(height, 1);
}

std::optional<SurfaceHit> pickSurface(const CsrIndex& faces, const Points& positions,
                                      const Ray& ray) {
  std::optional<SurfaceHit> best;
  const Vec3& o = ray.origin;
  const Vec3& d = ray.direction;
  for (Index f = 0; f < faces.rows(); ++f) {
    const auto corners = faces.row(f);
    if (corners.size() < 3) continue;
    const Vec3 a = positions.row(corners[0]).transpose();
    for (size_t k = 1; k + 1 < corners.size(); ++k) {
      // Moller-Trumbore, both sides.
      const Vec3 b = positions.row(corners[k]).transpose();
      const Vec3 c = positions.row(corners[k + 1]).transpose();
      const Vec3 e1 = b - a, e2 = c - a;
      const Vec3 p = d.cross(e2);
      const double det = e1.dot(p);
      if (std::abs(det) < 1e-300) continue;
      const double inv = 1.0 / det;
      const Vec3 s = o - a;
      const double u = s.dot(p) * inv;
      if (u < 0.0 || u > 1.0) continue;
      const Vec3 q = s.cross(e1);
      const double v = d.dot(q) * inv;
      if (v < 0.0 || u + v > 1.0) continue;
      const double t = e2.dot(q) * inv;
      if (t <= 0.0 || (best && t >= best->distance)) continue;
      Vec3 normal = e1.cross(e2).normalized();
      if (normal.dot(d) > 0.0) normal = -normal;
      best = SurfaceHit{f, o + t * d, t, -1, normal};
    }
  }
  if (best) {
    double nearest = std::numeric_limits<double>::infinity();
    for (Index v : faces.row(best->face)) {
      const double dist = (positions.row(v).transpose() - best->point).squaredNorm();
      if (dist < nearest) {
        nearest = dist;
        best->nearestCorner = v;
      }
    }
  }
  return best;
}

Index pickNearestVertex(const Points& positions, const Ray& ray, double maxDistance) {
  Index best = -1;
  double bestPerpendicular = maxDistance;
  double bestAlong = std::numeric_limits<double>::infinity();
  for (Index i = 0; i < positions.rows(); ++i) {
    const Vec3 r = positions.row(i).transpose() - ray.origin;
    const double along = r.dot(ray.direction);
    if (along <= 0.0) continue;
    const double perpendicular = (r - along * ray.direction).norm();
    if (perpendicular < bestPerpendicular ||
        (perpendicular == bestPerpendicular && best >= 0 && along < bestAlong)) {
      best = i;
      bestPerpendicular = perpendicular;
      bestAlong = along;
    }
  }
  return best;
}

Index nearestVertex(const Points& positions, const Vec3& point) {
  Index best = -1;
  double bestDistance = std::numeric_limits<double>::infinity();
  for (Index i = 0; i < positions.rows(); ++i) {
    const double d = (positions.row(i).transpose() - point).squaredNorm();
    if (d < bestDistance) {
      bestDistance = d;
      best = i;
    }
  }
  return best;
}

Vec3 onViewPlane(const render::Camera& camera, const Ray& ray, const Vec3& through) {
  const Vec3 normal = (camera.target - camera.eye()).normalized();
  const double denominator = ray.direction.dot(normal);
  if (std::abs(denominator) < 1e-12) return through;
  const double t = (through - ray.origin).dot(normal) / denominator;
  return ray.origin + t * ray.direction;
}

}  // namespace zsculpt::app
