#pragma once
// The divergence policy of every front end: the command line's simulate and render, the
// window's session and its replays. One policy, so that a scene that diverges in one
// diverges in the other. (The window used to call a vertex beyond 1e4 model sizes a
// divergence, which paused a model falling freely under gravity after a minute or so, and
// missed a blow-up of a large model that stayed within that bound.)
//
// Simulation::step already refuses a non-finite state. This also catches runaway energy:
// without damping the total energy can only change by the work the loads and constraints
// put in (and by edits, counted as work), up to the scheme's own bounded error,
// which is relative to the energy exchanged inside the model (a falling model turns
// hundreds of kilojoules of gravity into motion with a total that stays near zero). An
// energy that exceeds its start by ten times everything that flowed in plus the largest
// kinetic energy seen before is a numerical blow-up in progress, long before it becomes
// non-finite (in a blow-up the energy outgrows every earlier kinetic energy).
//
// Checkpoints: the state is copied every kCheckpointEvery cycles into one of two slots
// sized once (no allocation), while the energy is within bounds. After a divergence the
// older slot is the good state: the newer one may already be on its way out.

#include <cstdint>
#include <string>

#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/simulation/simulation.h"

namespace zsculpt {

class DivergenceGuard {
 public:
  static constexpr std::uint64_t kCheckpointEvery = 32;
  static constexpr double kEnergyFactor = 10.0;

  /// Starts from the simulation's present state and energy.
  explicit DivergenceGuard(const Simulation& sim);

  /// The energy the guard watches: the kinetic and gravitational energy plus sigma times
  /// the springs' where every vertex has the same elastic share sigma
  /// (Simulation::uniformElasticShare), else the total energy. With a uniform sigma the
  /// deformation keeps K + sigma V, not K + V: a stiffness-capped model (sigma = kappa_0 /
  /// kappa) moving stably shows a total up to 1 / sigma times its start, which is not a
  /// blow-up (a blow-up outgrows both). A sigma that varies keeps no such sum; weighting by
  /// the smallest sigma stopped stable models and missed runaways where a region was fully
  /// rigid (sigma_min = 0: the springs unwatched).
  [[nodiscard]] static double energyOf(const Simulation& sim, const Diagnostics& diagnostics);

  /// The present state and energy become the new start, and both checkpoints: after a
  /// reset, a state loaded or a model replaced.
  void restart(const Simulation& sim);
  /// The next checked cycle's energy becomes the start (inflow and the kinetic maximum
  /// forgotten): when a drag ends, so that its work does not loosen the bound for the rest
  /// of a long session.
  void rebase() { rebase_ = true; }
  /// After an edit that changed the stored energy (a brush dab, gravity, the stiffness cap):
  /// its change is counted as work put in, measured by measureEdit before the next step (the
  /// state has not moved since the last checked cycle, so the difference is the edit's
  /// alone), or else, at the next check, the change since the last one.
  void editChangedEnergy() { editPending_ = true; }
  [[nodiscard]] bool editPending() const { return editPending_; }
  /// The energy now (energyOf), after the edits and before the step: the edits' change is
  /// counted.
  void measureEdit(const Simulation& sim);
  /// Energy put in by an edit whose change was measured (the command line's timed edits).
  void addEnergy(double joules);

  /// Call before cycle `cycle` (0, 1, ...): takes a checkpoint every kCheckpointEvery.
  void beforeStep(const Simulation& sim, std::uint64_t cycle);
  /// Call after a step that did not throw, with its diagnostics. False when the energy is
  /// not finite or ran away; reason() says which, with the numbers.
  [[nodiscard]] bool afterStep(const Simulation& sim, const Diagnostics& diagnostics);

  /// The state to go back to after a divergence: the older checkpoint.
  [[nodiscard]] const State& lastGood() const { return slots_[1 - newest_]; }
  [[nodiscard]] std::uint64_t lastGoodCycle() const { return slotCycle_[1 - newest_]; }
  [[nodiscard]] const std::string& reason() const { return reason_; }

 private:
  double start_ = 0.0;
  double inflow_ = 0.0;
  double maxKinetic_ = 0.0;
  bool rebase_ = false;
  bool editPending_ = false;
  double lastEnergy_ = 0.0;
  State slots_[2];
  std::uint64_t slotCycle_[2] = {0, 0};
  int newest_ = 0;
  std::string reason_;
};

}  // namespace zsculpt
