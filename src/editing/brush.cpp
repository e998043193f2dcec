#include "zsculpt/editing/brush.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <iomanip>
#include <limits>
#include <sstream>
#include <string>

#include "zsculpt/core/errors.h"

namespace zsculpt::editing {

namespace {

template <class Enum, size_t N>
Enum fromName(std::string_view name, const Enum (&all)[N], std::string_view (*nameOf)(Enum),
              const char* what) {
  for (Enum e : all)
    if (nameOf(e) == name) return e;
  std::string valid;
  for (Enum e : all) {
    if (!valid.empty()) valid += ", ";
    valid += nameOf(e);
  }
  throw InvalidInputError(std::string(name) + ": unknown " + what + " (valid: " + valid + ")");
}

constexpr BrushMode kModes[] = {BrushMode::Set, BrushMode::Add, BrushMode::Multiply,
                                BrushMode::Smooth};
constexpr Falloff kFalloffs[] = {Falloff::Smooth, Falloff::Sphere, Falloff::Linear, Falloff::Sharp,
                                 Falloff::Constant};
constexpr DistanceKind kDistances[] = {DistanceKind::Surface, DistanceKind::Euclidean};

}  // namespace

std::string_view brushModeName(BrushMode mode) {
  switch (mode) {
    case BrushMode::Set:
      return "set";
    case BrushMode::Add:
      return "add";
    case BrushMode::Multiply:
      return "multiply";
    case BrushMode::Smooth:
      return "smooth";
  }
  return "?";
}

std::string_view falloffName(Falloff falloff) {
  switch (falloff) {
    case Falloff::Smooth:
      return "smooth";
    case Falloff::Sphere:
      return "sphere";
    case Falloff::Linear:
      return "linear";
    case Falloff::Sharp:
      return "sharp";
    case Falloff::Constant:
      return "constant";
  }
  return "?";
}

std::string_view distanceKindName(DistanceKind kind) {
  switch (kind) {
    case DistanceKind::Surface:
      return "surface";
    case DistanceKind::Euclidean:
      return "euclidean";
  }
  return "?";
}

BrushMode brushModeFromName(std::string_view name) {
  return fromName(name, kModes, brushModeName, "brush mode");
}
Falloff falloffFromName(std::string_view name) {
  return fromName(name, kFalloffs, falloffName, "falloff");
}
DistanceKind distanceKindFromName(std::string_view name) {
  return fromName(name, kDistances, distanceKindName, "distance kind");
}

std::string formatNumber(double value) {
  std::ostringstream out;
  out << std::setprecision(17) << value;
  std::string text = out.str();
  // Prefer the shortest form that reads back the same (0.1, not 0.10000000000000001).
  for (int digits = 1; digits < 17; ++digits) {
    std::ostringstream shorter;
    shorter << std::setprecision(digits) << value;
    if (std::strtod(shorter.str().c_str(), nullptr) == value) return shorter.str();
  }
  return text;
}

double falloffWeight(Falloff falloff, double t) {
  if (!(t < 1.0)) return 0.0;  // also NaN
  const double p = 1.0 - std::max(t, 0.0);
  switch (falloff) {
    case Falloff::Smooth:
      return p * p * (3.0 - 2.0 * p);
    case Falloff::Sphere:
      return std::sqrt(p * (2.0 - p));
    case Falloff::Linear:
      return p;
    case Falloff::Sharp:
      return p * p;
    case Falloff::Constant:
      return 1.0;
  }
  return 0.0;
}

void Brush::validate(bool needRadius) const {
  const std::string name(propertyName(property));
  if (mode == BrushMode::Set) {
    checkPropertyValue(property, value, "brush value");
  } else if (mode == BrushMode::Multiply) {
    if (!std::isfinite(value) || value < 0.0)
      throw InvalidInputError("brush value: multiply factor " + formatNumber(value) + " for " +
                              name + " must be finite and >= 0");
  } else if (mode == BrushMode::Add) {
    if (!std::isfinite(value))
      throw InvalidInputError("brush value: add amount for " + name + " must be finite");
  }
  if (!(strength >= 0.0 && strength <= 1.0))
    throw InvalidInputError("brush strength: " + formatNumber(strength) + " is outside [0, 1]");
  if (needRadius && !(radius > 0.0 && std::isfinite(radius)))
    throw InvalidInputError("brush radius: " + formatNumber(radius) +
                            " must be positive and finite");
}

BrushRegion::BrushRegion(const Mesh& mesh) {
  const size_t n = static_cast<size_t>(mesh.numVertices());
  distanceByVertex_.assign(n, 0.0);
  weightByVertex_.assign(n, 0.0);
  stamp_.assign(n, 0u);
  settled_.assign(n, 0u);
  generation_ = 0;
}

void BrushRegion::nextGeneration() {
  if (++generation_ == 0) {  // wrapped: forget every stamp once
    std::fill(stamp_.begin(), stamp_.end(), 0u);
    std::fill(settled_.begin(), settled_.end(), 0u);
    generation_ = 1;
  }
  vertices_.clear();
  weights_.clear();
  distances_.clear();
}

void BrushRegion::reach(Index v, double d) {
  const size_t i = static_cast<size_t>(v);
  if (stamp_[i] != generation_) {
    stamp_[i] = generation_;
    distanceByVertex_[i] = d;
    heap_.emplace_back(d, v);
    std::push_heap(heap_.begin(), heap_.end(), std::greater<>());
  } else if (d < distanceByVertex_[i]) {
    distanceByVertex_[i] = d;
    heap_.emplace_back(d, v);
    std::push_heap(heap_.begin(), heap_.end(), std::greater<>());
  }
}

void BrushRegion::compute(const Mesh& mesh, const Points& position, const BrushCentre& centre,
                          double radius, Falloff falloff, DistanceKind distance) {
  const Index n = mesh.numVertices();
  if (static_cast<Index>(stamp_.size()) != n || position.rows() != n)
    throw InvalidInputError("brush: the region was built for " + std::to_string(stamp_.size()) +
                            " vertices, the mesh has " + std::to_string(n) + " and the state " +
                            std::to_string(position.rows()));
  if (!(radius > 0.0 && std::isfinite(radius)))
    throw InvalidInputError("brush radius: " + formatNumber(radius) +
                            " must be positive and finite");
  switch (centre.kind) {
    case BrushCentre::Kind::Vertex:
      if (centre.vertex < 0 || centre.vertex >= n)
        throw InvalidInputError("brush centre: vertex " + std::to_string(centre.vertex) +
                                " is out of range [0, " + std::to_string(n) + ")");
      break;
    case BrushCentre::Kind::FacePoint:
      if (centre.face < 0 || centre.face >= mesh.numFaces())
        throw InvalidInputError("brush centre: face " + std::to_string(centre.face) +
                                " is out of range [0, " + std::to_string(mesh.numFaces()) + ")");
      [[fallthrough]];
    case BrushCentre::Kind::Point:
      if (!centre.point.allFinite())
        throw InvalidInputError("brush centre: the point is not finite");
      break;
  }
  nextGeneration();
  if (distance == DistanceKind::Surface)
    surface(mesh, position, centre, radius);
  else
    euclidean(mesh, position, centre, radius);
  weights_.resize(vertices_.size());
  for (size_t k = 0; k < vertices_.size(); ++k) {
    const double w = falloffWeight(falloff, distances_[k] / radius);
    weights_[k] = w;
    weightByVertex_[static_cast<size_t>(vertices_[k])] = w;
  }
}

namespace {

// The distance at c of a front that reached a at da and b at db, across the triangle (a, b,
// c) (fast marching's update: Kimmel and Sethian 1998, in the virtual-source form): unfolded
// into the triangle's plane, the front comes from the point s on the far side of ab with
// |s - a| = da and |s - b| = db, and reaches c at |c - s|, when the straight line from s to c
// crosses ab between a and b. Infinity when it does not (the edges then carry the front) or
// the distances are not those of one point source.
double acrossTriangle(const Vec3& a, const Vec3& b, const Vec3& c, double da, double db) {
  const Vec3 ab = b - a, ac = c - a;
  const double l = ab.norm();
  if (!(l > 0.0)) return std::numeric_limits<double>::infinity();
  const Vec3 x = ab / l;
  const double cx = ac.dot(x);
  const double cy = (ac - cx * x).norm();  // c above the line ab
  if (!(cy > 1e-12 * l)) return std::numeric_limits<double>::infinity();
  const double sx = (da * da - db * db + l * l) / (2.0 * l);
  const double h2 = da * da - sx * sx;
  if (h2 < 0.0) return std::numeric_limits<double>::infinity();
  const double sy = -std::sqrt(h2);  // the far side of ab from c
  // Where s -> c crosses the line ab (y = 0).
  const double t = -sy / (cy - sy);
  const double crossing = sx + t * (cx - sx);
  if (crossing < 0.0 || crossing > l) return std::numeric_limits<double>::infinity();
  const double dc = std::hypot(cx - sx, cy - sy);
  // Causality: c is reached after a and b (beyond an obtuse corner it would not be, and the
  // order of settling would break); otherwise the edges carry the front.
  return dc >= std::max(da, db) ? dc : std::numeric_limits<double>::infinity();
}

}  // namespace

void BrushRegion::surface(const Mesh& mesh, const Points& position, const BrushCentre& centre,
                          double radius) {
  // Fast marching bounded by the radius: Dijkstra over the edges, and each face crossed from
  // two of its vertices already settled (acrossTriangle). Only vertices closer than the radius
  // ever enter the heap, so the work is O(k log k) for a footprint of k vertices.
  heap_.clear();
  auto seed = [&](Index v) {
    const double d = (position.row(v).transpose() - centre.point).norm();
    if (d < radius) reach(v, d);
  };
  switch (centre.kind) {
    case BrushCentre::Kind::Vertex:
      reach(centre.vertex, 0.0);
      break;
    case BrushCentre::Kind::FacePoint:
      for (Index v : mesh.face(centre.face)) seed(v);
      break;
    case BrushCentre::Kind::Point: {
      Index nearest = 0;
      double best = std::numeric_limits<double>::infinity();
      for (Index v = 0; v < mesh.numVertices(); ++v) {
        const double d2 = (position.row(v).transpose() - centre.point).squaredNorm();
        if (d2 < best) best = d2, nearest = v;
      }
      seed(nearest);
      break;
    }
  }
  while (!heap_.empty()) {
    std::pop_heap(heap_.begin(), heap_.end(), std::greater<>());
    const auto [d, v] = heap_.back();
    heap_.pop_back();
    if (d > distanceByVertex_[static_cast<size_t>(v)] ||
        settled_[static_cast<size_t>(v)] == generation_)
      continue;  // stale entry
    settled_[static_cast<size_t>(v)] = generation_;
    vertices_.push_back(v);  // settled: increasing distance
    distances_.push_back(d);
    const Vec3 pv = position.row(v).transpose();
    for (Index u : mesh.vertexNeighbors(v)) {
      if (settled_[static_cast<size_t>(u)] == generation_) continue;
      const double nd = d + (position.row(u).transpose() - pv).norm();
      if (nd < radius) reach(u, nd);
    }
    // Across each face of v: from v and another settled corner w to each corner u not
    // settled yet (in a quad, also its far corner: the front crosses the face's diagonal).
    for (Index f : mesh.vertexFaces(v)) {
      const auto corners = mesh.face(f);
      for (Index w : corners) {
        if (w == v || settled_[static_cast<size_t>(w)] != generation_) continue;
        const Vec3 pw = position.row(w).transpose();
        const double dw = distanceByVertex_[static_cast<size_t>(w)];
        for (Index u : corners) {
          if (u == v || u == w || settled_[static_cast<size_t>(u)] == generation_) continue;
          const double nd = acrossTriangle(pv, pw, position.row(u).transpose(), d, dw);
          if (nd < radius) reach(u, nd);
        }
      }
    }
  }
}

void BrushRegion::euclidean(const Mesh& mesh, const Points& position, const BrushCentre& centre,
                            double radius) {
  const Vec3 p = centre.kind == BrushCentre::Kind::Vertex
                     ? Vec3(position.row(centre.vertex).transpose())
                     : centre.point;
  const double r2 = radius * radius;
  for (Index v = 0; v < mesh.numVertices(); ++v) {
    const double d2 = (position.row(v).transpose() - p).squaredNorm();
    if (!(d2 < r2)) continue;
    const double d = std::sqrt(d2);
    if (d < radius) {
      stamp_[static_cast<size_t>(v)] = generation_;
      distanceByVertex_[static_cast<size_t>(v)] = d;
      vertices_.push_back(v);
      distances_.push_back(d);
    }
  }
}

}  // namespace zsculpt::editing
