// Simulation module: the integrated solver cycle (loads, constraints, semi-rigid coupling)
// on the paper's models. Section 4.3 (rigidity, stiffness cap) and section 6 (constraints).

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <iostream>
#include <limits>
#include <numbers>

#include "support/allocation_counter.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/simulation/divergence_guard.h"
#include "zsculpt/simulation/simulation.h"

using namespace zsculpt;

namespace {

struct ModelSpec {
  double mass = 0.5;
  double stiffness = 5.0;
  double angular = 0.0;
  double rigidity = 0.0;
  double cap = std::numeric_limits<double>::infinity();
  double damping = 0.0;
  Vec3 gravity = Vec3::Zero();
};

Model makeModel(Mesh mesh, const ModelSpec& spec = {}) {
  UniformProperties u;
  u.mass = spec.mass;
  u.stiffness = spec.stiffness;
  u.angularStiffness = spec.angular;
  u.rigidity = spec.rigidity;
  u.stiffnessCap = spec.cap;
  u.damping = spec.damping;
  u.gravity = spec.gravity;
  return Model::fromMesh(std::move(mesh), u);
}

// The same faces with the positions scaled per axis: an asymmetric body.
Mesh scaled(const Mesh& mesh, const Vec3& factor) {
  Points p = mesh.positions();
  for (Index i = 0; i < p.rows(); ++i) p.row(i) = p.row(i).cwiseProduct(factor.transpose());
  std::vector<std::vector<Index>> faces;
  for (Index f = 0; f < mesh.numFaces(); ++f) {
    const auto c = mesh.face(f);
    faces.emplace_back(c.begin(), c.end());
  }
  return Mesh(p, faces);
}

SimulationSettings settingsFor(const Model& model, double ratio, Scheme scheme = Scheme::Default) {
  SimulationSettings s;
  s.scheme = scheme;
  s.period = ratio * criticalPeriod(SystemMatrices(model));
  return s;
}

SimulationSettings fixedPeriod(double period) {
  SimulationSettings s;
  s.period = period;
  return s;
}

double maxRelativeDistanceChange(const Points& a, const Points& b) {
  double worst = 0.0;
  for (Index i = 0; i < a.rows(); ++i)
    for (Index j = i + 1; j < a.rows(); ++j) {
      const double d0 = (a.row(i) - a.row(j)).norm();
      const double d1 = (b.row(i) - b.row(j)).norm();
      worst = std::max(worst, std::abs(d1 - d0) / d0);
    }
  return worst;
}

Vec3 centreOfMass(const VectorX& mass, const Points& p) {
  Vec3 c = Vec3::Zero();
  for (Index i = 0; i < p.rows(); ++i) c += mass[i] * p.row(i).transpose();
  return c / mass.sum();
}

// An independent rigid body: RK4 on (c, V, q, L) with the body-frame inertia, a force fixed
// in the world frame applied at a material point. The reference for the fully rigid model.
struct ReferenceBody {
  Vec3 c, v, l;
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
  Mat3 inverseInertia;  // body frame (= world frame at t = 0)
  double mass;
  Points arms;  // body frame
  Index loaded;
  Vec3 force;

  struct Rate {
    Vec3 dc, dv, dl;
    Eigen::Vector4d dq;
  };
  Rate rate(const Vec3& vel, const Eigen::Quaterniond& quat, const Vec3& angular) const {
    const Mat3 r = quat.normalized().toRotationMatrix();
    const Vec3 omega = r * inverseInertia * r.transpose() * angular;
    const Eigen::Quaterniond w(0.0, omega.x(), omega.y(), omega.z());
    const Eigen::Quaterniond dq = w * quat;
    Rate k;
    k.dc = vel;
    k.dv = force / mass;
    k.dl = (r * arms.row(loaded).transpose()).cross(force);
    k.dq = 0.5 * dq.coeffs();
    return k;
  }
  void step(double h) {
    auto add = [](const Eigen::Quaterniond& q, const Eigen::Vector4d& d, double s) {
      Eigen::Quaterniond out;
      out.coeffs() = q.coeffs() + s * d;
      return out;
    };
    const Rate k1 = rate(v, q, l);
    const Rate k2 = rate(v + 0.5 * h * k1.dv, add(q, k1.dq, 0.5 * h), l + 0.5 * h * k1.dl);
    const Rate k3 = rate(v + 0.5 * h * k2.dv, add(q, k2.dq, 0.5 * h), l + 0.5 * h * k2.dl);
    const Rate k4 = rate(v + h * k3.dv, add(q, k3.dq, h), l + h * k3.dl);
    c += h / 6.0 * (k1.dc + 2 * k2.dc + 2 * k3.dc + k4.dc);
    v += h / 6.0 * (k1.dv + 2 * k2.dv + 2 * k3.dv + k4.dv);
    l += h / 6.0 * (k1.dl + 2 * k2.dl + 2 * k3.dl + k4.dl);
    q.coeffs() += h / 6.0 * (k1.dq + 2 * k2.dq + 2 * k3.dq + k4.dq);
    q.normalize();
  }
  [[nodiscard]] Points positions() const {
    Points p(arms.rows(), 3);
    const Mat3 r = q.toRotationMatrix();
    for (Index i = 0; i < p.rows(); ++i) p.row(i) = (c + r * arms.row(i).transpose()).transpose();
    return p;
  }
};

// The dodecahedron with its pentagons fanned into triangles: edge springs alone make it
// rigid (a triangulated convex polyhedron), so no folding mode soaks up energy.
Mesh triangulatedDodecahedron() {
  const Mesh d = makeDodecahedron();
  std::vector<std::vector<Index>> faces;
  for (Index f = 0; f < d.numFaces(); ++f) {
    const auto c = d.face(f);
    for (size_t k = 1; k + 1 < c.size(); ++k) faces.push_back({c[0], c[k], c[k + 1]});
  }
  return Mesh(d.positions(), faces);
}

// Largest vertex distance between a fully rigid simulation and the reference after `time`.
double rigidBodyError(const Model& model, double dt, double time, Index loaded, const Vec3& force,
                      const Vec3& spin) {
  Simulation sim(model, fixedPeriod(dt));
  State start = State::atRest(model.mesh);
  spinVelocity(model.properties.mass, start.position, spin, start.velocity);
  sim.setState(start);
  sim.addForce(TimedLoad{loaded, force});
  const long steps = std::lround(time / dt);
  for (long k = 0; k < steps; ++k) sim.step();

  ReferenceBody body;
  const VectorX& m = model.properties.mass;
  body.mass = m.sum();
  body.c = centreOfMass(m, start.position);
  body.v = Vec3::Zero();
  body.arms = start.position.rowwise() - body.c.transpose();
  Mat3 inertia = Mat3::Zero();
  for (Index i = 0; i < body.arms.rows(); ++i) {
    const Vec3 a = body.arms.row(i).transpose();
    inertia += m[i] * (a.squaredNorm() * Mat3::Identity() - a * a.transpose());
  }
  body.inverseInertia = inertia.inverse();
  body.l = inertia * spin;
  body.loaded = loaded;
  body.force = force;
  const long fine = 40 * steps;
  for (long k = 0; k < fine; ++k) body.step(time / static_cast<double>(fine));
  return (sim.state().position - body.positions()).rowwise().norm().maxCoeff();
}

}  // namespace

// ---- semi-rigid motion (section 4.3) --------------------------------------------------------

TEST(SemiRigid, AllChiZeroIsTheElasticStepperBitForBit) {
  // chi = 0 everywhere (no painted rigidity, a cap above every stiffness): the cycle must be
  // the elastic stepper itself, under loads and a torque.
  ModelSpec spec;
  spec.cap = 50.0;
  spec.damping = 0.02;
  spec.gravity = Vec3(0, 0, -1);
  const Model model = makeModel(makeDodecahedron(), spec);
  SimulationSettings settings = settingsFor(model, 0.5);
  settings.substepStrain = 0.0;  // the reference below takes one step per cycle
  Simulation sim(model, settings);
  EXPECT_FALSE(sim.rigidActive());
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, 0.05, 7, start.velocity);
  sim.setState(start);
  const TimedLoad load{3, Vec3(0.3, -0.2, 1.153), 0.0, 2.0};
  sim.addForce(load);

  Stepper reference(model, settings.scheme, settings.period);
  State state = start;
  Points external = Points::Zero(model.mesh.numVertices(), 3);
  for (int k = 0; k < 400; ++k) {
    external.setZero();
    // The cycle holds the load times the share of the cycle it acts in.
    external.row(3) = load.shareOf(state.time, settings.period) * load.value.transpose();
    reference.step(state, external);
    sim.step();
  }
  EXPECT_EQ(sim.state().position, state.position);
  EXPECT_EQ(sim.state().velocity, state.velocity);
}

TEST(SemiRigid, FullyRigidModelFollowsTheRigidBodyEquations) {
  // chi = 1: a force at one vertex; the centre of mass accelerates at F / M, the body turns
  // under the torque with its (anisotropic) inertia, distances are kept. Compared with an
  // independent RK4 integration of the same rigid body, the error is second order in T.
  ModelSpec spec;
  spec.rigidity = 1.0;
  const Model model = makeModel(scaled(makeTorus(8, 4), Vec3(1.0, 0.8, 0.5)), spec);
  const Vec3 force(0.4, -0.3, 1.153);
  const Vec3 spin(0.2, -0.5, 0.9);

  Simulation sim(model, fixedPeriod(0.01));
  EXPECT_TRUE(sim.rigidActive());
  const Points initial = sim.state().position;
  sim.addForce(TimedLoad{5, force});
  const double mass = model.properties.mass.sum();
  const Vec3 c0 = centreOfMass(model.properties.mass, initial);
  double worstDistance = 0.0, worstCentre = 0.0;
  for (int k = 1; k <= 300; ++k) {
    sim.step();
    const double t = sim.time();
    const Vec3 expected = c0 + 0.5 * t * t / mass * force;
    worstCentre = std::max(
        worstCentre, (centreOfMass(model.properties.mass, sim.state().position) - expected).norm());
    worstDistance =
        std::max(worstDistance, maxRelativeDistanceChange(initial, sim.state().position));
  }
  EXPECT_LT(worstCentre, 1e-12);
  EXPECT_LT(worstDistance, 1e-9);

  const double coarse = rigidBodyError(model, 0.02, 2.0, 5, force, spin);
  const double fine = rigidBodyError(model, 0.01, 2.0, 5, force, spin);
  EXPECT_LT(coarse, 2e-3);
  EXPECT_GT(coarse / fine, 3.0);  // second order: 4 in the limit
  EXPECT_LT(coarse / fine, 5.0);
}

TEST(SemiRigid, TorqueFreeRigidSpinKeepsItsAngularMomentum) {
  // An asymmetric rigid body spinning about no principal axis (it tumbles): L is an exact
  // invariant of the splitting, the energy has no drift.
  ModelSpec spec;
  spec.rigidity = 1.0;
  const Model model = makeModel(scaled(makeDodecahedron(), Vec3(1.0, 0.7, 0.4)), spec);
  Simulation sim(model, fixedPeriod(0.02));
  State start = State::atRest(model.mesh);
  spinVelocity(model.properties.mass, start.position, Vec3(0.3, 2.0, 0.4), start.velocity);
  sim.setState(start);
  const Diagnostics d0 = sim.diagnostics();
  double worstL = 0.0, worstE = 0.0;
  for (int k = 0; k < 10000; ++k) {
    sim.step();
    const Diagnostics d = sim.diagnostics();
    worstL = std::max(worstL,
                      (d.angularMomentum - d0.angularMomentum).norm() / d0.angularMomentum.norm());
    worstE = std::max(worstE, std::abs(d.kinetic - d0.kinetic) / d0.kinetic);
  }
  EXPECT_LT(worstL, 1e-9);
  EXPECT_LT(worstE, 1e-3);
  EXPECT_LT(maxRelativeDistanceChange(start.position, sim.state().position), 1e-9);
}

TEST(SemiRigid, TorqueLoadChangesAngularMomentumByTorqueTimesTime) {
  ModelSpec spec;
  spec.rigidity = 1.0;
  const Model model = makeModel(makeDodecahedron(), spec);
  Simulation sim(model, fixedPeriod(0.01));
  State start = State::atRest(model.mesh);
  spinVelocity(model.properties.mass, start.position, Vec3(0.0, 0.4, 0.1), start.velocity);
  sim.setState(start);
  const Vec3 torque(0.2, -0.1, 1.3);
  sim.addTorque(TimedLoad{4, torque, 0.0, 1.0});
  const Vec3 l0 = sim.diagnostics().angularMomentum;
  for (int k = 0; k < 200; ++k) {
    sim.step();
    const double acting = std::min(sim.time(), 1.0);
    const Vec3 expected = l0 + acting * torque;
    EXPECT_LT((sim.diagnostics().angularMomentum - expected).norm(), 1e-9 * expected.norm());
  }
  EXPECT_LT(sim.diagnostics().momentum.norm(), 1e-12);  // a torque exerts no net force
}

TEST(SemiRigid, StiffnessCapRaisesTheCriticalPeriodAndStaysStable) {
  // kappa = 500 against a cap of 5: the matrices see the cap, so T_max grows tenfold, and
  // the capped model runs stably at a period where the uncapped one diverges.
  ModelSpec stiff;
  stiff.stiffness = 500.0;
  ModelSpec capped = stiff;
  capped.cap = 5.0;
  const Model a = makeModel(triangulatedDodecahedron(), stiff);
  const Model b = makeModel(triangulatedDodecahedron(), capped);
  const double tA = criticalPeriod(SystemMatrices(a));
  const double tB = criticalPeriod(SystemMatrices(b));
  EXPECT_NEAR(tB / tA, 10.0, 1e-9);  // T_max ~ 1 / sqrt(kappa): sqrt(500 / 5)

  const double period = 0.5 * tB;
  State start = State::atRest(a.mesh);
  randomVelocity(a.properties.mass, 0.05, 3, start.velocity);
  // One step per cycle: split steps (SimulationSettings::substepStrain) would tame the
  // uncapped model's linear instability once its motion grew.
  SimulationSettings settings = fixedPeriod(period);
  settings.substepStrain = 0.0;
  Simulation simA(a, settings);
  Simulation simB(b, settings);
  simA.setState(start);
  simB.setState(start);
  EXPECT_TRUE(simB.rigidActive());
  EXPECT_NEAR(simB.rigidity()[0], 0.99, 1e-15);
  bool divergedA = false;
  try {
    for (int k = 0; k < 200; ++k) simA.step();
  } catch (const DivergenceError&) {
    divergedA = true;
  }
  EXPECT_TRUE(divergedA || !std::isfinite(simA.diagnostics().total()) ||
              simA.diagnostics().total() > 1e6 * simB.diagnostics().total());
  // The elastic part feels sigma F = kappa_0 / kappa F: the energy it keeps is the kinetic
  // energy plus sigma times the springs' (section 4.3's capped stiffness).
  const double sigma = simB.elasticShare()[0];
  auto energy = [&](const Diagnostics& d) { return d.kinetic + sigma * d.potential.total(); };
  // It matches the energy behaviour of the elastic model of stiffness kappa_0 at the same
  // period (the default scheme's energy oscillates with (omega T)^2; it does not drift).
  ModelSpec soft;
  const Model c = makeModel(triangulatedDodecahedron(), soft);
  Simulation simC(c, fixedPeriod(period));
  simC.setState(start);
  const Diagnostics d0 = simB.diagnostics();
  const double e0 = simC.diagnostics().total();
  double worst = 0.0, worstSoft = 0.0, first = 0.0, last = 0.0;
  for (int k = 0; k < 2000; ++k) {
    simB.step();
    simC.step();
    const double e = energy(simB.diagnostics());
    worst = std::max(worst, std::abs(e - energy(d0)) / energy(d0));
    worstSoft = std::max(worstSoft, std::abs(simC.diagnostics().total() - e0) / e0);
    if (k < 200) first += e;
    if (k >= 1800) last += e;
  }
  std::cout << "energy range: capped " << worst << ", elastic kappa_0 " << worstSoft << "\n";
  EXPECT_LT(worst, 1.5 * worstSoft);
  EXPECT_LT(std::abs(last / first - 1.0), 0.02);
  // Internal forces: momentum and angular momentum exact, whatever the split.
  EXPECT_LT((simB.diagnostics().momentum - d0.momentum).norm(), 1e-12);
  EXPECT_LT((simB.diagnostics().angularMomentum - d0.angularMomentum).norm(), 1e-12);
}

TEST(SemiRigid, HalfRigidSpinConservesAngularMomentumExactly) {
  // chi = 0.5: the rigid body carries P and L, the elastic part only deformation; the
  // hand-over keeps L to rounding, which the elastic stepper alone does not.
  ModelSpec spec;
  spec.rigidity = 0.5;
  const Model model = makeModel(makeDodecahedron(), spec);
  for (RigidFrame frame : {RigidFrame::Body, RigidFrame::World}) {
    SimulationSettings settings = settingsFor(model, 0.5);
    settings.rigidFrame = frame;
    Simulation sim(model, settings);
    State start = State::atRest(model.mesh);
    spinVelocity(model.properties.mass, start.position, Vec3(0.2, 0.1, 1.5), start.velocity);
    Points kick;
    randomVelocity(model.properties.mass, 0.05, 11, kick);
    start.velocity += kick;
    sim.setState(start);
    const Diagnostics d0 = sim.diagnostics();
    double worst = 0.0;
    for (int k = 0; k < 3000; ++k) {
      sim.step();
      worst = std::max(worst, (sim.diagnostics().angularMomentum - d0.angularMomentum).norm() /
                                  d0.angularMomentum.norm());
    }
    EXPECT_LT(worst, 1e-11) << (frame == RigidFrame::Body ? "body" : "world");
  }
}

TEST(SemiRigid, PaintedRigidityKeepsMomentumAndAngularMomentumUnderInternalForces) {
  // Rigidity that varies from vertex to vertex: the rigid share of the end forces is taken
  // turned by the cycle's rotation, so the elastic share's must be counted so too, or every
  // cycle leaves (T / 2)(R - I) sum sigma_i f_i of momentum behind (zero only for uniform
  // chi). Every scheme (the default kicks at the end forces, the others step from the start
  // forces), both frames, with and without damping (the rigid kick's decay).
  struct Case {
    Scheme scheme;
    RigidFrame frame;
    double damping;
  };
  std::vector<Case> cases;
  for (const double damping : {0.0, 0.05}) {
    cases.push_back({Scheme::Default, RigidFrame::Body, damping});
    cases.push_back({Scheme::Default, RigidFrame::World, damping});
    for (const Scheme scheme :
         {Scheme::Paper, Scheme::Exact, Scheme::SymplecticEuler, Scheme::ImplicitEuler})
      cases.push_back({scheme, RigidFrame::Body, damping});
  }
  for (const Case& c : cases) {
    ModelSpec spec;
    spec.angular = 0.5;
    spec.damping = c.damping;
    Model model = makeModel(makeTorus(10, 10), spec);
    for (Index v = 0; v < model.mesh.numVertices(); ++v)
      model.properties.rigidity[v] = 0.14 * static_cast<double>(v % 7);
    SimulationSettings settings = settingsFor(model, 0.5, c.scheme);
    settings.rigidFrame = c.frame;
    Simulation sim(model, settings);
    State start = State::atRest(model.mesh);
    spinVelocity(model.properties.mass, start.position, Vec3(0.3, -0.2, 2.0), start.velocity);
    Points kick;
    randomVelocity(model.properties.mass, 0.05, 5, kick);
    start.velocity += kick;
    sim.setState(start);
    const Diagnostics d0 = sim.diagnostics();
    const double scale = model.properties.mass.sum() * 2.0 * 3.0;  // M |omega| R: a momentum
    double worstP = 0.0, worstL = 0.0;
    for (int k = 0; k < 1000; ++k) {
      sim.step();
      const Diagnostics d = sim.diagnostics();
      // Damping proportional to mass takes P away at the rate rho / mu, exactly.
      const Vec3 expected = d0.momentum * std::exp(-c.damping / spec.mass * sim.time());
      worstP = std::max(worstP, (d.momentum - expected).norm() / scale);
      if (c.damping == 0.0)
        worstL = std::max(
            worstL, (d.angularMomentum - d0.angularMomentum).norm() / d0.angularMomentum.norm());
    }
    const std::string name = std::string(schemeName(c.scheme)) +
                             (c.frame == RigidFrame::Body ? " body" : " world") + " damping " +
                             std::to_string(c.damping);
    // With damping the other schemes damp the elastic share's impulse their own way (the
    // exact scheme's propagator, symplectic Euler's factor), not as the rigid kick does: the
    // shares then cancel to first order in the damping only. Measured: 1.3e-9 (exact) to
    // 5.8e-6 (symplectic Euler) of the scale here; open (docs/semi-rigid-and-constraints.md).
    const bool exact = c.damping == 0.0 || c.scheme == Scheme::Default;
    EXPECT_LT(worstP, exact ? 1e-12 : 1e-5) << name;
    EXPECT_LT(worstL, 1e-11) << name;
  }
}

TEST(TimedLoads, ACyclesLoadIsItsShareOfTheCycleSoImpulsesAreExact) {
  // A force of 1.153 N for 3 s on the dodecahedron, at a period that does not divide 3 s:
  // the momentum put in is exactly F x 3 s (a load held for whole cycles would give
  // F x ceil(3 / T) T).
  const Model model = makeModel(makeDodecahedron());
  SimulationSettings settings = settingsFor(model, 0.37);
  ASSERT_GT(std::abs(std::remainder(3.0, settings.period)), 0.1 * settings.period);
  Simulation sim(model, settings);
  const Vec3 force(0.2, -0.4, 1.153);
  sim.addForce(TimedLoad{0, force, 0.0, 3.0});
  while (sim.time() < 5.0) sim.step();
  EXPECT_LT((sim.diagnostics().momentum - 3.0 * force).norm(), 1e-12 * force.norm());
  EXPECT_LT((sim.impulses().loads - 3.0 * force).norm(), 1e-12 * force.norm());
  TimedLoad late{0, force, 1.0, 1.25};
  EXPECT_DOUBLE_EQ(late.shareOf(0.9, 0.2), 0.5);
  EXPECT_DOUBLE_EQ(late.shareOf(1.1, 0.1), 1.0);
  EXPECT_DOUBLE_EQ(late.shareOf(1.2, 0.1), 0.5);
  EXPECT_DOUBLE_EQ(late.shareOf(1.3, 0.1), 0.0);
  EXPECT_DOUBLE_EQ(late.shareOf(0.5, 1.0), 0.25);
}

TEST(SemiRigid, BodyFrameKeepsTheLongRunEnergyOfSpinningSemiRigidModelsBetterThanTheWorldFrame) {
  // Paper section 4.3 composes the rigid motion with the elastic deformation; the choice is
  // whether the deformation velocities turn with the body over a cycle (Body, the default)
  // or stay in the world frame (World). energy_drift as cli.md defines it (mean of the last
  // 10 % of steps over the first 10 %, minus 1) of spinning semi-rigid models with a random
  // kick, at 0.9 T_max. With the kick filter alone the frame decides it (body within 1 %,
  // world up to 3 %); the drift filter (on by default for these braced models) commutes
  // with rotations, so there both frames stay within 1 % and the body frame within 1 % is
  // what is asserted. The full sweep is in docs/semi-rigid-and-constraints.md.
  struct Case {
    bool dodecahedron;
    double chi, spin;
  };
  for (bool driftFilter : {false, true}) {
    double worst[2] = {0.0, 0.0};
    for (const Case& c : {Case{false, 0.3, 0.5}, Case{false, 0.5, 2.0}, Case{true, 0.9, 0.5}}) {
      ModelSpec spec;
      spec.mass = 0.1;
      spec.angular = 0.05;
      spec.rigidity = c.chi;
      const Model model = makeModel(c.dodecahedron ? makeDodecahedron() : makeTorus(10, 10), spec);
      int i = 0;
      for (RigidFrame frame : {RigidFrame::Body, RigidFrame::World}) {
        SimulationSettings settings = settingsFor(model, 0.9);
        settings.rigidFrame = frame;
        settings.stepper.driftFilter = driftFilter;
        Simulation sim(model, settings);
        State start = State::atRest(model.mesh);
        spinVelocity(model.properties.mass, start.position, c.spin * Vec3(0.3, 0.2, 1.0),
                     start.velocity);
        Points kick;
        randomVelocity(model.properties.mass, 0.05, 5, kick);
        start.velocity += kick;
        sim.setState(start);
        constexpr int n = 20000;
        double first = 0.0, last = 0.0;
        for (int k = 0; k < n; ++k) {
          sim.step();
          const double e = sim.diagnostics().total();
          ASSERT_TRUE(std::isfinite(e));
          if (k < n / 10) first += e;
          if (k >= n - n / 10) last += e;
        }
        const double drift = last / first - 1.0;
        std::cout << (driftFilter ? "drift filter, " : "kick filter, ")
                  << (c.dodecahedron ? "dodecahedron" : "Torus-I") << " chi " << c.chi << " spin "
                  << c.spin << (i == 0 ? ": body " : ": world ") << drift << "\n";
        worst[i] = std::max(worst[i], std::abs(drift));
        ++i;
      }
    }
    EXPECT_LT(worst[0], 0.01) << driftFilter;
    if (!driftFilter) {
      EXPECT_LT(worst[0], 0.5 * worst[1]);
    }
  }
}

TEST(SemiRigid, SetStateKeepsOnlyTheRigidPartOfAFullyRigidModel) {
  ModelSpec spec;
  spec.rigidity = 1.0;
  const Model model = makeModel(makeTorus(6, 4), spec);
  Simulation sim(model, fixedPeriod(0.01));
  State start = State::atRest(model.mesh);
  spinVelocity(model.properties.mass, start.position, Vec3(0, 0, 1), start.velocity);
  Points kick;
  randomVelocity(model.properties.mass, 0.3, 5, kick);
  start.velocity += kick;
  const Diagnostics given = measure(model, start);
  sim.setState(start);
  const Diagnostics kept = sim.diagnostics();
  EXPECT_LT((kept.momentum - given.momentum).norm(), 1e-12);
  EXPECT_LT((kept.angularMomentum - given.angularMomentum).norm(), 1e-12);
  EXPECT_LT(kept.kinetic, given.kinetic);  // the deformation's energy is dropped
  for (int k = 0; k < 100; ++k) sim.step();
  EXPECT_LT(maxRelativeDistanceChange(start.position, sim.state().position), 1e-9);
}

TEST(SemiRigid, PaintingRigidityDoesNotKickTheModel) {
  const Model model = makeModel(makeDodecahedron());
  Simulation sim(model, settingsFor(model, 0.4));
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, 0.05, 2, start.velocity);
  sim.setState(start);
  for (int k = 0; k < 20; ++k) sim.step();
  const Points before = sim.state().velocity;
  const std::vector<Index> painted = {0, 1, 2, 3};
  for (Index v : painted) sim.mutableProperties().rigidity[v] = 0.6;
  sim.propertiesChanged(painted);
  EXPECT_TRUE(sim.rigidActive());
  EXPECT_LT((sim.state().velocity - before).cwiseAbs().maxCoeff(), 1e-14);
  for (Index v : painted) sim.mutableProperties().rigidity[v] = 0.0;
  sim.propertiesChanged(painted);
  EXPECT_FALSE(sim.rigidActive());
  EXPECT_LT((sim.state().velocity - before).cwiseAbs().maxCoeff(), 1e-14);
}

TEST(SemiRigid, RigidityOutsideTheUnitIntervalIsRejected) {
  ModelSpec spec;
  spec.rigidity = 1.5;
  EXPECT_THROW(makeModel(makeDodecahedron(), spec), InvalidInputError);
  const Model model = makeModel(makeDodecahedron());
  Simulation sim(model, settingsFor(model, 0.5));
  sim.mutableProperties().rigidity[2] = -0.1;
  const std::vector<Index> edited = {2};
  try {
    sim.propertiesChanged(edited);
    FAIL() << "rigidity -0.1 accepted";
  } catch (const InvalidInputError& e) {
    EXPECT_NE(std::string(e.what()).find("rigidity"), std::string::npos) << e.what();
  }
}

// ---- constraints (section 6) ----------------------------------------------------------------

TEST(Constraints, PinnedVertexStaysOnItsTargetUnderGravityAndForces) {
  for (double rigidity : {0.0, 0.7}) {
    ModelSpec spec;
    spec.gravity = Vec3(0, 0, -1.0);
    spec.damping = 0.1;
    spec.rigidity = rigidity;
    const Model model = makeModel(makeDodecahedron(), spec);
    Simulation sim(model, settingsFor(model, 0.5));
    const Vec3 target = model.mesh.positions().row(0).transpose();
    sim.addPositionConstraint(0);
    sim.addForce(TimedLoad{12, Vec3(1.153, 0.5, 0.0), 0.5, 3.0});
    double worst = 0.0;
    for (int k = 0; k < 1500; ++k) {
      sim.step();
      worst = std::max(worst, (sim.state().position.row(0).transpose() - target).norm());
    }
    EXPECT_LT(worst, 1e-9) << "rigidity " << rigidity;
    EXPECT_LT(sim.state().velocity.row(0).norm(), 1e-9);
    EXPECT_TRUE(sim.constraintReport().converged);
  }
}

TEST(Constraints, PinsHoldWithTheDriftFilter) {
  // The drift filter spreads a pin's force over the whole model (its projection is global);
  // the step response models that exactly, so a pin and a normal still hold to rounding.
  // With each fit of Psi: degree 1 to 4 at 0.2, 0.5, 0.75 and 0.9 T_max (x_max = 12 (T /
  // T_max)^2 on this mesh).
  ModelSpec spec;
  spec.gravity = Vec3(0, 0, -1.0);
  spec.angular = 0.3;
  const Model model = makeModel(makeDodecahedron(), spec);
  const double tMax = criticalPeriod(SystemMatrices(model));
  for (const auto& [ratio, degree] :
       {std::pair{0.2, 1}, std::pair{0.5, 2}, std::pair{0.75, 3}, std::pair{0.9, 4}}) {
    ASSERT_EQ(Stepper(model, Scheme::Default, ratio * tMax).driftProducts(), degree);
    SimulationSettings settings = settingsFor(model, ratio);
    settings.stepper.driftFilter = true;
    Simulation sim(model, settings);
    const Vec3 target = model.mesh.positions().row(0).transpose();
    sim.addPositionConstraint(0);
    sim.addForce(TimedLoad{12, Vec3(1.153, 0.5, 0.0), 0.5, 3.0});
    double worst = 0.0;
    const int cycles = static_cast<int>(1500 * 0.9 / ratio);
    for (int k = 0; k < cycles; ++k) {
      sim.step();
      worst = std::max(worst, (sim.state().position.row(0).transpose() - target).norm());
      ASSERT_LE(sim.constraintReport().steps, 2)
          << "at most one correction, cycle " << k << " at " << ratio << " T_max";
    }
    EXPECT_LT(worst, 1e-9) << ratio << " T_max";
    EXPECT_TRUE(sim.constraintReport().converged) << ratio << " T_max";
  }
}

TEST(Constraints, PinFollowsAMovingTarget) {
  ModelSpec spec;
  spec.damping = 0.1;
  const Model model = makeModel(makeGrid(6), spec);
  Simulation sim(model, settingsFor(model, 0.5));
  const Index corner = 0, other = 35;
  sim.addPositionConstraint(other);
  const Index drag = sim.addPositionConstraint(corner);
  const Vec3 origin = model.mesh.positions().row(corner).transpose();
  double worst = 0.0;
  for (int k = 0; k < 800; ++k) {
    const double t = sim.time() + sim.period();
    const Vec3 target = origin + Vec3(std::sin(t), 0.5 * (1 - std::cos(t)), 0.3 * std::sin(2 * t));
    sim.setConstraintTarget(drag, target);
    sim.step();
    worst = std::max(worst, (sim.state().position.row(corner).transpose() - target).norm());
  }
  EXPECT_LT(worst, 1e-9);
}

TEST(Constraints, ATravellingPinMovesItsVertexThereSmoothlyAndHoldsIt) {
  // A review: --pin 0:0,0,5 took the corner 5 edge lengths in one cycle and whipped the
  // sheet. A travel holds the vertex until T0, then eases it to the target by T1 (zero speed
  // at both ends), and holds it there. The grid with its other corners pinned, 0.5 T_max.
  ModelSpec spec;
  spec.damping = 0.05;
  const Model model = makeModel(makeGrid(8), spec);
  const Vec3 origin = model.mesh.positions().row(0).transpose();
  const Vec3 target = origin + Vec3(0, 0, 3);
  const double t0 = 1.0, t1 = 4.0;
  auto run = [&](bool travel, std::vector<Vec3>* path) {
    Simulation sim(model, settingsFor(model, 0.5));
    for (Index v : {7, 56, 63}) sim.addPositionConstraint(v);
    const Index id = travel ? sim.addPositionConstraint(0, target, PinTravel{t0, t1})
                            : sim.addPositionConstraint(0, target);
    double fastest = 0.0;
    while (sim.time() < 6.0) {
      sim.step();
      if (path) path->push_back(sim.state().position.row(0).transpose());
      fastest = std::max(fastest, sim.state().velocity.rowwise().norm().maxCoeff());
    }
    EXPECT_LT((sim.state().position.row(0).transpose() - target).norm(), 1e-9);
    // Arrived, the travel is kept (for a rollback and a save); a plain pin has none.
    EXPECT_EQ(sim.pinTravel(id).has_value(), travel);
    if (travel) {
      // A rollback to the start (setState) puts the pin back on its way: its target is a
      // function of time, so the next cycle does not jump to the far target.
      State start = State::atRest(model.mesh);
      sim.setState(start);
      sim.step();
      EXPECT_LT((sim.state().position.row(0).transpose() - origin).norm(), 1e-12);
    }
    return fastest;
  };
  std::vector<Vec3> path;
  const double smooth = run(true, &path);
  const double jump = run(false, nullptr);
  // The vertex follows the eased line: still until T0, halfway at the middle, there at T1.
  Simulation probe(model, settingsFor(model, 0.5));
  const double period = probe.period();
  for (size_t k = 0; k < path.size(); ++k) {
    const double t = static_cast<double>(k + 1) * period;
    const double s = std::clamp((t - t0) / (t1 - t0), 0.0, 1.0);
    const Vec3 expected = origin + s * s * (3 - 2 * s) * (target - origin);
    ASSERT_LT((path[k] - expected).norm(), 1e-9) << "t = " << t;
  }
  // The peak speed of a travel is 1.5 x 3 m / 3 s = 1.5 m/s for the pinned corner; a jump of
  // 3 m in one cycle (0.19 s) sets vertices going at 15 m/s (measured 1.52 and 15.5).
  std::cout << "peak speed: travel " << smooth << ", jump " << jump << " m/s over " << path.size()
            << " cycles\n";
  EXPECT_LT(smooth, 2.0);
  EXPECT_GT(jump, 5.0 * smooth);
  // Refused: a travel that does not end after it starts; the pin is not added.
  Simulation sim(model, settingsFor(model, 0.5));
  EXPECT_THROW(sim.addPositionConstraint(0, target, PinTravel{2.0, 2.0}), InvalidInputError);
  EXPECT_THROW(sim.addPositionConstraint(0, target, PinTravel{-1.0, 2.0}), InvalidInputError);
  EXPECT_TRUE(sim.constraints().empty());
  // A vertex pinned already cannot also travel (one of the two targets would be lost).
  sim.addPositionConstraint(0);
  EXPECT_THROW(sim.addPositionConstraint(0, target, PinTravel{0.0, 1.0}), InvalidInputError);
  sim.clearConstraints();
  // The drag tool taking the pin ends its travel.
  const Index id = sim.addPositionConstraint(0, target, PinTravel{0.0, 1.0});
  EXPECT_TRUE(sim.pinTravel(id).has_value());
  sim.setConstraintTarget(id, origin);
  EXPECT_FALSE(sim.pinTravel(id).has_value());
  sim.step();
  EXPECT_LT((sim.state().position.row(0).transpose() - origin).norm(), 1e-12);
}

TEST(Constraints, TheirWorkIsTheEnergyTheyPutIn) {
  // Undamped, no loads: every change of the total energy is the constraints' work (what the
  // soak counts) plus the scheme's own energy error, which is second order in T. A drag pulls
  // a corner out and back, another corner pinned; the largest gap between the energy gained
  // and the work falls fourfold when T halves, so nothing else is missing from the work.
  // Both forms of the default scheme: the kick filter alone at 0.3 and 0.15 T_max, and with
  // the drift filter (on for this braced grid) at a quarter of those periods, because its
  // error is larger (docs/solver.md section 6: the energy this drag puts in is 7.7 %, 2.3 %
  // and 0.7 % above the kick filter's converged value at 0.3, 0.15 and 0.075 T_max).
  const Model model = makeModel(makeGrid(6), ModelSpec{.angular = 0.2});
  auto run = [&](double ratio, bool driftFilter) {
    SimulationSettings settings = settingsFor(model, ratio);
    settings.stepper.driftFilter = driftFilter;
    Simulation sim(model, settings);
    sim.addPositionConstraint(35);
    const Index drag = sim.addPositionConstraint(0);
    const Vec3 origin = model.mesh.positions().row(0).transpose();
    const double e0 = sim.diagnostics().total();
    double work = 0.0, largest = 0.0, gap = 0.0;
    const double duration = 600 * 0.3 * criticalPeriod(SystemMatrices(model));
    while (sim.time() < duration) {
      const double t = sim.time() + sim.period();
      sim.setConstraintTarget(drag, origin + Vec3(0.0, 0.0, 0.4 * std::sin(0.5 * t)));
      sim.step();
      work += sim.constraintWork();
      const double e = sim.diagnostics().total() - e0;
      largest = std::max(largest, std::abs(e));
      gap = std::max(gap, std::abs(e - work));
    }
    return std::pair{largest, gap};
  };
  for (bool driftFilter : {false, true}) {
    const double ratio = driftFilter ? 0.075 : 0.3;
    const auto [energy, gap] = run(ratio, driftFilter);
    const auto [energyHalf, gapHalf] = run(ratio / 2, driftFilter);
    std::cout << (driftFilter ? "drift filter" : "kick filter") << ": energy " << energy << " / "
              << energyHalf << ", gap " << gap << " / " << gapHalf << " at " << ratio << " / "
              << ratio / 2 << " T_max\n";
    EXPECT_GT(energy, 0.1);  // the drag did put energy in
    EXPECT_NEAR(energyHalf, energy, 0.01 * energy) << driftFilter;
    EXPECT_LT(gap, 0.03 * energy) << driftFilter;
    EXPECT_LT(gapHalf, 0.3 * gap) << driftFilter;
  }
}

TEST(Constraints, PinsHoldOnAFullyRigidBody) {
  // A rigid pendulum: one pinned vertex, gravity; the body turns about the pin.
  ModelSpec spec;
  spec.rigidity = 1.0;
  spec.gravity = Vec3(0, 0, -9.81);
  const Model model = makeModel(makeTorus(6, 4), spec);
  Simulation sim(model, fixedPeriod(0.01));
  const Vec3 target = model.mesh.positions().row(0).transpose();
  sim.addPositionConstraint(0);
  const Points initial = sim.state().position;
  double worst = 0.0;
  for (int k = 0; k < 300; ++k) {
    sim.step();
    worst = std::max(worst, (sim.state().position.row(0).transpose() - target).norm());
  }
  EXPECT_LT(worst, 1e-9);
  EXPECT_LT(maxRelativeDistanceChange(initial, sim.state().position), 1e-9);
  // It swung: the centre of mass fell.
  EXPECT_LT(centreOfMass(model.properties.mass, sim.state().position).z(),
            centreOfMass(model.properties.mass, initial).z() - 0.1);
}

namespace {

// The corners of a 7 x 7 grid, pinned where they are; its centre is vertex 24.
constexpr Index kSheetCentre = 24;
// The 7 x 7 sheet with angle springs and damping whose settled centre the normal tests
// turn.
Model dampedBracedSheet() {
  return makeModel(makeGrid(7), ModelSpec{.angular = 0.5, .damping = 0.5});
}

void pinCorners(Simulation& sim) {
  for (Index corner : {0, 6, 42, 48}) sim.addPositionConstraint(corner);
}

// Random velocities of this size and zero net momentum, as `zsculpt simulate --perturb`
// gives them (seed 0).
void perturb(Simulation& sim, double size) {
  State s = sim.state();
  Points kick;
  randomVelocity(sim.model().properties.mass, size, 0, kick);
  s.velocity += kick;
  sim.setState(s);
}

}  // namespace

TEST(Damping, MomentumDecaysAtTheDampingRate) {
  // The paper's damping with rho / mu = gamma the same at every vertex and no loads: the
  // internal forces cancel in sum, so P(t) = P(0) e^{-gamma t}, through the drift filter
  // (the braced dodecahedron) and the kick filter (Torus-I), cycles split or not. (What
  // README's energy and momentum plots show decaying after the loads stop.)
  for (const auto& [name, model] :
       {std::pair{"braced dodecahedron",
                  makeModel(makeDodecahedron(), ModelSpec{.angular = 0.5, .damping = 0.1})},
        std::pair{"Torus-I", makeModel(makeTorus(10, 10), ModelSpec{.damping = 0.1})}}) {
    const double gamma = 0.1 / 0.5;
    Simulation sim(model, settingsFor(model, 0.5));
    perturb(sim, 0.3);  // fast enough that some cycles are split
    State s = sim.state();
    s.velocity.rowwise() += Eigen::RowVector3d(0.3, -0.1, 0.2);
    sim.setState(s);
    const Vec3 p0 = sim.diagnostics().momentum;
    double worst = 0.0;
    int split = 0;
    for (int k = 0; k < 400; ++k) {
      sim.step();
      split += sim.substeps() > 1 ? 1 : 0;
      const Vec3 expected = p0 * std::exp(-gamma * sim.time());
      worst = std::max(worst, (sim.diagnostics().momentum - expected).norm() / p0.norm());
    }
    std::printf(
        "%s: |P - P0 e^(-gamma t)| / |P0| at most %.3g over 400 cycles to t = %.3g s, "
        "%d of them split\n",
        name, worst, sim.time(), split);
    EXPECT_LT(worst, 1e-12) << name;
    EXPECT_LT(sim.diagnostics().momentum.norm(), 0.5 * p0.norm()) << name;  // it did decay
  }
}

TEST(Constraints, NormalConstraintHoldsOnceSettled) {
  const Model model = dampedBracedSheet();
  Simulation sim(model, settingsFor(model, 0.5));
  pinCorners(sim);
  const Index centre = kSheetCentre;
  const Vec3 wanted = Vec3(0.3, -0.2, 1.0).normalized();
  sim.addNormalConstraint(centre, wanted);
  sim.addForce(TimedLoad{10, Vec3(0, 0, 1.153)});
  for (int k = 0; k < 1500; ++k) sim.step();
  const auto normal = bestPlaneNormal(model.mesh, sim.state().position, centre);
  ASSERT_TRUE(normal.has_value());
  EXPECT_LT(std::acos(std::min(1.0, normal->dot(wanted))), 1e-3);
  EXPECT_LT(sim.constraintReport().normalError, 1e-3);
  // Without the constraint the same load leaves another normal there.
  Simulation free(model, settingsFor(model, 0.5));
  pinCorners(free);
  free.addForce(TimedLoad{10, Vec3(0, 0, 1.153)});
  for (int k = 0; k < 1500; ++k) free.step();
  const auto other = bestPlaneNormal(model.mesh, free.state().position, centre);
  EXPECT_GT(std::acos(std::min(1.0, other->dot(wanted))), 0.1);
}

TEST(Constraints, MomentumBookkeepingIncludesConstraintImpulses) {
  for (double rigidity : {0.0, 0.5}) {
    ModelSpec spec;
    spec.gravity = Vec3(0, -2.0, -9.81);
    spec.rigidity = rigidity;
    const Model model = makeModel(makeTorus(8, 5), spec);
    Simulation sim(model, settingsFor(model, 0.4));
    sim.addPositionConstraint(0);
    sim.addPositionConstraint(17, Vec3(1.0, 1.0, 0.5));
    sim.addForce(TimedLoad{20, Vec3(2, 0, 1), 0.0, 1.0});
    sim.addTorque(TimedLoad{30, Vec3(0, 0, 1.3), 0.5, 2.0});
    const Vec3 p0 = sim.diagnostics().momentum;
    for (int k = 0; k < 400; ++k) sim.step();
    const ImpulseLedger& ledger = sim.impulses();
    const Vec3 expected = p0 + ledger.loads + ledger.gravity + ledger.constraints;
    EXPECT_LT((sim.diagnostics().momentum - expected).norm(), 1e-9 * (1 + expected.norm()))
        << "rigidity " << rigidity;
    EXPECT_GT(ledger.constraints.norm(), 1.0);
  }
}

TEST(TimedLoads, AngularImpulsesAreLedgeredAboutTheCentreOfMass) {
  // A torque of 0.3 N m for 1.5 s puts in an angular impulse of exactly 0.45 N m s whatever
  // the body does, and the angular momentum about the centre of mass grows by it. With a
  // pin, the pin's angular impulse (about the centre of mass, not the origin: the torus sits
  // far from it) joins it, and the ledger's sum is what the momentum did. Braced torus, no
  // damping, at 0.2 T_max, where the default scheme keeps L within 1e-4.
  Mesh mesh = makeTorus(12, 8);
  Points moved = mesh.positions();
  moved.rowwise() += Eigen::RowVector3d(5.0, -3.0, 2.0);
  std::vector<std::vector<Index>> faces;
  for (Index f = 0; f < mesh.numFaces(); ++f) {
    const auto c = mesh.face(f);
    faces.emplace_back(c.begin(), c.end());
  }
  const Model model = makeModel(Mesh(moved, faces), ModelSpec{.angular = 0.3});
  const Vec3 torque(0.1, -0.05, 0.3);
  for (const bool pinned : {false, true}) {
    Simulation sim(model, settingsFor(model, 0.2));
    sim.addTorque(TimedLoad{30, torque, 0.0, 1.5});
    if (pinned) sim.addPositionConstraint(0);
    const Vec3 l0 = sim.diagnostics().angularMomentum;
    while (sim.time() < 3.0) sim.step();
    const ImpulseLedger& ledger = sim.impulses();
    EXPECT_LT((ledger.loadsAngular - 1.5 * torque).norm(), 1e-12) << (pinned ? "pinned" : "free");
    const Vec3 change = sim.diagnostics().angularMomentum - l0;
    const Vec3 expected = ledger.loadsAngular + ledger.constraintsAngular;
    EXPECT_LT((change - expected).norm(), 1e-3 * torque.norm()) << (pinned ? "pinned" : "free");
    if (pinned) {
      EXPECT_GT(ledger.constraintsAngular.norm(), 0.1 * torque.norm());
    } else {
      EXPECT_EQ(ledger.constraintsAngular.norm(), 0.0);
    }
    RecordProperty(pinned ? "pinned_error" : "free_error",
                   std::to_string((change - expected).norm()));
  }
}

TEST(Constraints, BadConstraintsAreRejected) {
  const Model model = makeModel(makeDodecahedron());
  Simulation sim(model, settingsFor(model, 0.5));
  EXPECT_THROW(sim.addPositionConstraint(20), InvalidInputError);
  EXPECT_THROW(sim.addNormalConstraint(-1), InvalidInputError);
  sim.addPositionConstraint(3, Vec3(0, 0, 1));
  EXPECT_THROW(sim.addPositionConstraint(3, Vec3(0, 0, 2)), InvalidInputError);
  sim.addPositionConstraint(3, Vec3(0, 0, 1));  // the same again: kept once, with a warning
  EXPECT_EQ(sim.constraints().size(), 1u);
  EXPECT_EQ(sim.takeWarnings().size(), 1u);

  const Model curve = makeModel(makeHelix(10));
  Simulation helix(curve, settingsFor(curve, 0.5));
  EXPECT_THROW(helix.addNormalConstraint(0), InvalidInputError);  // a curve end
  EXPECT_NO_THROW(helix.addNormalConstraint(4));

  Points p(4, 3);
  p << 0, 0, 0, 1, 0, 0, 0, 1, 0, 5, 5, 5;
  const Model lonely = makeModel(Mesh(p, {{0, 1, 2}}));
  Simulation withIsolated(lonely, fixedPeriod(0.01));
  try {
    withIsolated.addNormalConstraint(3);
    FAIL() << "normal at an isolated vertex accepted";
  } catch (const InvalidInputError& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 3"), std::string::npos) << e.what();
  }
}

TEST(Constraints, ANormalPinOnAnUnbracedModelFeedsNoEnergyIn) {
  // A surface without angle springs deforms freely, and its rings' fitted normals turn as
  // they deform, not only as they rotate. The constraint's forces follow the normal's
  // gradient and the end-of-cycle velocities are projected onto those that keep the normal
  // (RATTLE's velocity step), so holding it does no work: after the first cycle takes away
  // the initial velocity's share that moved the normal, the energy stays put. (Forces laid
  // out as a rigid couple, and the ring's rigid turn taken away, as before the tenth
  // session, pumped energy in: here the run diverged at cycle 434; on Torus-II at 0.1 T_max it
  // diverged at cycle 3258.) Near cycle 2435 this ring folds through a shape with no flattest
  // direction, where the constraint lets it go (Constraints.AFoldingRingIsLetGo...); hence the
  // warning, and 2000 cycles here, every one of them held.
  const Model model = makeModel(makeDodecahedron());
  Simulation sim(model, settingsFor(model, 0.1));
  State s = sim.state();
  std::uint64_t seed = 7;
  for (Index i = 0; i < s.velocity.rows(); ++i)
    for (int d = 0; d < 3; ++d) {
      seed = seed * 6364136223846793005ull + 1442695040888963407ull;
      s.velocity(i, d) = 0.1 * (static_cast<double>(seed >> 11) * 0x1.0p-53 - 0.5);
    }
  const Eigen::RowVector3d mean = s.velocity.colwise().mean();
  s.velocity.rowwise() -= mean;
  sim.setState(s);
  const Vec3 wanted = *bestPlaneNormal(model.mesh, model.mesh.positions(), 3);
  sim.addNormalConstraint(3);  // where it is: wanted, up to its orientation
  const std::vector<std::string> warnings = sim.takeWarnings();
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("normal constraint at vertex 3: its ring has no angle springs"),
            std::string::npos)
      << warnings[0];
  // Given twice: kept once, and said once (the ring's warning came again with it).
  sim.addNormalConstraint(3);
  const std::vector<std::string> again = sim.takeWarnings();
  ASSERT_EQ(again.size(), 1u);
  EXPECT_NE(again[0].find("normal constraint at vertex 3: given twice; kept once"),
            std::string::npos)
      << again[0];
  sim.step();
  const double start = sim.diagnostics().total();
  double low = start, high = start;
  bool held = true;
  for (int k = 0; k < 2000; ++k) {
    sim.step();
    const double e = sim.diagnostics().total();
    ASSERT_TRUE(std::isfinite(e)) << "cycle " << k;
    low = std::min(low, e);
    high = std::max(high, e);
    const ConstraintReport& report = sim.constraintReport();
    held = held && report.normalError < 1e-9 && report.targetError < 1e-9 && report.released == 0 &&
           report.turning == 0 && report.stopped == 0;
  }
  std::printf("energy after the first cycle %.6g J, then within [%.6g, %.6g]\n", start, low, high);
  EXPECT_TRUE(held);
  EXPECT_LT(high - low, 0.02 * start);
  const auto normal = bestPlaneNormal(model.mesh, sim.state().position, 3);
  ASSERT_TRUE(normal.has_value());
  // The angle as atan2(|n x w|, |n . w|): acos of the dot cannot tell angles below 1.5e-8
  // apart (one unit in the last place of the dot).
  EXPECT_LT(std::atan2(normal->cross(wanted).norm(), std::abs(normal->dot(wanted))), 1e-9);
}

TEST(Constraints, AFarNormalTargetIsTurnedToAtTheTurnRate) {
  // A target a radian from the normal is not taken in one cycle, which would take forces
  // that grow as 1 / T^2 (the split cycles of fast motion made them 1e5 N and more), but
  // turned to at kTurnRate radians per T_ring, each cycle meeting its goal.
  const Model model = dampedBracedSheet();
  Simulation sim(model, settingsFor(model, 0.5));
  pinCorners(sim);
  const Index centre = kSheetCentre;
  const Vec3 start = *bestPlaneNormal(model.mesh, model.mesh.positions(), centre);
  const Vec3 wanted = Eigen::AngleAxisd(1.0, Vec3::UnitX()) * start;
  sim.addNormalConstraint(centre, wanted);
  std::vector<Index> ring;
  normalFitVertices(model.mesh, centre, ring);
  const SystemMatrices system(model);
  double stiffest = 0.0;
  for (Index v : ring) stiffest = std::max(stiffest, system.omega2().coeff(v, v));
  const double maxTurn = ConstraintSolver::kTurnRate * sim.period() / std::sqrt(6.0 / stiffest);
  auto angle = [](const Vec3& a, const Vec3& b) { return std::atan2(a.cross(b).norm(), a.dot(b)); };
  Vec3 last = start;
  int cycles = 0;
  while (angle(last, wanted) > 1e-6 && cycles < 1000) {
    sim.step();
    ++cycles;
    const Vec3 now = *bestPlaneNormal(model.mesh, sim.state().position, centre);
    const ConstraintReport& report = sim.constraintReport();
    ASSERT_TRUE(report.converged) << "cycle " << cycles;
    EXPECT_LT(angle(last, now), maxTurn * (1.0 + 1e-6)) << "cycle " << cycles;
    if (angle(last, wanted) > 1.5 * maxTurn) {
      EXPECT_EQ(report.turning, 1) << "cycle " << cycles;
    }
    EXPECT_EQ(report.released, 0);
    last = now;
  }
  std::printf("a radian in %d cycles of at most %.4g rad\n", cycles, maxTurn);
  // Straight there, at the most a cycle may turn: over many cycles, not in one.
  EXPECT_GE(cycles, static_cast<int>(std::floor(1.0 / maxTurn)));
  EXPECT_LE(cycles, static_cast<int>(std::ceil(1.0 / maxTurn)) + 1);
  EXPECT_GT(cycles, 10);
  for (int k = 0; k < 20; ++k) {
    sim.step();
    EXPECT_EQ(sim.constraintReport().turning, 0);
  }
  EXPECT_LT(angle(*bestPlaneNormal(model.mesh, sim.state().position, centre), wanted), 1e-9);
}

TEST(Constraints, ADragFlungBesideAHeldNormalKeepsThePinsAndTheModel) {
  // A drag target flung 0.62 m in one cycle onto a vertex of a held normal's ring whose
  // centre and another ring vertex are pinned: the joint solve with the normal cannot follow
  // such motion, and left the pins unmet by more every cycle (0.025 m, then 0.19, 0.33,
  // 0.50 m ...) until the model blew up within four cycles (1e13 J). Positions first: where
  // the pins are unmet the normal yields for the cycle when that misfits less; this one did,
  // in the flung cycle. Since cycles whose motion outgrows their start are retaken
  // (kRetakeFactor), the flung cycle is taken again in many steps, each a small drag that the
  // joint solve follows, and the normal holds throughout (the yield itself:
  // ADragTheHeldNormalContradictsMovesTheVertex).
  const Model model =
      makeModel(makeTorus(10, 10), ModelSpec{.mass = 0.2, .angular = 0.02, .damping = 0.01});
  Simulation sim(model, settingsFor(model, 0.5));
  sim.addNormalConstraint(0);
  for (Index v : {0, 8, 9}) sim.addPositionConstraint(v);
  const Vec3 target = model.mesh.positions().row(10).transpose() + Vec3(0.3, 0.2, 0.5);
  sim.addPositionConstraint(10, target);
  int retakenCycles = 0, yieldedCycles = 0;
  double highest = 0.0, worstPin = 0.0;
  for (int k = 0; k < 300; ++k) {
    sim.step();
    if (sim.retakes() > 0) ++retakenCycles;
    if (sim.constraintReport().yielded > 0) ++yieldedCycles;
    for (const std::string& w : sim.takeWarnings())
      EXPECT_EQ(w.find("normal constraints let go"), std::string::npos) << "cycle " << k;
    ASSERT_TRUE(sim.state().position.allFinite()) << "cycle " << k;
    if (k >= 1) highest = std::max(highest, sim.diagnostics().kinetic);
    worstPin = std::max(worstPin, (sim.state().position.row(10).transpose() - target).norm());
  }
  std::printf(
      "kinetic energy at most %.6g J after the fling; drag at most %.3g m off; %d cycles "
      "retaken\n",
      highest, worstPin, retakenCycles);
  EXPECT_GE(retakenCycles, 1);
  EXPECT_EQ(yieldedCycles, 0);
  // The fling itself gives 12 J; the ring holds it without gaining more.
  EXPECT_LT(highest, 2.0);
  EXPECT_LT(worstPin, 0.05);
  EXPECT_LT((sim.state().position.row(10).transpose() - target).norm(), 1e-6);
}

TEST(Constraints, ADragTheHeldNormalContradictsMovesTheVertex) {
  // The corner of a sheet, its normal held and it pinned: its ring is two vertices, and a
  // drag of one of them out of the plane asks what the normal forbids. The joint solve
  // found no force that reduced its residual and left the dragged vertex where it was, the
  // whole 0.62 m from the pointer; the drag (positions first) now gets there in the cycle.
  const Model model =
      makeModel(makeGrid(10), ModelSpec{.mass = 0.2, .angular = 0.02, .damping = 0.01});
  Simulation sim(model, settingsFor(model, 0.5));
  sim.addNormalConstraint(0);
  for (Index v : {0, 8, 9}) sim.addPositionConstraint(v);
  const Vec3 target = model.mesh.positions().row(10).transpose() + Vec3(0.3, 0.2, 0.5);
  sim.addPositionConstraint(10, target);
  (void)sim.takeWarnings();
  sim.step();
  EXPECT_EQ(sim.constraintReport().yielded, 1);
  EXPECT_TRUE(sim.constraintReport().converged);
  EXPECT_LT((sim.state().position.row(10).transpose() - target).norm(), 1e-9);
  // The cycle is retaken in more steps (the fling outgrew its start), and the normal yields
  // in both attempts: the user is told once, by the retake, the abandoned attempt's warning
  // taken back with the flag that would otherwise hold the retake's back.
  EXPECT_GE(sim.retakes(), 1);
  int yieldWarnings = 0;
  for (const std::string& w : sim.takeWarnings())
    yieldWarnings += w.find("normal constraints let go") != std::string::npos;
  EXPECT_EQ(yieldWarnings, 1);
}

TEST(Constraints, ATargetTheRingCannotTurnToStopsTheTurning) {
  // A sheet pinned at its corners asked to turn its centre's normal over: the ring turns,
  // flips over and turns again, and every turn does work (before the turn budget the energy
  // climbed to 100 J in 300 cycles; before the turn rate, the first cycle put 105 J in). Once
  // the ring has lost pi radians of its way the constraint stops, says so, and holds the
  // normal where it is (AStopLastsThroughTheCyclesItsRingIsLetGo: also through let-go
  // cycles). What this does not check: that the energy then stays flat. It does at 0.5
  // T_max, by chance: the same sheet at 201 periods from 0.40 to 0.60 T_max jumps by more
  // than 5 % after its stop in 48 of the 189 runs that stop, before the drift filter's fits
  // changed in the twenty-second session (up to 2.6 times), and in 39 of 188 after (up to
  // 14 times), a held ring's open problem (docs/semi-rigid-and-constraints.md, "A stopped
  // normal can still jump").
  const Model model = makeModel(makeGrid(7), ModelSpec{.angular = 0.5});
  Simulation sim(model, settingsFor(model, 0.5));
  pinCorners(sim);
  const Index centre = kSheetCentre;
  const Vec3 start = *bestPlaneNormal(model.mesh, model.mesh.positions(), centre);
  sim.addNormalConstraint(centre, -start);
  (void)sim.takeWarnings();
  int stoppedAt = -1;
  bool warned = false;
  double atStop = 0.0, highest = 0.0;
  for (int k = 0; k < 300; ++k) {
    sim.step();
    for (const std::string& w : sim.takeWarnings())
      warned = warned || w.find("normal constraint at vertex 24 stopped") != std::string::npos;
    const ConstraintReport& report = sim.constraintReport();
    if (stoppedAt < 0 && report.stopped > 0) {
      stoppedAt = k;
      atStop = sim.diagnostics().total();
    }
    if (stoppedAt >= 0) {
      EXPECT_EQ(report.stopped, 1) << "cycle " << k;
      EXPECT_EQ(report.turning, 0) << "cycle " << k;
      highest = std::max(highest, sim.diagnostics().total());
    }
  }
  std::printf("stopped at cycle %d with %.6g J; at most %.6g J after\n", stoppedAt, atStop,
              highest);
  ASSERT_GE(stoppedAt, 0);
  EXPECT_TRUE(warned);
  // A drag stroke elsewhere (a pin added, then removed) does not start the turning again:
  // the record belongs to the normal constraint.
  const Index stroke = sim.addPositionConstraint(10);
  sim.step();
  sim.removeConstraint(stroke);
  sim.step();
  EXPECT_EQ(sim.constraintReport().stopped, 1);
  EXPECT_EQ(sim.constraintReport().turning, 0);
  // So does a change of scheme or period (the window's time-step panel).
  const double period = sim.period();
  sim.setTimeStep(Scheme::SymplecticEuler, 0.5 * period);
  sim.step();
  EXPECT_EQ(sim.constraintReport().stopped, 1);
  sim.setTimeStep(Scheme::Default, period);
  sim.step();
  EXPECT_EQ(sim.constraintReport().stopped, 1);
  EXPECT_EQ(sim.constraintReport().turning, 0);
  EXPECT_EQ(sim.period(), period);
  // A state set anew (the window's rollback, a reset) forgets the record.
  sim.setState(sim.state());
  sim.step();
  EXPECT_EQ(sim.constraintReport().stopped, 0);
  EXPECT_EQ(sim.constraintReport().turning, 1);
  // Another target starts afresh.
  sim.setConstraintNormal(*sim.constraints().find(ConstraintKind::Normal, centre), start);
  sim.step();
  EXPECT_EQ(sim.constraintReport().stopped, 0);
}

TEST(Constraints, AStopLastsThroughTheCyclesItsRingIsLetGo) {
  // The sheet above at other periods: after the stop its folding ring is let go for a cycle
  // now and then (kMaxPlaneFlatness). The stop belongs to the constraint's record, so every
  // cycle after it reports it, let go or held, and none turns the ring. Until the
  // twenty-second session a let-go cycle reported no stop (22 of 41 periods from 0.40
  // to 0.60 T_max failed on that); which periods fold after their stop follows the
  // trajectory, so several are run and some must fold.
  const Model model = makeModel(makeGrid(7), ModelSpec{.angular = 0.5});
  int letGo = 0;
  for (const double ratio : {0.43, 0.445, 0.525, 0.535, 0.545}) {
    Simulation sim(model, settingsFor(model, ratio));
    pinCorners(sim);
    const Vec3 start = *bestPlaneNormal(model.mesh, model.mesh.positions(), kSheetCentre);
    sim.addNormalConstraint(kSheetCentre, -start);
    bool stopped = false;
    for (int k = 0; k < 300; ++k) {
      sim.step();
      const ConstraintReport& report = sim.constraintReport();
      stopped = stopped || report.stopped > 0;
      if (!stopped) continue;
      EXPECT_EQ(report.stopped, 1) << ratio << " T_max, cycle " << k;
      EXPECT_EQ(report.turning, 0) << ratio << " T_max, cycle " << k;
      letGo += report.released;
    }
    EXPECT_TRUE(stopped) << ratio << " T_max";
  }
  std::printf("let go in %d cycles after the stops\n", letGo);
  EXPECT_GT(letGo, 0);
}

TEST(Constraints, ARingThatFoldsWhereItArrivesStopsInsteadOfPumpingEnergyIn) {
  // A braced Torus-I asked to turn a normal about 1 rad: the ring arrives, folds there (let
  // go), flattens, is turned back, folds again. Every turn does work and the folds let it
  // out as motion: the energy went from 0.0125 J to 2.7 J in 300 cycles and on to 32.8 J in
  // 9000 (`zsculpt simulate builtin:torus --mass 0.1 --angular-stiffness 0.3 --perturb
  // 0.05 --pin-normal 0:0.5,0.2,1`). After kFoldBudget folds where it arrived, it stops.
  const Model model = makeModel(makeTorus(10, 10), ModelSpec{.mass = 0.1, .angular = 0.3});
  Simulation sim(model, settingsFor(model, 0.5));
  perturb(sim, 0.05);
  sim.addNormalConstraint(0, Vec3(0.5, 0.2, 1.0).normalized());
  const double start = sim.diagnostics().total();
  bool stopped = false;
  double atStop = 0.0, after = 0.0;
  for (int k = 0; k < 3000; ++k) {
    sim.step();
    const double e = sim.diagnostics().total();
    if (!stopped && sim.constraintReport().stopped > 0) {
      stopped = true;
      atStop = e;
    }
    if (stopped) after = std::max(after, e);
  }
  std::printf("energy %.4g J at the start, %.4g J at the stop, at most %.4g J after it\n", start,
              atStop, after);
  ASSERT_TRUE(stopped);
  // Held where it stopped, the ring takes no more energy in than the scheme's own swing.
  EXPECT_LT(after, 1.3 * atStop);
  EXPECT_LT(after, 400.0 * start);  // 5 J; 19.9 J at 3000 cycles without the stop
}
TEST(Constraints, ARingThatSettledAtItsTargetMayFoldAgainWithoutBeingStopped) {
  // A normal pin on a damped braced Torus-I, at its target from the start, pushed hard along
  // its normal every 2500 cycles (a drag nearby; 7 N, since the angle springs' caps near
  // straight fold the ring less often than 5 N did): each push folds the ring once or twice,
  // and it comes back and settles. The folds after arriving used to be counted for ever, so
  // the third push stopped the constraint for good (cycle 3603); after kSettledPeriods
  // ring periods at the target they are forgotten, and it holds through six pushes.
  ModelSpec spec{.mass = 0.1, .angular = 0.3};
  spec.damping = 0.01;
  const Model model = makeModel(makeTorus(10, 10), spec);
  const SimulationSettings settings = settingsFor(model, 0.5);
  Simulation sim(model, settings);
  sim.addNormalConstraint(0);
  const Vec3 outward =
      Vec3(model.mesh.positions()(0, 0), model.mesh.positions()(0, 1), 0.0).normalized();
  int folds = 0;
  bool wasReleased = false;
  for (int k = 0; k < 15100; ++k) {
    if (k > 0 && k % 2500 == 0) {
      const double t = sim.state().time;
      sim.addForce(TimedLoad{
          .vertex = 0, .value = 7.0 * outward, .start = t, .end = t + 3.0 * settings.period});
    }
    sim.step();
    const ConstraintReport& report = sim.constraintReport();
    folds += report.released > 0 && !wasReleased;
    wasReleased = report.released > 0;
    ASSERT_EQ(report.stopped, 0) << "stopped at cycle " << k << " after " << folds << " folds";
  }
  EXPECT_GT(folds, 2 * (ConstraintSolver::kFoldBudget + 1));  // 12: each push folds it
  EXPECT_LT(sim.constraintReport().targetError, 1e-6);        // and it is back at its target
}

TEST(Constraints, ANormalThatCannotFollowASwingStopsInsteadOfPumpingEnergyIn) {
  // A braced dodecahedron dragged 2.3 m by a pin swings the ring of a normal pin round
  // faster than a cycle may turn it. Holding it anyway took forces that grew without
  // converging, 130 to 280 J a cycle, 455 J after 400 cycles (1.8e41 J before the turn
  // rate). What bounds it here is the turning budget: the normal, turned back over and over,
  // is stopped where it is (ConstraintReport::stopped) and held there, and the energy stays
  // near the drag's alone. (The test once claimed the normal yielded to the pins; in this
  // run it never does, and a constraint doing nothing passed the energy bound alone.)
  const Model model = makeModel(makeDodecahedron(), ModelSpec{.angular = 0.5});
  struct Outcome {
    double highest = 0.0;  // after the drag's first jolt
    int stoppedCycles = 0, turningCycles = 0;
  };
  auto run = [&](bool normal) {
    Simulation sim(model, settingsFor(model, 0.5));
    perturb(sim, 0.05);
    sim.addPositionConstraint(0, Vec3(-0.5, 1.0, 2.0));
    if (normal) sim.addNormalConstraint(5);
    Outcome o;
    for (int k = 0; k < 400; ++k) {
      sim.step();
      if (k >= 100) o.highest = std::max(o.highest, sim.diagnostics().total());
      const ConstraintReport& report = sim.constraintReport();
      o.stoppedCycles += report.stopped > 0;
      o.turningCycles += report.turning > 0;
    }
    return o;
  };
  const Outcome dragged = run(false), held = run(true);
  std::printf(
      "highest energy over cycles 100 to 400: %.6g J dragged, %.6g J with the normal pin "
      "(stopped in %d cycles, turning in %d)\n",
      dragged.highest, held.highest, held.stoppedCycles, held.turningCycles);
  EXPECT_GT(held.turningCycles, 0);  // the constraint acted: it turned the ring
  EXPECT_GT(held.stoppedCycles, 100);
  EXPECT_EQ(dragged.stoppedCycles + dragged.turningCycles, 0);
  EXPECT_LT(held.highest, 1.5 * dragged.highest);
}

TEST(Constraints, AFoldingRingIsLetGoInsteadOfTornApart) {
  // A pin dragged 1.5 m at once folds the torus, and the ring of a normal constraint nearby
  // with it: its two smallest principal variances meet, its fitted normal is undefined and
  // its gradient unbounded. Holding it there took forces along that gradient that tore the
  // ring apart (1e41 J within 300 cycles). It is let go while folded, then turned back to
  // its target at the turn rate: the energy stays near that of the same drag without it, and
  // once the torus settles the normal is back on its target (the way back from a fold does
  // not count against the turn budget, so the constraint never stops).
  UniformProperties u;
  u.mass = 0.01;
  u.stiffness = 9.5;
  u.angularStiffness = 0.05;
  const Model model = Model::fromMesh(makeBuiltin("builtin:torus:60:60"), u);
  struct Run {
    double energy = 0.0;
    bool letGo = false;   // a cycle let the normal go
    bool warned = false;  // and said so
    bool stopped = false;
    double targetError = 0.0;
  };
  auto run = [&](bool normal) {
    Simulation sim(model, settingsFor(model, 0.5));
    perturb(sim, 0.02);
    sim.addPositionConstraint(0, Vec3(1.5, 0.0, 0.1));
    if (normal) sim.addNormalConstraint(900);
    (void)sim.takeWarnings();
    Run r;
    for (int k = 0; k < 600; ++k) {
      sim.step();
      r.letGo = r.letGo || sim.constraintReport().released > 0;
      r.stopped = r.stopped || sim.constraintReport().stopped > 0;
      for (const std::string& w : sim.takeWarnings())
        r.warned =
            r.warned || w.find("normal constraint at vertex 900 let go") != std::string::npos;
    }
    r.energy = sim.diagnostics().total();
    r.targetError = sim.constraintReport().targetError;
    return r;
  };
  const double dragged = run(false).energy;
  const Run held = run(true);
  std::printf(
      "energy after 600 cycles: %.6g J dragged, %.6g J with the normal held, %.3g rad "
      "from its target\n",
      dragged, held.energy, held.targetError);
  EXPECT_TRUE(held.letGo);
  EXPECT_TRUE(held.warned);
  EXPECT_FALSE(held.stopped);
  EXPECT_LT(held.targetError, 1e-9);
  EXPECT_LT(held.energy, 1.2 * dragged);
}

// ---- split cycles (SimulationSettings::substepStrain) ----------------------------------------

namespace {

Model torusTwo() {  // Table 1's Torus-II, undamped
  UniformProperties u;
  u.mass = 0.01;
  u.stiffness = 9.5;
  return Model::fromMesh(makeBuiltin("builtin:torus:40:40"), u);
}

// Torus-II at 0.95 T_max from random velocities of `speed` (m/s RMS), split or not: the
// largest and smallest total energy over `cycles` cycles relative to the start, the most
// steps a cycle took, and whether the state stayed finite.
struct EnergyRange {
  double high = 1.0, low = 1.0;
  int mostSubsteps = 1;
  bool finite = true;
};

EnergyRange energyRange(const Model& model, double speed, double strain, int cycles) {
  SimulationSettings settings = settingsFor(model, 0.95);
  settings.substepStrain = strain;
  Simulation sim(model, settings);
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, speed, 11, start.velocity);
  sim.setState(start);
  const double e0 = sim.diagnostics().total();
  EnergyRange range;
  try {
    for (int k = 0; k < cycles; ++k) {
      sim.step();
      const double e = sim.diagnostics().total() / e0;
      range.high = std::max(range.high, e);
      range.low = std::min(range.low, e);
      range.mostSubsteps = std::max(range.mostSubsteps, sim.substeps());
    }
  } catch (const DivergenceError&) {
    range.finite = false;
  }
  return range;
}

}  // namespace

TEST(Substeps, FastMotionSplitsTheCycleAndTorusTwoKeepsItsEnergy) {
  // Random velocities of 1 m/s RMS (8 J): edges change length by about 0.7 of their rest
  // length per cycle at 0.95 T_max. In one step per cycle the springs' nonlinearity heats
  // the model until it runs away (equation 5's T_max is a linear bound); split into steps
  // that change an edge by at most 0.2, the energy stays within 1 % (measured 0.9 %).
  const Model model = torusTwo();
  const EnergyRange split = energyRange(model, 1.0, SimulationSettings{}.substepStrain, 3000);
  const EnergyRange whole = energyRange(model, 1.0, 0.0, 3000);
  std::cout << "split: E / E0 in [" << split.low << ", " << split.high << "], up to "
            << split.mostSubsteps << " steps a cycle; one step: E / E0 up to " << whole.high
            << (whole.finite ? "" : ", diverged") << "\n";
  ASSERT_TRUE(split.finite);
  EXPECT_GE(split.mostSubsteps, 4);
  EXPECT_LT(split.high, 1.01);
  EXPECT_GT(split.low, 0.99);
  EXPECT_TRUE(!whole.finite || whole.high > 100.0) << whole.high;
}

TEST(Substeps, SlowMotionTakesOneStepPerCycleBitForBit) {
  // 1 cm/s: no edge comes near the strain, so the cycle is the fixed-period one, bit for bit.
  const Model model = torusTwo();
  SimulationSettings fixed = settingsFor(model, 0.95);
  fixed.substepStrain = 0.0;
  Simulation a(model, settingsFor(model, 0.95)), b(model, fixed);
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, 0.01, 5, start.velocity);
  a.setState(start);
  b.setState(start);
  for (int k = 0; k < 500; ++k) {
    a.step();
    b.step();
    ASSERT_EQ(a.substeps(), 1) << k;
  }
  EXPECT_EQ(a.state().position, b.state().position);
  EXPECT_EQ(a.state().velocity, b.state().velocity);
  EXPECT_EQ(a.time(), b.time());
}

TEST(Substeps, AFastDragIsHeldAtEveryCycleEndAndItsWorkIsTheEnergyItPutsIn) {
  // A vertex of Torus-II dragged up and down by 0.3 m at 8 rad/s (up to 2.4 m/s) and a
  // constant force on another, undamped. Split cycles hold the pin at every cycle's end and
  // the energy stays the start energy plus the work of the drag and the force, to 1 % of
  // the energy moved in and out (the soak's bound; measured 0.3 %). In one step per cycle
  // the same drag heats the model to hundreds of times the energy moved (measured 211).
  const Model model = torusTwo();
  auto run = [&](double strain, double& gap, double& inflow, double& pinError, int& most) {
    SimulationSettings settings = settingsFor(model, 0.95);
    settings.substepStrain = strain;
    Simulation sim(model, settings);
    const Index drag = sim.addPositionConstraint(0);
    sim.addForce(TimedLoad{800, Vec3(0.3, 0.1, 0.2)});
    const Vec3 origin = model.mesh.positions().row(0).transpose();
    const double e0 = sim.diagnostics().total();
    double work = 0.0;
    gap = inflow = pinError = 0.0;
    most = 1;
    for (int k = 0; k < 1000; ++k) {
      const double t = sim.time() + sim.period();
      const Vec3 target = origin + Vec3(0.0, 0.0, 0.3 * std::sin(8.0 * t));
      sim.setConstraintTarget(drag, target);
      sim.step();
      work += sim.loadWork() + sim.constraintWork();
      inflow += std::abs(sim.loadWork()) + std::abs(sim.constraintWork());
      gap = std::max(gap, std::abs(sim.diagnostics().total() - e0 - work));
      pinError = std::max(pinError, (sim.state().position.row(0).transpose() - target).norm());
      most = std::max(most, sim.substeps());
    }
    EXPECT_TRUE(sim.takeWarnings().empty()) << "strain " << strain;
  };
  double gap = 0.0, inflow = 0.0, pinError = 0.0, wholeGap = 0.0, wholeInflow = 0.0, unused = 0.0;
  int most = 1, one = 1;
  run(SimulationSettings{}.substepStrain, gap, inflow, pinError, most);
  run(0.0, wholeGap, wholeInflow, unused, one);
  std::cout << "split (up to " << most << " steps): |E - E0 - W| up to " << gap << " J of "
            << inflow << " J moved; one step: " << wholeGap << " J of " << wholeInflow << " J\n";
  EXPECT_GE(most, 4);
  EXPECT_LT(pinError, 1e-9);
  EXPECT_GT(inflow, 10.0);
  EXPECT_LT(gap, 0.01 * inflow);
  EXPECT_GT(wholeGap, 20.0 * wholeInflow);
}

TEST(Substeps, ACycleThatRunsAwayWithinItselfIsTakenAgainInMoreSteps) {
  // The corner-pinned 7 x 7 sheet asked to turn its centre's normal over, at 0.502 T_max
  // (`zsculpt simulate builtin:grid:7 --angular-stiffness 0.5 --pin 0 --pin 6 --pin 42
  // --pin 48 --pin-normal 24:0,0,-1 --dt-ratio 0.502`). In the cycle the normal stops, the
  // ring folds and its angle springs, stiff where it folds, ran away within the cycle: 31 J
  // became 2808 J, split into no more steps than its start velocities asked for. Its end
  // velocities ask for many more: the cycle is taken again from its start in as many, and
  // the energy stays below 40 J. The abandoned attempt leaves nothing behind: momentum is
  // the ledger's, and each warning is given once.
  const Model model = makeModel(makeGrid(7), ModelSpec{.angular = 0.5});
  Simulation sim(model, settingsFor(model, 0.502));
  pinCorners(sim);
  sim.addNormalConstraint(kSheetCentre, Vec3(0, 0, -1));
  (void)sim.takeWarnings();
  int retaken = 0, stopWarnings = 0, unmetWarnings = 0, unmetInRetaken = 0;
  double highest = 0.0;
  for (int k = 0; k < 300; ++k) {
    sim.step();
    retaken += sim.retakes() > 0 ? 1 : 0;
    for (const std::string& w : sim.takeWarnings()) {
      stopWarnings += w.find("normal constraint at vertex 24 stopped") != std::string::npos;
      const bool unmet = w.find("constraints not met") != std::string::npos;
      unmetWarnings += unmet;
      unmetInRetaken += unmet && sim.retakes() > 0;
    }
    highest = std::max(highest, sim.diagnostics().total());
  }
  const Vec3 p = sim.diagnostics().momentum;
  const ImpulseLedger& ledger = sim.impulses();
  std::printf(
      "energy at most %.6g J; %d cycles retaken; %d stop warnings; %d unmet (%d in a "
      "retaken cycle); |p - ledger| %.3g\n",
      highest, retaken, stopWarnings, unmetWarnings, unmetInRetaken,
      (p - ledger.constraints).norm());
  EXPECT_GE(retaken, 1);
  EXPECT_LT(highest, 40.0);
  EXPECT_EQ(stopWarnings, 1);
  // Warned once, in the retaken cycle: the abandoned attempt's warning is taken back and its
  // warned-once flag with it, or the retake's would be held back for good.
  EXPECT_EQ(unmetWarnings, 1);
  EXPECT_EQ(unmetInRetaken, 1);
  EXPECT_LT((p - ledger.constraints).norm(), 1e-9 * (1.0 + p.norm()));
}

TEST(Substeps, AStateSetBetweenCyclesChoosesTheStepsFromItsOwnVelocities) {
  // Each cycle's end measures the strain the next one is split by. A state set (or a rest
  // length edited) in between must be measured afresh: the cycle after it is split from its
  // start, not retaken after running with the old measure.
  const Model model = torusTwo();
  Simulation sim(model, settingsFor(model, 0.95));
  sim.step();  // at rest: one step, and a measure of zero strain
  ASSERT_EQ(sim.substeps(), 1);
  State fast = sim.state();
  randomVelocity(model.properties.mass, 1.0, 11, fast.velocity);
  sim.setState(fast);
  sim.step();
  EXPECT_GE(sim.substeps(), 4);
  EXPECT_EQ(sim.retakes(), 0);
  // Shorter rest lengths: the same velocities are a larger strain.
  Simulation slow(model, settingsFor(model, 0.95));
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, 0.06, 11, start.velocity);
  slow.setState(start);
  slow.step();
  ASSERT_EQ(slow.substeps(), 1);
  for (double& lambda : slow.mutableProperties().restLength) lambda *= 0.05;
  slow.allPropertiesChanged();
  slow.step();
  EXPECT_GE(slow.substeps(), 4);
  EXPECT_EQ(slow.retakes(), 0);
}

TEST(Substeps, AnEditThatStiffensTheModelSplitsTheCyclesOfTheSchemesThatNeedIt) {
  // Torus-I at 0.5 T_max, shaken, its stiffness then multiplied by 100 everywhere (a scene's
  // global edit: T_max falls tenfold). The cycle keeps its period (a headless run's step
  // count, time and frames are in cycles); the conditionally stable schemes take it in 16
  // steps of 0.3125 T_max from the next cycle on, say so once, and do not run away, where
  // the same cycle in one step does within a few cycles (`zsculpt simulate` of such a scene
  // stopped at step 4 with symplectic Euler and the paper's scheme). Exact and implicit
  // Euler, stable at any period, are not split. An edit that softens the model again gives
  // the single step back; a time step set after the edit (the window's way: it keeps its
  // share of T_max by lowering the period) is taken as set.
  const Model model = makeModel(makeBuiltin("builtin:torus"), ModelSpec{.angular = 0.05});
  const Index n = model.mesh.numVertices();
  std::vector<Index> all(static_cast<size_t>(n));
  for (Index v = 0; v < n; ++v) all[static_cast<size_t>(v)] = v;
  for (const Scheme scheme : {Scheme::Default, Scheme::Paper, Scheme::SymplecticEuler,
                              Scheme::Exact, Scheme::ImplicitEuler}) {
    SCOPED_TRACE(std::string(schemeName(scheme)));
    const bool conditional = scheme != Scheme::Exact && scheme != Scheme::ImplicitEuler;
    // Without the default's split for strain, so that the steps counted are this rule's.
    SimulationSettings settings = settingsFor(model, 0.5, scheme);
    settings.substepStrain = 0.0;
    Simulation sim(model, settings);
    const double period = sim.period();
    State start = State::atRest(model.mesh);
    randomVelocity(model.properties.mass, 0.05, 7, start.velocity);
    sim.setState(start);
    for (int k = 0; k < 5; ++k) sim.step();
    // 5 % stiffer: the step (0.51 T_max) stays short of the trigger (0.9 of the limit),
    // and the run keeps one step a cycle.
    sim.mutableProperties().stiffness *= 1.05;
    sim.propertiesChanged(all);
    sim.step();
    ASSERT_EQ(sim.substeps(), 1);
    ASSERT_TRUE(sim.takeWarnings().empty());
    sim.mutableProperties().stiffness *= 100.0 / 1.05;
    sim.propertiesChanged(all);
    const State edited = sim.state();
    const double energyAfterEdit = sim.diagnostics().total();
    const double timeAtEdit = sim.time();
    double highest = energyAfterEdit;
    int lowered = 0;
    for (int k = 0; k < 200; ++k) {
      ASSERT_NO_THROW(sim.step()) << "cycle " << k;
      ASSERT_EQ(sim.substeps(), conditional ? 16 : 1) << "cycle " << k;
      highest = std::max(highest, sim.diagnostics().total());
      for (const std::string& w : sim.takeWarnings())
        lowered += w.find("after an edit") != std::string::npos;
    }
    EXPECT_EQ(lowered, conditional ? 1 : 0);
    EXPECT_EQ(sim.period(), period);
    EXPECT_NEAR(sim.time(), timeAtEdit + 200 * period, 1e-9 * sim.time());
    EXPECT_LT(highest, 1.5 * energyAfterEdit);
    if (conditional) {
      // The same cycles unsplit, from the same state.
      Model stiff = model;
      stiff.properties.stiffness *= 100.0;
      Simulation unsplit(stiff, settings);
      unsplit.setState(edited);
      double unsplitHighest = energyAfterEdit;
      try {
        for (int k = 0; k < 200 && unsplitHighest < 100.0 * energyAfterEdit; ++k) {
          unsplit.step();
          unsplitHighest = std::max(unsplitHighest, unsplit.diagnostics().total());
        }
      } catch (const DivergenceError&) {
        unsplitHighest = std::numeric_limits<double>::infinity();
      }
      EXPECT_GT(unsplitHighest, 100.0 * energyAfterEdit);
    }
    // Softer again: one step a cycle.
    sim.mutableProperties().stiffness /= 100.0;
    sim.propertiesChanged(all);
    sim.step();
    EXPECT_EQ(sim.substeps(), 1);
    // Stiffer, then a period set as the window sets it: taken as set, in one step.
    sim.mutableProperties().stiffness *= 100.0;
    sim.propertiesChanged(all);
    sim.setTimeStep(scheme, 0.5 * criticalPeriod(sim.stepper().system()));
    sim.step();
    EXPECT_EQ(sim.substeps(), 1);
    for (const std::string& w : sim.takeWarnings())
      EXPECT_EQ(w.find("after an edit"), std::string::npos) << w;
  }
}

TEST(Substeps, TheSplitAfterEditsDependsOnThePropertiesAloneAndHoldsTheSchemesLimit) {
  // Found by a review and a QA pass of the rule above. (1) The count is a function of the
  // properties: stiffness x4 then x0.5 (the paper scheme split into 2, then back to 1) is
  // what a run resumed with both edits applied at once (x2) takes, so a resumed run is the
  // whole run. (2) A run set near the limit (0.95 T_max) is not split by a stiffening of
  // 1e-4, which leaves it within the limit. (3) The paper scheme's limit is also its
  // damping's (1 / gamma): damping painted on a model whose T_max it leaves alone split
  // nothing, and the run diverged at step 8 (exit 3); it is split under that limit now.
  const Model model = makeModel(makeBuiltin("builtin:torus"), ModelSpec{.angular = 0.05});
  const Index n = model.mesh.numVertices();
  std::vector<Index> all(static_cast<size_t>(n));
  for (Index v = 0; v < n; ++v) all[static_cast<size_t>(v)] = v;
  auto edited = [&](Simulation& sim, double factor) {
    sim.mutableProperties().stiffness *= factor;
    sim.propertiesChanged(all);
    sim.step();
    return sim.substeps();
  };
  SimulationSettings paper = settingsFor(model, 0.5, Scheme::Paper);
  Simulation whole(model, paper), resumed(model, paper);
  EXPECT_EQ(edited(whole, 4.0), 2);
  EXPECT_EQ(edited(whole, 0.5), 1);
  EXPECT_EQ(edited(resumed, 2.0), 1);

  Simulation near(model, settingsFor(model, 0.95));
  EXPECT_EQ(edited(near, 1.0001), 1);
  EXPECT_TRUE(near.takeWarnings().empty());
  EXPECT_EQ(edited(near, 1.2), 2);                      // 1.04 T_max: past the limit
  Simulation nearer(model, settingsFor(model, 0.995));  // within the limit, past 0.99 of it
  EXPECT_EQ(edited(nearer, 1.0001), 1);
  // A fully rigid model takes no elastic step: nothing to split (and, for the paper scheme,
  // no stepper to build again for nothing).
  Model rigid = model;
  rigid.properties.rigidity.setConstant(1.0);
  Simulation body(rigid, paper);
  EXPECT_EQ(edited(body, 100.0), 1);

  Simulation damped(model, paper);
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, 0.05, 7, start.velocity);
  damped.setState(start);
  const double tMax = criticalPeriod(damped.stepper().system());
  const double e0 = damped.diagnostics().total();
  damped.mutableProperties().damping.setConstant(20.0);  // 1 / gamma = 0.05 s = 0.13 T_max
  damped.propertiesChanged(all);
  for (int k = 0; k < 100; ++k) ASSERT_NO_THROW(damped.step()) << k;
  EXPECT_EQ(criticalPeriod(damped.stepper().system()), tMax);
  EXPECT_EQ(damped.substeps(), 4);              // 0.0484 s steps, within 0.99 of 0.05 s
  EXPECT_LT(damped.diagnostics().total(), e0);  // damped, not run away
}

// ---- diagnostics (Simulation::diagnostics) ----------------------------------------------------

TEST(Diagnostics, ACycleTakesItsEnergyFromTheStep) {
  // A braced torus under gravity: after each cycle the radial and angular energy are the
  // step's own (Stepper::internalEnergy), equal to measure()'s to rounding; the kinetic
  // energy, momenta and gravity are measure()'s bit for bit. The same with a dragged vertex
  // (a constrained cycle ends at its last trial step's positions), and in a semi-rigid cycle
  // (the forces for the rigid body are taken where the rigid motion ended, with their
  // energy: Stepper::startAt). After anything that moves the state or may change a
  // property, or after a fully rigid cycle (no internal forces taken), the diagnostics are
  // measure()'s exactly.
  const Model model = makeModel(
      makeBuiltin("builtin:torus:24:16"),
      {0.01, 9.5, 0.05, 0.0, std::numeric_limits<double>::infinity(), 0.0, Vec3(0.0, 0.0, -9.81)});
  Simulation sim(model, settingsFor(model, 0.9));
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, 0.3, 7, start.velocity);
  sim.setState(start);
  auto expectMeasured = [&](const std::string& when) {
    const Diagnostics d = sim.diagnostics(), m = measure(sim.model(), sim.state());
    EXPECT_EQ(d.potential.radial, m.potential.radial) << when;
    EXPECT_EQ(d.potential.angular, m.potential.angular) << when;
    EXPECT_EQ(d.total(), m.total()) << when;
  };
  int fromStep = 0;
  auto expectFromStep = [&](const std::string& when) {
    const std::optional<PotentialEnergy> internal = sim.stepper().internalEnergy();
    ASSERT_TRUE(internal.has_value()) << when;
    const Diagnostics d = sim.diagnostics(), m = measure(sim.model(), sim.state());
    EXPECT_EQ(d.potential.radial, internal->radial) << when;
    EXPECT_EQ(d.potential.angular, internal->angular) << when;
    fromStep +=
        d.potential.radial != m.potential.radial || d.potential.angular != m.potential.angular;
    EXPECT_NEAR(d.potential.radial, m.potential.radial, 1e-13 * m.potential.radial) << when;
    EXPECT_NEAR(d.potential.angular, m.potential.angular, 1e-12 * m.potential.angular) << when;
    EXPECT_EQ(d.potential.gravity, m.potential.gravity) << when;
    EXPECT_EQ(d.kinetic, m.kinetic) << when;
    EXPECT_EQ(d.momentum, m.momentum) << when;
    EXPECT_EQ(d.angularMomentum, m.angularMomentum) << when;
    EXPECT_NEAR(d.partial, m.partial, 1e-12 * std::abs(m.partial)) << when;
  };
  expectMeasured("at the start");
  for (int k = 0; k < 40; ++k) {
    sim.step();
    expectFromStep("cycle " + std::to_string(k));
  }
  // Rounding differs somewhere: the two are not one evaluation under two names.
  EXPECT_GT(fromStep, 0);

  // A property edit through mutableProperties(), not yet announced: evaluated afresh.
  sim.mutableProperties().angularStiffness[3] = 0.5;
  expectMeasured("after an unannounced edit");
  sim.propertiesChanged(std::vector<Index>{3});
  expectMeasured("after the edit");
  sim.step();
  ASSERT_TRUE(sim.stepper().internalEnergy().has_value());
  sim.setState(start);
  expectMeasured("after setState");
  // A dragged vertex: the constrained cycle takes more than one trial step.
  const Index drag = sim.addPositionConstraint(0);
  int trials = 0;
  for (int k = 1; k <= 5; ++k) {
    sim.setConstraintTarget(
        drag, Vec3(model.mesh.positions().row(0).transpose()) + Vec3(0.0, 0.0, 0.01 * k));
    sim.step();
    trials = std::max(trials, sim.constraintReport().steps);
    expectFromStep("a constrained cycle");
  }
  EXPECT_GT(trials, 1);
  // Semi-rigid: the rigid motion moves the vertices after the elastic step.
  sim.mutableProperties().rigidity.setConstant(0.5);
  sim.allPropertiesChanged();
  ASSERT_TRUE(sim.rigidActive());
  for (int k = 0; k < 3; ++k) {
    sim.step();
    expectFromStep("a semi-rigid cycle");
  }
  sim.mutableProperties().rigidity.setConstant(1.0);
  sim.allPropertiesChanged();
  sim.step();
  expectMeasured("a fully rigid cycle");
}

TEST(Simulation, RemovedLoadsAndPinsLeaveNoForceBehind) {
  // Cycles without loads or constraints keep the external and constraint forces at zero
  // without clearing them every cycle: those of before the removal must not linger, in the
  // forces shown, in the step, or in the momentum ledger.
  const Model model = makeModel(makeTorus(8, 5));
  Simulation sim(model, settingsFor(model, 0.4));
  const Index pin = sim.addPositionConstraint(
      0, Vec3(0.3, 0.2, 0.1) + Vec3(model.mesh.positions().row(0).transpose()));
  sim.addForce(TimedLoad{20, Vec3(2, 0, 1), 0.0, 100.0});
  sim.addTorque(TimedLoad{30, Vec3(0, 0, 1.3), 0.0, 100.0});
  for (int k = 0; k < 20; ++k) sim.step();
  ASSERT_GT(sim.externalForces().norm(), 1.0);
  ASSERT_GT(sim.constraintForces().norm(), 1e-3);
  sim.removeConstraint(pin);
  sim.clearLoads();
  const Vec3 p0 = sim.diagnostics().momentum;
  const ImpulseLedger before = sim.impulses();
  for (int k = 0; k < 50; ++k) {
    sim.step();
    ASSERT_TRUE(sim.externalForces().isZero(0.0)) << "cycle " << k;
    ASSERT_TRUE(sim.constraintForces().isZero(0.0)) << "cycle " << k;
  }
  EXPECT_LT((sim.diagnostics().momentum - p0).norm(), 1e-12 * (1.0 + p0.norm()));
  EXPECT_TRUE(sim.impulses().loads == before.loads);
  EXPECT_TRUE(sim.impulses().loadsAngular == before.loadsAngular);
  EXPECT_TRUE(sim.impulses().constraints == before.constraints);
}

TEST(Simulation, ALoadThatEndsWhileAnotherActsLeavesNothingOnItsVertex) {
  // A cycle clears only the rows the last cycle's loads wrote (externalRows_): when the force
  // on vertex 20 ends and the torque on vertex 30 goes on, row 20 must be cleared although no
  // load writes it any more, and only the torque's vertex and ring may be loaded.
  const Model model = makeModel(makeTorus(8, 5));
  Simulation sim(model, settingsFor(model, 0.4));
  const double t = sim.period();
  sim.addForce(TimedLoad{20, Vec3(2, 0, 1), 0.0, 5.5 * t});
  sim.addTorque(TimedLoad{30, Vec3(0, 0, 1.3), 0.0, 100.0});
  std::vector<bool> ring(static_cast<size_t>(model.mesh.numVertices()), false);
  ring[30] = true;
  for (const Index w : model.mesh.vertexNeighbors(30)) ring[static_cast<size_t>(w)] = true;
  ASSERT_FALSE(ring[20]);
  for (int k = 0; k < 12; ++k) {
    sim.step();
    const Points& external = sim.externalForces();
    // (Cycle 5 holds the end: a split cycle shows its last step's loads, none.)
    if (k != 5) {
      EXPECT_EQ(external.row(20).isZero(0.0), k > 5) << "cycle " << k;
    }
    for (Index v = 0; v < model.mesh.numVertices(); ++v) {
      if (v != 20 && !ring[static_cast<size_t>(v)]) {
        ASSERT_TRUE(external.row(v).isZero(0.0)) << "cycle " << k << " vertex " << v;
      }
    }
    EXPECT_GT(external.row(30).norm(), 0.0) << "cycle " << k;
  }
}

TEST(Simulation, ALoadedPinnedCycleAllocatesNothing) {
  // The per-cycle path allocates nothing once running: a force, a torque and a pin on a
  // braced torus, the plain and the constrained cycle alike, on one thread and on two (a
  // torus large enough to be stepped on two). The torque starts after the counting does, so
  // that its rows join the loads' row lists then: they were reserved when it was added
  // (reserveLoadRows), and no cycle grows them. The counter sees C allocations too: on one
  // thread every parallel region made libgomp allocate a team, 8 a cycle, until the
  // twenty-sixth session (parallelRegion, forEachPart).
  struct Case {
    int u, v, threads;
  };
  for (const Case c : {Case{12, 8, 1}, Case{40, 40, 1}, Case{40, 40, 2}})
    for (const bool pinned : {false, true}) {
      const Model model = makeModel(makeTorus(c.u, c.v), ModelSpec{.angular = 0.2});
      SimulationSettings settings = settingsFor(model, 0.5);
      settings.stepper.threads = c.threads;
      Simulation sim(model, settings);
      const double t = sim.period();
      sim.addForce(TimedLoad{20, Vec3(0.5, 0, 0.2), 0.0, 100.0});
      sim.addTorque(TimedLoad{30, Vec3(0, 0, 0.3), 8.5 * t, 100.0});
      if (pinned) sim.addPositionConstraint(0);
      for (int k = 0; k < 3; ++k) sim.step();
      gAllocations = 0;
      gCounting = true;
      for (int k = 0; k < 20; ++k) sim.step();
      gCounting = false;
      EXPECT_EQ(gAllocations.load(), 0) << (pinned ? "pinned" : "loads only") << ", torus " << c.u
                                        << "x" << c.v << ", " << c.threads << " thread(s)";
    }
}

TEST(Simulation, EverySchemesCycleAllocatesNothing) {
  // The house rule holds for every scheme, the exact one (the tests' oracle, dense modes)
  // included: its blocked dense products allocated packing buffers every step until the
  // twenty-seventh session (at 900 vertices: 90 in 10 cycles; a 96-vertex model's packing
  // fitted on the stack).
  const Model model = makeModel(makeTorus(30, 30), ModelSpec{.angular = 0.2});
  for (const Scheme scheme : {Scheme::Default, Scheme::Paper, Scheme::Exact,
                              Scheme::SymplecticEuler, Scheme::ImplicitEuler}) {
    SimulationSettings settings = settingsFor(model, 0.5, scheme);
    settings.stepper.threads = 1;
    Simulation sim(model, settings);
    sim.addForce(TimedLoad{20, Vec3(0.5, 0, 0.2), 0.0, 100.0});
    for (int k = 0; k < 3; ++k) sim.step();
    gAllocations = 0;
    gCounting = true;
    for (int k = 0; k < 10; ++k) sim.step();
    gCounting = false;
    EXPECT_EQ(gAllocations.load(), 0) << schemeName(scheme);
  }
}

TEST(DivergenceGuard, AnEditsEnergyIsCountedAsWorkAndCheckpointsTakeTurns) {
  const Model model = makeModel(makeTorus(12, 8), ModelSpec{.angular = 0.2});
  SimulationSettings settings = settingsFor(model, 0.5);
  settings.substepStrain = 0.0;  // one step a cycle, so that a period too long blows up
  Simulation sim(model, settings);
  State start = State::atRest(model.mesh);
  start.velocity.col(2).setConstant(0.0);
  start.velocity(0, 2) = 1.0;
  start.velocity(40, 2) = -1.0;
  sim.setState(start);
  DivergenceGuard told(sim), untold(sim);
  std::uint64_t cycle = 0;
  auto cycleOnce = [&] {
    told.beforeStep(sim, cycle);
    untold.beforeStep(sim, cycle);
    sim.step();
    ++cycle;
    const Diagnostics d = sim.diagnostics();
    return std::pair{told.afterStep(sim, d), untold.afterStep(sim, d)};
  };
  for (int k = 0; k < 70; ++k) ASSERT_EQ(cycleOnce(), std::pair(true, true)) << k;
  // The older checkpoint is the one kept: at least kCheckpointEvery cycles back.
  EXPECT_EQ(told.lastGoodCycle(), 32u);
  EXPECT_GE(cycle - told.lastGoodCycle(), DivergenceGuard::kCheckpointEvery);
  // Rest lengths 1.3 times as long: the stored energy jumps far past ten times the start,
  // and the model stays stable (T_max does not depend on them). Told as an edit's change, it
  // is work put in; untold, it looks like a runaway.
  const double before = sim.diagnostics().total();
  sim.mutableProperties().restLength *= 1.3;
  sim.allPropertiesChanged();
  told.editChangedEnergy();
  told.measureEdit(sim);
  ASSERT_GT(sim.diagnostics().total(), 20.0 * before);
  const auto [toldOk, untoldOk] = cycleOnce();
  EXPECT_TRUE(toldOk);
  EXPECT_FALSE(untoldOk);
  EXPECT_NE(untold.reason().find("the energy ran away"), std::string::npos);
  for (int k = 0; k < 200; ++k) ASSERT_TRUE(cycleOnce().first) << k;
  // Still armed: measured before the step, an edit's credit is its own change, not the
  // step's. A stiffness 400 times higher at the same period (10 times T_max), the period set
  // again after the edit (so taken as set, not split: Simulation::chooseStableSubsteps),
  // blows up, and the told guard catches it while the energy is finite.
  sim.mutableProperties().stiffness *= 400.0;
  sim.allPropertiesChanged();
  sim.setTimeStep(sim.stepper().scheme(), sim.period());
  told.editChangedEnergy();
  told.measureEdit(sim);
  bool caught = false;
  for (int k = 0; k < 50 && !caught; ++k) {
    told.beforeStep(sim, cycle);
    try {
      sim.step();
    } catch (const DivergenceError&) {
      break;
    }
    ++cycle;
    caught = !told.afterStep(sim, sim.diagnostics());
  }
  EXPECT_TRUE(caught);
  EXPECT_NE(told.reason().find("the energy ran away"), std::string::npos) << told.reason();
}

TEST(DivergenceGuard, AStiffnessCappedModelMovingStablyIsNotARunaway) {
  // kappa 500 capped at 5: the deformation feels sigma = 0.01 of the springs' forces and
  // keeps K + sigma V, while K + V swings to tens of times its start (all of it kinetic at
  // the start). The guard watches K + sigma_min V, so it lets this run go, and still
  // catches the same model at three times its critical period.
  const Model model =
      makeModel(makeTorus(10, 10), ModelSpec{.stiffness = 500.0, .angular = 0.5, .cap = 5.0});
  for (const double ratio : {0.5, 3.0}) {
    SimulationSettings settings = settingsFor(model, ratio);
    settings.substepStrain = 0.0;
    Simulation sim(model, settings);
    ASSERT_DOUBLE_EQ(sim.uniformElasticShare(), 0.01);
    State start = State::atRest(model.mesh);
    randomVelocity(model.properties.mass, 0.05, 3, start.velocity);
    sim.setState(start);
    DivergenceGuard guard(sim);
    const double e0 = sim.diagnostics().total();
    double largest = e0;
    bool ok = true;
    for (std::uint64_t k = 0; k < 3000 && ok; ++k) {
      guard.beforeStep(sim, k);
      try {
        sim.step();
      } catch (const DivergenceError&) {
        ok = false;
        break;
      }
      const Diagnostics d = sim.diagnostics();
      largest = std::max(largest, d.total());
      ok = guard.afterStep(sim, d);
    }
    if (ratio < 1.0) {
      EXPECT_TRUE(ok) << guard.reason();
      EXPECT_GT(largest, 10.0 * e0);  // the total a guard on K + V would call a runaway
    } else {
      EXPECT_FALSE(ok);
    }
  }
}

TEST(DivergenceGuard, AVariedRigidityIsWatchedOnItsTotalEnergy) {
  // Torus-I stressed (rest lengths x0.9), half of it painted (nearly) rigid. Weighting the
  // springs by the smallest sigma stopped the 0.99 run at step 2 while its total energy
  // fell, and at rigidity 1 did not watch the springs at all. On the total energy the
  // stable runs go on, and the same model at three times its critical period is caught.
  auto run = [](double rigidity, double ratio, int cycles) {
    Model model = makeModel(makeTorus(10, 10), ModelSpec{.mass = 0.1, .angular = 0.05});
    model.properties.restLength *= 0.9;
    for (Index v = 50; v < 100; ++v) model.properties.rigidity[v] = rigidity;
    SimulationSettings settings = settingsFor(model, ratio);
    settings.substepStrain = 0.0;
    Simulation sim(model, settings);
    EXPECT_EQ(sim.uniformElasticShare(), 1.0);
    DivergenceGuard guard(sim);
    for (int k = 0; k < cycles; ++k) {
      guard.beforeStep(sim, static_cast<std::uint64_t>(k));
      try {
        sim.step();
      } catch (const DivergenceError&) {
        return k;
      }
      if (!guard.afterStep(sim, sim.diagnostics())) return k;
    }
    return cycles;
  };
  EXPECT_EQ(run(0.99, 0.5, 2000), 2000);
  EXPECT_EQ(run(1.0, 0.5, 2000), 2000);
  EXPECT_LT(run(0.99, 3.0, 2000), 2000);
  EXPECT_LT(run(1.0, 3.0, 2000), 2000);
}

TEST(DivergenceGuard, ARunawayWhereRigidityVariesSaysThatDampingHelps) {
  // Torus-I with rigidity 0.99 painted on half of it, gently shaken: the varied split heats it
  // and the guard stops it within a few dozen cycles (docs/semi-rigid-and-constraints.md,
  // open). The message says what helps; with damping the same run settles. A runaway of
  // another cause, on a model whose rigidity is uniform, is not told so.
  auto run = [](double rigidity, double damping, double ratio, std::string& why) -> int {
    Model model = makeModel(makeTorus(10, 10), ModelSpec{.mass = 0.1, .angular = 0.05});
    model.properties.damping.setConstant(damping);
    for (Index v = 0; v < 100; ++v) model.properties.rigidity[v] = v >= 50 ? rigidity : 0.5;
    SimulationSettings settings = settingsFor(model, ratio);
    settings.substepStrain = 0.0;
    Simulation sim(model, settings);
    perturb(sim, 0.05);
    DivergenceGuard guard(sim);
    for (int k = 0; k < 3000; ++k) {
      guard.beforeStep(sim, static_cast<std::uint64_t>(k));
      try {
        sim.step();
      } catch (const DivergenceError& e) {
        why = std::string("not finite: ") + e.what();  // not the guard's
        return k;
      }
      if (!guard.afterStep(sim, sim.diagnostics())) {
        why = guard.reason();
        return k;
      }
    }
    return 3000;
  };
  const std::string hint = "rigidity that varies from vertex to vertex can feed energy in";
  std::string why;
  EXPECT_LT(run(0.99, 0.0, 0.5, why), 200);
  EXPECT_NE(why.find(hint + " faster than anything takes it out: damping helps"), std::string::npos)
      << why;
  why.clear();
  EXPECT_EQ(run(0.99, 0.05, 0.5, why), 3000) << why;
  // Too little damping: the guard says more.
  EXPECT_LT(run(0.99, 0.002, 0.5, why), 3000);
  EXPECT_NE(why.find(hint + " faster than the damping takes it out: more damping helps"),
            std::string::npos)
      << why;
  // Uniform rigidity beyond its stable limit: caught by the guard, and not told so.
  EXPECT_LT(run(0.5, 0.0, 3.0, why), 3000);
  EXPECT_EQ(why.rfind("the energy ran away", 0), 0u) << why;
  EXPECT_EQ(why.find(hint), std::string::npos) << why;
}

TEST(SemiRigid, FullyRigidVerticesMoveOnlyWithTheBody) {
  // Half of a stressed Torus-I fully rigid (sigma = 0), shaken: the hand-over used to leave
  // its vertices a deformation velocity that no force ever took back, and they drifted off
  // the body: the energy ran from 5.9 J to 87,415 J in 3000 cycles. Their deformation is
  // now zero after every cycle, P and L are kept, and the energy only falls (the relative
  // motion dropped is lost, as in an inelastic constraint).
  Model model = makeModel(makeTorus(10, 10), ModelSpec{.mass = 0.1, .angular = 0.05});
  model.properties.restLength *= 0.9;
  for (Index v = 50; v < 100; ++v) model.properties.rigidity[v] = 1.0;
  Simulation sim(model, settingsFor(model, 0.5));
  perturb(sim, 0.5);
  const Diagnostics d0 = sim.diagnostics();
  double largest = d0.total(), worstP = 0.0, worstL = 0.0;
  for (int k = 0; k < 3000; ++k) {
    sim.step();
    const Diagnostics d = sim.diagnostics();
    largest = std::max(largest, d.total());
    worstP = std::max(worstP, (d.momentum - d0.momentum).norm());
    worstL = std::max(worstL,
                      (d.angularMomentum - d0.angularMomentum).norm() / d0.angularMomentum.norm());
  }
  std::printf("energy %.4g J at the start, at most %.4g J, %.4g J at the end\n", d0.total(),
              largest, sim.diagnostics().total());
  EXPECT_LT(largest, 1.05 * d0.total());
  EXPECT_LT(worstP, 1e-12);
  EXPECT_LT(worstL, 1e-11);
}

TEST(Simulation, ALargeModelThatDivergesIsCaughtAndRolledBack) {
  // 40000 vertices: the cycle's finiteness check runs on both threads, in parts. Symplectic
  // Euler at three times its stable limit blows up; the cycle that makes the state
  // non-finite throws and leaves the last good state.
  const Model model = makeModel(makeTorus(200, 200));
  SimulationSettings settings = settingsFor(model, 3.0, Scheme::SymplecticEuler);
  settings.substepStrain = 0.0;
  Simulation sim(model, settings);
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, 0.01, 5, start.velocity);
  sim.setState(start);
  State last = sim.state();
  bool diverged = false;
  for (int k = 0; k < 2000 && !diverged; ++k) {
    last = sim.state();
    try {
      sim.step();
    } catch (const DivergenceError&) {
      diverged = true;
    }
  }
  ASSERT_TRUE(diverged);
  EXPECT_TRUE(sim.state().position == last.position);
  EXPECT_TRUE(sim.state().velocity == last.velocity);
  EXPECT_EQ(sim.state().time, last.time);
}

TEST(Simulation, AMovedPinLeavesNoForceWhereItWas) {
  // The constraint forces are cleared only when the constrained vertices change (each trial
  // writes their rows): a pin moved to another vertex leaves no force at the first.
  for (double rigidity : {0.0, 0.5}) {
    ModelSpec spec;
    spec.rigidity = rigidity;
    const Model m = makeModel(makeTorus(8, 5), spec);
    Simulation sim(m, settingsFor(m, 0.4));
    const Vec3 offset(0.3, 0.2, 0.1);
    auto rest = [&](Index v) { return Vec3(m.mesh.positions().row(v).transpose()); };
    const Index first = sim.addPositionConstraint(0, rest(0) + offset);
    sim.addPositionConstraint(20, rest(20) - offset);
    for (int k = 0; k < 10; ++k) sim.step();
    ASSERT_GT(sim.constraintForces().row(0).norm(), 1e-3) << "rigidity " << rigidity;
    ASSERT_GT(sim.constraintForces().row(20).norm(), 1e-3) << "rigidity " << rigidity;
    sim.removeConstraint(first);
    sim.addPositionConstraint(7, rest(7) + offset);
    for (int k = 0; k < 3; ++k) {
      sim.step();
      for (Index v = 0; v < m.mesh.numVertices(); ++v) {
        if (v == 7 || v == 20)
          EXPECT_GT(sim.constraintForces().row(v).norm(), 1e-3) << "rigidity " << rigidity;
        else
          EXPECT_TRUE(sim.constraintForces().row(v).isZero(0.0))
              << "vertex " << v << ", rigidity " << rigidity;
      }
    }
  }
}

TEST(Simulation, APinMetByItsFirstTrialLeavesTheFreeCycleAsItWas) {
  // A constrained trial is finished only once it meets the constraints (Stepper::beginStep,
  // finishStep), with rigid motion where the elastic step ended, before the rigid motion
  // moved the vertices. A pin whose target is where the free cycle takes its vertex is met
  // by the first trial with no force: the cycle is the free one, bit for bit, but for the
  // pinned vertex's velocity (the correction).
  for (double rigidity : {0.0, 0.5}) {
    ModelSpec spec;
    spec.angular = 0.3;  // braced: the drift filter
    spec.rigidity = rigidity;
    spec.gravity = Vec3(0.0, 0.0, -9.81);
    const Model model = makeModel(makeTorus(8, 5), spec);
    State start = State::atRest(model.mesh);
    randomVelocity(model.properties.mass, 0.05, 31, start.velocity);
    Simulation free(model, settingsFor(model, 0.5)), pinned(model, settingsFor(model, 0.5));
    free.setState(start);
    pinned.setState(start);
    free.step();
    const Index v = 3;
    pinned.addPositionConstraint(v, free.state().position.row(v).transpose());
    pinned.step();
    ASSERT_EQ(pinned.constraintReport().steps, 1) << "rigidity " << rigidity;
    EXPECT_TRUE(pinned.state().position == free.state().position) << "rigidity " << rigidity;
    for (Index i = 0; i < model.mesh.numVertices(); ++i) {
      if (i == v) continue;
      ASSERT_TRUE(pinned.state().velocity.row(i) == free.state().velocity.row(i))
          << "vertex " << i << ", rigidity " << rigidity;
    }
  }
}

TEST(Simulation, APinnedLargeModelIsTheSameBitsOnOneThreadAndTwo) {
  // 60,000 vertices: the cycle's copies, sums of loads and constraint forces, finiteness check
  // and the ledger's centres of mass run on the step's threads, the centres in fixed parts;
  // with rigid motion, the forces for the rigid body come from the step's force kernel. One
  // thread and two give the same states, diagnostics and impulses, bit for bit.
  for (double rigidity : {0.0, 0.5}) {
    ModelSpec spec;
    spec.gravity = Vec3(0.0, 0.0, -9.81);
    spec.angular = 0.05;
    spec.rigidity = rigidity;
    const Model model = makeModel(makeTorus(250, 240), spec);
    std::vector<Simulation> runs;
    for (int threads : {1, 2}) {
      SimulationSettings settings = settingsFor(model, 0.4);
      settings.stepper.threads = threads;
      Simulation sim(model, settings);
      State start = State::atRest(model.mesh);
      randomVelocity(model.properties.mass, 0.01, 9, start.velocity);
      sim.setState(start);
      sim.addPositionConstraint(
          0, Vec3(model.mesh.positions().row(0).transpose()) + Vec3(0.01, 0.0, 0.02));
      sim.addForce(TimedLoad{1000, Vec3(0.5, 0.0, -0.2), 0.0, 1.0});
      for (int k = 0; k < 3; ++k) sim.step();
      runs.push_back(std::move(sim));
    }
    const Simulation &one = runs[0], &two = runs[1];
    EXPECT_TRUE(one.state().position == two.state().position) << "rigidity " << rigidity;
    EXPECT_TRUE(one.state().velocity == two.state().velocity) << "rigidity " << rigidity;
    const Diagnostics a = one.diagnostics(), b = two.diagnostics();
    EXPECT_EQ(a.kinetic, b.kinetic) << "rigidity " << rigidity;
    EXPECT_TRUE(a.angularMomentum == b.angularMomentum) << "rigidity " << rigidity;
    for (auto field : {&ImpulseLedger::loads, &ImpulseLedger::gravity, &ImpulseLedger::constraints,
                       &ImpulseLedger::loadsAngular, &ImpulseLedger::constraintsAngular})
      EXPECT_TRUE(one.impulses().*field == two.impulses().*field) << "rigidity " << rigidity;
    EXPECT_GT(one.impulses().constraintsAngular.norm(), 0.0);
    EXPECT_GT(one.impulses().loadsAngular.norm(), 0.0);
  }
}
