#pragma once
// Smooth surface from a modified Doo-Sabin subdivision that interpolates the mesh
// (paper section 3 "Smoothing", Figure 5). See docs/subdivision.md.
//
// The composition of L levels is one sparse matrix S (refined vertices x control
// vertices), built once per topology: a frame's refresh is one sparse product
// refined = S * control, with no allocation.
//
// One level (docs/subdivision.md has the full rule):
//   - every face corner gives a refined vertex (Doo-Sabin face-point masks); every face
//     gives an F-face, every interior edge an E-face (quad), every vertex a V-face;
//   - feature edges (boundary, non-manifold, or two faces of the same winding) follow a
//     Chaikin curve rule and keep their faces' E-faces, so open surfaces reach their
//     boundary; corners (curve ends and junctions, one-face boundary vertices) keep a
//     copy of themselves, and where every fan of faces wraps around one non-manifold edge
//     the curve simply ends there;
//   - curves (edges of no face: a curve, or loose edges beside a surface) use the same
//     curve rule, starting on the surface vertex they leave; vertices on no face of a surface
//     (a solid's interior, isolated vertices) are carried unchanged; an interior vertex on
//     only two faces keeps a copy between its two face points (no two-sided V-face).
// With `interpolate`, the first level translates each vertex's V-face (or boundary
// segment) so that its centroid sits on the vertex; later levels keep such centroids, so
// the limit passes through every control vertex.

#include <Eigen/SparseCore>
#include <array>
#include <cstdint>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/mesh/mesh.h"

namespace zsculpt {

using SparseRowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, Index>;

struct SubdivisionOptions {
  int levels = 2;
  /// Modified scheme: the limit surface passes through the control vertices. False gives
  /// classic Doo-Sabin (CGAL's masks), which does not interpolate.
  bool interpolate = true;
  /// Per-vertex masses (optional, size = control vertices): physics-dependent weights so
  /// that total mass and linear momentum carried to the refined mesh equal the original.
  /// Without masses the weights are the classic (geometric) masks.
  const VectorX* mass = nullptr;
  /// Levels whose estimated refined vertices (estimatedRefinedVertices) exceed this are
  /// refused up front, before any work. The default, 2^22, is about 6.5 GB at the peak of
  /// about 1.5 KB a refined vertex that `zsculpt subdivide` measures (docs/subdivision.md).
  double maxRefinedVertices = 4194304.0;
};

/// About how many vertices `levels` levels of the scheme make from `control`, without
/// building the stencil (the loose edges are judged as the stencil judges them, a ray test
/// each beside a closed surface: not a per-frame call): one per face corner at the first level and
/// four times as many at each later one (exact for a closed mesh), and two per curve edge, doubling
/// (the curves as the stencil finds them: a solid's inner edges are not curves).
double estimatedRefinedVertices(const Mesh& control, int levels);

/// The most levels, at most `wanted`, whose estimate stays within `maxRefinedVertices`.
int levelsWithin(const Mesh& control, int wanted, double maxRefinedVertices);

/// How a control vertex is reached at the last level: the (mass-weighted) centroid of a
/// refined face, the (mass-weighted) midpoint of a refined feature segment, or a refined
/// vertex that copies it. With `interpolate` that point is the control vertex itself.
enum class AnchorKind : std::uint8_t { Face, Segment, Vertex };
struct InterpolationAnchor {
  AnchorKind kind = AnchorKind::Vertex;
  Index a = -1;  ///< refined face (Face), first end (Segment) or refined vertex (Vertex)
  Index b = -1;  ///< second end (Segment)
};

class SubdivisionStencil {
 public:
  SubdivisionStencil() = default;
  /// Builds the stencil of `options.levels` levels (0 to 10) for `control`'s topology.
  /// Throws InvalidInputError for a level count out of range or too large a result, and
  /// for masses of the wrong size, non-finite or not positive.
  SubdivisionStencil(const Mesh& control, const SubdivisionOptions& options);
  SubdivisionStencil(const SubdivisionStencil&) = default;
  SubdivisionStencil& operator=(const SubdivisionStencil&) = default;
  /// Moves swap the matrices (Eigen 3.4's SparseMatrix would otherwise be copied).
  SubdivisionStencil(SubdivisionStencil&& other) noexcept;
  SubdivisionStencil& operator=(SubdivisionStencil&& other) noexcept;

  [[nodiscard]] int levels() const;
  [[nodiscard]] Index numControlVertices() const;
  [[nodiscard]] Index numRefinedVertices() const;
  /// Refined faces (CSR; polygons). Triangulate with a fan for drawing.
  [[nodiscard]] const CsrIndex& refinedFaces() const;
  /// Refined edges for curves (a refined polyline) and wireframes: the faces' edges, then
  /// the curves' (numRefinedCurveEdges of them: a curve, or the loose edges beside a surface).
  [[nodiscard]] const std::vector<std::array<Index, 2>>& refinedEdges() const;
  /// How many of refinedEdges(), at its end, are the curves' (edges of no face).
  [[nodiscard]] Index numRefinedCurveEdges() const { return numRefinedCurveEdges_; }
  /// One-ring of each refined vertex (for bestPlaneNormals): through the faces' edges for a
  /// vertex on a face, along the curves for a curve's own vertex.
  [[nodiscard]] const CsrIndex& refinedVertexNeighbors() const;
  [[nodiscard]] const SparseRowMatrix& matrix() const;

  /// refined = S * control. `refined` must already have numRefinedVertices() rows: no
  /// allocation.
  void apply(const Points& control, Points& refined) const;
  /// Per-vertex scalar (e.g. a painted property for colouring): refined = S * control.
  void apply(const VectorX& control, VectorX& refined) const;

  /// For each control vertex, the refined vertex that converges to it (interpolation).
  [[nodiscard]] const std::vector<Index>& controlToRefined() const;
  /// For each control vertex, the refined face / segment / vertex whose (mass-weighted)
  /// centre is the point of the last level that interpolates it.
  [[nodiscard]] const std::vector<InterpolationAnchor>& anchors() const;

  /// Mass carried to the refined vertices: refinedMass = T * controlMass, where T depends
  /// on the topology only and every column of T sums to 1 (total mass is kept). With the
  /// masses the stencil was built with, sum_r m'_r (S v)_r = sum_i m_i v_i for every
  /// velocity field v (linear momentum is kept). `refinedMass` is resized.
  void refinedMass(const VectorX& controlMass, VectorX& refinedMass) const;
  [[nodiscard]] VectorX refinedMass(const VectorX& controlMass) const;

  /// Best-plane normals of refined positions (bestPlaneNormals on the refined topology).
  /// `normals` must have numRefinedVertices() rows: no allocation.
  void refinedNormals(const Points& refined, Points& normals) const;

 private:
  int levels_ = 0;
  Index numControl_ = 0;
  SparseRowMatrix matrix_;
  std::vector<SparseRowMatrix> massTransfer_;  // one per level, applied in order
  CsrIndex refinedFaces_;
  std::vector<std::array<Index, 2>> refinedEdges_;
  Index numRefinedCurveEdges_ = 0;
  CsrIndex refinedNeighbors_;
  std::vector<Index> controlToRefined_;
  std::vector<InterpolationAnchor> anchors_;
};

/// One-call form: the refined mesh at the control mesh's current positions. Its vertices
/// are the stencil's refined vertices that a face or edge uses, in order: a solid's
/// interior vertices, which the stencil carries unchanged, are left out of the surface.
/// On degenerate input (e.g. two faces on the same vertices) refined vertices joined by an
/// edge coincide: those are merged (Mesh has no zero-length edge) and faces left
/// degenerate are dropped.
Mesh subdivide(const Mesh& control, const SubdivisionOptions& options);

/// The same mesh from a stencil already built and its refined positions (stencil.apply).
Mesh refinedMesh(const SubdivisionStencil& stencil, Points refined);

/// Normals by a best-plane (least-squares) fit of each vertex's one-ring in `faces`
/// (paper section 3), oriented consistently with the faces' winding. `normals` must have
/// positions.rows() rows; no allocation.
void bestPlaneNormals(const CsrIndex& faces, const CsrIndex& vertexNeighbors,
                      const Points& positions, Points& normals);

/// Distance from each control vertex to the point of the refined surface that
/// interpolates it: the nearest point of its anchor face (fan-triangulated from corner 0,
/// as drawn), of its anchor segment, or its anchor vertex. `errors` is resized.
void interpolationErrors(const SubdivisionStencil& stencil, const Points& control,
                         const Points& refined, VectorX& errors);
/// Largest of interpolationErrors: the `max_interpolation_error` of `zsculpt subdivide`.
double maxInterpolationError(const SubdivisionStencil& stencil, const Points& control,
                             const Points& refined);
/// Largest distance from a control vertex to the refined vertex controlToRefined() gives
/// (falls like 2^-levels: Doo-Sabin is a dual scheme, its vertices only approach the
/// surface point).
double maxVertexInterpolationError(const SubdivisionStencil& stencil, const Points& control,
                                   const Points& refined);

}  // namespace zsculpt
