// Rigid module: mass properties (lumped and continuous thin shell), the free rigid body
// rotation, Newton-Euler kicks and the Tisserand split (paper section 4.3).

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/rigid/rigid_body.h"

using namespace zsculpt;

namespace {

Mat3 randomRotation(unsigned seed) {
  std::srand(seed);
  const Vec3 axis = Vec3::Random().normalized();
  return Eigen::AngleAxisd(2.0 + seed, axis).toRotationMatrix();
}

// Reference for the torque-free body: RK4 on Euler's equations in the body frame,
// I dw/dt = (I w) x w, with the orientation R' = R [w]x, at a much smaller step.
Mat3 referenceRotation(const Vec3& moments, const Vec3& omegaBody, double time, int steps) {
  Vec3 w = omegaBody;
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
  const double h = time / steps;
  auto rate = [&](const Vec3& x) {
    return Vec3(moments.cwiseProduct(x).cross(x).cwiseQuotient(moments));
  };
  auto qrate = [&](const Eigen::Quaterniond& quat, const Vec3& x) {
    const Eigen::Quaterniond p(0.0, x.x(), x.y(), x.z());
    Eigen::Quaterniond out = quat * p;
    out.coeffs() *= 0.5;
    return out;
  };
  for (int k = 0; k < steps; ++k) {
    const Vec3 k1 = rate(w);
    const Eigen::Quaterniond q1 = qrate(q, w);
    const Vec3 w2 = w + 0.5 * h * k1;
    Eigen::Quaterniond qa;
    qa.coeffs() = q.coeffs() + 0.5 * h * q1.coeffs();
    const Vec3 k2 = rate(w2);
    const Eigen::Quaterniond q2 = qrate(qa, w2);
    const Vec3 w3 = w + 0.5 * h * k2;
    Eigen::Quaterniond qb;
    qb.coeffs() = q.coeffs() + 0.5 * h * q2.coeffs();
    const Vec3 k3 = rate(w3);
    const Eigen::Quaterniond q3 = qrate(qb, w3);
    const Vec3 w4 = w + h * k3;
    Eigen::Quaterniond qc;
    qc.coeffs() = q.coeffs() + h * q3.coeffs();
    const Vec3 k4 = rate(w4);
    const Eigen::Quaterniond q4 = qrate(qc, w4);
    w += h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4);
    q.coeffs() += h / 6.0 * (q1.coeffs() + 2 * q2.coeffs() + 2 * q3.coeffs() + q4.coeffs());
    q.normalize();
  }
  return q.toRotationMatrix();
}

}  // namespace

TEST(MassProperties, LumpedInertiaOfKnownConfigurations) {
  // Two masses on the x axis: no moment about x, m d^2 / 2 about y and z.
  Points p(2, 3);
  p << -1, 0, 0, 1, 0, 0;
  VectorX m(2);
  m << 2.0, 2.0;
  const MassProperties a = massProperties(m, p);
  EXPECT_DOUBLE_EQ(a.mass, 4.0);
  EXPECT_TRUE(a.centre.isZero(0.0));
  EXPECT_NEAR((a.inertia - Vec3(0, 4, 4).asDiagonal().toDenseMatrix()).norm(), 0.0, 1e-15);
  // The dodecahedron's vertices lie on a sphere of radius R: isotropic, 2/3 M R^2, the
  // thin spherical shell's value.
  const Mesh d = makeDodecahedron();
  const VectorX dm = VectorX::Constant(20, 0.5);
  const MassProperties b = massProperties(dm, d.positions());
  const double r = d.positions().row(0).norm();
  EXPECT_NEAR((b.inertia - (2.0 / 3.0 * 10.0 * r * r) * Mat3::Identity()).norm(), 0.0, 1e-12);
  // Covariant: rotating and moving the points rotates the tensor.
  const Mat3 rot = randomRotation(3);
  Points moved = d.positions();
  for (Index i = 0; i < moved.rows(); ++i)
    moved.row(i) = (rot * moved.row(i).transpose() + Vec3(1, 2, 3)).transpose();
  const MassProperties c = massProperties(dm, moved);
  EXPECT_NEAR((c.centre - Vec3(1, 2, 3)).norm(), 0.0, 1e-14);
  EXPECT_NEAR((c.inertia - rot * b.inertia * rot.transpose()).norm(), 0.0, 1e-12);
}

TEST(MassProperties, UniformShellOfACube) {
  // A thin cubic shell of side a and mass M: I = 5/18 M a^2 about every axis.
  const Mesh cube = makeLattice(2);
  Vec3 centre;
  const Mat3 shell = uniformShellInertia(cube, cube.positions(), 6.0, &centre);
  EXPECT_NEAR((centre - Vec3(0.5, 0.5, 0.5)).norm(), 0.0, 1e-15);
  EXPECT_NEAR((shell - 5.0 / 18.0 * 6.0 * Mat3::Identity()).norm(), 0.0, 1e-14);
  // The lumped shell of the same mass (corners only) is stiffer in rotation: M a^2 / 2.
  const MassProperties lumped = massProperties(VectorX::Constant(8, 0.75), cube.positions());
  EXPECT_NEAR(lumped.inertia(0, 0), 0.5 * 6.0, 1e-14);
  EXPECT_TRUE(uniformShellInertia(makeHelix(8), makeHelix(8).positions(), 1.0).isZero(0.0));
}

TEST(AngularVelocity, PseudoInverseForARod) {
  Points p(3, 3);
  p << 0, 0, -1, 0, 0, 0, 0, 0, 1;
  const MassProperties rod = massProperties(VectorX::Ones(3), p);
  // No moment about the rod's axis: that component of L carries no rotation.
  const Vec3 omega = angularVelocity(rod.inertia, Vec3(1.0, 2.0, 5.0));
  EXPECT_NEAR((omega - Vec3(0.5, 1.0, 0.0)).norm(), 0.0, 1e-15);
}

TEST(FreeRotation, IsotropicBodyTurnsAboutL) {
  const Vec3 l(0.3, -0.4, 1.2);
  const Mat3 r = freeRotation(2.0 * Mat3::Identity(), l, 0.7);
  const Mat3 expected = Eigen::AngleAxisd(0.7 * l.norm() / 2.0, l.normalized()).toRotationMatrix();
  EXPECT_NEAR((r - expected).norm(), 0.0, 1e-15);
}

TEST(FreeRotation, KeepsLAndEnergyAndConvergesAtSecondOrder) {
  // An asymmetric top spinning near its unstable middle axis, in a tilted frame.
  const Vec3 moments(1.0, 2.0, 3.5);
  const Mat3 frame = randomRotation(5);
  const Vec3 omegaBody(0.2, 1.5, 0.3);
  const double time = 3.0;
  const Mat3 reference = referenceRotation(moments, omegaBody, time, 30000);
  const Mat3 world0 = frame * moments.asDiagonal() * frame.transpose();
  const Vec3 l = frame * moments.cwiseProduct(omegaBody);
  auto integrate = [&](int steps, double* energyError) {
    Mat3 orientation = Mat3::Identity();
    const double e0 = 0.5 * l.dot(world0.inverse() * l);
    *energyError = 0.0;
    for (int k = 0; k < steps; ++k) {
      const Mat3 inertia = orientation * world0 * orientation.transpose();
      const Mat3 turn = freeRotation(inertia, l, time / steps);
      orientation = turn * orientation;
      const Mat3 after = orientation * world0 * orientation.transpose();
      *energyError = std::max(*energyError, std::abs(0.5 * l.dot(after.inverse() * l) - e0) / e0);
      // World L is untouched and the turn is a rotation.
      EXPECT_NEAR((turn * turn.transpose() - Mat3::Identity()).norm(), 0.0, 1e-14);
    }
    return orientation;
  };
  double energyCoarse = 0.0, energyFine = 0.0;
  const Mat3 coarse = integrate(300, &energyCoarse);
  const Mat3 fine = integrate(600, &energyFine);
  // Compare in the world frame: the reference body turns R_b in its own frame.
  const Mat3 expected = frame * reference * frame.transpose();
  const double errorCoarse = (coarse - expected).norm();
  const double errorFine = (fine - expected).norm();
  EXPECT_LT(errorCoarse, 1e-2);
  EXPECT_NEAR(errorCoarse / errorFine, 4.0, 0.6);
  EXPECT_LT(energyCoarse, 1e-3);
  EXPECT_LT(energyFine, energyCoarse);
}

TEST(RigidKicks, ConstantForceGivesTheExactParabola) {
  MassProperties body;
  body.mass = 2.0;
  body.inertia = Mat3::Identity();
  RigidMomentum m;
  m.linear = Vec3(1, 0, 0);
  const Vec3 force(0, 0, -4);
  Vec3 position = Vec3::Zero();
  const double dt = 0.1;
  for (int k = 0; k < 10; ++k) {
    const RigidDrift d = rigidDrift(body, m, force, Vec3::Zero(), dt, 0.0);
    position += d.translation;
    m = rigidKick(d.half, force, Vec3::Zero(), dt, 0.0);
  }
  EXPECT_NEAR((position - Vec3(0.5, 0.0, -1.0)).norm(), 0.0, 1e-14);  // v0 t + F t^2 / 2M
  EXPECT_NEAR((m.linear - Vec3(1, 0, -4)).norm(), 0.0, 1e-14);
  // Damping: exponential decay of the momenta, exp(-2 gamma t).
  RigidMomentum damped;
  damped.linear = Vec3(1, 2, 3);
  damped.angular = Vec3(0, 0, 1);
  for (int k = 0; k < 10; ++k)
    damped = rigidKick(rigidDrift(body, damped, Vec3::Zero(), Vec3::Zero(), dt, 0.5).half,
                       Vec3::Zero(), Vec3::Zero(), dt, 0.5);
  EXPECT_NEAR((damped.linear - std::exp(-1.0) * Vec3(1, 2, 3)).norm(), 0.0, 1e-14);
  EXPECT_NEAR((damped.angular - std::exp(-1.0) * Vec3(0, 0, 1)).norm(), 0.0, 1e-15);
}

TEST(TisserandSplit, LeavesNoMomentumAndSplitsEnergy) {
  const Mesh torus = makeTorus(6, 4);
  const VectorX m = VectorX::LinSpaced(torus.numVertices(), 0.2, 1.0);
  Points v;
  randomVelocity(m, 0.3, 9, v);
  Points spin;
  spinVelocity(m, torus.positions(), Vec3(0.5, -1.0, 2.0), spin);
  v += spin + Points::Constant(v.rows(), 3, 0.4);
  const MassProperties props = massProperties(m, torus.positions());
  const RigidMomentum before = momentumOf(m, torus.positions(), v, props.centre);
  Points rest = v;
  const RigidMomentum removed = removeRigidMotion(m, props, torus.positions(), rest);
  const RigidMomentum left = momentumOf(m, torus.positions(), rest, props.centre);
  EXPECT_LT(left.linear.norm(), 1e-13);
  EXPECT_LT(left.angular.norm(), 1e-13);
  EXPECT_NEAR((removed.linear - before.linear).norm(), 0.0, 1e-13);
  EXPECT_NEAR((removed.angular - before.angular).norm(), 0.0, 1e-13);
  // Kinetic energy: rigid part (P^2 / 2M + L . omega / 2) plus what is left.
  auto kinetic = [&](const Points& x) {
    double e = 0.0;
    for (Index i = 0; i < x.rows(); ++i) e += 0.5 * m[i] * x.row(i).squaredNorm();
    return e;
  };
  const double rigid = removed.linear.squaredNorm() / (2.0 * props.mass) +
                       0.5 * removed.angular.dot(angularVelocity(props.inertia, removed.angular));
  EXPECT_NEAR(kinetic(v), rigid + kinetic(rest), 1e-12 * kinetic(v));
  // Adding the rigid velocity back restores the field.
  addRigidVelocity(props, removed, torus.positions(), rest);
  EXPECT_LT((rest - v).cwiseAbs().maxCoeff(), 1e-13);
}

TEST(Resultant, WeightedForceAndTorque) {
  Points p(2, 3), f(2, 3);
  p << 1, 0, 0, -1, 0, 0;
  f << 0, 1, 0, 0, 1, 0;
  Vec3 force, torque;
  const std::vector<double> w = {1.0, 0.25};
  weightedResultant(w, p, f, Vec3::Zero(), force, torque);
  EXPECT_NEAR((force - Vec3(0, 1.25, 0)).norm(), 0.0, 1e-15);
  EXPECT_NEAR((torque - Vec3(0, 0, 0.75)).norm(), 0.0, 1e-15);
  weightedResultant({}, p, f, Vec3::Zero(), force, torque);
  EXPECT_NEAR(torque.norm(), 0.0, 1e-15);
}

TEST(RigidPasses, LargeModelsSumInFixedPartsTheSameOnAnyThreadCount) {
  // Above kRigidPartRows vertices the rigid body's sums run in fixed parts on the step's
  // threads: one thread and two give the same bits, and the sums agree with one plain loop
  // to rounding. The per-vertex passes (the rigid motion, the rigid velocity) give the same
  // rows on any thread count.
  const Index n = kRigidPartRows + 12345;
  std::mt19937 random(41);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  VectorX mass(n);
  Points position(n, 3), velocity(n, 3), force(n, 3);
  std::vector<double> weight(static_cast<size_t>(n));
  for (Index i = 0; i < n; ++i) {
    mass[i] = 1.5 + unit(random);
    weight[static_cast<size_t>(i)] = i % 7 == 0 ? 0.0 : 0.5 + 0.5 * unit(random);
    for (int d = 0; d < 3; ++d) {
      position(i, d) = 3.0 * unit(random) + (d == 0 ? 10.0 : 0.0);
      velocity(i, d) = unit(random);
      force(i, d) = unit(random);
    }
  }
  const MassProperties one = massProperties(mass, position, 1);
  const MassProperties two = massProperties(mass, position, 2);
  EXPECT_EQ(one.mass, two.mass);
  EXPECT_TRUE(one.centre == two.centre);
  EXPECT_TRUE(one.inertia == two.inertia);
  // One plain loop, as below kRigidPartRows.
  double total = 0.0;
  Vec3 weighted = Vec3::Zero(), resultant = Vec3::Zero(), torque = Vec3::Zero();
  Vec3 linear = Vec3::Zero(), angular = Vec3::Zero();
  for (Index i = 0; i < n; ++i) {
    total += mass[i];
    weighted += mass[i] * position.row(i).transpose();
  }
  const Vec3 centre = weighted / total;
  Mat3 second = Mat3::Zero();
  for (Index i = 0; i < n; ++i) {
    const Vec3 rho = position.row(i).transpose() - centre;
    second += mass[i] * rho * rho.transpose();
    const Vec3 f = weight[static_cast<size_t>(i)] * force.row(i).transpose();
    resultant += f;
    torque += rho.cross(f);
    const Vec3 p = mass[i] * velocity.row(i).transpose();
    linear += p;
    angular += rho.cross(p);
  }
  EXPECT_NEAR(one.mass, total, 1e-12 * total);
  EXPECT_LT((one.centre - centre).norm(), 1e-12 * centre.norm());
  const Mat3 inertia = second.trace() * Mat3::Identity() - second;
  EXPECT_LT((one.inertia - inertia).norm(), 1e-12 * inertia.norm());
  Vec3 r1, t1, r2, t2;
  weightedResultant(weight, position, force, one.centre, r1, t1, 1);
  weightedResultant(weight, position, force, one.centre, r2, t2, 2);
  EXPECT_TRUE(r1 == r2 && t1 == t2);
  EXPECT_LT((r1 - resultant).norm(), 1e-10);
  EXPECT_LT((t1 - torque).norm(), 1e-9);
  const RigidMomentum m1 = momentumOf(mass, position, velocity, one.centre, 1);
  const RigidMomentum m2 = momentumOf(mass, position, velocity, one.centre, 2);
  EXPECT_TRUE(m1.linear == m2.linear && m1.angular == m2.angular);
  EXPECT_LT((m1.linear - linear).norm(), 1e-10);
  EXPECT_LT((m1.angular - angular).norm(), 1e-9);
  Points moved1 = position, moved2 = position, v1 = velocity, v2 = velocity;
  const Mat3 rotation = rotationFromVector(Vec3(0.3, -0.2, 0.5));
  applyRigidMotion(one.centre, Vec3(0.1, 0.2, 0.3), rotation, moved1, 1);
  applyRigidMotion(one.centre, Vec3(0.1, 0.2, 0.3), rotation, moved2, 2);
  EXPECT_TRUE(moved1 == moved2);
  const RigidMomentum removed1 = removeRigidMotion(mass, one, position, v1, 1);
  const RigidMomentum removed2 = removeRigidMotion(mass, one, position, v2, 2);
  EXPECT_TRUE(v1 == v2);
  EXPECT_TRUE(removed1.linear == removed2.linear && removed1.angular == removed2.angular);
  const RigidMomentum left = momentumOf(mass, position, v1, one.centre, 2);
  EXPECT_LT(left.linear.norm(), 1e-9 * m1.linear.norm() + 1e-9);
}
