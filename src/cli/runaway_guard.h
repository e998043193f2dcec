#pragma once
// Internal to the cli module: one headless cycle after another (simulate, render), checked by
// the divergence policy every front end shares (simulation/divergence_guard.h).

#include <string>

#include "timed_edits.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/simulation/divergence_guard.h"
#include "zsculpt/simulation/simulation.h"

namespace zsculpt::cli {

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
    return runaway_ ? guard_.lastGood() : sim_.state();
  }

 private:
  void tellWarnings();
  Simulation& sim_;
  TimedEdits& edits_;
  DivergenceGuard guard_;
  Diagnostics diagnostics_;
  std::string why_;
  bool runaway_ = false;
};

}  // namespace zsculpt::cli
