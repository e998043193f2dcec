#include "zsculpt/editing/local_update.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace zsculpt::editing {

bool propertyChangesMatrices(Property property) {
  switch (property) {
    case Property::Mass:
    case Property::Damping:
    case Property::Stiffness:
    case Property::AngularStiffness:
    case Property::RestLength:  // the angle springs' bound (matrixEdgeStiffness)
      return true;
    case Property::Rigidity:
    case Property::RestAngle:
      return false;
  }
  return false;
}

void appendAffectedRows(const Mesh& mesh, Property property, std::span<const Index> elements,
                        std::vector<Index>& rows) {
  switch (property) {
    case Property::Mass:
    case Property::Damping:
      rows.insert(rows.end(), elements.begin(), elements.end());
      break;
    case Property::Stiffness:
    case Property::AngularStiffness:
      for (Index v : elements) {
        rows.push_back(v);
        for (Index j : mesh.vertexNeighbors(v)) rows.push_back(j);
      }
      break;
    case Property::RestLength:  // an edge's entry: its two rows
      for (Index e : elements) {
        const auto [i, j] = mesh.edge(e);
        rows.push_back(i);
        rows.push_back(j);
      }
      break;
    case Property::Rigidity:
    case Property::RestAngle:
      break;
  }
}

namespace {

constexpr double kEmpty = -std::numeric_limits<double>::infinity();

}  // namespace

CriticalPeriodTracker::CriticalPeriodTracker(const SystemMatrices& system) {
  const Index n = static_cast<Index>(system.omega2().rows());
  leaves_ = 1;
  while (leaves_ < n) leaves_ *= 2;
  tree_.assign(2 * static_cast<size_t>(leaves_), kEmpty);
  for (Index i = 0; i < n; ++i)
    tree_[static_cast<size_t>(leaves_ + i)] = csrEntry(system.omega2(), i, i);
  for (Index k = leaves_ - 1; k >= 1; --k)
    tree_[static_cast<size_t>(k)] =
        std::max(tree_[2 * static_cast<size_t>(k)], tree_[2 * static_cast<size_t>(k) + 1]);
}

void CriticalPeriodTracker::update(const SystemMatrices& system, std::span<const Index> rows) {
  for (Index i : rows) {
    size_t k = static_cast<size_t>(leaves_ + i);
    tree_[k] = csrEntry(system.omega2(), i, i);
    for (k /= 2; k >= 1; k /= 2) {
      const double m = std::max(tree_[2 * k], tree_[2 * k + 1]);
      if (m == tree_[k]) break;  // nothing above changes either
      tree_[k] = m;
    }
  }
}

Index CriticalPeriodTracker::limitingVertex() const {
  if (tree_.size() < 2) return -1;
  size_t k = 1;
  while (k < static_cast<size_t>(leaves_)) k = tree_[2 * k] == tree_[k] ? 2 * k : 2 * k + 1;
  return static_cast<Index>(k) - leaves_;
}

double CriticalPeriodTracker::period() const {
  // The same expression as criticalPeriod() in physics/matrices.cpp.
  const double largest = maxDiagonal();
  if (!(largest > 0.0)) return std::numeric_limits<double>::infinity();
  return std::sqrt(6.0 / largest);
}

LocalMatrices::LocalMatrices(const Model& model, std::optional<double> transformationPeriod)
    : system_(model) {
  if (transformationPeriod) transformation_.emplace(system_, *transformationPeriod);
  critical_ = CriticalPeriodTracker(system_);
}

void LocalMatrices::update(const Model& model, std::span<const Index> rows) {
  system_.updateVertices(model, rows);
  if (transformation_) transformation_->updateVertices(system_, rows);
  critical_.update(system_, rows);
}

void LocalMatrices::rebuild(const Model& model) {
  system_ = SystemMatrices(model);
  if (transformation_) {
    const double period = transformation_->period();
    transformation_.emplace(system_, period);
  }
  critical_ = CriticalPeriodTracker(system_);
}

double MatrixVerification::maxAbs() const {
  return std::max({system, transformation, criticalPeriod});
}

namespace {

double vectorDifference(const VectorX& a, const VectorX& b) {
  return a.size() ? (a - b).cwiseAbs().maxCoeff() : 0.0;
}

}  // namespace

MatrixVerification verifyAgainstRebuild(const Model& model, const SystemMatrices& system,
                                        const TransformationMatrices* transformation,
                                        const CriticalPeriodTracker* critical) {
  MatrixVerification result;
  const SystemMatrices full(model);
  result.system =
      std::max({maxAbsDifference(system.stiffness(), full.stiffness()),
                maxAbsDifference(system.omega2(), full.omega2()),
                vectorDifference(system.inverseMass(), full.inverseMass()),
                vectorDifference(system.dampingCoefficient(), full.dampingCoefficient())});
  if (transformation) {
    const TransformationMatrices t(full, transformation->period());
    result.transformation = std::max({maxAbsDifference(transformation->omega4(), t.omega4()),
                                      maxAbsDifference(transformation->h(), t.h()),
                                      maxAbsDifference(transformation->hPrime(), t.hPrime()),
                                      maxAbsDifference(transformation->hSecond(), t.hSecond()),
                                      maxAbsDifference(transformation->x(), t.x()),
                                      maxAbsDifference(transformation->xPrime(), t.xPrime())});
  }
  if (critical) {
    const double tracked = critical->period(), exact = zsculpt::criticalPeriod(full);
    result.criticalPeriod = tracked == exact ? 0.0 : std::abs(tracked - exact);
    if (std::isnan(result.criticalPeriod))
      result.criticalPeriod = std::numeric_limits<double>::infinity();
  }
  return result;
}

}  // namespace zsculpt::editing
