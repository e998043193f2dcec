#include "zsculpt/rigid/rigid_body.h"

#include <Eigen/Eigenvalues>
#include <array>
#include <cmath>
#include <utility>

#include "zsculpt/core/errors.h"

namespace zsculpt {

MassProperties massProperties(const VectorX& mass, const Points& position) {
  ZSCULPT_ASSERT(mass.size() == position.rows(), "massProperties: one mass per vertex");
  MassProperties p;
  Vec3 weighted = Vec3::Zero();
  for (Index i = 0; i < position.rows(); ++i) {
    p.mass += mass[i];
    weighted += mass[i] * position.row(i).transpose();
  }
  if (!(p.mass > 0.0)) return p;
  p.centre = weighted / p.mass;
  // Second moment S = sum m rho rho^T, then I = tr(S) 1 - S.
  Mat3 second = Mat3::Zero();
  for (Index i = 0; i < position.rows(); ++i) {
    const Vec3 rho = position.row(i).transpose() - p.centre;
    second.noalias() += mass[i] * rho * rho.transpose();
  }
  p.inertia = second.trace() * Mat3::Identity() - second;
  return p;
}

Mat3 uniformShellInertia(const Mesh& mesh, const Points& position, double totalMass,
                         Vec3* centre) {
  // Triangle (a, b, c) of area A: integral of x dA = A (a + b + c) / 3 and
  // integral of x x^T dA = A / 12 (a a^T + b b^T + c c^T + s s^T), s = a + b + c.
  double area = 0.0;
  Vec3 first = Vec3::Zero();
  Mat3 second = Mat3::Zero();
  for (Index f = 0; f < mesh.numFaces(); ++f) {
    const auto corners = mesh.face(f);
    const Vec3 a = position.row(corners[0]).transpose();
    for (size_t k = 1; k + 1 < corners.size(); ++k) {
      const Vec3 b = position.row(corners[k]).transpose();
      const Vec3 c = position.row(corners[k + 1]).transpose();
      const double t = 0.5 * (b - a).cross(c - a).norm();
      const Vec3 s = a + b + c;
      area += t;
      first += t / 3.0 * s;
      second += t / 12.0 * (a * a.transpose() + b * b.transpose() + c * c.transpose() + s * s.transpose());
    }
  }
  if (!(area > 0.0)) {
    if (centre) *centre = Vec3::Zero();
    return Mat3::Zero();
  }
  const Vec3 c = first / area;
  if (centre) *centre = c;
  // Shift the second moment to the centre, then scale by the surface density.
  const Mat3 central = (second - area * c * c.transpose()) * (totalMass / area);
  return central.trace() * Mat3::Identity() - central;
}

Vec3 angularVelocity(const Mat3& inertia, const Vec3& angularMomentum) {
  if (angularMomentum.isZero(0.0)) return Vec3::Zero();
  Eigen::SelfAdjointEigenSolver<Mat3> eig(inertia);
  const Vec3 moments = eig.eigenvalues();
  const double largest = moments.cwiseAbs().maxCoeff();
  Vec3 omega = Vec3::Zero();
  for (int k = 0; k < 3; ++k)
    if (moments[k] > 1e-12 * largest) {
      const Vec3 axis = eig.eigenvectors().col(k);
      omega += (axis.dot(angularMomentum) / moments[k]) * axis;
    }
  return omega;
}

Mat3 rotationFromVector(const Vec3& theta) {
  const double angle = theta.norm();
  if (angle == 0.0) return Mat3::Identity();
  return Eigen::AngleAxisd(angle, theta / angle).toRotationMatrix();
}

Mat3 freeRotation(const Mat3& inertia, const Vec3& angularMomentum, double dt) {
  if (angularMomentum.isZero(0.0) || dt == 0.0) return Mat3::Identity();
  Eigen::SelfAdjointEigenSolver<Mat3> eig(inertia);
  const Vec3 moments = eig.eigenvalues();  // ascending
  const double largest = moments[2];
  if (!(largest > 0.0)) return Mat3::Identity();
  if (moments[2] - moments[0] <= 1e-12 * largest) {
    // Isotropic: omega = L / I is constant and the flow is one rotation.
    return rotationFromVector(dt / moments.mean() * angularMomentum);
  }
  Mat3 axes = eig.eigenvectors();
  if (axes.determinant() < 0.0) axes.col(0) = -axes.col(0);
  Vec3 body = axes.transpose() * angularMomentum;  // L in the principal frame
  Mat3 turned = Mat3::Identity();                  // the body's rotation, principal frame
  // Symmetric composition A(dt/2) B(dt/2) C(dt) B(dt/2) A(dt/2); the axis of the largest
  // moment (slowest rotation) in the middle (see docs for the measured alternatives).
  constexpr std::array<std::pair<int, double>, 5> kSequence = {
      {{0, 0.5}, {1, 0.5}, {2, 1.0}, {1, 0.5}, {0, 0.5}}};
  for (const auto& [k, fraction] : kSequence) {
    if (!(moments[k] > 1e-12 * largest)) continue;  // no rotation about a massless axis
    // Under H_k = L_k^2 / (2 I_k) the body turns about its axis k at the constant rate
    // L_k / I_k, and the body-frame L turns the other way.
    const double angle = fraction * dt * body[k] / moments[k];
    const Mat3 q = Eigen::AngleAxisd(angle, Vec3::Unit(k)).toRotationMatrix();
    turned = turned * q;
    body = q.transpose() * body;
  }
  return axes * turned * axes.transpose();
}

void weightedResultant(std::span<const double> weight, const Points& position,
                       const Points& force, const Vec3& centre, Vec3& resultant, Vec3& torque) {
  resultant.setZero();
  torque.setZero();
  for (Index i = 0; i < position.rows(); ++i) {
    const double w = weight.empty() ? 1.0 : weight[static_cast<size_t>(i)];
    if (w == 0.0) continue;
    const Vec3 f = w * force.row(i).transpose();
    resultant += f;
    torque += (position.row(i).transpose() - centre).cross(f);
  }
}

RigidMomentum momentumOf(const VectorX& mass, const Points& position, const Points& velocity,
                         const Vec3& centre) {
  RigidMomentum m;
  for (Index i = 0; i < position.rows(); ++i) {
    const Vec3 p = mass[i] * velocity.row(i).transpose();
    m.linear += p;
    m.angular += (position.row(i).transpose() - centre).cross(p);
  }
  return m;
}

RigidDrift rigidDrift(const MassProperties& start, const RigidMomentum& momentum,
                      const Vec3& force, const Vec3& torque, double dt, double damping) {
  RigidDrift d;
  // Damping -rho v of the rigid velocity field, exact for damping proportional to mass.
  const double decay = damping != 0.0 ? std::exp(-damping * dt) : 1.0;
  d.half.linear = decay * momentum.linear + (0.5 * dt) * force;
  d.half.angular = decay * momentum.angular + (0.5 * dt) * torque;
  if (start.mass > 0.0) d.translation = (dt / start.mass) * d.half.linear;
  d.rotation = freeRotation(start.inertia, d.half.angular, dt);
  return d;
}

RigidMomentum rigidKick(const RigidMomentum& half, const Vec3& force, const Vec3& torque,
                        double dt, double damping) {
  const double decay = damping != 0.0 ? std::exp(-damping * dt) : 1.0;
  RigidMomentum m;
  m.linear = decay * (half.linear + (0.5 * dt) * force);
  m.angular = decay * (half.angular + (0.5 * dt) * torque);
  return m;
}

void applyRigidMotion(const Vec3& pivot, const Vec3& translation, const Mat3& rotation,
                      Points& position) {
  const Vec3 target = pivot + translation;
  for (Index i = 0; i < position.rows(); ++i) {
    const Vec3 rho = position.row(i).transpose() - pivot;
    position.row(i) = (target + rotation * rho).transpose();
  }
}

void addRigidVelocity(const MassProperties& properties, const RigidMomentum& momentum,
                      const Points& position, Points& velocity, double scale) {
  if (!(properties.mass > 0.0)) return;
  const Vec3 v = momentum.linear / properties.mass;
  const Vec3 omega = angularVelocity(properties.inertia, momentum.angular);
  for (Index i = 0; i < position.rows(); ++i) {
    const Vec3 rho = position.row(i).transpose() - properties.centre;
    velocity.row(i) += (scale * (v + omega.cross(rho))).transpose();
  }
}

RigidMomentum removeRigidMotion(const VectorX& mass, const MassProperties& properties,
                                const Points& position, Points& velocity) {
  const RigidMomentum m = momentumOf(mass, position, velocity, properties.centre);
  addRigidVelocity(properties, m, position, velocity, -1.0);
  // What was removed: M V and I omega (I omega = L unless the inertia is singular).
  RigidMomentum removed;
  removed.linear = m.linear;
  removed.angular = properties.inertia * angularVelocity(properties.inertia, m.angular);
  return removed;
}

}  // namespace zsculpt
