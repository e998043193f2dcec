#include "zsculpt/physics/forces.h"

#include <Eigen/Eigenvalues>
#include <cmath>

namespace zsculpt {

double angleAt(const Vec3& centre, const Vec3& a, const Vec3& b) {
  const Vec3 u = a - centre;
  const Vec3 w = b - centre;
  return std::atan2(u.cross(w).norm(), u.dot(w));
}

double radialSpringForce(const Vec3& ri, const Vec3& rj, double kappa, double restLength,
                         Vec3& forceOnI) {
  const Vec3 d = ri - rj;
  const double length = d.norm();
  if (restLength == 0.0) {
    forceOnI = -kappa * d;
    return 0.5 * kappa * length * length;
  }
  const double stretch = length - restLength;
  // At zero length the direction is undefined; the spring then pushes along no axis (the
  // energy kappa/2 lambda^2 is at a cusp there). Only reachable by a collapsed edge.
  forceOnI = length > 0.0 ? Vec3(-kappa * stretch / length * d) : Vec3::Zero();
  return 0.5 * kappa * stretch * stretch;
}

namespace {

// A unit vector perpendicular to v (deterministic).
Vec3 anyPerpendicular(const Vec3& v) {
  Eigen::Index axis = 0;
  v.cwiseAbs().minCoeff(&axis);
  return v.cross(Vec3::Unit(axis)).normalized();
}

}  // namespace

double angleSpringForce(const Vec3& centre, const Vec3& a, const Vec3& b, double kappa,
                        double restAngle, Vec3& forceOnCentre, Vec3& forceOnA, Vec3& forceOnB) {
  const Vec3 u = a - centre;
  const Vec3 w = b - centre;
  const double lu = u.norm(), lw = w.norm();
  if (kappa == 0.0 || lu == 0.0 || lw == 0.0) {
    forceOnCentre.setZero();
    forceOnA.setZero();
    forceOnB.setZero();
    return 0.0;
  }
  const Vec3 uh = u / lu, wh = w / lw;
  const double sinTheta = uh.cross(wh).norm();
  const double cosTheta = uh.dot(wh);
  const double theta = std::atan2(sinTheta, cosTheta);
  const double excess = theta - restAngle;
  // e_a: in the plane of the angle, perpendicular to u, towards w (d theta / d a = -e_a/|u|).
  Vec3 ea, eb;
  if (sinTheta > 1e-12) {
    ea = (wh - cosTheta * uh) / sinTheta;
    eb = (uh - cosTheta * wh) / sinTheta;
  } else {
    ea = anyPerpendicular(uh);
    eb = cosTheta > 0.0 ? Vec3(-ea) : ea;  // theta ~ 0: arms together; theta ~ pi: opposite
  }
  forceOnA = (kappa * excess / lu) * ea;
  forceOnB = (kappa * excess / lw) * eb;
  forceOnCentre = -(forceOnA + forceOnB);
  return 0.5 * kappa * excess * excess;
}

Vec3 torqueToForces(const Vec3& centre, std::span<const Vec3> neighbours, const Vec3& torque,
                    std::span<Vec3> forceOnNeighbours, Vec3& forceOnCentre) {
  // sum_k d_k x (lambda x d_k) = A lambda with A = sum_k (|d_k|^2 I - d_k d_k^T).
  Mat3 a = Mat3::Zero();
  for (const Vec3& n : neighbours) {
    const Vec3 d = n - centre;
    a += d.squaredNorm() * Mat3::Identity() - d * d.transpose();
  }
  // Pseudo-inverse: directions the arms cannot turn about (eigenvalue ~ 0) get nothing.
  Eigen::SelfAdjointEigenSolver<Mat3> eig(a);
  const double largest = eig.eigenvalues().cwiseAbs().maxCoeff();
  Vec3 lambda = Vec3::Zero();
  for (int k = 0; k < 3; ++k) {
    const double e = eig.eigenvalues()[k];
    if (e > 1e-12 * largest) {
      const Vec3 axis = eig.eigenvectors().col(k);
      lambda += (axis.dot(torque) / e) * axis;
    }
  }
  forceOnCentre.setZero();
  Vec3 applied = Vec3::Zero();
  for (size_t k = 0; k < neighbours.size(); ++k) {
    const Vec3 d = neighbours[k] - centre;
    forceOnNeighbours[k] = lambda.cross(d);
    forceOnCentre -= forceOnNeighbours[k];
    applied += d.cross(forceOnNeighbours[k]);
  }
  return applied;
}

PotentialEnergy accumulateInternalForces(const Model& model, const Points& position,
                                         Points& force) {
  PotentialEnergy energy;
  const Mesh& mesh = model.mesh;
  const PhysicalProperties& p = model.properties;
  for (Index e = 0; e < mesh.numEdges(); ++e) {
    const auto [i, j] = mesh.edge(e);
    const double kappa = edgeStiffness(p.stiffness[i], p.stiffness[j]);
    if (kappa == 0.0) continue;
    Vec3 fi;
    energy.radial +=
        radialSpringForce(position.row(i), position.row(j), kappa, p.restLength[e], fi);
    force.row(i) += fi.transpose();
    force.row(j) -= fi.transpose();
  }
  const auto& angles = model.angles.angles;
  for (size_t k = 0; k < angles.size(); ++k) {
    const auto [c, a, b] = angles[k];
    const double kappa = p.angularStiffness[c];
    if (kappa == 0.0) continue;
    Vec3 fc, fa, fb;
    energy.angular += angleSpringForce(position.row(c), position.row(a), position.row(b), kappa,
                                       p.restAngle[static_cast<Index>(k)], fc, fa, fb);
    force.row(c) += fc.transpose();
    force.row(a) += fa.transpose();
    force.row(b) += fb.transpose();
  }
  return energy;
}

double accumulateGravity(const PhysicalProperties& properties, const Points& position,
                         Points& force) {
  if (properties.gravity.isZero()) return 0.0;
  double energy = 0.0;
  const Eigen::RowVector3d g = properties.gravity.transpose();
  for (Index i = 0; i < position.rows(); ++i) {
    force.row(i) += properties.mass[i] * g;
    energy -= properties.mass[i] * g.dot(position.row(i));
  }
  return energy;
}

PotentialEnergy potentialEnergy(const Model& model, const Points& position) {
  PotentialEnergy energy;
  const Mesh& mesh = model.mesh;
  const PhysicalProperties& p = model.properties;
  for (Index e = 0; e < mesh.numEdges(); ++e) {
    const auto [i, j] = mesh.edge(e);
    const double kappa = edgeStiffness(p.stiffness[i], p.stiffness[j]);
    const double stretch = (position.row(i) - position.row(j)).norm() - p.restLength[e];
    energy.radial += 0.5 * kappa * stretch * stretch;
  }
  const auto& angles = model.angles.angles;
  for (size_t k = 0; k < angles.size(); ++k) {
    const auto [c, a, b] = angles[k];
    const double excess = angleAt(position.row(c), position.row(a), position.row(b)) -
                          p.restAngle[static_cast<Index>(k)];
    energy.angular += 0.5 * p.angularStiffness[c] * excess * excess;
  }
  for (Index i = 0; i < position.rows(); ++i)
    energy.gravity -= p.mass[i] * p.gravity.dot(position.row(i).transpose());
  return energy;
}

}  // namespace zsculpt
