#include "zsculpt/rigid/rigid_body.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <utility>

#include "zsculpt/core/errors.h"
#include "zsculpt/core/parts.h"

namespace zsculpt {

namespace {

// Sum over rows [0, n) of body(begin, end, sum), which adds its rows into sum: in one loop up
// to kRigidPartRows rows, else in kRigidParts fixed parts on up to `threads` threads.
template <class Sum, class Body>
Sum sumRows(Index n, int threads, Body&& body) {
  if (n <= kRigidPartRows) {
    Sum total = Sum::Zero();
    body(Index{0}, n, total);
    return total;
  }
  return sumInParts<kRigidParts>(n, threads, 0, Sum(Sum::Zero()), body);
}

// body(begin, end) over rows [0, n), in parts on `threads` threads above kRigidPartRows
// rows (each row's result does not depend on the split).
template <class Body>
void forRows(Index n, int threads, Body&& body) {
  forEachPart<kRigidParts>(n, threads, kRigidPartRows,
                           [&](int, Index begin, Index end) { body(begin, end); });
}

}  // namespace

MassProperties massProperties(const VectorX& mass, const Points& position, int threads) {
  ZSCULPT_ASSERT(mass.size() == position.rows(), "massProperties: one mass per vertex");
  MassProperties p;
  const Index n = position.rows();
  // (total mass, sum m r)
  const Eigen::Vector4d first =
      sumRows<Eigen::Vector4d>(n, threads, [&](Index begin, Index end, Eigen::Vector4d& sum) {
        double total = sum[0];
        Vec3 weighted = sum.tail<3>();
        for (Index i = begin; i < end; ++i) {
          total += mass[i];
          weighted += mass[i] * position.row(i).transpose();
        }
        sum << total, weighted;
      });
  p.mass = first[0];
  if (!(p.mass > 0.0)) return p;
  p.centre = first.tail<3>() / p.mass;
  // Second moment S = sum m rho rho^T, then I = tr(S) 1 - S.
  const Mat3 second = sumRows<Mat3>(n, threads, [&](Index begin, Index end, Mat3& sum) {
    for (Index i = begin; i < end; ++i) {
      const Vec3 rho = position.row(i).transpose() - p.centre;
      sum.noalias() += mass[i] * rho * rho.transpose();
    }
  });
  p.inertia = second.trace() * Mat3::Identity() - second;
  return p;
}

Mat3 uniformShellInertia(const Mesh& mesh, const Points& position, double totalMass, Vec3* centre) {
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
      second += t / 12.0 *
                (a * a.transpose() + b * b.transpose() + c * c.transpose() + s * s.transpose());
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

void weightedResultant(std::span<const double> weight, const Points& position, const Points& force,
                       const Vec3& centre, Vec3& resultant, Vec3& torque, int threads) {
  using Sum = Eigen::Matrix<double, 6, 1>;  // resultant, torque
  const Sum total = sumRows<Sum>(position.rows(), threads, [&](Index begin, Index end, Sum& sum) {
    Vec3 r = sum.head<3>(), t = sum.tail<3>();
    for (Index i = begin; i < end; ++i) {
      const double w = weight.empty() ? 1.0 : weight[static_cast<size_t>(i)];
      if (w == 0.0) continue;
      const Vec3 f = w * force.row(i).transpose();
      r += f;
      t += (position.row(i).transpose() - centre).cross(f);
    }
    sum << r, t;
  });
  resultant = total.head<3>();
  torque = total.tail<3>();
}

RigidMomentum momentumOf(const VectorX& mass, const Points& position, const Points& velocity,
                         const Vec3& centre, int threads) {
  using Sum = Eigen::Matrix<double, 6, 1>;  // linear, angular
  const Sum total = sumRows<Sum>(position.rows(), threads, [&](Index begin, Index end, Sum& sum) {
    Vec3 linear = sum.head<3>(), angular = sum.tail<3>();
    for (Index i = begin; i < end; ++i) {
      const Vec3 p = mass[i] * velocity.row(i).transpose();
      linear += p;
      angular += (position.row(i).transpose() - centre).cross(p);
    }
    sum << linear, angular;
  });
  RigidMomentum m;
  m.linear = total.head<3>();
  m.angular = total.tail<3>();
  return m;
}

RigidDrift rigidDrift(const MassProperties& start, const RigidMomentum& momentum, const Vec3& force,
                      const Vec3& torque, double dt, double damping) {
  RigidDrift d;
  // Damping -rho v of the rigid velocity field, exact for damping proportional to mass.
  const double decay = damping != 0.0 ? std::exp(-damping * dt) : 1.0;
  d.half.linear = decay * momentum.linear + (0.5 * dt) * force;
  d.half.angular = decay * momentum.angular + (0.5 * dt) * torque;
  if (start.mass > 0.0) d.translation = (dt / start.mass) * d.half.linear;
  d.rotation = freeRotation(start.inertia, d.half.angular, dt);
  return d;
}

RigidMomentum rigidKick(const RigidMomentum& half, const Vec3& force, const Vec3& torque, double dt,
                        double damping) {
  const double decay = damping != 0.0 ? std::exp(-damping * dt) : 1.0;
  RigidMomentum m;
  m.linear = decay * (half.linear + (0.5 * dt) * force);
  m.angular = decay * (half.angular + (0.5 * dt) * torque);
  return m;
}

void applyRigidMotion(const Vec3& pivot, const Vec3& translation, const Mat3& rotation,
                      Points& position, int threads) {
  const Vec3 target = pivot + translation;
  forRows(position.rows(), threads, [&](Index begin, Index end) {
    for (Index i = begin; i < end; ++i) {
      const Vec3 rho = position.row(i).transpose() - pivot;
      position.row(i) = (target + rotation * rho).transpose();
    }
  });
}

void addRigidVelocity(const MassProperties& properties, const RigidMomentum& momentum,
                      const Points& position, Points& velocity, double scale, int threads) {
  if (!(properties.mass > 0.0)) return;
  const Vec3 v = momentum.linear / properties.mass;
  const Vec3 omega = angularVelocity(properties.inertia, momentum.angular);
  forRows(position.rows(), threads, [&](Index begin, Index end) {
    for (Index i = begin; i < end; ++i) {
      const Vec3 rho = position.row(i).transpose() - properties.centre;
      velocity.row(i) += (scale * (v + omega.cross(rho))).transpose();
    }
  });
}

RigidMomentum removeRigidMotion(const VectorX& mass, const MassProperties& properties,
                                const Points& position, Points& velocity, int threads) {
  const RigidMomentum m = momentumOf(mass, position, velocity, properties.centre, threads);
  addRigidVelocity(properties, m, position, velocity, -1.0, threads);
  // What was removed: M V and I omega (I omega = L unless the inertia is singular).
  RigidMomentum removed;
  removed.linear = m.linear;
  removed.angular = properties.inertia * angularVelocity(properties.inertia, m.angular);
  return removed;
}

}  // namespace zsculpt
