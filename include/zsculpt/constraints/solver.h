#pragma once
// Virtual forces for position and normal constraints (paper section 6): the forces that
// make every constraint hold at the end of the cycle in which they act.
//
// The constrained vertices, the vertices of each constrained normal's best plane (vertex
// plus one-ring), form the support S. A position constraint's unknown is the force on its
// vertex; a normal constraint's are two weights lambda of forces along the gradient of its
// plane's fitted normal n, f_j = d (n . a) / d r_j lambda for the two directions a across
// the target (the constraint forces of RATTLE): they exert no net force, since a
// translation does not turn the plane, and do no work along motions that keep the normal.
// Where S ends up after the step is modelled by StepResponse:
//
//   elastic   r_e = r_e0 + C (f - f0): every scheme's position update is affine in the
//             forces held over the step; C is exact for default (T^2/2 (1 - T^2/12 Omega^2)
//             sigma M^-1, or T^2/2 Psi Phi sigma M^-1 with the drift filter, a column per
//             support vertex from Stepper::filteredPositionColumn), paper (H sigma M^-1) and
//             symplectic-euler, a first-order model for exact and implicit-euler;
//   rigid     the same Newton-Euler drift and composition the cycle runs (rigid module),
//             evaluated exactly.
//
// The cycle computes a step, anchors the model at it (r_e0, f0), lets ConstraintSolver
// solve for the forces on the model (damped Newton on pin forces and plane weights
// together; with pins alone and no rigid motion the model is linear and one step with
// C's pseudo-inverse, built with the response, solves it), and recomputes the step: one correction
// makes the constraints hold to rounding for the exact-response schemes; the others take a few.
// Positions come first: a cycle that leaves a pin unmet is solved again with the normals let
// go (yieldPlanes), and the cycle that misfits less is kept (Simulation::coupledStep).
// Velocities are then made consistent: a pinned vertex moves with its target, a constrained normal
// does not move.

#include <Eigen/Dense>
#include <numbers>
#include <span>
#include <vector>

#include "zsculpt/constraints/constraints.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/physics/stepper.h"
#include "zsculpt/rigid/rigid_body.h"

namespace zsculpt {

/// Where the support vertices are at the end of a step, as a function of the virtual forces
/// on them.
class StepResponse {
 public:
  /// The elastic response for `support` (sorted vertex ids) under `stepper`'s scheme; an
  /// empty `elasticShare` means sigma = 1. Rebuild after property or constraint changes.
  void buildElastic(const Stepper& stepper, const Model& model,
                    std::span<const double> elasticShare, std::span<const Index> support);

  /// The rigid component of this step, or none (positions are then the elastic ones).
  struct Rigid {
    MassProperties start;        // at the start of the step
    RigidMomentum momentum;      // at the start of the step
    Vec3 force = Vec3::Zero();   // sum chi_i F_i without virtual forces
    Vec3 torque = Vec3::Zero();  // about start.centre
    double damping = 0.0;
    double period = 0.0;
  };
  /// `startPosition` and `rigidShare` (chi) of the support vertices, |S| rows.
  void setRigid(const Rigid& rigid, const Points& startPosition,
                std::span<const double> rigidShare);
  void clearRigid() { rigidActive_ = false; }

  /// Anchors the affine elastic model at a computed step: the support's positions after the
  /// elastic step, the centre of mass after it, and the virtual forces it had.
  void anchor(const Points& elasticPosition, const Vec3& elasticCentre, const Points& force);

  /// End-of-step positions of the support (|S| x 3) under virtual forces `force` (|S| x 3).
  void predict(const Points& force, Points& position) const;
  [[nodiscard]] Index size() const { return static_cast<Index>(elastic_.rows()); }
  /// Whether predict() is affine in the forces (no rigid component this step).
  [[nodiscard]] bool affine() const { return !rigidActive_; }
  /// The force change (|S| x 3) that moves the elastic positions by `displacement` (|S| x 3):
  /// C^+ displacement, with C^+ the pseudo-inverse built with the response (least squares of
  /// minimum norm where C is singular, as for vertices with no elastic share).
  void elasticForceFor(const Points& displacement, Points& force) const;
  /// How far the elastic positions (|S| x 3) move under a change of the virtual forces by
  /// `force` (|S| x 3): C force.
  void elasticDisplacement(const Points& force, Points& displacement) const;

 private:
  void rigidMotion(const Points& force, Vec3& centre, RigidDrift& drift) const;

  Eigen::MatrixXd elastic_;         // |S| x |S|
  Eigen::MatrixXd elasticInverse_;  // its pseudo-inverse, for pins-only solves
  VectorX centreShift_;             // d (centre after the elastic step) / d f_l, times total mass
  double totalMass_ = 0.0;
  Points anchorPosition_, anchorForce_, start_;
  Vec3 anchorCentre_ = Vec3::Zero();
  bool rigidActive_ = false;
  Rigid rigid_;
  std::vector<double> chi_;
  mutable Points elasticWork_;
};

/// How well the constraints held in the last step (of a split cycle: its last step).
struct ConstraintReport {
  int steps = 0;               // elastic steps computed for this cycle (1 = no correction)
  double positionError = 0.0;  // largest distance of a pinned vertex from its target
  double normalError = 0.0;    // largest angle (rad) of a held normal from its cycle's goal
  int released = 0;            // normal constraints let go this cycle (ConstraintSolver::held)
  int yielded = 0;             // held normals let go to hold the pins (yieldPlanes)
  int turning = 0;             // held normals whose cycle goal falls short of their target
  int stopped = 0;           // normals stopped short of their target (kTurnBudget), held or let go
  double targetError = 0.0;  // largest angle (rad) of a held normal from its target
  bool converged = true;     // both within tolerance
};

class ConstraintSolver {
 public:
  /// (Re)builds the support for the constraints (after any add or remove); forces restart
  /// from zero.
  void setUp(const Mesh& mesh, const ConstraintSet& constraints);
  [[nodiscard]] std::span<const Index> support() const { return support_; }
  /// Position in support() of a vertex, or -1.
  [[nodiscard]] Index local(Index vertex) const;

  /// Starts a cycle of `period` seconds at `position`: the normals' orientation, goals and
  /// gradients. The forces start from the previous cycle's (warm start). A normal whose ring
  /// has no distinct flattest direction at `position` is let go for the cycle
  /// (releasedVertices(); kMaxPlaneFlatness). A normal further from its target than the
  /// cycle may turn it (kTurnRate) aims only that far towards it: the cycle's goal. One whose
  /// ring lost kTurnBudget of its way to the target without arriving stops and is held where
  /// it is (ConstraintReport::stopped) until its target is set to another value.
  void beginStep(const Mesh& mesh, const ConstraintSet& constraints, const Points& position,
                 const VectorX& mass, const SparseRowMatrix& omega2, double period);
  /// The fastest a normal constraint turns its ring towards its target: this many radians
  /// per T_ring = sqrt(6 / max_k Omega^2_kk) over the ring's vertices k (equation 5's
  /// critical period, for the ring alone). A target further off (set so, or left behind
  /// while the ring was let go) is reached over several cycles instead of in one, which in
  /// the split cycles of fast motion took forces of 1e5 N and more on a ring of 0.01 kg
  /// vertices. Each turn towards the target does work against the ring's springs: the
  /// slower, the less (docs/semi-rigid-and-constraints.md measures it).
  static constexpr double kTurnRate = 0.1;
  /// A plane's forces may move the vertices of its ring by at most this many cycle turns
  /// (kTurnRate's) times its radius in a cycle, and never by more than its diameter. Holding a
  /// normal against a ring that its surroundings swing round faster than that would take
  /// forces that grow as 1 / T^2 without converging: on a braced dodecahedron dragged 2.3 m
  /// by a pin, such cycles put 130 to 280 J in each (455 J after 400 cycles, against 34 J
  /// without the normal pin). The normal yields to such a swing instead.
  static constexpr double kReachTurns = 8.0;
  /// The most a ring may lose of its way to a target before the constraint stops turning it
  /// (radians, summed over the cycles, each following a held one, in which its angle from the
  /// target grew, since it last arrived): pi. Every turn does work against the ring's springs,
  /// and a ring that turns back as it is turned (the sheet around it is pinned and cannot face
  /// the other way, or it is floppy) would be turned for ever: a 7 x 7 grid pinned at its
  /// corners, asked to turn its centre's normal over, gained 100 J in 300 cycles. In the
  /// cases measured the loss comes as a flip: the faces around the ring turn over, the
  /// oriented normal with them, and an angle x from the target becomes pi - x at once; one or
  /// two flips spend the budget. The way back after the ring was let go (a fold) is not
  /// counted: a braced ring dragged hard folds many times before it settles, then arrives. A
  /// stopped constraint holds the normal where it is until its target is set to another value.
  static constexpr double kTurnBudget = std::numbers::pi;
  /// The most times a ring may fold (be let go, kMaxPlaneFlatness) after it arrived at its
  /// target before the constraint stops turning it, as for kTurnBudget. The way back after a
  /// fold is not counted as lost, so a ring that cannot be held where it arrived (it folds
  /// there) was turned back after every fold, and every turn does work: a braced torus whose
  /// normal was asked to turn 1 rad folded 17 times in 1000 cycles, 12 of them after arriving,
  /// and its energy went from 0.0125 J to 2.7 J in 300 cycles and 32.8 J in 9000. A ring
  /// folded by a drag folds in a burst on its way, without arriving between the folds, and
  /// then arrives and stays (Constraints.AFoldingRingIsLetGoInsteadOfTornApart: 16 folds, 2
  /// after arriving).
  static constexpr int kFoldBudget = 4;
  /// Ring periods a normal must stay at its target, unbroken, for its folds to be forgotten
  /// (kFoldBudget): a ring that settled has shown it can be held there, and a later fold is
  /// a new disturbance (a drag nearby), not the pumping above, whose ring stayed at most 100
  /// ring periods (193 cycles) between folds. Without it, five pushes an hour apart stopped
  /// the constraint for good.
  static constexpr double kSettledPeriods = 500.0;
  /// The vertices of the normal constraints let go this cycle.
  [[nodiscard]] std::span<const Index> releasedVertices() const { return releasedVertices_; }
  /// Lets go, for the rest of the cycle, every normal held in it, and returns how many: the
  /// pins then have the virtual forces to themselves (the caller solves again). For a cycle
  /// whose pins the joint solve left unmet (Simulation's positions-first rule): a normal that
  /// cannot be held together with the pins yields to them, as a folded ring does (the way
  /// back is not counted against kTurnBudget), and is held again from the next cycle.
  int yieldPlanes();
  /// Normal constraints held this cycle.
  [[nodiscard]] int heldPlanes() const;
  /// How far the constraints are from holding at `endPosition` (N x 3), in metres, as the
  /// solve weighs them: the largest distance of a pinned vertex from its target and of
  /// radius x angle of a plane held or yielded this cycle from its goal. It ranks a cycle's
  /// joint solve against the one in which the normals yielded.
  [[nodiscard]] double misfit(const ConstraintSet& constraints, const Points& endPosition);
  /// Keeps the unknowns and which planes are held, to put them back with restore().
  void save();
  void restore();
  /// Forgets every normal's turning record (what it lost, whether it stopped): after the
  /// state was set anew.
  void forgetTurning();
  /// Marks the start of a cycle: every normal's turning record and orientation hint and the
  /// unknowns (the warm start), for rewindCycle() to put back when the cycle is retaken or
  /// rolled back. Not across a setUp().
  void markCycle();
  void rewindCycle();
  /// Those that stopped this cycle, each with its angle from its target (rad).
  struct Stop {
    Index vertex;
    double angle;
  };
  [[nodiscard]] std::span<const Stop> newlyStopped() const { return newlyStopped_; }
  /// The virtual forces on the support (|S| x 3) for the current unknowns.
  [[nodiscard]] const Points& forces() const { return forces_; }
  /// Checks the end-of-step positions (N x 3); fills the report's errors and returns true
  /// when every constraint holds within the tolerances.
  bool check(const ConstraintSet& constraints, const Points& endPosition, double positionTolerance,
             double normalTolerance, ConstraintReport& report);
  /// Improves the forces against `response` (anchored at the last computed step); false when
  /// it left them as they were (no step reduced the residual).
  bool solve(const ConstraintSet& constraints, const StepResponse& response,
             double positionTolerance, double normalTolerance);
  /// The part of forces() that hold the planes' normals (|S| x 3; zero net force on each
  /// plane): the gradient of the normal, times weights the solve finds.
  [[nodiscard]] const Points& coupleForces() const { return coupleForces_; }
  /// Velocity consistency at the end of the cycle, as velocity changes of the support
  /// vertices (`delta`, |S| x 3): a plane's forces count as an impulse at the start of the
  /// cycle (the stepper's second half kick of them is taken back), a constrained normal does
  /// not move (the velocities are projected onto those that keep it, in the mass-weighted
  /// norm), a pinned vertex moves as its target did ((end - start) / T).
  /// Vertices with no elastic share (sigma = 0) move with the rigid body: the last two leave
  /// them alone.
  void velocityCorrection(double period, const Points& startPosition, const Points& endPosition,
                          const Points& velocity, const VectorX& mass,
                          std::span<const double> elasticShare, Points& delta) const;

 private:
  struct Pin {
    Index id;
    Index local;
  };
  // A normal constraint's turning towards its target (kTurnBudget), kept from cycle to cycle.
  struct TurnRecord {
    Vec3 target = Vec3::Zero();  // the target it is for (a new one starts a new record)
    double lastOff = -1.0;       // its angle from the normal at the last cycle's start, if held
    double lost = 0.0;           // radians the ring lost of its way since it last arrived
    bool arrived = false;        // it arrived since it last folded
    int foldsAfterArriving = 0;  // folds that came after an arrival (kFoldBudget)
    double settled = 0.0;        // ring periods at the target, unbroken (kSettledPeriods)
    bool stopped = false;        // the budget is spent: hold `kept`
    Vec3 kept = Vec3::UnitZ();
  };
  struct Plane {
    Index id;
    std::vector<Index> locals;  // vertex first, then its one-ring
    double radius = 1.0;        // mean distance of its vertices from their centre of mass
    double reach = 2.0;         // the most its forces may move a vertex of it this cycle (m)
    // d (n . across_j) / d r_k at the start of the step, per vertex k (3 x 2): the plane's
    // virtual forces are gradient_k lambda.
    std::vector<Eigen::Matrix<double, 3, 2>> gradient;
    Eigen::Matrix<double, 3, 2> across = Eigen::Matrix<double, 3, 2>::Zero();  // _|_ target
    Vec3 hint = Vec3::UnitZ();  // the oriented normal at the start of the step
    bool held = true;           // the ring defines its normal at the start of the step
    bool yielded = false;       // held, then let go for the pins (yieldPlanes)
    Vec3 goal = Vec3::UnitZ();  // the normal at the end of the step: the target, or short of it
    TurnRecord turn;            // its constraint's, carried over set-ups
  };
  void assembleForces();
  Vec3 planeNormal(const Plane& plane, const Points& supportPosition) const;
  // d (n . across_j) / d r_k of the plane's fitted normal n at `supportPosition` (which it
  // moves and restores), by central differences.
  void normalGradient(const Plane& plane, Points& supportPosition,
                      std::vector<Eigen::Matrix<double, 3, 2>>& out) const;
  // The angle of the plane's normal at `supportPosition` from its goal, and the rotation
  // that takes it there.
  double planeResidual(const Plane& plane, const Points& supportPosition, Vec3& rotation) const;
  void gatherSupport(const Points& all, Points& out) const;

  std::vector<Index> support_;
  std::vector<Index> localOf_;  // vertex -> position in support_, or -1
  std::vector<Pin> pins_;
  std::vector<Plane> planes_;
  std::vector<Vec3> pinForce_;
  std::vector<Eigen::Vector2d> lambda_;  // per plane, the weights of its gradient forces
  std::vector<Index> releasedVertices_;
  std::vector<Stop> newlyStopped_;
  Points forces_, coupleForces_, predicted_, supportEnd_;
  mutable std::vector<Vec3> points_;
  mutable Points scratch_;  // |S| x 3, for the end-of-step gradients
  mutable std::vector<Eigen::Matrix<double, 3, 2>> endGradient_;
  double residual(const ConstraintSet& constraints, const StepResponse& response, VectorX& out,
                  double& positionError, double& normalError);
  // Whether every held plane's forces (as last assembled) move its ring by at most its
  // reach in the cycle (kReachTurns).
  bool planesWithinReach(const StepResponse& response);
  void unknowns(VectorX& x) const;
  void setUnknowns(const VectorX& x);

  Points pinError_, pinStep_;  // |S| x 3, for the pins-only solve
  // save() / restore(): the unknowns, held flags and gradients.
  VectorX savedUnknowns_;
  // markCycle() / rewindCycle(): per plane its turning record and hint, and the unknowns.
  std::vector<TurnRecord> markedTurn_;
  std::vector<Vec3> markedHint_;
  VectorX markedUnknowns_;
  std::vector<char> savedHeld_;
  std::vector<std::vector<Eigen::Matrix<double, 3, 2>>> savedGradient_;
  Points planeMotion_;  // |S| x 3, for planesWithinReach
  Eigen::MatrixXd jacobian_;
  Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> factor_;
  VectorX rhs_, step_, base_, trial_, shifted_, initial_;
  VectorX solveWork_, solveUnpermuted_;  // leastNormSolve's, sized once in setUp
};

/// x = the least-squares, least-norm solution of A x = b from A's complete orthogonal
/// decomposition, as factor.solve(b) gives it, but without its allocations (it copies b and
/// makes workspaces on every call): `work` (A's rows) and `unpermuted` (its columns) are
/// the caller's, sized once, and so is x.
void leastNormSolve(const Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd>& factor,
                    const VectorX& b, VectorX& work, VectorX& unpermuted, VectorX& x);

}  // namespace zsculpt
