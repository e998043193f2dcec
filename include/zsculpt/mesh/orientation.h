#pragma once
// Consistent face winding for imported meshes. Downloaded assets often have a face or a
// whole model wound the wrong way; the subdivision then treats every edge of a reversed face
// as a crease (two neighbours running an edge the same way do not form a smooth sheet), and
// an inward-wound model shows its back faces. Done on the face lists, before a Mesh is
// built; vertex indices do not change.

#include <vector>

#include "zsculpt/core/types.h"

namespace zsculpt {

struct OrientationReport {
  Index facesReversed = 0;
  /// Components in which no winding agrees across every shared edge (a Moebius band): they
  /// are left as they are.
  Index nonOrientableComponents = 0;
};

/// Makes the faces' winding agree across every edge shared by exactly two faces (an edge of
/// three or more faces, non-manifold, joins sheets that have no common side, and is not
/// crossed), sheet by sheet. A closed sheet is then wound outward (positive signed volume),
/// unless it lies inside a larger closed sheet: a hollow model's inner wall (wound into its
/// cavity) and a part inside another (wound outward) look alike, so a nested sheet keeps its
/// winding relative to the one around it, turned only with it. An open sheet keeps the
/// winding most of its faces had, so that one stray face is the one turned. A non-orientable
/// sheet is left as it is. A face is reversed keeping its first corner.
OrientationReport orientFaces(const Points& positions, std::vector<std::vector<Index>>& faces);

}  // namespace zsculpt
