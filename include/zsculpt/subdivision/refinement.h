#pragma once
// One level of the modified Doo-Sabin scheme on a bare topology (no positions): the
// building block of SubdivisionStencil. Exposed for tests and tools; most users want
// subdivision.h. The rule is described in docs/subdivision.md.

#include <array>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::subdivision_detail {

/// A level's connectivity: `faces` (their edges come from them) and `curveEdges`, the edges
/// of no face (a curve, or loose edges beside a surface; smaller index first).
struct LevelTopology {
  Index numVertices = 0;
  CsrIndex faces;
  std::vector<std::array<Index, 2>> curveEdges;
  /// Vertices that must stay corners (the copies of the previous level's corners); empty
  /// for a control mesh. Without it a corner's copy can look like a regular boundary vertex.
  std::vector<char> keep;
};

/// What refineLevel produces. Refined vertices are numbered: one per old face corner (in
/// corner order, so F-face f keeps index f and corner order), then two per old feature
/// edge (the point near its first end, then near its second), then one copy per old
/// corner, carried vertex or interior vertex of valence 2 (in vertex order).
struct LevelStep {
  LevelTopology next;
  /// Positions: new = positions * old (rows sum to 1).
  SparseRowMatrix positions;
  /// Masses: new = mass * old (non-negative, columns sum to 1).
  SparseRowMatrix mass;
  /// Old feature edges (smaller index first) and, per old vertex, its feature edges.
  std::vector<std::array<Index, 2>> featureEdges;
  CsrIndex vertexFeatureEdges;
  Index numCorners = 0;
  /// Per old vertex: its copy (corners, carried and valence-2 vertices) or -1; its first V-face or
  /// -1; a refined vertex near it (always defined), used to follow a vertex down levels.
  std::vector<Index> copy;
  std::vector<Index> vertexFace;
  std::vector<Index> child;
  /// Per old vertex: the refined face, segment or vertex that interpolates it when this is
  /// the first, interpolating level.
  std::vector<InterpolationAnchor> anchor;

  /// The refined point of old feature edge e nearest its end v.
  [[nodiscard]] Index curvePoint(Index e, Index v) const {
    return numCorners + 2 * e + (featureEdges[e][0] == v ? 0 : 1);
  }
  /// The old feature edge joining a and b, or -1.
  [[nodiscard]] Index findFeatureEdge(Index a, Index b) const;
};

/// Refines one level. `mass` (old vertex masses, or null for the classic geometric masks)
/// weights the masks; `interpolate` applies the first-level translation that makes the
/// limit pass through the old vertices.
LevelStep refineLevel(const LevelTopology& topology, const VectorX* mass, bool interpolate);

/// Unique edges of polygons (smaller index first, ordered by smaller end then first use)
/// and each vertex's one-ring through them (in order of first use).
void faceEdgesAndRings(Index numVertices, const CsrIndex& faces,
                       std::vector<std::array<Index, 2>>& edges, CsrIndex& rings);

/// C = A * B for row-major sparse matrices (columns sorted; cancellations are kept as
/// explicit zeros).
SparseRowMatrix multiplyRowMajor(const SparseRowMatrix& a, const SparseRowMatrix& b);

}  // namespace zsculpt::subdivision_detail
