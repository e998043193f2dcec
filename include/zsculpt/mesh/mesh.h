#pragma once
// The mesh a mass-spring solver needs, for any topology: curves (edges, no faces),
// surfaces (open, closed, non-manifold), solids (boundary faces plus interior edges).
// Nothing here assumes a manifold: an edge may have 0, 1, 2 or more faces.
//
// Connectivity is immutable after construction; positions may be replaced (same count).
// All adjacency is stored as CSR so queries allocate nothing.

#include <array>
#include <span>
#include <vector>

#include "zsculpt/core/types.h"

namespace zsculpt {

struct BoundingBox {
  Vec3 min = Vec3::Zero();
  Vec3 max = Vec3::Zero();
  [[nodiscard]] double diagonal() const { return (max - min).norm(); }
  [[nodiscard]] Vec3 center() const { return 0.5 * (min + max); }
};

class Mesh {
 public:
  Mesh() = default;

  /// Builds the connectivity. Throws InvalidInputError for non-finite coordinates and
  /// TopologyError for an empty mesh, a face with fewer than 3 corners, an index out of
  /// range, a face that repeats a vertex, or an edge whose ends coincide (a zero-length
  /// spring). Edges are numbered in order of first occurrence: face edges (face order,
  /// corner order), then the explicit edges.
  Mesh(Points positions, const std::vector<std::vector<Index>>& faces,
       const std::vector<std::array<Index, 2>>& explicitEdges = {});

  [[nodiscard]] Index numVertices() const { return static_cast<Index>(positions_.rows()); }
  [[nodiscard]] Index numEdges() const { return static_cast<Index>(edges_.size()); }
  [[nodiscard]] Index numFaces() const { return faces_.rows(); }

  [[nodiscard]] const Points& positions() const { return positions_; }
  /// Replaces the positions (same vertex count; finite). Connectivity is unchanged.
  void setPositions(const Points& positions);

  [[nodiscard]] std::span<const Index> face(Index f) const { return faces_.row(f); }
  [[nodiscard]] const CsrIndex& faces() const { return faces_; }
  /// Edge e's two vertices, smaller index first.
  [[nodiscard]] const std::array<Index, 2>& edge(Index e) const { return edges_[e]; }
  [[nodiscard]] const std::vector<std::array<Index, 2>>& edges() const { return edges_; }
  /// Edges incident to v, increasing edge index.
  [[nodiscard]] std::span<const Index> vertexEdges(Index v) const { return vertexEdges_.row(v); }
  /// The one-ring of v: the vertex across each of vertexEdges(v), in the same order.
  [[nodiscard]] std::span<const Index> vertexNeighbors(Index v) const {
    return vertexNeighbors_.row(v);
  }
  [[nodiscard]] Index valence(Index v) const { return vertexEdges_.rowSize(v); }
  [[nodiscard]] const CsrIndex& vertexEdgeTable() const { return vertexEdges_; }
  [[nodiscard]] const CsrIndex& vertexNeighborTable() const { return vertexNeighbors_; }
  /// Faces incident to e, increasing face index.
  [[nodiscard]] std::span<const Index> edgeFaces(Index e) const { return edgeFaces_.row(e); }
  /// Edge k of face f joins corners k and k+1 (mod n).
  [[nodiscard]] std::span<const Index> faceEdges(Index f) const { return faceEdges_.row(f); }
  /// Faces incident to v, increasing face index.
  [[nodiscard]] std::span<const Index> vertexFaces(Index v) const { return vertexFaces_.row(v); }

  /// The edge joining a and b, or -1.
  [[nodiscard]] Index findEdge(Index a, Index b) const;

  [[nodiscard]] bool isBoundaryEdge(Index e) const { return edgeFaces_.rowSize(e) == 1; }
  [[nodiscard]] bool isNonManifoldEdge(Index e) const { return edgeFaces_.rowSize(e) > 2; }
  /// An edge with no face: a curve segment or an interior edge of a solid.
  [[nodiscard]] bool isWireEdge(Index e) const { return edgeFaces_.rowSize(e) == 0; }
  [[nodiscard]] bool isIsolatedVertex(Index v) const { return vertexEdges_.rowSize(v) == 0; }

  [[nodiscard]] std::vector<Index> boundaryEdges() const;
  [[nodiscard]] std::vector<Index> nonManifoldEdges() const;
  [[nodiscard]] std::vector<Index> isolatedVertices() const;
  /// Connected components through edges: a label per vertex (0-based, in order of the
  /// smallest vertex of each component) and the component count.
  [[nodiscard]] std::vector<Index> componentLabels(Index* count = nullptr) const;
  [[nodiscard]] Index numComponents() const;
  /// Vertices within two edges of v, v excluded, sorted.
  [[nodiscard]] std::vector<Index> twoRing(Index v) const;

  [[nodiscard]] BoundingBox boundingBox() const;
  /// Mean edge length (0 when there are no edges).
  [[nodiscard]] double meanEdgeLength() const;
  /// Mean length of v's edges with the vertices at `positions` (0 when v has none).
  [[nodiscard]] double meanEdgeLengthAt(Index v, const Points& positions) const;

 private:
  Points positions_;
  CsrIndex faces_;
  std::vector<std::array<Index, 2>> edges_;
  CsrIndex vertexEdges_;
  CsrIndex vertexNeighbors_;
  CsrIndex vertexFaces_;
  CsrIndex edgeFaces_;
  CsrIndex faceEdges_;
};

/// Builds CSR rows from (row, value) pairs, keeping values in the order given within rows.
CsrIndex buildCsr(Index rows, const std::vector<std::pair<Index, Index>>& pairs);

}  // namespace zsculpt
