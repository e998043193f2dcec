#include "zsculpt/physics/properties.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>
#include <utility>

#include "zsculpt/core/errors.h"
#include "zsculpt/physics/forces.h"

namespace zsculpt {

std::string_view propertyUnit(Property property) {
  switch (property) {
    case Property::Mass:
      return "kg";
    case Property::Damping:
      return "kg/s";
    case Property::Stiffness:
      return "N/m";
    case Property::AngularStiffness:
      return "N m/rad\u00b2";
    case Property::Rigidity:
      return "";
    case Property::RestLength:
      return "m";
    case Property::RestAngle:
      return "rad";
  }
  return "";
}

std::string propertyLabel(Property property) {
  // For people (legends, panels): words, not the identifier ("rest length", not
  // "rest_length").
  std::string label(propertyName(property));
  std::replace(label.begin(), label.end(), '_', ' ');
  if (const std::string_view unit = propertyUnit(property); !unit.empty())
    label.append(" (").append(unit).append(")");
  return label;
}

std::string_view propertyName(Property property) {
  switch (property) {
    case Property::Mass:
      return "mass";
    case Property::Damping:
      return "damping";
    case Property::Stiffness:
      return "stiffness";
    case Property::AngularStiffness:
      return "angular_stiffness";
    case Property::Rigidity:
      return "rigidity";
    case Property::RestLength:
      return "rest_length";
    case Property::RestAngle:
      return "rest_angle";
  }
  return "?";
}

Property propertyFromName(std::string_view name) {
  for (Property p : kAllProperties)
    if (propertyName(p) == name) return p;
  std::string valid;
  for (Property p : kAllProperties) {
    if (!valid.empty()) valid += ", ";
    valid += propertyName(p);
  }
  throw InvalidInputError("unknown property '" + std::string(name) + "' (valid: " + valid + ")");
}

PropertyDomain propertyDomain(Property property) {
  switch (property) {
    case Property::RestLength:
      return PropertyDomain::Edge;
    case Property::RestAngle:
      return PropertyDomain::Angle;
    default:
      return PropertyDomain::Vertex;
  }
}

PropertyRange propertyRange(Property property) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  switch (property) {
    case Property::Mass:
      return {0.0, inf, true};
    case Property::Rigidity:
      return {0.0, 1.0, false};
    case Property::RestAngle:
      return {0.0, std::numbers::pi, false};
    default:
      return {0.0, inf, false};
  }
}

void checkPropertyValue(Property property, double value, std::string_view what) {
  const PropertyRange range = propertyRange(property);
  const bool below = range.minExclusive ? !(value > range.min) : !(value >= range.min);
  if (!std::isfinite(value) || below || value > range.max) {
    std::ostringstream msg;
    msg << what << ": " << propertyName(property) << " " << value << " is outside "
        << (range.minExclusive ? "(" : "[") << range.min << ", " << range.max
        << (std::isinf(range.max) ? ")" : "]");
    throw InvalidInputError(msg.str());
  }
}

AngleTable buildAngleTable(const Mesh& mesh) {
  AngleTable table;
  const Index n = mesh.numVertices();
  table.vertexOffsets.assign(1, 0);
  std::vector<std::pair<Index, Index>> edgeAnglePairs;
  for (Index v = 0; v < n; ++v) {
    const auto neighbors = mesh.vertexNeighbors(v);
    const auto edges = mesh.vertexEdges(v);
    for (size_t p = 0; p < neighbors.size(); ++p)
      for (size_t q = p + 1; q < neighbors.size(); ++q) {
        const Index angle = table.size();
        const Index a = neighbors[p], b = neighbors[q];
        table.angles.push_back({v, std::min(a, b), std::max(a, b)});
        edgeAnglePairs.emplace_back(edges[p], angle);
        edgeAnglePairs.emplace_back(edges[q], angle);
      }
    table.vertexOffsets.push_back(table.size());
  }
  table.edgeAngles = buildCsr(mesh.numEdges(), edgeAnglePairs);
  return table;
}

PhysicalProperties PhysicalProperties::uniform(const Mesh& mesh, const AngleTable& angles,
                                               const UniformProperties& values) {
  const Index n = mesh.numVertices();
  PhysicalProperties p;
  p.mass = VectorX::Constant(n, values.mass);
  p.damping = VectorX::Constant(n, values.damping);
  p.stiffness = VectorX::Constant(n, values.stiffness);
  p.angularStiffness = VectorX::Constant(n, values.angularStiffness);
  p.rigidity = VectorX::Constant(n, values.rigidity);
  p.restLength.resize(mesh.numEdges());
  const Points& x = mesh.positions();
  for (Index e = 0; e < mesh.numEdges(); ++e) {
    const auto [a, b] = mesh.edge(e);
    p.restLength[e] = values.restLengthScale * (x.row(a) - x.row(b)).norm();
  }
  p.restAngle.resize(angles.size());
  for (Index k = 0; k < angles.size(); ++k) {
    const auto [c, a, b] = angles.angles[k];
    p.restAngle[k] = angleAt(x.row(c), x.row(a), x.row(b));
  }
  p.stiffnessCap = values.stiffnessCap;
  p.gravity = values.gravity;
  return p;
}

void PhysicalProperties::validate(const Mesh& mesh, const AngleTable& angles) const {
  const Index n = mesh.numVertices();
  for (Property property : kAllProperties) {
    const VectorX& v = values(property);
    const Index expected = propertyDomain(property) == PropertyDomain::Vertex ? n
                           : propertyDomain(property) == PropertyDomain::Edge ? mesh.numEdges()
                                                                              : angles.size();
    if (v.size() != expected)
      throw InvalidInputError(std::string(propertyName(property)) + " has " +
                              std::to_string(v.size()) + " values, expected " +
                              std::to_string(expected));
    const char* kind = propertyDomain(property) == PropertyDomain::Vertex ? "vertex "
                       : propertyDomain(property) == PropertyDomain::Edge ? "edge "
                                                                          : "angle ";
    for (Index i = 0; i < v.size(); ++i) {
      const PropertyRange r = propertyRange(property);
      const double x = v[i];
      if (!std::isfinite(x) || (r.minExclusive ? x <= r.min : x < r.min) || x > r.max)
        checkPropertyValue(property, x, kind + std::to_string(i));
    }
  }
  if (!(stiffnessCap > 0.0))
    throw InvalidInputError("stiffness cap " + std::to_string(stiffnessCap) + " must be positive");
  if (!gravity.allFinite()) throw InvalidInputError("gravity is not finite");
}

const VectorX& PhysicalProperties::values(Property property) const {
  switch (property) {
    case Property::Mass:
      return mass;
    case Property::Damping:
      return damping;
    case Property::Stiffness:
      return stiffness;
    case Property::AngularStiffness:
      return angularStiffness;
    case Property::Rigidity:
      return rigidity;
    case Property::RestLength:
      return restLength;
    case Property::RestAngle:
      return restAngle;
  }
  return mass;
}

VectorX& PhysicalProperties::values(Property property) {
  return const_cast<VectorX&>(std::as_const(*this).values(property));
}

const VectorX& PhysicalProperties::vertexValues(Property property) const {
  ZSCULPT_ASSERT(propertyDomain(property) == PropertyDomain::Vertex, "not a per-vertex property");
  return values(property);
}

VectorX& PhysicalProperties::vertexValues(Property property) {
  ZSCULPT_ASSERT(propertyDomain(property) == PropertyDomain::Vertex, "not a per-vertex property");
  return values(property);
}

Model Model::fromMesh(Mesh mesh, const UniformProperties& values) {
  Model model;
  model.mesh = std::move(mesh);
  model.angles = buildAngleTable(model.mesh);
  model.properties = PhysicalProperties::uniform(model.mesh, model.angles, values);
  model.properties.validate(model.mesh, model.angles);
  return model;
}

}  // namespace zsculpt
