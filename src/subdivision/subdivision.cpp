// SubdivisionStencil: L levels of refineLevel composed into one sparse matrix (paper
// section 3, "Smoothing"), so that a frame's refresh is one sparse product.

#include "zsculpt/subdivision/subdivision.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <optional>
#include <string>
#include <utility>

#include "zsculpt/core/errors.h"
#include "zsculpt/subdivision/refinement.h"

namespace zsculpt {

using subdivision_detail::LevelStep;
using subdivision_detail::LevelTopology;

namespace {

constexpr int kMaxLevels = 10;
// Each refined vertex's row has up to ~16 entries per level pair; 2^25 rows keeps the
// stencil within a few gigabytes and every index within Index.
constexpr std::int64_t kMaxRefinedVertices = std::int64_t{1} << 25;

SparseRowMatrix identity(Index n) {
  SparseRowMatrix m(n, n);
  m.resizeNonZeros(n);
  for (Index i = 0; i <= n; ++i) m.outerIndexPtr()[i] = i;
  for (Index i = 0; i < n; ++i) {
    m.innerIndexPtr()[i] = i;
    m.valuePtr()[i] = 1.0;
  }
  return m;
}

void validateMass(const Mesh& control, const VectorX& mass) {
  if (mass.size() != control.numVertices())
    throw InvalidInputError("mass: " + std::to_string(mass.size()) + " values for " +
                            std::to_string(control.numVertices()) + " vertices");
  for (Index i = 0; i < mass.size(); ++i)
    if (!std::isfinite(mass[i]) || mass[i] <= 0.0)
      throw InvalidInputError("mass: vertex " + std::to_string(i) + " has mass " +
                              std::to_string(mass[i]) + ", which is not positive and finite");
}

/// Disjoint sets over 0 .. n-1 (path halving); a union keeps the smaller root, so that each
/// set's root is its first member.
class UnionFind {
 public:
  explicit UnionFind(Index n) : parent_(static_cast<size_t>(n)) {
    for (Index i = 0; i < n; ++i) parent_[static_cast<size_t>(i)] = i;
  }
  Index find(Index x) {
    while (parent_[static_cast<size_t>(x)] != x)
      x = parent_[static_cast<size_t>(x)] =
          parent_[static_cast<size_t>(parent_[static_cast<size_t>(x)])];
    return x;
  }
  /// Joins the sets of a and b; false when they were one already.
  bool unite(Index a, Index b) {
    a = find(a);
    b = find(b);
    if (a == b) return false;
    parent_[static_cast<size_t>(std::max(a, b))] = std::min(a, b);
    return true;
  }

 private:
  std::vector<Index> parent_;
};

/// Whether points are inside one of the closed parts of a surface, each part by the parity
/// of a ray's crossings of its own triangles (orientation does not matter: faces wound either
/// way count alike; a shell inside another, or two that overlap, each say inside for their
/// own). The triangles are bucketed by the cells of a sparse grid across the ray that their
/// projection covers, row by row (a long thin triangle covers a line of cells), the cells a
/// median triangle's size, coarser while the entries pass kEntriesPerTriangle a triangle; a
/// triangle that would cover more than kWideCells cells (a face of a large box around fine
/// detail) is met by every query instead. A ray that passes within rounding of a triangle's edge,
/// or starts on one, is cast again in another direction; after three such, the point is called
/// outside.
class ClosedSurfaceInside {
 public:
  struct Triangle {
    std::array<Vec3, 3> corners;
    Index part = 0;
  };

  /// `centre`: a point near the triangles, subtracted before projecting (coordinates far
  /// from the origin would otherwise lose the digits the cells need).
  ClosedSurfaceInside(std::vector<Triangle> triangles, Index parts, const Vec3& centre)
      : triangles_(std::move(triangles)), centre_(centre), parity_(static_cast<size_t>(parts), 0) {}

  bool inside(const Vec3& point) {
    // Directions of no particular alignment with the axes (a lattice's grid of points and
    // faces would put the axes' rays on edges).
    static const Vec3 kDirections[] = {Vec3(0.5773, 0.6123, 0.5402).normalized(),
                                       Vec3(-0.3172, 0.8251, -0.4675).normalized(),
                                       Vec3(0.7071, -0.2931, 0.6437).normalized()};
    for (size_t k = 0; k < std::size(kDirections); ++k) {
      if (grids_.size() <= k) grids_.push_back(buildGrid(kDirections[k]));
      if (const int verdict = insideAlong(grids_[k], point); verdict >= 0) return verdict == 1;
    }
    return false;
  }

 private:
  static constexpr std::int64_t kWideCells = 4096;
  // Cells are made coarser while the entries pass this many a triangle (two sizes of
  // triangle, the large ones each covering thousands of the small ones' cells).
  static constexpr std::int64_t kEntriesPerTriangle = 64;
  static constexpr double kLastCell = 1073741823.0;  // 2^30 - 1 cells a side at most
  // Spans and rows padded by this share of a cell, so that a point on a boundary, rounded
  // either way, finds the triangles on both sides.
  static constexpr double kPad = 1e-6;

  struct Grid {
    Vec3 direction, across, up;  // the ray and two directions across it
    double u0 = 0, v0 = 0, cell = 1;
    std::vector<std::pair<std::uint64_t, Index>> entries;  // (cell, triangle), by cell
    std::vector<Index> wide;                               // triangles met by every query
  };

  static std::uint64_t cellKey(std::int64_t a, std::int64_t b) {
    return (static_cast<std::uint64_t>(a) << 32) ^ static_cast<std::uint64_t>(b);
  }
  // Coordinates in cells (from the grid's corner); the cell of such a coordinate.
  static double inCells(const Grid& g, double x, double origin) { return (x - origin) / g.cell; }
  static std::int64_t cellOf(double x) {
    return static_cast<std::int64_t>(std::clamp(std::floor(x), 0.0, kLastCell));
  }

  Grid buildGrid(const Vec3& direction) const {
    Grid g;
    g.direction = direction;
    g.across = direction.cross(Vec3::UnitX()).normalized();
    g.up = direction.cross(g.across);
    const size_t n = triangles_.size();
    std::vector<std::array<double, 6>> projected(n);
    double u1 = -std::numeric_limits<double>::infinity(), v1 = u1;
    g.u0 = g.v0 = std::numeric_limits<double>::infinity();
    std::vector<double> sizes;
    for (size_t i = 0; i < n; ++i) {
      auto& q = projected[i];
      for (int k = 0; k < 3; ++k) {
        const Vec3 c = triangles_[i].corners[static_cast<size_t>(k)] - centre_;
        q[2 * k] = c.dot(g.across);
        q[2 * k + 1] = c.dot(g.up);
        g.u0 = std::min(g.u0, q[2 * k]);
        u1 = std::max(u1, q[2 * k]);
        g.v0 = std::min(g.v0, q[2 * k + 1]);
        v1 = std::max(v1, q[2 * k + 1]);
      }
      const double area =
          0.5 * std::abs((q[2] - q[0]) * (q[5] - q[1]) - (q[4] - q[0]) * (q[3] - q[1]));
      if (area > 0.0) sizes.push_back(std::sqrt(area));
    }
    const double extent = std::max({u1 - g.u0, v1 - g.v0, std::numeric_limits<double>::min()});
    double typical = extent / std::sqrt(static_cast<double>(std::max<size_t>(n, 1)));
    if (!sizes.empty()) {
      std::nth_element(sizes.begin(), sizes.begin() + static_cast<std::ptrdiff_t>(sizes.size() / 2),
                       sizes.end());
      typical = std::max(typical * 1e-3, sizes[sizes.size() / 2]);
    }
    g.cell = std::max(typical, extent / kLastCell);
    const std::int64_t budget =
        kEntriesPerTriangle * static_cast<std::int64_t>(std::max<size_t>(n, 1));
    // (At a cell the size of the whole, every triangle covers at most four cells.)
    while (
        !fill(g, projected, g.cell >= extent ? std::numeric_limits<std::int64_t>::max() : budget))
      g.cell *= 4.0;
    std::sort(g.entries.begin(), g.entries.end());
    return g;
  }

  // Buckets every triangle at g.cell; false, with nothing kept, past `budget` entries.
  bool fill(Grid& g, const std::vector<std::array<double, 6>>& projected,
            std::int64_t budget) const {
    g.entries.clear();
    g.wide.clear();
    for (size_t i = 0; i < projected.size(); ++i) {
      std::array<double, 6> q = projected[i];  // in cells
      for (int k = 0; k < 3; ++k) {
        q[2 * k] = inCells(g, q[2 * k], g.u0);
        q[2 * k + 1] = inCells(g, q[2 * k + 1], g.v0);
      }
      const double lv = std::min({q[1], q[3], q[5]}), hv = std::max({q[1], q[3], q[5]});
      const double lu = std::min({q[0], q[2], q[4]}), hu = std::max({q[0], q[2], q[4]});
      const std::int64_t b0 = cellOf(lv - kPad), b1 = cellOf(hv + kPad);
      const std::int64_t a0 = cellOf(lu - kPad), a1 = cellOf(hu + kPad);
      const size_t first = g.entries.size();
      bool wide = b1 - b0 + 1 > kWideCells;
      // A row at a time: the u-span of the triangle's part within the row's strip [b, b+1].
      for (std::int64_t b = b0; b <= b1 && !wide; ++b) {
        const double lo = static_cast<double>(b) - kPad, hi = static_cast<double>(b + 1) + kPad;
        double su = std::numeric_limits<double>::infinity(), eu = -su;
        for (int k = 0; k < 3; ++k) {
          const double pu = q[2 * k], pv = q[2 * k + 1];
          const double qu = q[(2 * k + 2) % 6], qv = q[(2 * k + 3) % 6];
          double t0 = 0.0, t1 = 1.0;
          if (pv == qv) {
            if (pv < lo || pv > hi) continue;
          } else {
            const double ta = (lo - pv) / (qv - pv), tb = (hi - pv) / (qv - pv);
            t0 = std::max(0.0, std::min(ta, tb));
            t1 = std::min(1.0, std::max(ta, tb));
            if (t0 > t1) continue;
          }
          for (const double t : {t0, t1}) {
            const double x = pu + t * (qu - pu);
            su = std::min(su, x);
            eu = std::max(eu, x);
          }
        }
        if (!(su <= eu)) continue;
        const std::int64_t sa = std::max(a0, cellOf(su - kPad));
        const std::int64_t ea = std::min(a1, cellOf(eu + kPad));
        if (static_cast<std::int64_t>(g.entries.size() - first) + (ea - sa + 1) > kWideCells) {
          wide = true;
          break;
        }
        for (std::int64_t a = sa; a <= ea; ++a)
          g.entries.emplace_back(cellKey(a, b), static_cast<Index>(i));
      }
      if (wide) {
        g.entries.resize(first);
        g.wide.push_back(static_cast<Index>(i));
      }
      if (static_cast<std::int64_t>(g.entries.size()) > budget) return false;
    }
    return true;
  }

  // Whether the ray from `point` crosses triangle i (Moeller and Trumbore): 1 or 0, or -1
  // when it grazes an edge or starts on the triangle.
  int crosses(const Grid& g, const Vec3& point, Index i) const {
    constexpr double kGraze = 1e-9;
    const auto& [a, b, c] = triangles_[static_cast<size_t>(i)].corners;
    const Vec3 e1 = b - a, e2 = c - a, h = g.direction.cross(e2);
    const double det = e1.dot(h);
    const double scale = e1.norm() * e2.norm();
    if (std::abs(det) <= 1e-12 * scale) return 0;  // the ray runs along the triangle
    const Vec3 s = point - a;
    const double f = 1.0 / det;
    const double beta = f * s.dot(h);
    const Vec3 q = s.cross(e1);
    const double gamma = f * g.direction.dot(q);
    const double t = f * e2.dot(q);
    const double alpha = 1.0 - beta - gamma;
    if (beta < -kGraze || gamma < -kGraze || alpha < -kGraze) return 0;
    if (beta < kGraze || gamma < kGraze || alpha < kGraze) return -1;
    if (std::abs(t) <= kGraze * std::sqrt(scale)) return -1;  // the point is on the surface
    return t > 0.0 ? 1 : 0;
  }

  // 1 inside a closed part, 0 outside all, -1 when the ray grazes an edge.
  int insideAlong(const Grid& g, const Vec3& point) {
    const double u = inCells(g, (point - centre_).dot(g.across), g.u0);
    const double v = inCells(g, (point - centre_).dot(g.up), g.v0);
    touched_.clear();
    auto visit = [&](Index i) {
      const int crossing = crosses(g, point, i);
      if (crossing < 0) return false;
      if (crossing > 0) {
        const Index part = triangles_[static_cast<size_t>(i)].part;
        if (parity_[static_cast<size_t>(part)] == 0 &&
            std::find(touched_.begin(), touched_.end(), part) == touched_.end())
          touched_.push_back(part);
        parity_[static_cast<size_t>(part)] ^= 1;
      }
      return true;
    };
    bool clean = true;
    for (Index i : g.wide) clean = clean && visit(i);
    if (clean && u >= -kPad && v >= -kPad && u <= kLastCell && v <= kLastCell) {
      const std::uint64_t key = cellKey(cellOf(u), cellOf(v));
      auto it = std::lower_bound(g.entries.begin(), g.entries.end(),
                                 std::pair<std::uint64_t, Index>(key, 0));
      for (; it != g.entries.end() && it->first == key; ++it)
        if (!(clean = visit(it->second))) break;
    }
    bool odd = false;
    for (Index part : touched_) {
      odd = odd || parity_[static_cast<size_t>(part)] != 0;
      parity_[static_cast<size_t>(part)] = 0;
    }
    return !clean ? -1 : odd ? 1 : 0;
  }

  std::vector<Triangle> triangles_;
  Vec3 centre_;
  std::vector<Grid> grids_;
  std::vector<char> parity_;    // per part, during a query
  std::vector<Index> touched_;  // parts crossed during a query
};

/// The edges of no face that are curves of their own: all of a curve's, and beside a surface
/// those outside it (a sheet's hair, a wire beside a shell). Left to the surface, as before:
/// a solid's interior lattice edges, inside a closed part of the surface (faces joined across
/// their edges, none of them a border), which is what is drawn and exported of a solid; and
/// braces, edges joining two corners of one face. Each edge is judged by its midpoint, so
/// that the verdict depends neither on the order of the edges nor on its neighbours (a wire
/// that crosses the surface is a curve where it is outside).
std::vector<std::array<Index, 2>> curveEdges(const Mesh& control) {
  std::vector<std::array<Index, 2>> curves;
  for (Index e = 0; e < control.numEdges(); ++e)
    if (control.isWireEdge(e)) curves.push_back(control.edge(e));
  if (control.numFaces() == 0 || curves.empty()) return curves;
  const Index nF = control.numFaces();
  const Points& p = control.positions();
  auto position = [&](Index v) { return Vec3(p.row(v).transpose()); };
  // Closed parts: faces joined across edges of exactly two faces (so that a fin on a solid's
  // edge is a part of its own, and does not open the solid); a part with a border edge (one
  // face) is open and has no inside.
  UnionFind partsOf(nF);
  auto find = [&](Index f) { return partsOf.find(f); };
  for (Index e = 0; e < control.numEdges(); ++e)
    if (const auto faces = control.edgeFaces(e); faces.size() == 2)
      partsOf.unite(faces[0], faces[1]);
  // A part is closed when each of its edges has exactly two of its faces: a border (one),
  // or a rim where a brim or a repeated face meets it (a box cut in two cups along a loop of
  // edges of three faces), opens it (a QA pass: the cups' crossings made a hair far outside
  // the box "inside").
  std::vector<char> open(static_cast<size_t>(nF), 0);
  std::vector<Index> roots;
  for (Index e = 0; e < control.numEdges(); ++e) {
    const auto faces = control.edgeFaces(e);
    if (faces.empty() || faces.size() == 2) continue;  // a wire, or two faces of one part
    roots.clear();
    for (Index f : faces) roots.push_back(find(f));
    std::sort(roots.begin(), roots.end());
    for (size_t k = 0; k < roots.size();) {
      size_t end = k;
      while (end < roots.size() && roots[end] == roots[k]) ++end;
      if ((end - k) % 2 != 0) open[roots[k]] = 1;  // parity needs an even count
      k = end;
    }
  }
  std::vector<Index> partOf(static_cast<size_t>(nF), -1);
  Index parts = 0;
  std::vector<ClosedSurfaceInside::Triangle> triangles;
  for (Index f = 0; f < nF; ++f) {
    const Index root = find(f);
    if (open[root]) continue;
    if (partOf[root] < 0) partOf[root] = parts++;
    const auto face = control.face(f);
    for (size_t k = 1; k + 1 < face.size(); ++k) {
      const Vec3 a = position(face[0]), b = position(face[k]), c = position(face[k + 1]);
      // A sliver of collinear corners (an n-gon's fan) no ray crosses: kept out of the grid.
      if ((b - a).cross(c - a).norm() <= 1e-12 * (b - a).norm() * (c - a).norm()) continue;
      triangles.push_back({{a, b, c}, partOf[root]});
    }
  }
  std::optional<ClosedSurfaceInside> surface;
  const BoundingBox box = control.boundingBox();
  // Coordinates near the largest doubles would overflow the grid's arithmetic: no inside.
  if (!triangles.empty() && std::isfinite(box.diagonal()))
    surface.emplace(std::move(triangles), parts, box.center());
  std::erase_if(curves, [&](const std::array<Index, 2>& edge) {
    const auto fa = control.vertexFaces(edge[0]), fb = control.vertexFaces(edge[1]);
    const bool brace = std::any_of(fa.begin(), fa.end(), [&](Index f) {
      return std::find(fb.begin(), fb.end(), f) != fb.end();
    });
    return brace || (surface && surface->inside(0.5 * (position(edge[0]) + position(edge[1]))));
  });
  return curves;
}

/// One per face corner at the first level and four times as many at each later one, and two
/// per curve edge, doubling.
double estimateFor(const Mesh& control, double curveEdgeCount, int levels) {
  if (levels <= 0) return static_cast<double>(control.numVertices());
  const double corners = static_cast<double>(control.faces().indices.size());
  return corners * std::pow(4.0, levels - 1) + 2.0 * curveEdgeCount * std::pow(2.0, levels - 1);
}

/// The most levels, at most `wanted`, whose estimate stays within the budget.
int levelsWithinFor(const Mesh& control, double curveEdgeCount, int wanted,
                    double maxRefinedVertices) {
  int levels = 0;
  while (levels < wanted && estimateFor(control, curveEdgeCount, levels + 1) <= maxRefinedVertices)
    ++levels;
  return levels;
}

}  // namespace

double estimatedRefinedVertices(const Mesh& control, int levels) {
  if (levels <= 0) return static_cast<double>(control.numVertices());
  return estimateFor(control, static_cast<double>(curveEdges(control).size()), levels);
}

int levelsWithin(const Mesh& control, int wanted, double maxRefinedVertices) {
  if (wanted <= 0) return 0;
  return levelsWithinFor(control, static_cast<double>(curveEdges(control).size()), wanted,
                         maxRefinedVertices);
}

SubdivisionStencil::SubdivisionStencil(const Mesh& control, const SubdivisionOptions& options)
    : levels_(options.levels), numControl_(control.numVertices()) {
  if (options.levels < 0 || options.levels > kMaxLevels)
    throw InvalidInputError("levels: " + std::to_string(options.levels) + " is outside [0, " +
                            std::to_string(kMaxLevels) + "]");
  if (options.mass) validateMass(control, *options.mass);
  // Refuse up front, before any work, what would not fit, naming the levels that would.
  // (Level 0 is the control mesh itself: a format conversion, whatever its size.)
  std::vector<std::array<Index, 2>> curves = curveEdges(control);
  const double estimate = estimateFor(control, static_cast<double>(curves.size()), levels_);
  if (levels_ > 0 && estimate > options.maxRefinedVertices) {
    const int fit = levelsWithinFor(control, static_cast<double>(curves.size()), levels_,
                                    options.maxRefinedVertices);
    char text[320];
    std::snprintf(text, sizeof text,
                  "levels: %d levels of this %lld-vertex mesh would make about %.3g million "
                  "vertices (about %.2g GB), more than the %.0f allowed; at most %d level%s fit",
                  levels_, static_cast<long long>(numControl_), estimate / 1e6,
                  estimate * 1536.0 / 1e9, options.maxRefinedVertices, fit, fit == 1 ? "" : "s");
    throw InvalidInputError(text);
  }
  auto tooLarge = [&] {
    return InvalidInputError("levels: " + std::to_string(levels_) + " levels of this " +
                             std::to_string(numControl_) + "-vertex mesh would exceed " +
                             std::to_string(kMaxRefinedVertices) + " refined vertices");
  };

  LevelTopology topology;
  topology.numVertices = control.numVertices();
  topology.faces = control.faces();
  const bool surface = control.numFaces() > 0;
  // A curve's edges, or beside a surface its loose edges outside it (a sheet with a hair):
  // refined by the curve rule, so that the whole mesh is drawn and exported.
  topology.curveEdges = std::move(curves);

  VectorX mass;
  if (options.mass) mass = *options.mass;
  massTransfer_.reserve(static_cast<size_t>(levels_));  // growth would copy the matrices
  anchors_.resize(static_cast<size_t>(numControl_));
  for (Index v = 0; v < numControl_; ++v) anchors_[v] = {AnchorKind::Vertex, v, -1};
  {
    SparseRowMatrix unit = identity(numControl_);
    matrix_.swap(unit);
  }

  for (int level = 0; level < levels_; ++level) {
    // Refined vertices: one per corner, two per feature edge, at most one per vertex.
    const std::int64_t bound = static_cast<std::int64_t>(topology.faces.indices.size()) * 3 +
                               2 * static_cast<std::int64_t>(topology.curveEdges.size()) +
                               topology.numVertices;
    if (bound > kMaxRefinedVertices) throw tooLarge();
    const bool first = level == 0;
    LevelStep step = subdivision_detail::refineLevel(topology, options.mass ? &mass : nullptr,
                                                     options.interpolate && first);
    // Follow each control vertex's anchor down one level.
    for (Index v = 0; v < numControl_; ++v) {
      InterpolationAnchor& anchor = anchors_[v];
      if (first) {
        anchor = step.anchor[v];
        continue;
      }
      switch (anchor.kind) {
        case AnchorKind::Face:
          break;  // the F-face of face f is face f of the next level
        case AnchorKind::Segment: {
          const Index e = step.findFeatureEdge(anchor.a, anchor.b);
          if (e >= 0)
            anchor = {AnchorKind::Segment, step.curvePoint(e, anchor.a),
                      step.curvePoint(e, anchor.b)};
          else
            anchor = {AnchorKind::Vertex, step.child[anchor.a], -1};
          break;
        }
        case AnchorKind::Vertex:
          anchor.a = step.child[anchor.a];
          break;
      }
    }
    // Eigen 3.4's SparseMatrix has no move operations: swap, never copy, the large ones.
    if (first) {
      matrix_.swap(step.positions);
    } else {
      SparseRowMatrix composed = subdivision_detail::multiplyRowMajor(step.positions, matrix_);
      matrix_.swap(composed);
    }
    if (options.mass) mass = step.mass * mass;
    massTransfer_.emplace_back();
    massTransfer_.back().swap(step.mass);
    topology = std::move(step.next);
  }

  refinedFaces_ = std::move(topology.faces);
  numRefinedCurveEdges_ = static_cast<Index>(topology.curveEdges.size());
  if (surface) {
    subdivision_detail::faceEdgesAndRings(topology.numVertices, refinedFaces_, refinedEdges_,
                                          refinedNeighbors_);
  }
  if (!topology.curveEdges.empty()) {
    // The curves' edges after the faces'. A vertex on a face keeps its ring through the faces
    // (a corner's copy that a curve leaves would tilt its best-plane normal towards the
    // curve); the curves' own vertices get rings along them.
    std::vector<std::pair<Index, Index>> pairs;
    pairs.reserve(refinedNeighbors_.indices.size() + 2 * topology.curveEdges.size());
    for (Index v = 0; v < refinedNeighbors_.rows(); ++v)
      for (Index w : refinedNeighbors_.row(v)) pairs.emplace_back(v, w);
    auto onFace = [&](Index v) {
      return v < refinedNeighbors_.rows() && refinedNeighbors_.rowSize(v) > 0;
    };
    for (const auto& [a, b] : topology.curveEdges) {
      if (!onFace(a)) pairs.emplace_back(a, b);
      if (!onFace(b)) pairs.emplace_back(b, a);
    }
    refinedNeighbors_ = buildCsr(topology.numVertices, pairs);
    refinedEdges_.insert(refinedEdges_.end(), topology.curveEdges.begin(),
                         topology.curveEdges.end());
  } else if (!surface) {
    refinedNeighbors_ = buildCsr(topology.numVertices, {});
  }
  controlToRefined_.resize(static_cast<size_t>(numControl_));
  for (Index v = 0; v < numControl_; ++v) {
    const InterpolationAnchor& anchor = anchors_[v];
    controlToRefined_[v] =
        anchor.kind == AnchorKind::Face ? refinedFaces_.row(anchor.a)[0] : anchor.a;
  }
}

SubdivisionStencil::SubdivisionStencil(SubdivisionStencil&& other) noexcept {
  *this = std::move(other);
}

SubdivisionStencil& SubdivisionStencil::operator=(SubdivisionStencil&& other) noexcept {
  if (this == &other) return *this;
  levels_ = other.levels_;
  numControl_ = other.numControl_;
  matrix_.swap(other.matrix_);
  massTransfer_.swap(other.massTransfer_);  // swaps buffers: no element is copied
  refinedFaces_ = std::move(other.refinedFaces_);
  refinedEdges_ = std::move(other.refinedEdges_);
  numRefinedCurveEdges_ = std::exchange(other.numRefinedCurveEdges_, 0);
  refinedNeighbors_ = std::move(other.refinedNeighbors_);
  controlToRefined_ = std::move(other.controlToRefined_);
  anchors_ = std::move(other.anchors_);
  return *this;
}

int SubdivisionStencil::levels() const {
  return levels_;
}
Index SubdivisionStencil::numControlVertices() const {
  return numControl_;
}
Index SubdivisionStencil::numRefinedVertices() const {
  return static_cast<Index>(matrix_.rows());
}
const CsrIndex& SubdivisionStencil::refinedFaces() const {
  return refinedFaces_;
}
const std::vector<std::array<Index, 2>>& SubdivisionStencil::refinedEdges() const {
  return refinedEdges_;
}
const CsrIndex& SubdivisionStencil::refinedVertexNeighbors() const {
  return refinedNeighbors_;
}
const SparseRowMatrix& SubdivisionStencil::matrix() const {
  return matrix_;
}
const std::vector<Index>& SubdivisionStencil::controlToRefined() const {
  return controlToRefined_;
}
const std::vector<InterpolationAnchor>& SubdivisionStencil::anchors() const {
  return anchors_;
}

void SubdivisionStencil::apply(const Points& control, Points& refined) const {
  ZSCULPT_ASSERT(control.rows() == numControl_, "apply: control has the wrong row count");
  ZSCULPT_ASSERT(refined.rows() == matrix_.rows(), "apply: refined has the wrong row count");
  // One pass over the stencil's rows; the control points (24 bytes each) stay in cache.
  const Index rows = static_cast<Index>(matrix_.rows());
  const Index* outer = matrix_.outerIndexPtr();
  const Index* inner = matrix_.innerIndexPtr();
  const double* value = matrix_.valuePtr();
  const double* x = control.data();
  double* y = refined.data();
  for (Index r = 0; r < rows; ++r) {
    double sx = 0.0, sy = 0.0, sz = 0.0;
    for (Index p = outer[r]; p < outer[r + 1]; ++p) {
      const double w = value[p];
      const double* xi = x + 3 * static_cast<std::ptrdiff_t>(inner[p]);
      sx += w * xi[0];
      sy += w * xi[1];
      sz += w * xi[2];
    }
    double* yr = y + 3 * static_cast<std::ptrdiff_t>(r);
    yr[0] = sx;
    yr[1] = sy;
    yr[2] = sz;
  }
}

void SubdivisionStencil::apply(const VectorX& control, VectorX& refined) const {
  ZSCULPT_ASSERT(control.size() == numControl_, "apply: control has the wrong size");
  ZSCULPT_ASSERT(refined.size() == matrix_.rows(), "apply: refined has the wrong size");
  const Index rows = static_cast<Index>(matrix_.rows());
  const Index* outer = matrix_.outerIndexPtr();
  const Index* inner = matrix_.innerIndexPtr();
  const double* value = matrix_.valuePtr();
  for (Index r = 0; r < rows; ++r) {
    double s = 0.0;
    for (Index p = outer[r]; p < outer[r + 1]; ++p) s += value[p] * control[inner[p]];
    refined[r] = s;
  }
}

void SubdivisionStencil::refinedMass(const VectorX& controlMass, VectorX& refinedMass) const {
  if (controlMass.size() != numControl_)
    throw InvalidInputError("mass: " + std::to_string(controlMass.size()) + " values for " +
                            std::to_string(numControl_) + " vertices");
  refinedMass = controlMass;
  for (const SparseRowMatrix& transfer : massTransfer_) refinedMass = transfer * refinedMass;
}

VectorX SubdivisionStencil::refinedMass(const VectorX& controlMass) const {
  VectorX out;
  refinedMass(controlMass, out);
  return out;
}

void SubdivisionStencil::refinedNormals(const Points& refined, Points& normals) const {
  bestPlaneNormals(refinedFaces_, refinedNeighbors_, refined, normals);
}

namespace {

/// Merges refined vertices joined by a zero-length edge (Mesh refuses them: they would be
/// zero-length springs). Degenerate input makes them: two faces on the same vertices give
/// identical face points. Faces left with a repeated corner are dropped; vertices are
/// renumbered in order, keeping the first of each merged set.
void weldZeroLengthEdges(Points& positions, std::vector<std::vector<Index>>& faces,
                         std::vector<std::array<Index, 2>>& edges) {
  const Index n = static_cast<Index>(positions.rows());
  UnionFind sets(n);
  auto find = [&](Index v) { return sets.find(v); };
  auto coincide = [&](Index a, Index b) {
    return a != b && (positions.row(a) - positions.row(b)).squaredNorm() == 0.0;
  };
  bool merged = false;
  // Collapsing a face can join two of its corners that were not adjacent: repeat until no
  // zero-length edge is left (each pass merges at least one pair, so this ends).
  for (bool changed = true; changed;) {
    changed = false;
    auto unite = [&](Index a, Index b) {
      if (sets.unite(a, b)) changed = merged = true;
    };
    for (const auto& face : faces)
      for (size_t k = 0; k < face.size(); ++k)
        if (coincide(face[k], face[(k + 1) % face.size()]))
          unite(face[k], face[(k + 1) % face.size()]);
    for (const auto& [a, b] : edges)
      if (coincide(a, b)) unite(a, b);
    if (!changed) break;
    for (auto& face : faces) {
      std::vector<Index> kept;
      for (Index v : face) {
        const Index r = find(v);
        if (kept.empty() || kept.back() != r) kept.push_back(r);
      }
      while (kept.size() > 1 && kept.back() == kept.front()) kept.pop_back();
      face = std::move(kept);
    }
    std::erase_if(faces, [](std::vector<Index>& face) {
      if (face.size() < 3) return true;
      std::vector<Index> sorted = face;
      std::sort(sorted.begin(), sorted.end());
      return std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end();
    });
    for (auto& edge : edges) edge = {find(edge[0]), find(edge[1])};
    std::erase_if(edges, [](const std::array<Index, 2>& e) { return e[0] == e[1]; });
  }
  if (!merged) return;
  std::vector<Index> index(static_cast<size_t>(n), -1);
  Index next = 0;
  for (Index v = 0; v < n; ++v)
    if (find(v) == v) {
      index[v] = next;
      positions.row(next++) = positions.row(v);
    }
  positions.conservativeResize(next, 3);
  for (auto& face : faces)
    for (Index& v : face) v = index[find(v)];
  for (auto& edge : edges) {
    edge = {index[find(edge[0])], index[find(edge[1])]};
    if (edge[0] > edge[1]) std::swap(edge[0], edge[1]);
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
}

/// Drops the vertices no face or edge uses (a solid's interior, carried unchanged by the
/// stencil): the smooth surface is what is exported and drawn, and mesh checkers, printers
/// and engines flag stray points. The rest keep their order. A cloud of bare points (no
/// face, no edge) is its own refinement, and is kept.
void dropUnusedVertices(Points& positions, std::vector<std::vector<Index>>& faces,
                        std::vector<std::array<Index, 2>>& edges) {
  if (faces.empty() && edges.empty()) return;
  const Index n = static_cast<Index>(positions.rows());
  std::vector<Index> index(static_cast<size_t>(n), -1);
  for (const auto& face : faces)
    for (Index v : face) index[v] = 0;
  for (const auto& [a, b] : edges) index[a] = index[b] = 0;
  Index next = 0;
  for (Index v = 0; v < n; ++v)
    if (index[v] == 0) {
      index[v] = next;
      if (next != v) positions.row(next) = positions.row(v);
      ++next;
    }
  if (next == n) return;
  positions.conservativeResize(next, 3);
  for (auto& face : faces)
    for (Index& v : face) v = index[v];
  for (auto& [a, b] : edges) {
    a = index[a];
    b = index[b];
  }
}

}  // namespace

Mesh subdivide(const Mesh& control, const SubdivisionOptions& options) {
  const SubdivisionStencil stencil(control, options);
  Points refined(stencil.numRefinedVertices(), 3);
  stencil.apply(control.positions(), refined);
  return refinedMesh(stencil, std::move(refined));
}

Mesh refinedMesh(const SubdivisionStencil& stencil, Points refined) {
  ZSCULPT_ASSERT(refined.rows() == stencil.numRefinedVertices(),
                 "refinedMesh: the positions are not the stencil's refined vertices");
  const CsrIndex& faces = stencil.refinedFaces();
  std::vector<std::vector<Index>> polygons(static_cast<size_t>(faces.rows()));
  for (Index f = 0; f < faces.rows(); ++f)
    polygons[f].assign(faces.row(f).begin(), faces.row(f).end());
  // The curves' edges (the last numRefinedCurveEdges of refinedEdges); the faces' come
  // from the faces.
  const auto& all = stencil.refinedEdges();
  std::vector<std::array<Index, 2>> edges(all.end() - stencil.numRefinedCurveEdges(), all.end());
  weldZeroLengthEdges(refined, polygons, edges);
  dropUnusedVertices(refined, polygons, edges);
  return Mesh(std::move(refined), polygons, edges);
}

// ---- interpolation error ---------------------------------------------------------------

namespace {

/// Closest point of triangle abc to p (Ericson, Real-Time Collision Detection, 5.1.5).
Vec3 closestOnTriangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return a;
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + d1 / (d1 - d3) * ab;
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0)
    return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  const double denom = va + vb + vc;
  if (denom == 0.0) return a;  // degenerate triangle
  return a + ab * (vb / denom) + ac * (vc / denom);
}

double distanceToSegment(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0.0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

void checkSizes(const SubdivisionStencil& stencil, const Points& control, const Points& refined) {
  if (control.rows() != stencil.numControlVertices() ||
      refined.rows() != stencil.numRefinedVertices())
    throw InvalidInputError("interpolation error: positions do not match the stencil's sizes");
}

}  // namespace

void interpolationErrors(const SubdivisionStencil& stencil, const Points& control,
                         const Points& refined, VectorX& errors) {
  checkSizes(stencil, control, refined);
  const auto& anchors = stencil.anchors();
  const CsrIndex& faces = stencil.refinedFaces();
  errors.resize(control.rows());
  for (Index v = 0; v < control.rows(); ++v) {
    const Vec3 p = control.row(v).transpose();
    const InterpolationAnchor& anchor = anchors[v];
    auto at = [&](Index r) { return Vec3(refined.row(r).transpose()); };
    switch (anchor.kind) {
      case AnchorKind::Vertex:
        errors[v] = (at(anchor.a) - p).norm();
        break;
      case AnchorKind::Segment:
        errors[v] = distanceToSegment(p, at(anchor.a), at(anchor.b));
        break;
      case AnchorKind::Face: {
        const auto corners = faces.row(anchor.a);
        double best = (at(corners[0]) - p).norm();
        for (size_t k = 1; k + 1 < corners.size(); ++k) {
          const Vec3 q = closestOnTriangle(p, at(corners[0]), at(corners[k]), at(corners[k + 1]));
          best = std::min(best, (q - p).norm());
        }
        errors[v] = best;
        break;
      }
    }
  }
}

double maxInterpolationError(const SubdivisionStencil& stencil, const Points& control,
                             const Points& refined) {
  VectorX errors;
  interpolationErrors(stencil, control, refined, errors);
  return errors.size() > 0 ? errors.maxCoeff() : 0.0;
}

double maxVertexInterpolationError(const SubdivisionStencil& stencil, const Points& control,
                                   const Points& refined) {
  checkSizes(stencil, control, refined);
  double worst = 0.0;
  const auto& map = stencil.controlToRefined();
  for (Index v = 0; v < control.rows(); ++v)
    worst = std::max(worst, (refined.row(map[v]) - control.row(v)).norm());
  return worst;
}

}  // namespace zsculpt
