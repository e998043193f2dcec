#pragma once
// Brushes for dynamic editing (paper section 3, "Dynamic Editing", and section 6): where a
// dab lands and how strongly each vertex is affected.
//
// A brush has a centre (a vertex, a point on a face, or a free point), a radius in scene
// units, a falloff curve and a distance kind:
//
//   surface    the distance along the surface (fast marching: Dijkstra over the edges, and
//              across each face from two vertices already reached, by unfolding the face
//              to find where the front came from; stopped at the radius), on the positions
//              the caller passes (the shape the user sees). Exact on a flat region, so a dab
//              there is the round footprint the brush circle shows (edges alone measured
//              |di| + |dj| on a grid: a diamond). Costs O(k log k) for a dab covering k
//              vertices: independent of the mesh size.
//   euclidean  straight-line distance: every vertex inside the ball, also across gaps
//              the surface would walk around. Costs one O(N) scan of the positions.
//
// Falloff: the weight of a vertex at distance d < radius r, with p = 1 - d / r (Blender's
// presets, BKE_brush_curve_strength): 0 at d >= r.
//
//   smooth    3 p^2 - 2 p^3      (smoothstep; 1 at the centre, flat at both ends)
//   sphere    sqrt(2 p - p^2)    (= sqrt(1 - (d/r)^2): a hemisphere's profile)
//   linear    p
//   sharp     p^2
//   constant  1
//
// BrushRegion computes the weights into buffers it keeps: a dab allocates nothing once the
// buffers have grown to the largest footprint seen.

#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/mesh/mesh.h"
#include "zsculpt/physics/properties.h"

namespace zsculpt::editing {

/// How the brush's value combines with the old value v (before the strength blend):
/// set -> value, add -> v + value, multiply -> v * value, smooth -> the mean of the
/// element's neighbours (vertex: its one-ring; edge: the edges sharing an end; angle: the
/// angles at the same centre sharing an arm).
enum class BrushMode { Set, Add, Multiply, Smooth };
enum class Falloff { Smooth, Sphere, Linear, Sharp, Constant };
enum class DistanceKind { Surface, Euclidean };

std::string_view brushModeName(BrushMode mode);
std::string_view falloffName(Falloff falloff);
std::string_view distanceKindName(DistanceKind kind);
/// Throw InvalidInputError "<name>: unknown brush mode (valid: set, add, ...)".
BrushMode brushModeFromName(std::string_view name);
Falloff falloffFromName(std::string_view name);
DistanceKind distanceKindFromName(std::string_view name);

/// A number for a message: shortest round-trip form ("0.5", "-1e-09", "nan").
std::string formatNumber(double value);

/// Weight for t = d / r: the curve above for 0 <= t < 1, 0 for t >= 1.
double falloffWeight(Falloff falloff, double t);

/// What a dab (or a global edit) does. The new value of an element of weight w is
/// lerp(old, target, strength * w), target as in BrushMode: strength 1 at the centre of a
/// set brush gives exactly `value`.
struct Brush {
  Property property = Property::Stiffness;
  BrushMode mode = BrushMode::Set;
  double value = 0.0;     // set: in the property's range; multiply: >= 0; add: finite
  double strength = 1.0;  // [0, 1]
  double radius = 1.0;    // scene units, > 0 (unused by global edits)
  Falloff falloff = Falloff::Smooth;
  DistanceKind distance = DistanceKind::Surface;

  /// Throws InvalidInputError "brush: <reason>" for a value, strength or radius out of
  /// range (`needRadius` false for global edits).
  void validate(bool needRadius = true) const;
};

/// Where a dab lands.
struct BrushCentre {
  enum class Kind { Vertex, FacePoint, Point };
  Kind kind = Kind::Vertex;
  Index vertex = 0;           // Vertex
  Index face = -1;            // FacePoint: the face the point lies on (a ray pick's result)
  Vec3 point = Vec3::Zero();  // FacePoint, Point

  /// Distance 0 at the vertex.
  static BrushCentre atVertex(Index v) { return {Kind::Vertex, v, -1, Vec3::Zero()}; }
  /// A point on face f: surface distances start at the face's corners, each at its
  /// straight-line distance from the point. O(face size).
  static BrushCentre onFace(Index f, const Vec3& p) { return {Kind::FacePoint, -1, f, p}; }
  /// A point anywhere: surface distances start at the nearest vertex (found by an O(N)
  /// scan), at its distance from the point. For scene files; interactive tools pick a face.
  static BrushCentre atPoint(const Vec3& p) { return {Kind::Point, -1, -1, p}; }
};

/// The vertices a dab reaches and their weights, with reusable buffers.
class BrushRegion {
 public:
  BrushRegion() = default;
  /// Buffers sized for `mesh` (O(N) once).
  explicit BrushRegion(const Mesh& mesh);

  /// The vertices at distance < radius from `centre` on `position` (N x 3) and their
  /// falloff weights (> 0). Throws InvalidInputError for a centre out of range or not
  /// finite, or a radius that is not positive and finite.
  void compute(const Mesh& mesh, const Points& position, const BrushCentre& centre, double radius,
               Falloff falloff, DistanceKind distance);

  /// Inside vertices, in the order they were reached (surface: increasing distance).
  [[nodiscard]] std::span<const Index> vertices() const { return vertices_; }
  [[nodiscard]] std::span<const double> weights() const { return weights_; }
  [[nodiscard]] std::span<const double> distances() const { return distances_; }
  /// The weight of any vertex: 0 outside the region. O(1).
  [[nodiscard]] double weightOf(Index v) const {
    return stamp_[static_cast<size_t>(v)] == generation_ ? weightByVertex_[static_cast<size_t>(v)]
                                                         : 0.0;
  }
  [[nodiscard]] Index size() const { return static_cast<Index>(vertices_.size()); }

 private:
  void surface(const Mesh& mesh, const Points& position, const BrushCentre& centre, double radius);
  void euclidean(const Mesh& mesh, const Points& position, const BrushCentre& centre,
                 double radius);
  void reach(Index v, double d);
  void nextGeneration();

  std::vector<Index> vertices_;
  std::vector<double> weights_, distances_;
  // Per vertex, valid where stamp_ == generation_ (so nothing is reset per dab).
  std::vector<double> distanceByVertex_, weightByVertex_;
  std::vector<unsigned> stamp_, settled_;  // settled_: the distance is final (== generation_)
  unsigned generation_ = 0;
  std::vector<std::pair<double, Index>> heap_;
};

}  // namespace zsculpt::editing
