#include "zsculpt/render/camera.h"

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <numbers>

#include "zsculpt/core/errors.h"

namespace zsculpt::render {
namespace {

constexpr double kDegrees = std::numbers::pi / 180.0;
// Near and far planes as fractions of the eye distance: the framed model lies well within
// (0.02, 20) distances, and a 24-bit depth buffer resolves 1e3 to 1 comfortably.
constexpr double kNear = 0.02;
constexpr double kFar = 20.0;

}  // namespace

Vec3 Camera::eye() const {
  const double yaw = yawDegrees * kDegrees;
  const double pitch = pitchDegrees * kDegrees;
  return target + distance * Vec3(std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw),
                                  std::sin(pitch));
}

Eigen::Matrix4d Camera::viewMatrix() const {
  const Vec3 e = eye();
  const Vec3 forward = (target - e).normalized();
  Vec3 right = forward.cross(Vec3::UnitZ());
  if (right.norm() < 1e-12) right = Vec3::UnitX();  // looking straight along z
  right.normalize();
  const Vec3 up = right.cross(forward);
  Eigen::Matrix4d view = Eigen::Matrix4d::Identity();
  view.block<1, 3>(0, 0) = right.transpose();
  view.block<1, 3>(1, 0) = up.transpose();
  view.block<1, 3>(2, 0) = -forward.transpose();
  view(0, 3) = -right.dot(e);
  view(1, 3) = -up.dot(e);
  view(2, 3) = forward.dot(e);
  return view;
}

Eigen::Matrix4d Camera::projectionMatrix(double aspect) const {
  const double n = kNear * distance;
  const double f = kFar * distance;
  const double t = 1.0 / std::tan(0.5 * fovYDegrees * kDegrees);
  Eigen::Matrix4d p = Eigen::Matrix4d::Zero();
  p(0, 0) = t / aspect;
  p(1, 1) = t;
  p(2, 2) = -(f + n) / (f - n);
  p(2, 3) = -2.0 * f * n / (f - n);
  p(3, 2) = -1.0;
  return p;
}

void Camera::frame(const Points& points, double aspect, double margin) {
  if (points.rows() == 0) return;
  const Vec3 lo = points.colwise().minCoeff().transpose();
  const Vec3 hi = points.colwise().maxCoeff().transpose();
  target = 0.5 * (lo + hi);
  distance = distanceToFit(points, aspect, margin);
}

double Camera::distanceToFit(const Points& points, double aspect, double margin) const {
  if (points.rows() == 0) return distance;
  const double tanY = std::tan(0.5 * fovYDegrees * kDegrees);
  const double tanX = tanY * aspect;
  // The smallest distance at which every point projects inside the view for this
  // orientation: a point at view coordinates (x, y, z) relative to the target (z towards
  // the eye) needs |x| <= (d - z) tan(halfX), and likewise for y. (The rotation does not
  // depend on the distance.)
  const Eigen::Matrix3d rotation = viewMatrix().block<3, 3>(0, 0);
  const Vec3 lo = points.colwise().minCoeff().transpose();
  const Vec3 hi = points.colwise().maxCoeff().transpose();
  double needed = 1e-9 * std::max(1.0, (hi - lo).norm());
  for (Index i = 0; i < points.rows(); ++i) {
    const Vec3 q = rotation * (points.row(i).transpose() - target);
    needed = std::max({needed, std::abs(q.x()) / tanX + q.z(), std::abs(q.y()) / tanY + q.z()});
  }
  // Apparent size goes as 1 / distance: the margin shrinks the model by about 1 / margin.
  return margin * needed;
}

void Camera::frame(const BoundingBox& box, double aspect, double margin) {
  Points corners(8, 3);
  for (int c = 0; c < 8; ++c) {
    corners.row(c) << ((c & 1) ? box.max.x() : box.min.x()), ((c & 2) ? box.max.y() : box.min.y()),
        ((c & 4) ? box.max.z() : box.min.z());
  }
  frame(corners, aspect, margin);
}

void Camera::orbit(double deltaYawDegrees, double deltaPitchDegrees) {
  yawDegrees = std::fmod(yawDegrees + deltaYawDegrees, 360.0);
  pitchDegrees = std::clamp(pitchDegrees + deltaPitchDegrees, -89.0, 89.0);
}

void Camera::zoom(double factor) {
  if (factor > 0.0 && std::isfinite(factor))
    distance =
        std::clamp(distance * factor, std::min(kNearest, distance), std::max(kFarthest, distance));
}

void Camera::pan(double dxFraction, double dyFraction) {
  const Eigen::Matrix4d view = viewMatrix();
  const Vec3 right = view.block<1, 3>(0, 0).transpose();
  const Vec3 up = view.block<1, 3>(1, 0).transpose();
  const double height = 2.0 * distance * std::tan(0.5 * fovYDegrees * kDegrees);
  const Vec3 moved = target + height * (dxFraction * right + dyFraction * up);
  // As zoom: a target already beyond kFarthest (a scene may hold one) may still come back.
  const double limit = std::max(kFarthest, target.cwiseAbs().maxCoeff());
  if (moved.allFinite() && moved.cwiseAbs().maxCoeff() <= limit) target = moved;
}

bool Camera::project(const Vec3& point, int width, int height, Eigen::Vector2d& pixel) const {
  const Eigen::Vector4d clip =
      projectionMatrix(static_cast<double>(width) / height) * (viewMatrix() * point.homogeneous());
  if (!(clip.w() > 0.0)) return false;
  pixel = Eigen::Vector2d((clip.x() / clip.w() * 0.5 + 0.5) * width,
                          (0.5 - clip.y() / clip.w() * 0.5) * height);
  return true;
}

void Camera::ray(double x, double y, int width, int height, Vec3& origin, Vec3& direction) const {
  const double tanY = std::tan(0.5 * fovYDegrees * kDegrees);
  const double aspect = static_cast<double>(width) / height;
  const double ndcX = 2.0 * x / width - 1.0;
  const double ndcY = 1.0 - 2.0 * y / height;
  const Eigen::Matrix4d view = viewMatrix();
  const Eigen::Matrix3d toWorld = view.block<3, 3>(0, 0).transpose();
  origin = eye();
  direction = (toWorld * Vec3(ndcX * tanY * aspect, ndcY * tanY, -1.0)).normalized();
}

void to_json(nlohmann::json& j, const Camera& camera) {
  j = nlohmann::json{{"target", {camera.target.x(), camera.target.y(), camera.target.z()}},
                     {"distance", camera.distance},
                     {"yaw", camera.yawDegrees},
                     {"pitch", camera.pitchDegrees},
                     {"fov", camera.fovYDegrees}};
}

void from_json(const nlohmann::json& j, Camera& camera) {
  Camera c = camera;
  try {
    if (j.contains("target")) {
      const auto& t = j.at("target");
      if (!t.is_array() || t.size() != 3) throw InvalidInputError("camera target: need [x, y, z]");
      c.target = Vec3(t[0].get<double>(), t[1].get<double>(), t[2].get<double>());
    }
    if (j.contains("distance")) c.distance = j.at("distance").get<double>();
    if (j.contains("yaw")) c.yawDegrees = j.at("yaw").get<double>();
    if (j.contains("pitch")) c.pitchDegrees = j.at("pitch").get<double>();
    if (j.contains("fov")) c.fovYDegrees = j.at("fov").get<double>();
  } catch (const nlohmann::json::exception& e) {
    throw InvalidInputError(std::string("camera: ") + e.what());
  }
  if (!c.target.allFinite()) throw InvalidInputError("camera target: must be finite");
  if (!(c.distance > 0.0) || !std::isfinite(c.distance)) {
    throw InvalidInputError("camera distance: must be positive");
  }
  if (!(c.pitchDegrees > -90.0 && c.pitchDegrees < 90.0)) {
    throw InvalidInputError("camera pitch: must be within (-90, 90) degrees");
  }
  if (!(c.fovYDegrees > 0.0 && c.fovYDegrees < 180.0)) {
    throw InvalidInputError("camera fov: must be within (0, 180) degrees");
  }
  if (!std::isfinite(c.yawDegrees)) throw InvalidInputError("camera yaw: must be finite");
  camera = c;
}

}  // namespace zsculpt::render
