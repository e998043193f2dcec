#pragma once
// --levels of `subdivide` and `render`: one range and one way of refusing what will not fit.

#include "zsculpt/mesh/mesh.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::cli {

/// The most levels a command takes (8: a dodecahedron's 60 corners times 4^7, about 1 M
/// vertices; larger meshes are refused earlier, by the estimate).
inline constexpr int kMaxLevels = 8;

/// Throws InvalidInputError "--levels: L is outside [0, 8]".
void checkLevelsRange(int levels);

/// The stencil of `options.levels` levels of `control`. What the estimate refuses (too many
/// vertices) and memory that runs out anyway are said of --levels, with the levels that fit.
SubdivisionStencil stencilForLevels(const Mesh& control, const SubdivisionOptions& options);

}  // namespace zsculpt::cli
