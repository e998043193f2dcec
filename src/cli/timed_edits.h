#pragma once
// Internal to the cli module: a scene's timed edits (paper section 3, "Dynamic Editing")
// applied between solver cycles with the local matrix update. Shared by simulate and
// render so that both play a scene the same way.

#include <optional>
#include <string>

#include "model_options.h"
#include "zsculpt/editing/local_update.h"
#include "zsculpt/io/scene_edits.h"

namespace zsculpt::cli {

struct TimedEdits {
  editing::EditSchedule schedule;
  std::optional<editing::Editor> editor;
  std::string source;
  bool verify = false;  ///< compare every local update with a full rebuild
  long applied = 0;
  double maxDifference = 0.0;
  /// Sum of |change of the total energy| over the edits applied since the last take: an
  /// edit changes the stored energy without any work (paper section 3).
  double energyChange = 0.0;

  TimedEdits(const LoadedModel& loaded, const Simulation& sim, bool verifyMatrices);
  /// Applies the edits due at the simulation's current time. Throws InvalidInputError
  /// "<scene>: /edits/<k>: <reason>" for an edit the model refuses.
  void beforeStep(Simulation& sim);
  /// After a run that ended at the simulation's current time: a warning naming the edits
  /// still pending (due at or after the end), which a run that stopped short never applies.
  void sayWhatIsLeft(const Simulation& sim) const;
  double takeEnergyChange() {
    const double e = energyChange;
    energyChange = 0.0;
    return e;
  }
};

}  // namespace zsculpt::cli
