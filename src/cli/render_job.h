#pragma once
// Internal to the cli module: simulate a model and write what a person looks at, offscreen
// (OSMesa): PNG frames of the smooth surface, the diagnostics CSV and the energy and
// momentum plot. `zsculpt render` and `zsculpt demo` are thin front ends of this.

#include <optional>
#include <string>
#include <vector>

#include "model_options.h"

namespace zsculpt::cli {

struct RenderJobOptions {
  ModelOptions model;
  RunOptions run;
  std::string out;                ///< folder (created when missing)
  std::optional<long> frames;     ///< frames to write (default 30, or as --every implies)
  std::optional<long> every;      ///< steps between frames
  std::string size = "1280x720";  ///< WxH
  std::string property;           ///< colour the surface by this property ("" or "none": clay)
  std::optional<int>
      levels;            ///< Doo-Sabin levels of the drawn surface (default: app::levelsForImage)
  bool classic = false;  ///< classic Doo-Sabin for the drawn surface (no interpolation)
  bool progress = true;  ///< a progress bar on standard error when it is a terminal
  bool verifyMatrices = false;  ///< after every edit, compare the matrices with a rebuild
};

struct RenderJobResult {
  std::vector<std::string> frames;
  std::vector<double> frameTimes;  ///< the simulated time of each frame, in seconds
  std::string diagnostics, plot, stateOut;
  long steps = 0;       ///< asked for
  long stepsTaken = 0;  ///< done: steps, or those before a divergence
  double period = 0.0, tMax = 0.0, wallSeconds = 0.0;
  int width = 0, height = 0, levels = 0;
  bool diverged = false;
  long divergedAt = -1;
  std::string divergence;         ///< why: non-finite state, or runaway energy
  long editsApplied = 0;          ///< the scene's edits that changed something
  double matrixDifference = 0.0;  ///< with verifyMatrices: largest |local - rebuilt|
};

/// Runs the job. Everything that can be refused (size, property, levels, output folder,
/// no OSMesa) is checked before any simulation work and thrown as zsculpt::Error. A
/// divergence is not thrown: the result says so, and what was rendered up to it is kept.
RenderJobResult runRenderJob(const RenderJobOptions& options);

/// Prints the result (paths, or JSON with --json) and returns the exit status (3 after a
/// divergence, with the one-line error on standard error).
int reportRenderJob(const RenderJobOptions& options, const RenderJobResult& result,
                    const std::string& source);

}  // namespace zsculpt::cli
