#pragma once
// The solver cycle (paper section 6, Figure 2, "Solver"): gather the loads that act during
// this cycle (timed forces and torques, gravity), step the state, and keep diagnostics.
// A stateful class; the one-call form is simulate() below. Knows nothing of threads,
// windows or files: the app and the command line drive it.

#include <limits>
#include <vector>

#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/stepper.h"

namespace zsculpt {

/// A force or torque at a vertex, active for start <= t < end (seconds).
struct TimedLoad {
  Index vertex = 0;
  Vec3 value = Vec3::Zero();
  double start = 0.0;
  double end = std::numeric_limits<double>::infinity();
  [[nodiscard]] bool activeAt(double t) const { return t >= start && t < end; }
};

struct SimulationSettings {
  Scheme scheme = Scheme::Default;
  /// The sampling period T (seconds).
  double period = 0.0;
  StepperOptions stepper;
};

class Simulation {
 public:
  /// Validates the model's properties; throws InvalidInputError.
  Simulation(Model model, const SimulationSettings& settings);

  [[nodiscard]] const Model& model() const { return model_; }
  [[nodiscard]] const State& state() const { return state_; }
  [[nodiscard]] double time() const { return state_.time; }
  [[nodiscard]] const Stepper& stepper() const { return *stepper_; }
  [[nodiscard]] double period() const { return stepper_->period(); }

  /// Replaces the state (same vertex count, finite). Throws InvalidInputError.
  void setState(const State& state);

  /// Loads: forces and torques (section 5.3). Vertex indices are checked.
  void addForce(const TimedLoad& force);
  void addTorque(const TimedLoad& torque);
  void clearLoads();
  [[nodiscard]] const std::vector<TimedLoad>& forces() const { return forces_; }
  [[nodiscard]] const std::vector<TimedLoad>& torques() const { return torques_; }

  /// One cycle. Throws DivergenceError if the state becomes non-finite (the state is then
  /// left at the last finite one).
  void step();

  /// Energy and momentum of the current state.
  [[nodiscard]] Diagnostics diagnostics() const { return measure(model_, state_); }
  /// External forces applied during the last step (N x 3, torques as virtual forces).
  [[nodiscard]] const Points& externalForces() const { return external_; }

  /// For property edits: change model().properties through this, then call
  /// propertiesChanged() with the vertices whose properties (or edges/angles) changed.
  PhysicalProperties& mutableProperties() { return model_.properties; }
  void propertiesChanged(std::span<const Index> vertices);
  void allPropertiesChanged();

 private:
  void gatherLoads(double t);

  Model model_;
  State state_;
  State lastGood_;
  std::unique_ptr<Stepper> stepper_;
  std::vector<TimedLoad> forces_;
  std::vector<TimedLoad> torques_;
  Points external_;
  std::vector<Vec3> armBuffer_, forceBuffer_;
};

}  // namespace zsculpt
