#pragma once
// Internal to the cli module: the divergence guard of a headless run (simulate, render).
// Simulation::step already refuses a non-finite state. This also catches runaway energy:
// without damping the total energy can only change by the work the loads and constraints
// put in (and by edits that change the stored energy), up to the scheme's own bounded
// error, which is relative to the energy exchanged inside the model (a falling model turns
// hundreds of kilojoules of gravity into motion with a total that stays near zero). An
// energy that exceeds its start by ten times everything that flowed in plus the largest
// kinetic energy seen before is a numerical blow-up in progress, long before it becomes
// non-finite (in a blow-up the energy outgrows every earlier kinetic energy). A checkpoint of the
// state is kept every kCheckpointEvery steps while the energy is within bounds, so that
// what is written after a divergence is a good state, not the first bad one.

#include <string>

#include "timed_edits.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/simulation/simulation.h"

namespace zsculpt::cli {

class RunawayGuard {
 public:
  static constexpr long kCheckpointEvery = 100;
  static constexpr double kFactor = 10.0;

  explicit RunawayGuard(const Simulation& sim);
  /// Call right after step `k` with its diagnostics. Returns false when the energy ran
  /// away (see reason()).
  bool afterStep(const Simulation& sim, long k, const Diagnostics& diagnostics);
  /// Energy the caller put in by other means (an edit that changed the stored energy).
  void addEnergy(double joules) { inflow_ += std::abs(joules); }

  [[nodiscard]] const State& checkpoint() const { return checkpoint_; }
  [[nodiscard]] long checkpointStep() const { return checkpointStep_; }
  [[nodiscard]] const std::string& reason() const { return reason_; }

 private:
  double start_ = 0.0;
  double inflow_ = 0.0;
  double maxKinetic_ = 0.0;
  State checkpoint_;
  long checkpointStep_ = 0;
  std::string reason_;
};

/// One headless cycle after another, as simulate and render run them: the scene's due
/// edits, the step, then the divergence checks (a non-finite state, runaway energy).
class GuardedRun {
 public:
  GuardedRun(Simulation& sim, TimedEdits& edits) : sim_(sim), edits_(edits), guard_(sim) {}
  /// Runs cycle `k` (1, 2, ...). False when the run diverged: why() says how, lastGood()
  /// is the state to keep (the last finite one, or the checkpoint before a runaway).
  bool step(long k);
  /// The diagnostics after the last successful step.
  [[nodiscard]] const Diagnostics& diagnostics() const { return diagnostics_; }
  [[nodiscard]] const std::string& why() const { return why_; }
  [[nodiscard]] const State& lastGood() const {
    return runaway_ ? guard_.checkpoint() : sim_.state();
  }

 private:
  void tellWarnings();
  Simulation& sim_;
  TimedEdits& edits_;
  RunawayGuard guard_;
  Diagnostics diagnostics_;
  std::string why_;
  bool runaway_ = false;
};

}  // namespace zsculpt::cli
