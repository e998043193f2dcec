#pragma once
// Per-vertex, per-edge and per-angle physical properties (section 4.1 and section 3,
// "Dynamic Editing": every one of them can be painted).
//
//   per vertex: mass mu, damping rho, radial stiffness kappa, angular stiffness
//               kappa_theta, rigidity chi (section 4.3)
//   per edge:   rest length lambda
//   per angle:  rest angle theta_0
//
// How per-vertex stiffness becomes an edge's (equation 1 has a directional kappa_j per
// neighbour and K must be symmetric): a spring is two half-springs in series, each
// owned by one end and of stiffness 2 kappa_i, so kappa_ij = 2 kappa_i kappa_j /
// (kappa_i + kappa_j), the harmonic mean. It equals kappa on a uniform model, is
// symmetric, is zero when either end is painted to zero (a cut), and an edit at a
// vertex changes only that vertex's edges.

#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/mesh/mesh.h"

namespace zsculpt {

enum class Property {
  Mass,
  Damping,
  Stiffness,
  AngularStiffness,
  Rigidity,
  RestLength,
  RestAngle,
};

inline constexpr std::array<Property, 7> kAllProperties = {
    Property::Mass,     Property::Damping,    Property::Stiffness, Property::AngularStiffness,
    Property::Rigidity, Property::RestLength, Property::RestAngle};

/// Scene and command-line name: mass, damping, stiffness, angular_stiffness, rigidity,
/// rest_length, rest_angle.
std::string_view propertyName(Property property);
/// The SI unit of a property's values, e.g. "N/m" ("" for rigidity, which has none).
std::string_view propertyUnit(Property property);
/// The name in words with its unit, for legends and plots: "stiffness (N/m)", "rest length
/// (m)", "rigidity".
std::string propertyLabel(Property property);
/// Throws InvalidInputError naming the unknown property and listing the valid ones.
Property propertyFromName(std::string_view name);
/// Where the property lives: per vertex, per edge (rest_length) or per angle (rest_angle).
enum class PropertyDomain { Vertex, Edge, Angle };
PropertyDomain propertyDomain(Property property);
/// Valid range, inclusive: mass (0, inf) (min is exclusive), damping, stiffness,
/// angular_stiffness [0, inf), rigidity [0, 1], rest_length [0, inf), rest_angle [0, pi].
struct PropertyRange {
  double min;
  double max;
  bool minExclusive;
};
PropertyRange propertyRange(Property property);
/// Throws InvalidInputError "<what>: <property> <value> is outside <range>" when out of range
/// or non-finite.
void checkPropertyValue(Property property, double value, std::string_view what);

/// Angle springs (section 5.2). At every vertex, one spring for every pair of its
/// neighbours: pairs that share a face resist in-plane shear, the others (opposite
/// neighbours across the vertex) resist bending, and the rule needs no manifold, so
/// curves (one pair at an interior vertex), surfaces, solids and non-manifold fins are
/// treated alike. Angles are stored grouped by centre vertex.
struct AngleTable {
  /// (centre, a, b) with a < b, neighbours of centre.
  std::vector<std::array<Index, 3>> angles;
  /// Angles centred at v are [vertexOffsets[v], vertexOffsets[v + 1]).
  std::vector<Index> vertexOffsets{0};
  /// For each edge (i, j): the angles with i or j at the centre that use this edge as
  /// one of their two arms, in CSR form (used by the stiffness bound, see matrices.h).
  CsrIndex edgeAngles;

  [[nodiscard]] Index size() const { return static_cast<Index>(angles.size()); }
};
AngleTable buildAngleTable(const Mesh& mesh);

/// Uniform values a bare mesh starts with (command-line model flags override them).
struct UniformProperties {
  double mass = 0.5;              // kg per vertex (Table 1, dodecahedron)
  double damping = 0.0;           // kg/s
  double stiffness = 5.0;         // N/m (Table 1, dodecahedron)
  double angularStiffness = 0.0;  // N m / rad^2
  double rigidity = 0.0;          // chi in [0, 1]
  double restLengthScale = 1.0;   // rest length = scale * length as loaded
  /// kappa_0 of section 4.3; infinity disables the automatic rigidity.
  double stiffnessCap = std::numeric_limits<double>::infinity();
  Vec3 gravity = Vec3::Zero();
};

struct PhysicalProperties {
  VectorX mass;              // per vertex, > 0
  VectorX damping;           // per vertex, >= 0
  VectorX stiffness;         // per vertex, >= 0
  VectorX angularStiffness;  // per vertex, >= 0
  VectorX rigidity;          // per vertex, in [0, 1] (painted; see effectiveRigidity)
  VectorX restLength;        // per edge, >= 0
  VectorX restAngle;         // per angle, in [0, pi]
  double stiffnessCap = std::numeric_limits<double>::infinity();
  Vec3 gravity = Vec3::Zero();

  /// Uniform properties; rest lengths and rest angles from the mesh's positions.
  static PhysicalProperties uniform(const Mesh& mesh, const AngleTable& angles,
                                    const UniformProperties& values);
  /// Throws InvalidInputError for a size mismatch or a value out of its range.
  void validate(const Mesh& mesh, const AngleTable& angles) const;

  /// Values of a per-vertex property (Mass .. Rigidity).
  [[nodiscard]] const VectorX& vertexValues(Property property) const;
  VectorX& vertexValues(Property property);
  /// The vector holding a property, whatever its domain.
  [[nodiscard]] const VectorX& values(Property property) const;
  VectorX& values(Property property);
};

/// kappa_ij of an edge from its ends' stiffness: the harmonic mean (series half-springs).
inline double edgeStiffness(double kappaI, double kappaJ) {
  const double sum = kappaI + kappaJ;
  if (!(sum > 0.0)) return 0.0;
  const double mean = 2.0 * kappaI * kappaJ / sum;
  // Past 1e154 the product overflows (1e308 and 1e308 gave inf / inf = NaN, a start "whose
  // springs' energy is not finite" at rest): the same mean in a form that does not, taken
  // only there so that every ordinary value keeps its bits.
  if (std::isfinite(mean) || !std::isfinite(kappaI) || !std::isfinite(kappaJ)) return mean;
  return kappaI / (0.5 * kappaI + 0.5 * kappaJ) * kappaJ;  // a ratio of at most 2 first
}

/// Section 4.3: sigma_i = min(kappa_0 / kappa_i, 1); the elastic share of vertex i's force.
inline double elasticShare(double kappa, double cap) {
  return kappa > cap ? cap / kappa : 1.0;
}

/// The stiffness the solver's matrices see at a vertex: kappa_i capped at kappa_0
/// (section 4.3: "the critical sampling time depends on kappa_0").
inline double cappedStiffness(double kappa, double cap) {
  return kappa > cap ? cap : kappa;
}

/// Rigidity actually used at vertex i: the larger of the painted chi_i and the automatic
/// 1 - sigma_i from the stiffness cap (section 4.3).
inline double effectiveRigidity(double paintedChi, double kappa, double cap) {
  const double automatic = 1.0 - elasticShare(kappa, cap);
  return paintedChi > automatic ? paintedChi : automatic;
}

/// A mesh with its angle springs and physical properties: what the solver simulates.
struct Model {
  Mesh mesh;
  AngleTable angles;
  PhysicalProperties properties;

  static Model fromMesh(Mesh mesh, const UniformProperties& values = {});
};

/// The dynamic state: positions r and velocities v (N x 3 each), and the time.
struct State {
  Points position;
  Points velocity;
  double time = 0.0;

  static State atRest(const Mesh& mesh) {
    return State{mesh.positions(), Points::Zero(mesh.numVertices(), 3), 0.0};
  }
};

}  // namespace zsculpt
