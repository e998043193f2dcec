#pragma once
// Position and normal constraints (paper section 6, "Constraints"): a modeller pins the
// position of a vertex, or the surface normal at a vertex, and "the solver generates
// virtual forces such that the appropriate result is obtained in the next time cycle".
//
// This file holds the constraints themselves (ConstraintSet: what is pinned, checked
// against the mesh) and the best-plane normal they use. solver.h computes the virtual
// forces; the simulation module runs them inside the solver cycle.
//
// Bad input gets InvalidInputError "<which constraint>: <reason>": a vertex that does not
// exist, a non-finite target, a zero normal, a normal constraint where no normal is
// defined (an isolated vertex, a curve end, a vertex whose one-ring is collinear), two
// position constraints with different targets (or two normal constraints with different
// normals) on one vertex, and a normal constraint on a vertex whose whole one-ring is
// pinned in a configuration with another normal. The same constraint given twice is kept
// once, with a warning (takeWarnings()).

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/mesh/mesh.h"

namespace zsculpt {

enum class ConstraintKind { Position, Normal };

struct Constraint {
  Index id = -1;
  ConstraintKind kind = ConstraintKind::Position;
  Index vertex = 0;
  /// Position: the target point. Normal: the unit normal to hold.
  Vec3 value = Vec3::Zero();
};

/// Unit normal of the least-squares plane through `points` (the eigenvector of the
/// smallest eigenvalue of their covariance), unoriented; nullopt for fewer than three
/// points or (nearly) collinear ones.
std::optional<Vec3> fitPlaneNormal(std::span<const Vec3> points);

/// How well `points` define fitPlaneNormal's plane: l0 / l1, the smallest principal
/// variance of the points over the middle one. 0 for points in a plane, 1 where no
/// direction is flattest (the fitted normal is then undefined, and jumps under the
/// slightest change); 1 also for fewer than three points or collinear ones.
double planeFlatness(std::span<const Vec3> points);

/// The most planeFlatness a ring may have for its normal to be held: a normal constraint is
/// refused on a ring beyond it, and let go for a cycle that starts with its ring beyond it
/// (ConstraintSolver). Where l0 and l1 meet the fitted normal is undefined, its gradient
/// grows as 1 / (l1 - l0), and forces along that gradient tear the ring apart
/// (docs/semi-rigid-and-constraints.md, "A folding ring is let go"). A braced ring stays far
/// below it (a flat grid's: 0); an unbraced dodecahedron's, held through 2000 cycles of
/// random motion, reaches 0.77.
inline constexpr double kMaxPlaneFlatness = 0.8;

/// The best-plane normal at `vertex` (paper section 3): the plane through the vertex and
/// its one-ring, as the subdivision module computes vertex normals, oriented along the
/// Newell vector of the vertex's faces (a curve has none: the largest component is made
/// positive). nullopt where no normal is defined: fewer than two neighbours (an isolated
/// vertex, a curve end) or collinear points.
std::optional<Vec3> bestPlaneNormal(const Mesh& mesh, const Points& position, Index vertex);

/// The vertices whose plane defines the normal at `vertex`: the vertex, then its one-ring.
void normalFitVertices(const Mesh& mesh, Index vertex, std::vector<Index>& out);

class ConstraintSet {
 public:
  /// Pins `vertex` at `target`. Returns the constraint's id.
  Index addPosition(const Mesh& mesh, Index vertex, const Vec3& target);
  /// Holds the normal at `vertex` along `normal` (normalised); `position` is the current
  /// shape (to check that a normal is defined there). Returns the constraint's id.
  Index addNormal(const Mesh& mesh, const Points& position, Index vertex, const Vec3& normal);
  /// Moves a position constraint's target (the drag tool calls this every frame).
  void setTarget(Index id, const Vec3& target);
  /// The position constraint `id` holds `vertex` at `target` from now on (a drag moved to
  /// another vertex): same id, same place in the list. All or nothing: throws
  /// InvalidInputError (no such vertex, a vertex another position constraint holds, a pin
  /// that would contradict a normal constraint) with the constraint as it was.
  void movePosition(const Mesh& mesh, Index id, Index vertex, const Vec3& target);
  /// Changes a normal constraint's normal.
  void setNormal(Index id, const Vec3& normal);
  void remove(Index id);
  void clear();

  [[nodiscard]] bool empty() const { return items_.empty(); }
  [[nodiscard]] std::size_t size() const { return items_.size(); }
  /// Live constraints in increasing id order.
  [[nodiscard]] std::span<const Constraint> constraints() const { return items_; }
  /// Throws InvalidInputError for an unknown id.
  [[nodiscard]] const Constraint& get(Index id) const;
  /// The id of the constraint of this kind at `vertex`, if any.
  [[nodiscard]] std::optional<Index> find(ConstraintKind kind, Index vertex) const;
  /// Changes whenever a constraint is added or removed (not when a target moves).
  [[nodiscard]] std::uint64_t revision() const { return revision_; }
  /// Warnings since the last call (duplicates that were merged), for the user.
  std::vector<std::string> takeWarnings();

 private:
  [[nodiscard]] std::size_t indexOf(Index id) const;
  void checkNormalAgainstPins(const Mesh& mesh, Index vertex, const Vec3& normal) const;
  // checkNormalAgainstPins for every normal constraint whose ring holds `vertex`.
  void checkNormalsAroundPin(const Mesh& mesh, Index vertex) const;

  std::vector<Constraint> items_;
  Index nextId_ = 0;
  std::uint64_t revision_ = 0;
  std::vector<std::string> warnings_;
};

/// "position constraint at vertex 3" / "normal constraint at vertex 3": the prefix of
/// every message about a constraint.
std::string describeConstraint(ConstraintKind kind, Index vertex);

}  // namespace zsculpt
