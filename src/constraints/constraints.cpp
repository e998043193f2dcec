#include "zsculpt/constraints/constraints.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "zsculpt/core/errors.h"

namespace zsculpt {

std::string describeConstraint(ConstraintKind kind, Index vertex) {
  return std::string(kind == ConstraintKind::Position ? "position" : "normal") +
         " constraint at vertex " + std::to_string(vertex);
}

namespace {

// v / |v|: the plain quotient where |v|^2 is a normal number (the same bits as before), the
// scaled one where it would overflow or underflow (components of 1e200 made the zero vector).
Vec3 unitVector(const Vec3& v) {
  return std::isnormal(v.squaredNorm()) ? Vec3(v.normalized()) : Vec3(v.stableNormalized());
}

Eigen::SelfAdjointEigenSolver<Mat3> principalDirections(std::span<const Vec3> points) {
  Vec3 mean = Vec3::Zero();
  for (const Vec3& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Mat3 covariance = Mat3::Zero();
  for (const Vec3& p : points) covariance.noalias() += (p - mean) * (p - mean).transpose();
  return Eigen::SelfAdjointEigenSolver<Mat3>(covariance);
}

// Collinear (or coincident) points: the two smallest eigenvalues vanish together and the
// plane is not defined.
bool definesPlane(const Vec3& values) {
  return values[1] > 1e-12 * values[2] && values[2] > 0.0;
}

}  // namespace

std::optional<Vec3> fitPlaneNormal(std::span<const Vec3> points) {
  if (points.size() < 3) return std::nullopt;
  const Eigen::SelfAdjointEigenSolver<Mat3> eig = principalDirections(points);
  if (!definesPlane(eig.eigenvalues())) return std::nullopt;  // ascending eigenvalues
  return Vec3(eig.eigenvectors().col(0).normalized());
}

double planeFlatness(std::span<const Vec3> points) {
  if (points.size() < 3) return 1.0;
  const Vec3 values = principalDirections(points).eigenvalues();
  if (!definesPlane(values)) return 1.0;
  return std::max(values[0], 0.0) / values[1];
}

void normalFitVertices(const Mesh& mesh, Index vertex, std::vector<Index>& out) {
  out.clear();
  out.push_back(vertex);
  for (Index w : mesh.vertexNeighbors(vertex)) out.push_back(w);
}

std::optional<Vec3> bestPlaneNormal(const Mesh& mesh, const Points& position, Index vertex) {
  if (vertex < 0 || vertex >= mesh.numVertices() || mesh.valence(vertex) < 2) return std::nullopt;
  std::vector<Vec3> points;
  points.push_back(position.row(vertex).transpose());
  for (Index w : mesh.vertexNeighbors(vertex)) points.push_back(position.row(w).transpose());
  std::optional<Vec3> normal = fitPlaneNormal(points);
  if (!normal) return normal;
  // The fitted plane has no orientation of its own: take the faces' (Newell's vector area).
  Vec3 reference = Vec3::Zero();
  for (Index f : mesh.vertexFaces(vertex)) {
    const auto corners = mesh.face(f);
    for (size_t k = 0; k < corners.size(); ++k)
      reference += Vec3(position.row(corners[k]).transpose())
                       .cross(Vec3(position.row(corners[(k + 1) % corners.size()]).transpose()));
  }
  if (reference.squaredNorm() > 0.0) {
    if (normal->dot(reference) < 0.0) *normal = -*normal;
  } else {
    Index k = 0;
    normal->cwiseAbs().maxCoeff(&k);
    if ((*normal)[k] < 0.0) *normal = -*normal;
  }
  return normal;
}

namespace {

void checkVertex(const Mesh& mesh, ConstraintKind kind, Index vertex) {
  if (vertex < 0 || vertex >= mesh.numVertices())
    throw InvalidInputError(describeConstraint(kind, vertex) + ": no such vertex (the model has " +
                            std::to_string(mesh.numVertices()) + " vertices)");
}

std::string format(const Vec3& v) {
  std::ostringstream out;
  out.precision(6);
  out << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return out.str();
}

}  // namespace

std::size_t ConstraintSet::indexOf(Index id) const {
  const auto it = std::lower_bound(items_.begin(), items_.end(), id,
                                   [](const Constraint& c, Index value) { return c.id < value; });
  if (it == items_.end() || it->id != id)
    throw InvalidInputError("constraint " + std::to_string(id) + ": no such constraint");
  return static_cast<std::size_t>(it - items_.begin());
}

const Constraint& ConstraintSet::get(Index id) const {
  return items_[indexOf(id)];
}

std::optional<Index> ConstraintSet::find(ConstraintKind kind, Index vertex) const {
  for (const Constraint& c : items_)
    if (c.kind == kind && c.vertex == vertex) return c.id;
  return std::nullopt;
}

void ConstraintSet::checkNormalAgainstPins(const Mesh& mesh, Index vertex,
                                           const Vec3& normal) const {
  // When the vertex and its whole one-ring are pinned, the pins decide the plane: a
  // different normal cannot be reached by any force.
  std::vector<Index> fit;
  normalFitVertices(mesh, vertex, fit);
  std::vector<Vec3> targets;
  for (Index w : fit) {
    const auto pin = find(ConstraintKind::Position, w);
    if (!pin) return;
    targets.push_back(get(*pin).value);
  }
  const std::optional<Vec3> pinned = fitPlaneNormal(targets);
  if (!pinned || std::abs(pinned->dot(normal)) < std::cos(1e-6))
    throw InvalidInputError(describeConstraint(ConstraintKind::Normal, vertex) +
                            ": contradicts the position constraints on the vertex and all of "
                            "its neighbours, which fix another plane");
}

void ConstraintSet::checkNormalsAroundPin(const Mesh& mesh, Index vertex) const {
  // A pin at `vertex` may complete the pinning of a constrained normal's one-ring.
  std::vector<Index> fit;
  for (const Constraint& c : items_) {
    if (c.kind != ConstraintKind::Normal) continue;
    normalFitVertices(mesh, c.vertex, fit);
    if (std::find(fit.begin(), fit.end(), vertex) != fit.end())
      checkNormalAgainstPins(mesh, c.vertex, c.value);
  }
}

Index ConstraintSet::addPosition(const Mesh& mesh, Index vertex, const Vec3& target) {
  checkVertex(mesh, ConstraintKind::Position, vertex);
  const std::string what = describeConstraint(ConstraintKind::Position, vertex);
  if (!target.allFinite()) throw InvalidInputError(what + ": the target is not finite");
  if (const auto existing = find(ConstraintKind::Position, vertex)) {
    const Vec3& old = get(*existing).value;
    const double scale = std::max({1.0, old.cwiseAbs().maxCoeff(), target.cwiseAbs().maxCoeff()});
    if ((old - target).norm() > 1e-12 * scale)
      throw InvalidInputError(what + ": given twice with different targets " + format(old) +
                              " and " + format(target));
    warnings_.push_back(what + ": given twice; kept once");
    return *existing;
  }
  items_.push_back(Constraint{nextId_, ConstraintKind::Position, vertex, target});
  try {
    checkNormalsAroundPin(mesh, vertex);
  } catch (const InvalidInputError&) {
    items_.pop_back();
    throw;
  }
  ++revision_;
  return nextId_++;
}

Index ConstraintSet::addNormal(const Mesh& mesh, const Points& position, Index vertex,
                               const Vec3& normal) {
  checkVertex(mesh, ConstraintKind::Normal, vertex);
  const std::string what = describeConstraint(ConstraintKind::Normal, vertex);
  // Stable norms: a target of 1e200 components has an infinite plain norm, and normalized()
  // then made it the zero vector (a constraint that held nothing).
  if (!normal.allFinite() || !(normal.stableNorm() > 0.0))
    throw InvalidInputError(what + ": the normal must be a finite, non-zero vector");
  const Index valence = mesh.valence(vertex);
  if (valence == 0) throw InvalidInputError(what + ": an isolated vertex has no normal");
  if (valence == 1)
    throw InvalidInputError(what +
                            ": a vertex with a single neighbour (a curve end) has no normal");
  if (!bestPlaneNormal(mesh, position, vertex))
    throw InvalidInputError(what + ": no plane fits the vertex and its neighbours (collinear)");
  // Judged on the mesh as loaded, not on the current shape: a ring folded for the moment is
  // let go while it is (ConstraintSolver), and a constraint carried over (a change of scheme)
  // must not be refused for where its ring happens to be.
  std::vector<Index> ring;
  normalFitVertices(mesh, vertex, ring);
  std::vector<Vec3> points;
  for (Index v : ring) points.push_back(mesh.positions().row(v).transpose());
  if (const double flatness = planeFlatness(points); flatness > kMaxPlaneFlatness) {
    std::ostringstream message;
    message << what << ": the vertex and its neighbours have no flattest direction in the mesh "
            << "(flatness " << flatness << " > " << kMaxPlaneFlatness << "), so no normal to hold";
    throw InvalidInputError(message.str());
  }
  const Vec3 unit = unitVector(normal);
  if (const auto existing = find(ConstraintKind::Normal, vertex)) {
    if (get(*existing).value.dot(unit) < std::cos(1e-9))
      throw InvalidInputError(what + ": given twice with different normals " +
                              format(get(*existing).value) + " and " + format(unit));
    warnings_.push_back(what + ": given twice; kept once");
    return *existing;
  }
  checkNormalAgainstPins(mesh, vertex, unit);
  items_.push_back(Constraint{nextId_, ConstraintKind::Normal, vertex, unit});
  ++revision_;
  return nextId_++;
}

void ConstraintSet::setTarget(Index id, const Vec3& target) {
  Constraint& c = items_[indexOf(id)];
  if (c.kind != ConstraintKind::Position)
    throw InvalidInputError(describeConstraint(c.kind, c.vertex) + ": has no target to move");
  if (!target.allFinite())
    throw InvalidInputError(describeConstraint(c.kind, c.vertex) + ": the target is not finite");
  c.value = target;
}

void ConstraintSet::movePosition(const Mesh& mesh, Index id, Index vertex, const Vec3& target) {
  const size_t at = indexOf(id);
  if (items_[at].kind != ConstraintKind::Position)
    throw InvalidInputError(describeConstraint(items_[at].kind, items_[at].vertex) +
                            ": not a position constraint");
  checkVertex(mesh, ConstraintKind::Position, vertex);
  const std::string what = describeConstraint(ConstraintKind::Position, vertex);
  if (!target.allFinite()) throw InvalidInputError(what + ": the target is not finite");
  if (vertex == items_[at].vertex) {
    items_[at].value = target;
    return;
  }
  if (find(ConstraintKind::Position, vertex))
    throw InvalidInputError(what + ": another position constraint holds the vertex");
  const Constraint before = items_[at];
  items_[at].vertex = vertex;
  items_[at].value = target;
  try {
    checkNormalsAroundPin(mesh, vertex);  // where it was, it no longer counts
  } catch (const InvalidInputError&) {
    items_[at] = before;
    throw;
  }
  ++revision_;
}

void ConstraintSet::setNormal(Index id, const Vec3& normal) {
  Constraint& c = items_[indexOf(id)];
  if (c.kind != ConstraintKind::Normal)
    throw InvalidInputError(describeConstraint(c.kind, c.vertex) + ": has no normal to set");
  if (!normal.allFinite() || !(normal.stableNorm() > 0.0))
    throw InvalidInputError(describeConstraint(c.kind, c.vertex) +
                            ": the normal must be a finite, non-zero vector");
  c.value = unitVector(normal);
}

void ConstraintSet::remove(Index id) {
  items_.erase(items_.begin() + static_cast<std::ptrdiff_t>(indexOf(id)));
  ++revision_;
}

void ConstraintSet::clear() {
  if (items_.empty()) return;
  items_.clear();
  ++revision_;
}

std::vector<std::string> ConstraintSet::takeWarnings() {
  std::vector<std::string> out;
  out.swap(warnings_);
  return out;
}

}  // namespace zsculpt
