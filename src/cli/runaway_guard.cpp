#include "runaway_guard.h"

#include <algorithm>
#include <cmath>
#include <iostream>
#include <sstream>

#include "console.h"
#include "zsculpt/core/errors.h"

namespace zsculpt::cli {

RunawayGuard::RunawayGuard(const Simulation& sim)
    : start_(sim.diagnostics().total()), checkpoint_(sim.state()) {}

bool RunawayGuard::afterStep(const Simulation& sim, long k, const Diagnostics& diagnostics) {
  const double energy = diagnostics.total();
  // Work of the loads and of the constraints over this cycle, counted in absolute value: the
  // scale of energy moved in and out.
  inflow_ += std::abs(sim.loadWork()) + std::abs(sim.constraintWork());
  const double bound = start_ + kFactor * (std::abs(start_) + inflow_) + maxKinetic_ + 1e-12;
  maxKinetic_ = std::max(maxKinetic_, diagnostics.kinetic);
  if (!(energy <= bound)) {
    std::ostringstream msg;
    msg.precision(4);
    msg << "the energy ran away at step " << k << " (" << energy << " J, more than " << kFactor
        << " times the start energy " << start_ << " J plus the work put in, " << inflow_
        << " J, plus the largest kinetic energy before it)";
    reason_ = msg.str();
    return false;
  }
  if (k % kCheckpointEvery == 0) {
    checkpoint_ = sim.state();
    checkpointStep_ = k;
  }
  return true;
}

void GuardedRun::tellWarnings() {
  // What a cycle found (a constraint not met, a normal let go) is told as it happens.
  for (const std::string& warning : sim_.takeWarnings()) warn(edits_.source + ": " + warning);
}

bool GuardedRun::step(long k) {
  try {
    edits_.beforeStep(sim_);
    guard_.addEnergy(edits_.takeEnergyChange());
    sim_.step();  // rolls back and throws on a non-finite state
  } catch (const DivergenceError&) {
    tellWarnings();
    why_ = "the state became non-finite";
    return false;
  }
  tellWarnings();
  diagnostics_ = sim_.diagnostics();
  if (!std::isfinite(diagnostics_.total())) {
    why_ = "the energy became non-finite";
    return false;
  }
  if (!guard_.afterStep(sim_, k, diagnostics_)) {
    why_ = guard_.reason();
    runaway_ = true;
    return false;
  }
  return true;
}

}  // namespace zsculpt::cli
