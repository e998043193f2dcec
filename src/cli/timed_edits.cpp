#include "timed_edits.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "console.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/simulation/divergence_guard.h"

namespace zsculpt::cli {

TimedEdits::TimedEdits(const LoadedModel& loaded, const Simulation& sim, bool verifyMatrices)
    : source(loaded.source), verify(verifyMatrices) {
  if (loaded.scene) schedule = io::scheduleFromScene(loaded.scene->edits);
  if (schedule.size()) editor.emplace(sim.model().mesh, sim.model().angles);
}

void TimedEdits::beforeStep(Simulation& sim) {
  if (schedule.finished()) return;
  // A millionth of a period absorbs the rounding of the accumulated time.
  for (const editing::TimedEdit& edit : schedule.due(sim.time(), 1e-6 * sim.period())) {
    const double energyBefore = DivergenceGuard::energyOf(sim, sim.diagnostics());
    editing::EditResult result;
    try {
      result = editor->apply({sim.model().mesh, sim.model().angles, sim.mutableProperties()},
                             sim.state(), edit.command);
    } catch (const InvalidInputError& e) {
      throw InvalidInputError(source + ": /edits/" + std::to_string(edit.source) + ": " + e.what());
    }
    if (!result.changed) {
      // Said, not skipped silently: a scene's edit that does nothing is usually a brush whose
      // centre the model has left (edits_applied counts the edits that changed something).
      std::ostringstream text;
      text << source << ": /edits/" << edit.source << " at t = " << sim.time()
           << " s changed nothing (its brush reached no vertex, or the values were already "
              "there)";
      warn(text.str());
      continue;
    }
    ++applied;
    sim.propertiesChanged(result.matrixRows);  // local, even for global edits
    energyChange += std::abs(DivergenceGuard::energyOf(sim, sim.diagnostics()) - energyBefore);
    if (verify)
      maxDifference =
          std::max(maxDifference, editing::verifyAgainstRebuild(sim.model(), sim.stepper().system(),
                                                                sim.stepper().transformation())
                                      .maxAbs());
  }
}

}  // namespace zsculpt::cli
