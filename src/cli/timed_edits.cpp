#include "timed_edits.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <variant>

#include "console.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/simulation/divergence_guard.h"

namespace zsculpt::cli {

TimedEdits::TimedEdits(const LoadedModel& loaded, const Simulation& sim, bool verifyMatrices)
    : source(loaded.source), verify(verifyMatrices) {
  if (loaded.scene) schedule = io::scheduleFromScene(loaded.scene->edits);
  if (schedule.size()) editor.emplace(sim.model().mesh, sim.model().angles);
  // A run resumed at --start-time applies the edits due before it at its first cycle, to the
  // state it resumed from. An edit that reads the shape (a dab's region and weights, relax's
  // new rest shape) then reads another shape than at its own time, and the run can differ
  // from one run from t = 0 (a QA pass: 0.48 m on Torus-I after a relax): said, once.
  const double slack = 1e-6 * sim.period();
  size_t shaped = 0;
  const editing::TimedEdit* first = nullptr;
  for (const editing::TimedEdit& edit : schedule.edits()) {
    if (!(edit.time < sim.time() - slack)) break;  // sorted by time
    if (!std::holds_alternative<editing::Dab>(edit.command) &&
        !std::holds_alternative<editing::Relax>(edit.command))
      continue;
    if (!first) first = &edit;
    ++shaped;
  }
  if (first) {
    std::ostringstream text;
    text << source << ": /edits/" << first->source << " at t = " << first->time
         << " s comes before the start time " << sim.time()
         << " s: it is applied at the start, to the shape the run resumes from, not to the "
            "shape at its own time, so this run can differ from one run from t = 0";
    if (shaped > 1) text << " (" << shaped - 1 << " more such edits)";
    warn(text.str());
  }
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
    const double energyAfter = DivergenceGuard::energyOf(sim, sim.diagnostics());
    // Input, not a divergence: rest lengths scaled by 1e300 made the springs' energy infinite,
    // and the run "diverged" at the next step, writing that step's state as the last good one.
    if (!std::isfinite(energyAfter) && std::isfinite(energyBefore)) {
      std::ostringstream text;
      text << source << ": /edits/" << edit.source << " at t = " << sim.time()
           << " s: the model's energy after it is not finite (a value beyond what a double "
              "holds)";
      throw InvalidInputError(text.str());
    }
    energyChange += std::abs(energyAfter - energyBefore);
    if (verify)
      maxDifference =
          std::max(maxDifference, editing::verifyAgainstRebuild(sim.model(), sim.stepper().system(),
                                                                sim.stepper().transformation())
                                      .maxAbs());
  }
}

void TimedEdits::sayWhatIsLeft(const Simulation& sim) const {
  // Said, not skipped silently: an edit at t = 1000 s in a run of 3 steps was dropped and the
  // run exited 0, edits_applied 0 (a QA pass).
  const std::span<const editing::TimedEdit> left = schedule.pending();
  if (left.empty()) return;
  std::ostringstream text;
  text << source << ": /edits/" << left.front().source << " at t = " << left.front().time << " s";
  if (left.size() > 1) text << " and " << left.size() - 1 << " more after it";
  text << (left.size() > 1 ? " come" : " comes") << " at or after the run's end (t = " << sim.time()
       << " s): not applied (--time or --steps longer would reach "
       << (left.size() > 1 ? "them" : "it") << ")";
  warn(text.str());
}

}  // namespace zsculpt::cli
