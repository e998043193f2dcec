// Constraints module: best-plane normals, the constraint set and its errors, the step
// response model against the real stepper, and the solve for virtual forces (section 6).

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdlib>
#include <functional>

#include "zsculpt/constraints/constraints.h"
#include "zsculpt/constraints/solver.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/matrices.h"

using namespace zsculpt;

namespace {

Model makeModel(Mesh mesh, double angular = 0.0, double damping = 0.0) {
  UniformProperties u;
  u.angularStiffness = angular;
  u.damping = damping;
  return Model::fromMesh(std::move(mesh), u);
}

bool throwsWith(const std::function<void()>& f, const std::string& text) {
  try {
    f();
  } catch (const InvalidInputError& e) {
    return std::string(e.what()).find(text) != std::string::npos;
  }
  return false;
}

/// One cycle by hand: a free step anchors the response of `scheme`, the solver (set up for
/// `set`, with no forces yet) finds the virtual forces, and a real step with them is
/// checked against the constraints (1e-11 m, 1e-9 rad).
ConstraintReport solveOneCycle(const Model& model, const ConstraintSet& set, Scheme scheme,
                               ConstraintSolver& solver) {
  const Mesh& mesh = model.mesh;
  Stepper stepper(model, scheme, 0.5 * criticalPeriod(SystemMatrices(model)));
  StepResponse response;
  response.buildElastic(stepper, model, {}, solver.support());
  const State start = State::atRest(mesh);
  solver.beginStep(mesh, set, start.position, model.properties.mass, stepper.system().omega2(),
                   stepper.period());
  State free = start;
  stepper.step(free, Points::Zero(mesh.numVertices(), 3));
  const Index s = static_cast<Index>(solver.support().size());
  Points anchor(s, 3);
  for (Index a = 0; a < s; ++a) anchor.row(a) = free.position.row(solver.support()[a]);
  response.anchor(anchor, Vec3::Zero(), solver.forces());
  solver.solve(set, response, 1e-12, 1e-10);
  Points loaded = Points::Zero(mesh.numVertices(), 3);
  for (Index a = 0; a < s; ++a) loaded.row(solver.support()[a]) = solver.forces().row(a);
  State pushed = start;
  stepper.invalidate();
  stepper.step(pushed, loaded);
  ConstraintReport report;
  solver.check(set, pushed.position, 1e-11, 1e-9, report);
  return report;
}

}  // namespace

TEST(LeastNormSolve, IsEigensCompleteOrthogonalSolve) {
  // The Newton step's solve without Eigen's allocations: the same least-squares, least-norm
  // solution, for full-rank, wide, tall and rank-deficient Jacobians (as a pin and a normal
  // on one ring make them).
  std::srand(11);
  for (const auto [rows, cols, rank] :
       {std::array<Index, 3>{6, 6, 6}, {9, 6, 6}, {6, 9, 6}, {9, 8, 5}, {12, 12, 7}, {3, 3, 0}}) {
    const Eigen::MatrixXd a = rank > 0 ? Eigen::MatrixXd(Eigen::MatrixXd::Random(rows, rank) *
                                                         Eigen::MatrixXd::Random(rank, cols))
                                       : Eigen::MatrixXd::Zero(rows, cols);
    const VectorX b = VectorX::Random(rows);
    Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> factor(a);
    ASSERT_EQ(factor.rank(), rank);
    VectorX work(rows), unpermuted(cols), x(cols);
    leastNormSolve(factor, b, work, unpermuted, x);
    const VectorX expected = factor.solve(b);
    EXPECT_LT((x - expected).norm(), 1e-12 * (1.0 + expected.norm()))
        << rows << " x " << cols << ", rank " << rank;
    // And it is the least-squares solution of least norm: A^T (A x - b) = 0, x in A's row
    // space (orthogonal to its null space).
    EXPECT_LT((a.transpose() * (a * x - b)).norm(), 1e-10 * (1.0 + b.norm()));
  }
}

TEST(Normals, BestPlaneFit) {
  const std::vector<Vec3> plane = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(1, 1, 0)};
  const auto n = fitPlaneNormal(plane);
  ASSERT_TRUE(n.has_value());
  EXPECT_NEAR(std::abs(n->z()), 1.0, 1e-15);
  const std::vector<Vec3> line = {Vec3(0, 0, 0), Vec3(1, 1, 1), Vec3(2, 2, 2)};
  EXPECT_FALSE(fitPlaneNormal(line).has_value());
  EXPECT_FALSE(fitPlaneNormal(std::span<const Vec3>(plane.data(), 2)).has_value());

  // Dodecahedron: radial and outward. Grid: +z (faces face +z).
  const Mesh d = makeDodecahedron();
  for (Index v = 0; v < d.numVertices(); ++v) {
    const auto normal = bestPlaneNormal(d, d.positions(), v);
    ASSERT_TRUE(normal.has_value());
    EXPECT_NEAR(normal->dot(d.positions().row(v).normalized()), 1.0, 1e-12);
  }
  const Mesh g = makeGrid(4);
  EXPECT_NEAR(bestPlaneNormal(g, g.positions(), 5)->z(), 1.0, 1e-15);
  // A helix: defined inside (the osculating plane), not at its ends.
  const Mesh h = makeHelix(12);
  EXPECT_FALSE(bestPlaneNormal(h, h.positions(), 0).has_value());
  EXPECT_FALSE(bestPlaneNormal(h, h.positions(), 11).has_value());
  EXPECT_TRUE(bestPlaneNormal(h, h.positions(), 5).has_value());
}

TEST(ConstraintSet, AddMoveRemove) {
  const Mesh d = makeDodecahedron();
  ConstraintSet set;
  const Index a = set.addPosition(d, 3, Vec3(1, 2, 3));
  const Index b = set.addNormal(d, d.positions(), 4, Vec3(0, 0, 2));
  EXPECT_NE(a, b);
  EXPECT_EQ(set.size(), 2u);
  EXPECT_NEAR(set.get(b).value.norm(), 1.0, 1e-15);  // normalised
  const auto revision = set.revision();
  set.setTarget(a, Vec3(0, 0, 0));
  EXPECT_EQ(set.revision(), revision);  // moving a target is not a structural change
  EXPECT_TRUE(set.get(a).value.isZero(0.0));
  EXPECT_EQ(set.find(ConstraintKind::Position, 3), a);
  EXPECT_FALSE(set.find(ConstraintKind::Normal, 3).has_value());
  EXPECT_THROW(set.setTarget(b, Vec3::Zero()), InvalidInputError);  // a normal has no target
  EXPECT_THROW(set.setNormal(a, Vec3::UnitZ()), InvalidInputError);
  set.remove(a);
  EXPECT_NE(set.revision(), revision);
  EXPECT_THROW((void)set.get(a), InvalidInputError);
  EXPECT_THROW(set.remove(a), InvalidInputError);
  set.clear();
  EXPECT_TRUE(set.empty());
}

TEST(ConstraintSet, BadInputGetsAClearError) {
  const Mesh d = makeDodecahedron();
  ConstraintSet set;
  EXPECT_TRUE(throwsWith([&] { set.addPosition(d, 20, Vec3::Zero()); },
                         "position constraint at vertex 20: no such vertex"));
  EXPECT_TRUE(throwsWith([&] { set.addPosition(d, 1, Vec3(0, NAN, 0)); }, "not finite"));
  EXPECT_TRUE(throwsWith([&] { set.addNormal(d, d.positions(), 1, Vec3::Zero()); }, "non-zero"));
  set.addPosition(d, 1, Vec3(0, 0, 1));
  EXPECT_TRUE(throwsWith([&] { set.addPosition(d, 1, Vec3(0, 0, 1.5)); }, "different targets"));
  EXPECT_EQ(set.addPosition(d, 1, Vec3(0, 0, 1)), set.find(ConstraintKind::Position, 1));
  EXPECT_EQ(set.takeWarnings().size(), 1u);
  EXPECT_TRUE(set.takeWarnings().empty());
  set.addNormal(d, d.positions(), 2, Vec3(0, 0, 1));
  EXPECT_TRUE(
      throwsWith([&] { set.addNormal(d, d.positions(), 2, Vec3(0, 1, 0)); }, "different normals"));

  const Mesh h = makeHelix(6);
  EXPECT_TRUE(throwsWith([&] { set.addNormal(h, h.positions(), 0, Vec3::UnitZ()); }, "curve end"));
  Points straight(3, 3);
  straight << 0, 0, 0, 1, 0, 0, 2, 0, 0;
  const Mesh line(straight, {}, {{0, 1}, {1, 2}});
  EXPECT_TRUE(
      throwsWith([&] { set.addNormal(line, line.positions(), 1, Vec3::UnitZ()); }, "collinear"));
  Points lonely(4, 3);
  lonely << 0, 0, 0, 1, 0, 0, 0, 1, 0, 3, 3, 3;
  const Mesh withIsolated(lonely, {{0, 1, 2}});
  EXPECT_TRUE(throwsWith([&] { set.addNormal(withIsolated, lonely, 3, Vec3::UnitZ()); },
                         "isolated vertex"));
  // An interior vertex of a cubic lattice: its six neighbours lie along three axes alike, so
  // no plane is flatter than another (planeFlatness 1).
  const Mesh lattice = makeLattice(4);
  EXPECT_TRUE(throwsWith([&] { set.addNormal(lattice, lattice.positions(), 21, Vec3::UnitZ()); },
                         "normal constraint at vertex 21: the vertex and its neighbours have no "
                         "flattest direction in the mesh (flatness 1 > 0.8)"));
}

TEST(ConstraintSet, PlaneFlatnessTellsARingWithAPlaneFromOneWithout) {
  auto flatness = [](std::vector<Vec3> points) { return planeFlatness(points); };
  // Principal variances 1/3, 4/3 and h^2/3 along x, y and z: l0 / l1 = min(1, h^2) / 1 for
  // h <= 2.
  auto box = [](double h) {
    return std::vector<Vec3>{Vec3(1, 0, 0),  Vec3(-1, 0, 0), Vec3(0, 2, 0),
                             Vec3(0, -2, 0), Vec3(0, 0, h),  Vec3(0, 0, -h)};
  };
  EXPECT_EQ(flatness(box(0.0)), 0.0);
  EXPECT_NEAR(flatness(box(0.5)), 0.25, 1e-12);
  EXPECT_NEAR(flatness(box(0.9)), 0.81, 1e-12);
  // A regular tetrahedron's corners: no direction is flattest.
  EXPECT_NEAR(flatness({Vec3(1, 1, 1), Vec3(1, -1, -1), Vec3(-1, 1, -1), Vec3(-1, -1, 1)}), 1.0,
              1e-12);
  // No plane at all.
  EXPECT_EQ(flatness({Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(2, 0, 0)}), 1.0);
  EXPECT_EQ(flatness({Vec3(0, 0, 0), Vec3(1, 0, 0)}), 1.0);
}

TEST(ConstraintSet, NormalAgainstAFullyPinnedRingIsContradictory) {
  const Mesh g = makeGrid(3);  // vertex 4 in the middle, ring 1, 3, 5, 7
  ConstraintSet set;
  for (Index v : {4, 1, 3, 5, 7}) set.addPosition(g, v, g.positions().row(v).transpose());
  // The pins hold the plane z = 0: +z is consistent (kept), a tilted normal is not.
  EXPECT_NO_THROW(set.addNormal(g, g.positions(), 4, Vec3::UnitZ()));
  ConstraintSet other;
  other.addNormal(g, g.positions(), 4, Vec3(0, 1, 1));
  for (Index v : {4, 1, 3, 5}) other.addPosition(g, v, g.positions().row(v).transpose());
  EXPECT_TRUE(throwsWith([&] { other.addPosition(g, 7, g.positions().row(7).transpose()); },
                         "contradicts"));
  EXPECT_FALSE(other.find(ConstraintKind::Position, 7).has_value());  // not added
}

TEST(StepResponse, ElasticModelIsExactForTheAffineSchemes) {
  // Against the real stepper: positions after one step with arbitrary virtual forces on the
  // support equal the model anchored at a step without them.
  const Model model = makeModel(makeTorus(8, 5), 0.3, 0.2);
  const Mesh& mesh = model.mesh;
  ConstraintSet set;
  set.addPosition(mesh, 3, Vec3::Zero());
  set.addPosition(mesh, 4, Vec3::Zero());  // a neighbour: coupled through Omega^2
  set.addNormal(mesh, mesh.positions(), 20, mesh.positions().row(20).normalized().transpose());
  ConstraintSolver solver;
  solver.setUp(mesh, set);
  const auto support = solver.support();
  const Index s = static_cast<Index>(support.size());
  State start = State::atRest(mesh);
  randomVelocity(model.properties.mass, 0.1, 4, start.velocity);
  start.position += 0.05 * start.velocity;
  const Points external = Points::Zero(mesh.numVertices(), 3);
  Points force = Points::Random(s, 3);
  for (Scheme scheme : {Scheme::Default, Scheme::Paper, Scheme::SymplecticEuler}) {
    Stepper stepper(model, scheme, 0.5 * criticalPeriod(SystemMatrices(model)));
    StepResponse response;
    response.buildElastic(stepper, model, {}, support);
    State free = start;
    stepper.invalidate();
    stepper.step(free, external);
    Points anchor(s, 3);
    for (Index a = 0; a < s; ++a) anchor.row(a) = free.position.row(support[a]);
    response.anchor(anchor, Vec3::Zero(), Points::Zero(s, 3));
    Points predicted(s, 3);
    response.predict(force, predicted);

    Points loaded = external;
    for (Index a = 0; a < s; ++a) loaded.row(support[a]) = force.row(a);
    State pushed = start;
    stepper.invalidate();
    stepper.step(pushed, loaded);
    for (Index a = 0; a < s; ++a)
      EXPECT_LT((pushed.position.row(support[a]) - predicted.row(a)).norm(), 1e-14)
          << schemeName(scheme);
  }
}

TEST(StepResponse, ElasticForceForInvertsTheElasticModel) {
  // The pins-only solve takes C^+ from the response: the force change it gives must move
  // the predicted positions by exactly the displacement asked for, for every scheme
  // (including the drift-filtered default, whose C is global), with unequal masses.
  Model model = makeModel(makeTorus(8, 5), 0.3, 0.2);
  for (Index v = 0; v < model.mesh.numVertices(); ++v)
    model.properties.mass[v] *= 1.0 + 0.5 * static_cast<double>(v % 3);
  ConstraintSet set;
  for (Index v = 0; v < 12; ++v) set.addPosition(model.mesh, v, Vec3::Zero());
  ConstraintSolver solver;
  solver.setUp(model.mesh, set);
  const Index s = static_cast<Index>(solver.support().size());
  const Points anchor = Points::Random(s, 3), start = Points::Random(s, 3);
  const Points wanted = 1e-3 * Points::Random(s, 3);
  for (Scheme scheme :
       {Scheme::Default, Scheme::Paper, Scheme::SymplecticEuler, Scheme::ImplicitEuler}) {
    Stepper stepper(model, scheme, 0.5 * criticalPeriod(SystemMatrices(model)));
    StepResponse response;
    response.buildElastic(stepper, model, {}, solver.support());
    ASSERT_TRUE(response.affine());
    response.anchor(anchor, Vec3::Zero(), start);
    Points change(s, 3), predicted(s, 3);
    response.elasticForceFor(wanted, change);
    response.predict(start + change, predicted);
    EXPECT_LT((predicted - anchor - wanted).cwiseAbs().maxCoeff(),
              1e-9 * wanted.cwiseAbs().maxCoeff())
        << schemeName(scheme);
  }
}

TEST(ConstraintSolver, ManyPinsAreMetByOneSolve) {
  // Forty pins on the braced grid, pulled away from where a free step leaves them: a single
  // solve finds forces that meet every pin in a real step of each scheme.
  const Model model = makeModel(makeGrid(9), 0.5);
  const Mesh& mesh = model.mesh;
  ConstraintSet set;
  for (Index v = 0; v < 40; ++v)
    set.addPosition(mesh, v, mesh.positions().row(v).transpose() + Vec3(0.0, 0.01 * v, 0.05));
  for (Scheme scheme : {Scheme::Default, Scheme::Paper, Scheme::SymplecticEuler}) {
    ConstraintSolver solver;  // fresh: the anchor is a step without virtual forces
    solver.setUp(mesh, set);
    ASSERT_EQ(solver.support().size(), 40u);
    const ConstraintReport report = solveOneCycle(model, set, scheme, solver);
    EXPECT_TRUE(report.converged) << schemeName(scheme) << ": " << report.positionError;
  }
}

TEST(ConstraintSolver, TheNormalsVelocityStepOnlyTakesKineticEnergyAwayAndKeepsMomentum) {
  // docs/semi-rigid-and-constraints.md: at the end of a cycle a held normal's ring has its
  // velocities projected, in the mass-weighted norm, onto those that keep the normal (RATTLE's
  // velocity step), "which can only take kinetic energy away", and, its gradient summing to
  // zero, keeps the momentum. A ring on its target (no couple to take back) given random
  // velocities: less kinetic energy after, the same momentum, and a second projection changes
  // nothing.
  const Model model = makeModel(makeGrid(6), 0.5);
  const Mesh& mesh = model.mesh;
  const VectorX& mass = model.properties.mass;
  ConstraintSet set;
  const Vec3 here = *bestPlaneNormal(mesh, mesh.positions(), 14);
  set.addNormal(mesh, mesh.positions(), 14, here);
  ConstraintSolver solver;
  solver.setUp(mesh, set);
  (void)solveOneCycle(model, set, Scheme::Default, solver);
  ASSERT_LT(solver.coupleForces().norm(), 1e-12);
  const double period = 0.5 * criticalPeriod(SystemMatrices(model));
  for (const unsigned seed : {3u, 4u, 5u}) {
    Points velocity;
    randomVelocity(mass, 0.3, seed, velocity);
    Points delta;
    solver.velocityCorrection(period, mesh.positions(), mesh.positions(), velocity, mass, {},
                              delta);
    double before = 0.0, after = 0.0;
    Vec3 momentum = Vec3::Zero(), scale = Vec3::Zero();
    Points corrected = velocity;
    for (Index a = 0; a < delta.rows(); ++a) {
      const Index v = solver.support()[static_cast<size_t>(a)];
      corrected.row(v) += delta.row(a);
      before += 0.5 * mass[v] * velocity.row(v).squaredNorm();
      after += 0.5 * mass[v] * corrected.row(v).squaredNorm();
      momentum += mass[v] * delta.row(a).transpose();
      scale += mass[v] * velocity.row(v).transpose().cwiseAbs();
    }
    EXPECT_LT(after, before) << seed;        // random velocities turn the plane: some is taken
    EXPECT_GT(after, 0.5 * before) << seed;  // and the rest kept
    EXPECT_LT(momentum.norm(), 1e-12 * scale.norm()) << seed;
    Points again;
    solver.velocityCorrection(period, mesh.positions(), mesh.positions(), corrected, mass, {},
                              again);
    EXPECT_LT(again.cwiseAbs().maxCoeff(), 1e-12 * velocity.cwiseAbs().maxCoeff()) << seed;
  }
}

TEST(ConstraintSolver, SolvesPinsAndNormalsAgainstTheResponse) {
  const Model model = makeModel(makeGrid(6), 0.5);
  const Mesh& mesh = model.mesh;
  ConstraintSet set;
  set.addPosition(mesh, 0, Vec3(0.1, -0.2, 0.3));
  set.addPosition(mesh, 1, Vec3(1.0, 0.0, 0.2));
  const Vec3 wanted = Vec3(0.2, 0.1, 1.0).normalized();
  set.addNormal(mesh, mesh.positions(), 14, wanted);
  ConstraintSolver solver;
  solver.setUp(mesh, set);
  // The forces found, applied in a real step, meet the constraints.
  const ConstraintReport report = solveOneCycle(model, set, Scheme::Default, solver);
  EXPECT_TRUE(report.converged) << report.positionError << " " << report.normalError;
  const Index s = static_cast<Index>(solver.support().size());
  // The normal's couple exerts no net force: the net force is the pins'.
  Vec3 net = Vec3::Zero(), pins = Vec3::Zero();
  for (Index a = 0; a < s; ++a) {
    net += solver.forces().row(a).transpose();
    const Index v = solver.support()[a];
    if (v == 0 || v == 1) pins += solver.forces().row(a).transpose();
  }
  EXPECT_LT((net - pins).norm(), 1e-12 * pins.norm());
}
