#include "zsculpt/editing/editor.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "zsculpt/core/errors.h"
#include "zsculpt/core/overloaded.h"
#include "zsculpt/editing/local_update.h"
#include "zsculpt/physics/forces.h"

namespace zsculpt::editing {

namespace {

void describeBrush(std::ostringstream& out, const Brush& b) {
  out << propertyName(b.property) << ' ' << brushModeName(b.mode);
  if (b.mode != BrushMode::Smooth) out << ' ' << b.value;
  out << ", strength " << b.strength;
}

bool inRange(Property property, double value) {
  const PropertyRange r = propertyRange(property);
  if (!std::isfinite(value) || value > r.max) return false;
  return r.minExclusive ? value > r.min : value >= r.min;
}

const char* elementKind(Property property) {
  switch (propertyDomain(property)) {
    case PropertyDomain::Vertex:
      return "vertex ";
    case PropertyDomain::Edge:
      return "edge ";
    case PropertyDomain::Angle:
      return "angle ";
  }
  return "";
}

}  // namespace

std::string describe(const EditCommand& command) {
  std::ostringstream out;
  std::visit(Overloaded{
                 [&](const Dab& d) {
                   out << "dab ";
                   describeBrush(out, d.brush);
                   switch (d.centre.kind) {
                     case BrushCentre::Kind::Vertex:
                       out << " at vertex " << d.centre.vertex;
                       break;
                     case BrushCentre::Kind::FacePoint:
                       out << " at face " << d.centre.face << " point ("
                           << d.centre.point.transpose() << ")";
                       break;
                     case BrushCentre::Kind::Point:
                       out << " at point (" << d.centre.point.transpose() << ")";
                       break;
                   }
                   out << ", radius " << d.brush.radius << ", " << falloffName(d.brush.falloff)
                       << " falloff, " << distanceKindName(d.brush.distance) << " distance";
                 },
                 [&](const GlobalEdit& g) {
                   out << "global ";
                   describeBrush(out, g.brush);
                 },
                 [&](const Relax&) { out << "relax"; },
                 [&](const ScaleRest& s) { out << "scale rest lengths by " << s.factor; },
                 [&](const Undo&) { out << "undo"; },
                 [&](const Redo&) { out << "redo"; },
             },
             command);
  return out.str();
}

Editor::Editor(const Mesh& mesh, const AngleTable& angles, const EditorOptions& options)
    : vertices_(mesh.numVertices()),
      edges_(mesh.numEdges()),
      angles_(angles.size()),
      options_(options),
      region_(mesh),
      edgeStamp_(static_cast<size_t>(mesh.numEdges()), 0u) {}

void Editor::checkTarget(const EditTarget& target, const State& state) const {
  if (target.mesh.numVertices() != vertices_ || target.mesh.numEdges() != edges_ ||
      target.angles.size() != angles_)
    throw InvalidInputError("editor: the model is not the one the editor was made for");
  if (state.position.rows() != vertices_ || state.velocity.rows() != vertices_)
    throw InvalidInputError("editor: the state has " + std::to_string(state.position.rows()) +
                            " vertices, the model " + std::to_string(vertices_));
}

void Editor::clearHistory() {
  while (!undo_.empty()) {
    recycle(std::move(undo_.back()));
    undo_.pop_back();
  }
  while (!redo_.empty()) {
    recycle(std::move(redo_.back()));
    redo_.pop_back();
  }
}

Editor::Record Editor::takeRecord() {
  if (spare_.empty()) return {};
  Record r = std::move(spare_.back());
  spare_.pop_back();
  return r;
}

void Editor::recycle(Record&& record) {
  for (Change& c : record.changes) {
    c.indices.clear();
    c.before.clear();
    c.after.clear();
  }
  record.wholeModel = false;
  spare_.push_back(std::move(record));
}

double Editor::neighbourMean(const EditTarget& target, Property property, Index element) const {
  const VectorX& values = target.properties.values(property);
  const Mesh& mesh = target.mesh;
  double sum = 0.0;
  Index count = 0;
  switch (propertyDomain(property)) {
    case PropertyDomain::Vertex:
      for (Index u : mesh.vertexNeighbors(element)) sum += values[u], ++count;
      break;
    case PropertyDomain::Edge:
      for (Index end : mesh.edge(element))
        for (Index e : mesh.vertexEdges(end))
          if (e != element) sum += values[e], ++count;
      break;
    case PropertyDomain::Angle: {
      const auto& table = target.angles;
      const auto [c, a, b] = table.angles[static_cast<size_t>(element)];
      for (Index k = table.vertexOffsets[static_cast<size_t>(c)];
           k < table.vertexOffsets[static_cast<size_t>(c) + 1]; ++k) {
        if (k == element) continue;
        const auto& other = table.angles[static_cast<size_t>(k)];
        if (other[1] == a || other[1] == b || other[2] == a || other[2] == b)
          sum += values[k], ++count;
      }
      break;
    }
  }
  return count ? sum / static_cast<double>(count) : values[element];
}

void Editor::brushValues(const EditTarget& target, const Brush& brush, bool global,
                         Change& change) {
  change.property = brush.property;
  const VectorX& values = target.properties.values(brush.property);
  auto consider = [&](Index element, double weight) {
    const double old = values[element];
    double goal = old;
    switch (brush.mode) {
      case BrushMode::Set:
        goal = brush.value;
        break;
      case BrushMode::Add:
        goal = old + brush.value;
        break;
      case BrushMode::Multiply:
        goal = old * brush.value;
        break;
      case BrushMode::Smooth:
        goal = neighbourMean(target, brush.property, element);
        break;
    }
    // lerp is exact at both ends: full strength and weight give exactly the target.
    const double next = std::lerp(old, goal, brush.strength * weight);
    if (next == old) return;
    if (!inRange(brush.property, next))
      checkPropertyValue(brush.property, next,
                         "brush: " + std::string(elementKind(brush.property)) +
                             std::to_string(element) + " would get a value out of range");
    change.indices.push_back(element);
    change.before.push_back(old);
    change.after.push_back(next);
  };
  const Index count = static_cast<Index>(values.size());
  if (global) {
    for (Index k = 0; k < count; ++k) consider(k, 1.0);
    return;
  }
  const Mesh& mesh = target.mesh;
  const auto inside = region_.vertices();
  const auto weight = region_.weights();
  switch (propertyDomain(brush.property)) {
    case PropertyDomain::Vertex:
      for (size_t q = 0; q < inside.size(); ++q) consider(inside[q], weight[q]);
      break;
    case PropertyDomain::Edge:
      // An edge takes the mean of its ends' weights (an end outside the brush weighs 0).
      if (++edgeGeneration_ == 0) {
        std::fill(edgeStamp_.begin(), edgeStamp_.end(), 0u);
        edgeGeneration_ = 1;
      }
      for (Index v : inside)
        for (Index e : mesh.vertexEdges(v)) {
          if (edgeStamp_[static_cast<size_t>(e)] == edgeGeneration_) continue;
          edgeStamp_[static_cast<size_t>(e)] = edgeGeneration_;
          const auto [i, j] = mesh.edge(e);
          consider(e, 0.5 * (region_.weightOf(i) + region_.weightOf(j)));
        }
      break;
    case PropertyDomain::Angle:
      // An angle takes its centre's weight.
      for (size_t q = 0; q < inside.size(); ++q) {
        const size_t c = static_cast<size_t>(inside[q]);
        for (Index k = target.angles.vertexOffsets[c]; k < target.angles.vertexOffsets[c + 1]; ++k)
          consider(k, weight[q]);
      }
      break;
  }
}

void Editor::collectEnergyTerms(const EditTarget& target, const Change& change) {
  edgeTerms_.clear();
  angleTerms_.clear();
  vertexTerms_.clear();
  const Mesh& mesh = target.mesh;
  switch (change.property) {
    case Property::Stiffness:
      // kappa_ij depends on both ends: every edge at a changed vertex, once.
      if (++edgeGeneration_ == 0) {
        std::fill(edgeStamp_.begin(), edgeStamp_.end(), 0u);
        edgeGeneration_ = 1;
      }
      for (Index v : change.indices)
        for (Index e : mesh.vertexEdges(v))
          if (edgeStamp_[static_cast<size_t>(e)] != edgeGeneration_) {
            edgeStamp_[static_cast<size_t>(e)] = edgeGeneration_;
            edgeTerms_.push_back(e);
          }
      break;
    case Property::RestLength:
      edgeTerms_.assign(change.indices.begin(), change.indices.end());
      break;
    case Property::AngularStiffness:
      for (Index c : change.indices)
        for (Index k = target.angles.vertexOffsets[static_cast<size_t>(c)];
             k < target.angles.vertexOffsets[static_cast<size_t>(c) + 1]; ++k)
          angleTerms_.push_back(k);
      break;
    case Property::RestAngle:
      angleTerms_.assign(change.indices.begin(), change.indices.end());
      break;
    case Property::Mass:
      vertexTerms_.assign(change.indices.begin(), change.indices.end());
      break;
    case Property::Damping:
    case Property::Rigidity:
      break;  // neither stores energy
  }
}

EnergyChange Editor::termEnergy(const EditTarget& target, const State& state,
                                Property property) const {
  // The same expressions as potentialEnergy() and measureKinematics(), over the terms only.
  const PhysicalProperties& p = target.properties;
  const Points& x = state.position;
  EnergyChange energy;
  for (Index e : edgeTerms_) {
    const auto [i, j] = target.mesh.edge(e);
    const double kappa = edgeStiffness(p.stiffness[i], p.stiffness[j]);
    energy.potential += radialSpringEnergy((x.row(i) - x.row(j)).norm(), kappa, p.restLength[e]);
  }
  for (Index k : angleTerms_) {
    const auto [c, a, b] = target.angles.angles[static_cast<size_t>(k)];
    energy.potential += angleSpringEnergy(angleAt(x.row(c), x.row(a), x.row(b)), p.restAngle[k],
                                          p.angularStiffness[c]);
  }
  if (property == Property::Mass)
    for (Index i : vertexTerms_) {
      energy.potential -= p.mass[i] * p.gravity.dot(x.row(i).transpose());
      energy.kinetic += 0.5 * p.mass[i] * state.velocity.row(i).squaredNorm();
    }
  return energy;
}

EditResult Editor::write(EditTarget target, const State& state, const Record& record,
                         bool forward) {
  rows_.clear();
  touched_.clear();
  EditResult result;
  result.wholeModel = record.wholeModel;
  const Mesh& mesh = target.mesh;
  bool allRows = false;
  for (size_t q = 0; q < record.changes.size(); ++q) {
    const Change& change = record.changes[forward ? q : record.changes.size() - 1 - q];
    if (change.indices.empty()) continue;
    collectEnergyTerms(target, change);
    const EnergyChange before = termEnergy(target, state, change.property);
    VectorX& values = target.properties.values(change.property);
    const std::vector<double>& source = forward ? change.after : change.before;
    for (size_t k = 0; k < change.indices.size(); ++k) values[change.indices[k]] = source[k];
    const EnergyChange after = termEnergy(target, state, change.property);
    result.energy.potential += after.potential - before.potential;
    result.energy.kinetic += after.kinetic - before.kinetic;
    result.entriesChanged += static_cast<Index>(change.indices.size());

    // Locality (local_update.h): which rows of K, Omega^2, M^-1, G depend on the change.
    if (record.wholeModel && propertyChangesMatrices(change.property)) {
      allRows = true;
    } else if (!allRows) {
      appendAffectedRows(mesh, change.property, change.indices, rows_);
    }
    switch (propertyDomain(change.property)) {
      case PropertyDomain::Vertex:
        touched_.insert(touched_.end(), change.indices.begin(), change.indices.end());
        break;
      case PropertyDomain::Edge:
        for (Index e : change.indices) {
          touched_.push_back(mesh.edge(e)[0]);
          touched_.push_back(mesh.edge(e)[1]);
        }
        break;
      case PropertyDomain::Angle:
        for (Index k : change.indices)
          touched_.push_back(target.angles.angles[static_cast<size_t>(k)][0]);
        break;
    }
  }
  if (allRows) {
    rows_.resize(static_cast<size_t>(vertices_));
    for (Index v = 0; v < vertices_; ++v) rows_[static_cast<size_t>(v)] = v;
  } else {
    std::sort(rows_.begin(), rows_.end());
    rows_.erase(std::unique(rows_.begin(), rows_.end()), rows_.end());
  }
  std::sort(touched_.begin(), touched_.end());
  touched_.erase(std::unique(touched_.begin(), touched_.end()), touched_.end());
  result.changed = result.entriesChanged > 0;
  result.matrixRows = rows_;
  result.vertices = touched_;
  return result;
}

EditResult Editor::writeAccepted(EditTarget target, const State& state, const Record& record,
                                 bool forward, const Acceptance& accept) {
  EditResult result = write(target, state, record, forward);
  if (!accept || !result.changed) return result;
  try {
    accept(result);
  } catch (...) {
    write(target, state, record, !forward);  // the values as they were
    throw;
  }
  return result;
}

EditResult Editor::commit(EditTarget target, const State& state, Record&& record,
                          const Acceptance& accept) {
  bool any = false;
  for (const Change& c : record.changes) any = any || !c.indices.empty();
  if (!any) {
    recycle(std::move(record));
    rows_.clear();
    touched_.clear();
    return EditResult{};
  }
  EditResult result;
  try {
    result = writeAccepted(target, state, record, true, accept);
  } catch (...) {
    recycle(std::move(record));
    throw;
  }
  while (!redo_.empty()) {
    recycle(std::move(redo_.back()));
    redo_.pop_back();
  }
  if (options_.historyLimit == 0) {
    recycle(std::move(record));
    return result;
  }
  undo_.push_back(std::move(record));
  while (undo_.size() > options_.historyLimit) {
    recycle(std::move(undo_.front()));
    undo_.pop_front();
  }
  return result;
}

EditResult Editor::apply(EditTarget target, const State& state, const EditCommand& command,
                         const Acceptance& accept) {
  checkTarget(target, state);
  if (std::holds_alternative<Undo>(command)) return undo(target, state, accept);
  if (std::holds_alternative<Redo>(command)) return redo(target, state, accept);

  Record record = takeRecord();
  auto change = [&](size_t k) -> Change& {
    if (record.changes.size() <= k) record.changes.resize(k + 1);
    return record.changes[k];
  };
  try {
    if (const Dab* dab = std::get_if<Dab>(&command)) {
      dab->brush.validate(true);
      region_.compute(target.mesh, state.position, dab->centre, dab->brush.radius,
                      dab->brush.falloff, dab->brush.distance);
      record.changes.resize(1);
      brushValues(target, dab->brush, false, change(0));
    } else if (const GlobalEdit* global = std::get_if<GlobalEdit>(&command)) {
      global->brush.validate(false);
      record.changes.resize(1);
      brushValues(target, global->brush, true, change(0));
      record.wholeModel = true;
    } else if (std::holds_alternative<Relax>(command)) {
      // The current shape becomes the rest shape, with the same expressions as
      // PhysicalProperties::uniform, so the relaxed state is an equilibrium.
      const Points& x = state.position;
      if (!x.allFinite()) throw InvalidInputError("relax: the state is not finite");
      record.changes.resize(2);
      Change& lengths = change(0);
      lengths.property = Property::RestLength;
      const VectorX& restLength = target.properties.restLength;
      for (Index e = 0; e < edges_; ++e) {
        const auto [a, b] = target.mesh.edge(e);
        const double next = (x.row(a) - x.row(b)).norm();
        if (next == restLength[e]) continue;
        lengths.indices.push_back(e);
        lengths.before.push_back(restLength[e]);
        lengths.after.push_back(next);
      }
      Change& angles = change(1);
      angles.property = Property::RestAngle;
      const VectorX& restAngle = target.properties.restAngle;
      for (Index k = 0; k < angles_; ++k) {
        const auto [c, a, b] = target.angles.angles[static_cast<size_t>(k)];
        const double next = angleAt(x.row(c), x.row(a), x.row(b));
        if (next == restAngle[k]) continue;
        angles.indices.push_back(k);
        angles.before.push_back(restAngle[k]);
        angles.after.push_back(next);
      }
      record.wholeModel = true;
    } else if (const ScaleRest* scale = std::get_if<ScaleRest>(&command)) {
      if (!(scale->factor > 0.0 && std::isfinite(scale->factor)))
        throw InvalidInputError("scale rest: factor " + formatNumber(scale->factor) +
                                " must be positive and finite");
      record.changes.resize(1);
      Change& lengths = change(0);
      lengths.property = Property::RestLength;
      const VectorX& restLength = target.properties.restLength;
      for (Index e = 0; e < edges_; ++e) {
        const double next = restLength[e] * scale->factor;
        if (next == restLength[e]) continue;
        if (!inRange(Property::RestLength, next))
          checkPropertyValue(
              Property::RestLength, next,
              "scale rest: edge " + std::to_string(e) + " would get a value out of range");
        lengths.indices.push_back(e);
        lengths.before.push_back(restLength[e]);
        lengths.after.push_back(next);
      }
      record.wholeModel = true;
    }
  } catch (...) {
    recycle(std::move(record));  // nothing was written yet
    throw;
  }
  return commit(target, state, std::move(record), accept);
}

EditResult Editor::undo(EditTarget target, const State& state, const Acceptance& accept) {
  checkTarget(target, state);
  if (undo_.empty()) {
    rows_.clear();
    touched_.clear();
    return EditResult{};
  }
  // The record stays on its stack until the undo is accepted.
  EditResult result = writeAccepted(target, state, undo_.back(), false, accept);
  redo_.push_back(std::move(undo_.back()));
  undo_.pop_back();
  return result;
}

EditResult Editor::redo(EditTarget target, const State& state, const Acceptance& accept) {
  checkTarget(target, state);
  if (redo_.empty()) {
    rows_.clear();
    touched_.clear();
    return EditResult{};
  }
  EditResult result = writeAccepted(target, state, redo_.back(), true, accept);
  undo_.push_back(std::move(redo_.back()));
  redo_.pop_back();
  return result;
}

}  // namespace zsculpt::editing
