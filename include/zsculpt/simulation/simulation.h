#pragma once
// The solver cycle (paper section 6, Figure 2, "Solver"): gather the loads that act during
// this cycle (timed forces and torques, gravity), compute the constraints' virtual forces,
// split every vertex's total force into its elastic share sigma_i F_i and rigid share
// chi_i F_i (section 4.3), step the elastic part and the rigid body, compose them, and keep
// diagnostics. A stateful class; it knows nothing of threads, windows or files: the app
// and the command line drive it. docs/semi-rigid-and-constraints.md describes the cycle.
//
// Semi-rigid motion. chi_i is the larger of the painted rigidity and 1 - sigma_i from the
// stiffness cap kappa_0 (effectiveRigidity). When every chi_i is 0 the cycle is exactly the
// elastic stepper. Otherwise the state is split, Tisserand fashion, into a rigid motion
// (momentum P and angular momentum L of the whole model, integrated by the Newton-Euler
// equations under sum chi_i F_i and its torque) and a deformation velocity u_i with zero net
// momentum and angular momentum (stepped by the elastic stepper under sigma_i F_i). Each
// cycle the deformation's net momentum and angular momentum are handed to the rigid body,
// so P and L are conserved exactly (to rounding) by internal forces, whatever chi is.
// Vertex velocities are v_i = P / M + omega x (r_i - c) + u_i, omega = I^+ L.

#include <algorithm>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "zsculpt/constraints/constraints.h"
#include "zsculpt/constraints/solver.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/stepper.h"
#include "zsculpt/rigid/rigid_body.h"

namespace zsculpt {

/// A force or torque at a vertex, active for start <= t < end (seconds).
struct TimedLoad {
  Index vertex = 0;
  Vec3 value = Vec3::Zero();
  double start = 0.0;
  double end = std::numeric_limits<double>::infinity();
  [[nodiscard]] bool activeAt(double t) const { return t >= start && t < end; }
  /// The share of the cycle [t, t + period) during which the load acts. A cycle holds
  /// value x share, so a load's impulse is value x (end - start) exactly, whatever the
  /// period (a load held for whole cycles would overshoot by up to one period).
  [[nodiscard]] double shareOf(double t, double period) const {
    const double overlap = std::min(t + period, end) - std::max(t, start);
    return overlap <= 0.0 ? 0.0 : std::min(1.0, overlap / period);
  }
};

/// A pin's way to its target: it holds its vertex where it is until `start`, then moves
/// there by `end` (seconds), eased in and out (smoothstep: no jump in speed at either end),
/// rather than in one cycle, which jerks the model.
struct PinTravel {
  double start = 0.0;
  double end = 0.0;
  /// The share of the way covered at time t: 0 until start, 1 from end.
  [[nodiscard]] double shareAt(double t) const {
    if (!(t > start)) return 0.0;
    if (!(t < end)) return 1.0;
    const double s = (t - start) / (end - start);
    return s * s * (3.0 - 2.0 * s);
  }
};

/// How the deformation velocities follow the rigid body's rotation over a cycle.
enum class RigidFrame {
  /// Turned with the body: the elastic part is stepped in the rigid body's frame (default;
  /// measured better, see docs).
  Body,
  /// Left in the world frame: the plain composition of the two motions.
  World,
};

/// The most steps SimulationSettings::substepStrain splits a cycle into.
inline constexpr int kMaxSubsteps = 64;
/// An edit that stiffens the model lowers T_max (equation 5) under a cycle whose period was
/// set as a share of the old one. Once the cycle of a conditionally stable scheme (default,
/// paper, symplectic Euler) passes kStiffenedTrigger of the scheme's Gershgorin limit (the
/// limit itself for a period set beyond the trigger already), each cycle is taken in 2, 4, ... up
/// to kMaxSubsteps steps, the fewest that bring every step back within the larger of the
/// share of T_max the period was set at and kStiffenedStepShare, and within 0.99 of the
/// limit. The count is a function of the properties (not of the splits before), so a run
/// resumed after several edits splits as the whole run did. The cycle's period, and so a
/// run's step count, time and frames, stays. The window keeps its share by lowering the
/// period itself (app::Session); a headless run has a step count and frames fixed in cycles.
inline constexpr double kStiffenedTrigger = 0.9;
inline constexpr double kStiffenedStepShare = 0.5;
/// A cycle whose end velocities ask for more than this many times the steps it took (by
/// SimulationSettings::substepStrain's rule) is taken again from its start in as many as
/// they ask for: the motion grew within it by more than its start could tell.
inline constexpr int kRetakeFactor = 2;

struct SimulationSettings {
  Scheme scheme = Scheme::Default;
  /// The sampling period T (seconds).
  double period = 0.0;
  StepperOptions stepper;
  RigidFrame rigidFrame = RigidFrame::Body;
  /// Steps computed per cycle at most while constraints do not yet hold (1 + corrections).
  int constraintSteps = 6;
  /// A pinned vertex must end within this of its target (times max(1, model size)).
  double positionTolerance = 1e-12;
  /// A constrained normal must end within this angle (rad) of its target.
  double normalTolerance = 1e-10;
  /// Default scheme: the most an edge's length may change in one step, relative to its rest
  /// length, estimated from the relative velocity of its ends at the cycle's start (measured
  /// at the end of the cycle before, unless the state changed since): |v_a - v_b| T /
  /// lambda_ab. A faster cycle is split into 2, 4, ... steps of T / n
  /// (Stepper::setPeriod), and joined again once fewer steps would each change an edge by
  /// at most half this. A cycle whose end asks for more than kRetakeFactor times its steps
  /// is taken again in as many. Equation 5's T_max bounds the linear motion only; beyond
  /// this strain the springs' nonlinearity lets an undamped model heat up and run away
  /// (docs/reliability.md, "Soak"). 0: never split (the paper's fixed period).
  double substepStrain = 0.2;
};

/// Impulses that entered the model since the start (or the last setState), so that momentum
/// bookkeeping stays honest: P(t) - P(0) = loads + gravity + constraints - damping.
struct ImpulseLedger {
  Vec3 loads = Vec3::Zero();        // timed forces and torques, N s
  Vec3 gravity = Vec3::Zero();      // N s
  Vec3 constraints = Vec3::Zero();  // virtual forces and velocity corrections, N s
  /// Angular impulses about the centre of mass at the start of each cycle, N m s.
  Vec3 loadsAngular = Vec3::Zero();
  Vec3 constraintsAngular = Vec3::Zero();
};

class Simulation {
 public:
  /// Validates the model's properties; throws InvalidInputError.
  Simulation(Model model, const SimulationSettings& settings);

  [[nodiscard]] const Model& model() const { return model_; }
  [[nodiscard]] const State& state() const { return state_; }
  [[nodiscard]] double time() const { return state_.time; }
  [[nodiscard]] const Stepper& stepper() const { return *stepper_; }
  /// The sampling period T of one cycle (step()).
  [[nodiscard]] double period() const { return cyclePeriod_; }
  /// Steps per cycle at present: 1, 2, 4, ... (SimulationSettings::substepStrain, and
  /// kStiffenedStepShare after an edit that stiffened the model).
  [[nodiscard]] int substeps() const { return substeps_; }
  /// The fewest steps a cycle takes since an edit brought the scheme's stable limit near the
  /// period (kStiffenedTrigger), 1 otherwise; counted at the cycle after the edit.
  [[nodiscard]] int stableSubsteps() const { return stableSubsteps_; }
  /// How many times the last cycle was taken again with more steps (kRetakeFactor).
  [[nodiscard]] int retakes() const { return retakes_; }
  [[nodiscard]] const SimulationSettings& settings() const { return settings_; }

  /// Changes the scheme and the cycle's period T in place; the state, loads, constraints (their
  /// ids, and the normals' turning records), settings and ledger stay. The new stepper is
  /// built first: if that throws (a period that is not positive, the exact scheme on too
  /// large a model) nothing changes.
  void setTimeStep(Scheme scheme, double period);

  /// Replaces the state (same vertex count, finite). Throws InvalidInputError. With rigid
  /// vertices, the velocity is split into the rigid motion and the deformation; vertices
  /// that are fully rigid (chi = 1) keep only the rigid part of theirs. Resets the ledger.
  void setState(const State& state);

  /// Loads: forces and torques (section 5.3). Vertex indices are checked.
  void addForce(const TimedLoad& force);
  void addTorque(const TimedLoad& torque);
  void clearLoads();
  [[nodiscard]] const std::vector<TimedLoad>& forces() const { return forces_; }
  [[nodiscard]] const std::vector<TimedLoad>& torques() const { return torques_; }

  /// Constraints (section 6). A position constraint without a target pins the vertex where
  /// it is; a normal constraint without a normal holds the current best-plane normal.
  /// Errors (InvalidInputError): see constraints.h.
  Index addPositionConstraint(Index vertex, std::optional<Vec3> target = std::nullopt);
  /// A pin that travels to `target` over `travel` (PinTravel), from where the model as loaded
  /// has the vertex, its target a function of time alone (so a rollback, a reset or a run
  /// resumed at --start-time finds it where an uninterrupted run has it). Throws
  /// InvalidInputError as addPositionConstraint does, for a vertex pinned already, or for a
  /// travel whose end is not after its start (or is not finite). The drag tool taking the
  /// pin (setConstraintTarget, moveConstraint) or its removal ends the travel.
  Index addPositionConstraint(Index vertex, const Vec3& target, const PinTravel& travel);
  /// The target and travel of position constraint `id` if it was given one (on its way or
  /// arrived); nullopt otherwise.
  [[nodiscard]] std::optional<std::pair<Vec3, PinTravel>> pinTravel(Index id) const;
  Index addNormalConstraint(Index vertex, std::optional<Vec3> normal = std::nullopt);
  /// The drag tool: move a position constraint's target (takes effect at the next cycle).
  void setConstraintTarget(Index id, const Vec3& target);
  /// The position constraint `id` holds `vertex` at `target` (ConstraintSet::movePosition).
  void moveConstraint(Index id, Index vertex, const Vec3& target);
  void setConstraintNormal(Index id, const Vec3& normal);
  void removeConstraint(Index id);
  void clearConstraints();
  [[nodiscard]] const ConstraintSet& constraints() const { return constraints_; }
  /// How well the constraints held in the last cycle.
  [[nodiscard]] const ConstraintReport& constraintReport() const { return report_; }
  /// Warnings for the user since the last call (merged duplicate constraints, constraints
  /// that could not be met).
  std::vector<std::string> takeWarnings();

  /// One cycle. Throws DivergenceError if the state becomes non-finite; on that or any other
  /// error the state is left at the last finite one, where the cycle started. A cycle of the
  /// default scheme that ran away within itself (kRetakeFactor) is taken again from its
  /// start, its loads, constraints, turning records, ledger and warnings as they were then.
  void step();

  /// Energy and momentum of the current state. After a cycle of the default scheme the
  /// radial and angular energy come from the step's own force pass at the end position
  /// (Stepper::internalEnergy; with rigid motion, which moves the vertices after the
  /// elastic step and does not change the springs' energy, that of the elastic end), which
  /// agrees with measure()'s to rounding and costs the step a few per cent instead of a pass
  /// over every spring; otherwise (another scheme, a fully rigid model, after an edit or
  /// setState) they are evaluated as measure() does.
  [[nodiscard]] Diagnostics diagnostics() const;
  /// External forces applied during the last step of the last cycle (N x 3, torques as
  /// virtual forces).
  [[nodiscard]] const Points& externalForces() const { return external_; }
  /// Work the loads (forces and torques) did during the last cycle (J): each step's forces
  /// times the displacement of their vertices over it.
  [[nodiscard]] double loadWork() const { return loadWork_; }
  /// Virtual forces of the constraints during the last step of the last cycle (N x 3).
  [[nodiscard]] const Points& constraintForces() const { return constraintForce_; }
  /// Work the constraints did during the last cycle (J): their virtual forces times the
  /// constrained vertices' displacements, plus the kinetic energy of the velocity correction.
  [[nodiscard]] double constraintWork() const { return constraintWork_; }
  [[nodiscard]] const ImpulseLedger& impulses() const { return ledger_; }

  /// chi_i in use (painted, or from the stiffness cap) and sigma_i = 1 - chi_i.
  [[nodiscard]] const std::vector<double>& rigidity() const { return chi_; }
  [[nodiscard]] const std::vector<double>& elasticShare() const { return sigma_; }
  /// True when some chi_i > 0: the rigid body is part of the cycle.
  [[nodiscard]] bool rigidActive() const { return rigidActive_; }
  /// sigma when every vertex has the same sigma_i, else 1 (and 1 without rigidity). The
  /// deformation feels sigma times the springs' forces, so it keeps the kinetic energy plus
  /// sigma times the springs' energy, not plus all of it (a capped model's springs may hold
  /// a hundred times what the motion does). A sigma that varies keeps no such sum (sigma_i
  /// f_i is no energy's gradient): 1, the total energy.
  [[nodiscard]] double uniformElasticShare() const { return uniformShare_; }
  /// Rigidity is active and differs from vertex to vertex (painted): sigma_i f_i is then no
  /// energy's gradient, and an undamped model can gain energy
  /// (docs/semi-rigid-and-constraints.md).
  [[nodiscard]] bool elasticShareVaries() const { return rigidActive_ && uniformShare_ == 1.0; }
  /// P and L (about the centre of mass) carried by the rigid motion (zero when inactive).
  [[nodiscard]] const RigidMomentum& rigidMomentum() const { return rigidMomentum_; }

  /// For property edits: change model().properties through this, then call
  /// propertiesChanged() with the vertices whose properties (or edges/angles) changed.
  /// Throws InvalidInputError when a value is out of range (e.g. rigidity outside [0, 1]).
  PhysicalProperties& mutableProperties() {
    energyAtState_ = false;
    endRateValid_ = false;  // rest lengths may change
    return model_.properties;
  }
  void propertiesChanged(std::span<const Index> vertices);
  void allPropertiesChanged();

 private:
  // out = the loads at time t. With `rows`: only the rows it lists (those the last gathering
  // into out wrote) are cleared, and it gets the rows written now, sorted and once each.
  void gatherLoads(double t, const Points& position, Points& out,
                   std::vector<Index>* rows = nullptr);
  // Reserves the row lists for the most rows the loads and the support can write, so that
  // no cycle grows them (called when a load is added and when the support changes).
  void reserveLoadRows();
  // SimulationSettings::substepStrain: splits or joins the coming cycle's steps.
  void chooseSubsteps();
  [[nodiscard]] bool substepping() const;
  // The largest (|v_a - v_b| / lambda_ab)^2 over the edges of rest length > 0.
  [[nodiscard]] double strainRate2() const;
  void setSubsteps(int n);
  // kStiffenedStepShare: periodShare_ from the period just set (a new stepper), and
  // stableSubsteps_ after edits (propertiesEdited_), said when it rises.
  void notePeriodShare();
  void chooseStableSubsteps();
  // A new constraint support (constraints added, moved or removed) set up.
  void syncSupport();
  // Back to the cycle's start (step()): state, rigid motion, ledger, stepper caches.
  void rewindState(const ImpulseLedger& ledgerBefore);
  // One step of the cycle: loads, the elastic (or coupled) step, the constraints. Throws
  // DivergenceError on a non-finite state. `start` holds the positions at its start.
  void subCycle(const Points& start);
  void updateRigidity();
  void splitVelocity();
  void coupledStep();
  // The elastic share sigma_i the stepper takes (section 4.3): empty (1 everywhere) without
  // rigid motion.
  [[nodiscard]] std::span<const double> stepperShare() const {
    return rigidActive_ ? std::span<const double>(sigma_) : std::span<const double>();
  }
  void runTrial(bool constrained, bool first);
  // Finishes the constrained trial that met the constraints (or the last one allowed): the
  // stepper's second part, where the elastic step ended.
  void finishTrial();
  void finishRigid();
  void computeBaseForce(const Points& position);
  void addToLedger(const Vec3& centre, const Points& velocityDelta);

  Model model_;
  SimulationSettings settings_;
  State state_;
  State lastGood_;
  std::unique_ptr<Stepper> stepper_;
  double cyclePeriod_ = 0.0;
  int substeps_ = 1;  // the stepper's period is cyclePeriod_ / substeps_
  // kStiffenedStepShare, as the period was set: its share of T_max (0: T_max infinite),
  // whether it was at or past the Gershgorin limit, or past kStiffenedTrigger of it.
  double periodShare_ = 0.0;
  bool startedBeyondBound_ = false;
  bool startedNearBound_ = false;
  // The fewest steps a cycle takes since the last edit, and whether an edit came since they
  // were counted (chooseStableSubsteps, at the next cycle).
  int stableSubsteps_ = 1;
  bool propertiesEdited_ = false;
  int retakes_ = 0;
  // strainRate2() at the end of the last cycle, for the next one's chooseSubsteps (cleared by
  // anything that changes the velocities or the rest lengths between cycles).
  double endRate2_ = 0.0;
  bool endRateValid_ = false;
  double loadWork_ = 0.0;
  std::vector<Vec3> targetStart_, targetEnd_;  // position targets over a split cycle
  struct Travelling {
    Index id = 0;
    Vec3 from = Vec3::Zero();  // the vertex in the model as loaded
    Vec3 to = Vec3::Zero();
    PinTravel travel;
  };
  std::vector<Travelling> travelling_;
  void moveTravellingPins();  // their targets at the end of the coming cycle
  Points subStart_;           // positions at a split cycle's step's start
  std::vector<TimedLoad> forces_;
  std::vector<TimedLoad> torques_;
  Points external_;
  bool externalZero_ = true;  // external_ is all zero (no loads): a cycle need not clear it
  // The rows of external_ the loads wrote (sorted, once each); every other row is +0. A load
  // on a few vertices of a large model costs the cycle passes over those rows, not over all.
  std::vector<Index> externalRows_;
  std::vector<Vec3> armBuffer_, forceBuffer_;

  // Semi-rigid motion (section 4.3).
  std::vector<double> chi_, sigma_;
  double uniformShare_ = 1.0;
  // Some vertices fully rigid (sigma = 0) and some not: their masses are 0 in elasticMass_.
  bool someFullyRigid_ = false;
  VectorX elasticMass_;
  void holdFullyRigidVertices();
  // sum_i sigma_i f_i of the internal forces at the cycle's start (finishRigid).
  Vec3 startElasticShare_ = Vec3::Zero();
  [[nodiscard]] Vec3 elasticInternalShare(const Points& force) const;
  bool rigidActive_ = false;
  bool allRigid_ = false;
  double rigidDamping_ = 0.0;
  RigidMomentum rigidMomentum_, lastGoodMomentum_;
  Points deformation_, lastGoodDeformation_;  // u_i (N x 3), when rigid
  MassProperties start_, end_;
  Points baseForce_;  // internal + gravity at state_.position, when baseForceValid_
  bool baseForceValid_ = false;
  // The stepper's internal energy is that of state_.position and the current properties
  // (set by a cycle without rigid motion; cleared by anything that moves the state or may
  // change a property).
  bool energyAtState_ = false;
  Points totalForce_, loadForce_;     // work buffers
  std::vector<Index> loadForceRows_;  // loadForce_'s rows that can be nonzero, as externalRows_
  double scale_ = 1.0;                // max(1, size of the model): tolerances are relative to it
  Vec3 startRigidForce_ = Vec3::Zero(), startRigidTorque_ = Vec3::Zero();
  Vec3 startElasticTorque_ = Vec3::Zero();
  RigidDrift drift_;
  Vec3 elasticCentre_ = Vec3::Zero();
  State elasticStart_;  // the elastic solver's start (positions, u) for trials
  State trial_;
  // With rigid motion, a constrained trial's elastic end positions, before the rigid motion
  // moved them (finishTrial). Sized with the rigidity (updateRigidity).
  Points elasticEnd_;

  // Constraints (section 6).
  ConstraintSet constraints_;
  ConstraintSolver solver_;
  StepResponse response_;
  std::uint64_t constraintRevision_ = 0;
  bool responseValid_ = false;
  Points constraintForce_;
  bool constraintForceZero_ = true;  // constraintForce_ is all zero
  double constraintWork_ = 0.0;
  Points supportStart_, supportElastic_, velocityDelta_;
  std::vector<double> supportChi_;
  ConstraintReport report_;
  bool warnedUnmet_ = false;
  bool warnedReleased_ = false;
  bool warnedYielded_ = false;
  std::vector<std::string> warnings_;

  ImpulseLedger ledger_;
};

}  // namespace zsculpt
