#include "levels.h"

#include <new>
#include <string>

#include "zsculpt/core/errors.h"

namespace zsculpt::cli {

void checkLevelsRange(int levels) {
  if (levels < 0 || levels > kMaxLevels)
    throw InvalidInputError("--levels: " + std::to_string(levels) + " is outside [0, " +
                            std::to_string(kMaxLevels) + "]");
}

SubdivisionStencil stencilForLevels(const Mesh& control, const SubdivisionOptions& options) {
  // The estimate (subdivision.h) refuses what would not fit before any work; memory that
  // runs out anyway (a smaller machine) is said of the flag.
  try {
    return SubdivisionStencil(control, options);
  } catch (const InvalidInputError& e) {
    const std::string what = e.what();
    throw InvalidInputError(what.rfind("levels: ", 0) == 0 ? "--" + what : what);
  } catch (const std::bad_alloc&) {
    // Nothing here that allocates much (the estimate judges the loose edges, building a grid).
    throw InvalidInputError("--levels: out of memory building " + std::to_string(options.levels) +
                            " levels of this " + std::to_string(control.numVertices()) +
                            "-vertex mesh; try fewer levels");
  }
}

}  // namespace zsculpt::cli
