#include "runaway_guard.h"

#include <algorithm>
#include <cmath>

#include "console.h"
#include "zsculpt/core/errors.h"

namespace zsculpt::cli {

void GuardedRun::tellWarnings() {
  // What a cycle found (a constraint not met, a normal let go) is told as it happens.
  for (const std::string& warning : sim_.takeWarnings()) warn(edits_.source + ": " + warning);
}

bool GuardedRun::step(long k) {
  throwIfInterrupted();
  try {
    guard_.beforeStep(sim_, static_cast<std::uint64_t>(k - 1));
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
  if (!guard_.afterStep(sim_, diagnostics_)) {
    why_ = guard_.reason();
    runaway_ = std::isfinite(diagnostics_.total());
    return false;
  }
  return true;
}

}  // namespace zsculpt::cli
