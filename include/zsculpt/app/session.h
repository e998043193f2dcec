#pragma once
// The deterministic heart of an interactive session, single-threaded: a Simulation with its
// editor, loads and constraints, driven by commands (commands.h) and cycles. The solver
// thread (solver_thread.h) runs one in real time; a replay (recording.h) runs one as fast as
// it can. Both call the same apply() and advance() in the same order, so a replay gives the
// same state bit for bit.
//
// A cycle (paper section 6, Figure 2, "Solver"): scheduled scene edits that are due, the
// loads of this cycle (timed forces and torques, the drag), one step, the constraints, the
// divergence check. cycle() counts the steps taken since the session started (a reset does
// not rewind it): recordings key commands by it.
//
// Divergence (a non-finite state or energy, or runaway energy: the policy the command line
// shares, simulation/divergence_guard.h): the session rolls back to a checkpoint taken at
// least DivergenceGuard::kCheckpointEvery cycles earlier, reports it (advance() returns
// Diverged, lastDivergence() says when and where to), and the caller pauses.

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "zsculpt/app/commands.h"
#include "zsculpt/editing/editor.h"
#include "zsculpt/editing/schedule.h"
#include "zsculpt/io/scene.h"
#include "zsculpt/simulation/divergence_guard.h"
#include "zsculpt/simulation/simulation.h"

namespace zsculpt::app {

/// Everything a session starts from. The scene is the source of truth (a recording stores
/// it): the model is io::buildModel(scene, mesh), its constraints, loads and timed edits
/// apply, and `scheme` / `period` replace its simulation settings.
struct SessionSetup {
  io::SceneDescription scene;
  Mesh mesh;
  Scheme scheme = Scheme::Default;
  double period = 0.0;
  /// Initial state (empty: at rest as loaded).
  std::optional<State> initial;
};

/// Resolves a MESH|SCENE the way the command line does: a scene's own simulation settings,
/// else the default scheme at half of equation 5's T_max (0.01 s for a model without
/// stiffness). Throws as io::loadScene / io::loadMeshSource / io::buildModel do. `up` other
/// than Auto replaces the scene's up axis (the window's Open, the --up flag). A bare mesh
/// takes `meshDefaults`' properties and simulation settings when given (the flags the window
/// was opened with); a scene keeps its own.
SessionSetup loadSessionSetup(const std::string& source, io::UpAxis up = io::UpAxis::Auto,
                              const io::SceneDescription* meshDefaults = nullptr);
/// The same from a scene already read (`scene.mesh` is loaded). The scene's up axis becomes
/// the one the mesh was turned by (an Auto resolved by the file's format), so that a save or
/// a recording reloads the mesh as it was loaded here.
SessionSetup sessionSetupFromScene(io::SceneDescription scene);
/// The period a setup resolves to from a scene's simulation settings and the model's T_max.
double resolvePeriod(const io::SceneDescription& scene, const Model& model);

/// assets/scenes/default.json: under $ZSCULPT_DATA_DIR if set, else in the source tree this
/// program was built from. Throws IOError when it is not found.
std::string defaultScenePath();

/// A hash of a state's bytes (positions, velocities, time): equal states, equal hashes.
std::uint64_t stateHash(const State& state);
/// A hash of a mesh's positions and connectivity (to check a replay loads the same mesh).
std::uint64_t meshHash(const Mesh& mesh);

/// What the display reads after each cycle: the published copy of the session.
struct Snapshot {
  std::uint64_t serial = 0;  ///< increases with every publish
  std::uint64_t cycle = 0;   ///< steps taken
  std::uint64_t commandsApplied = 0;
  double time = 0.0;  ///< simulated seconds
  Points position;
  Points velocity;
  /// The per-vertex scalar the display asked for (SolverThread::setDisplayProperty).
  Property scalarProperty = Property::Stiffness;
  VectorX scalar;
  Diagnostics diagnostics;
  std::vector<Index> pins;
  std::vector<std::pair<Index, Vec3>> normalPins;
  std::vector<std::pair<Index, Vec3>> forces;   ///< active now
  std::vector<std::pair<Index, Vec3>> torques;  ///< active now
  Index dragVertex = -1;
  Vec3 dragTarget = Vec3::Zero();

  // Solver status.
  bool running = false;
  Scheme scheme = Scheme::Default;
  double period = 0.0;
  double tMax = 0.0;  ///< equation 5 for the current properties
  /// The scheme's stable period: Gershgorin's bound, or, for a period above it set by the
  /// user, the tight limit (largest eigenvalue) that `zsculpt simulate` gives.
  double stableLimit = 0.0;
  /// stableLimit is the tight limit, or the period is within the bound; false: the period is
  /// above the bound after an edit, and may still be stable.
  bool stableLimitTight = true;
  int substeps = 1;  ///< steps in the last cycle (split when the motion is fast)
  /// The fewest steps a cycle takes since an edit brought the stable limit near T
  /// (Simulation::stableSubsteps); 1 otherwise.
  int stableSubsteps = 1;
  Vec3 gravity = Vec3::Zero();
  double stiffnessCap = 0.0;
  double meanDamping = 0.0;
  /// The least and greatest damping over the vertices (they differ once damping is painted).
  double minDamping = 0.0;
  double maxDamping = 0.0;
  double solverSecondsPerStep = 0.0;  ///< moving average of the step's wall time
  double simOverWall = 0.0;           ///< simulated seconds per wall second (1 = real time)
  bool fallingBehind = false;         ///< running, and the solver cannot keep up with wall time
  std::size_t undoDepth = 0;
  std::size_t redoDepth = 0;
  bool unsaved = false;  ///< edits since the start or the last MarkSaved
  std::uint64_t divergences = 0;
};

struct Divergence {
  std::uint64_t cycle = 0;  ///< the cycle whose step diverged
  double time = 0.0;        ///< simulated time it diverged at
  double rolledBackTo = 0.0;
  std::string message;
};

class Session {
 public:
  /// Builds the model and the simulation. Throws InvalidInputError (scene or settings).
  explicit Session(SessionSetup setup);
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  /// Applies a command. Throws InvalidInputError with a one-line reason and changes nothing
  /// when it is invalid. Play, Pause and StepOnce only set flags read by the loop
  /// (running(), takeStepRequest()).
  void apply(const Command& command);

  enum class Outcome { Stepped, Diverged };
  /// One cycle (see the top of this file).
  Outcome advance();

  [[nodiscard]] std::uint64_t cycle() const { return cycle_; }
  [[nodiscard]] bool running() const { return running_; }
  /// True once after a StepOnce (consumes the request).
  bool takeStepRequest();
  [[nodiscard]] const Simulation& simulation() const { return *sim_; }
  [[nodiscard]] const Model& model() const { return sim_->model(); }
  [[nodiscard]] const State& state() const { return sim_->state(); }
  [[nodiscard]] const io::SceneDescription& scene() const { return setup_.scene; }
  [[nodiscard]] const SessionSetup& setup() const { return setup_; }
  [[nodiscard]] const editing::Editor& editor() const { return editor_; }
  [[nodiscard]] bool unsaved() const { return unsaved_; }
  [[nodiscard]] const std::optional<Divergence>& lastDivergence() const { return divergence_; }
  [[nodiscard]] double tMax() const { return tMax_; }
  /// Vertices held by position constraints (not counting the drag's own), in id order.
  [[nodiscard]] std::vector<Index> pins() const;

  /// The scene as it stands: painted properties (recordProperties), the constraints now in
  /// force, the scheme and period; loads and timed edits of the original scene. For "save
  /// scene".
  [[nodiscard]] io::SceneDescription currentScene() const;
  /// The mesh at the current positions (for "save mesh").
  [[nodiscard]] Mesh currentMesh() const;

  /// Moves the messages of the last cycles (divergence, refused scene edits) to `out`.
  void takeNotices(std::vector<std::string>& out);

  /// Fills everything in `out` that the session knows (not the solver-thread timing
  /// fields). Allocates only when a vector must grow.
  void fill(Snapshot& out, Property scalarProperty);

 private:
  void changeTimeStep(Scheme scheme, double period);
  void reloadLoads();
  /// T_max and the stable limit; `tight`: the largest eigenvalue too, for a period above
  /// Gershgorin's bound (when the period or the model is set, not after each edit).
  void refreshLimits(bool tight = false);
  /// After an edit that lowered T_max: bring the period back to the chosen fraction of it
  /// (a rebuild of the stepper, with a notice), so painting stiffness never makes the
  /// running model diverge. A softer model keeps its period.
  void keepPeriodFraction();
  void addConstraints(const std::vector<io::ConstraintSpec>& constraints);
  void endDrag();
  [[nodiscard]] bool isDragConstraint(const Constraint& c) const {
    return dragOwnsConstraint_ && c.id == dragId_;
  }

  SessionSetup setup_;
  std::unique_ptr<Simulation> sim_;
  editing::Editor editor_;
  editing::EditSchedule schedule_;
  State initial_;

  // Loads: the scene's and the commands', with absolute start/end times.
  std::vector<TimedLoad> forces_, torques_;
  std::vector<TimedLoad> baseForces_, baseTorques_;  // the scene's, restored by Reset
  int toolLoads_ = 0;  // loads added with the tools since the start (Reset drops them)

  // The drag: a position constraint of its own, or the vertex's pin when it has one (the
  // drag then moves the pin).
  Index dragVertex_ = -1;
  Index dragId_ = -1;
  bool dragOwnsConstraint_ = false;
  Vec3 dragTarget_ = Vec3::Zero();
  editing::BrushRegion region_;  // pin brush
  std::vector<std::string> notices_;

  std::unique_ptr<DivergenceGuard> guard_;  // with its checkpoints
  // The diagnostics of the last cycle, which the guard took; a snapshot reuses them until a
  // command changes the model or state.
  Diagnostics diagnostics_;
  bool diagnosticsFresh_ = false;
  std::optional<Divergence> divergence_;
  std::uint64_t divergences_ = 0;

  std::uint64_t cycle_ = 0;
  bool running_ = false;
  bool stepRequest_ = false;
  bool unsaved_ = false;
  double tMax_ = 0.0;
  double stableLimit_ = 0.0;
  bool stableLimitTight_ = true;
  /// The period as a fraction of T_max that the user chose (start, or SetTimeStep).
  double periodFraction_ = 0.5;

  // Display scalar cache.
  bool scalarStale_ = true;
  Property scalarProperty_ = Property::Stiffness;
  VectorX scalar_;
};

}  // namespace zsculpt::app
