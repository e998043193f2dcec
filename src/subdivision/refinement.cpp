// One level of the modified Doo-Sabin scheme (paper section 3, "Smoothing"; Figure 5).
//
// Every refined vertex r is made from old vertices by two rows:
//   mass      A_ri >= 0, each column summing to 1: old vertex i lends the share A_ri of its
//             mass to r, so m'_r = sum_i A_ri m_i and the total mass is kept;
//   position  S_ri = A_ri m_i / m'_r (mass-dependent weights), so m'_r x'_r =
//             sum_i A_ri m_i x_i and, summed over r, the linear momentum is kept.
// A_ri is a mask weight (Doo-Sabin face-point mask, or Chaikin's 3/4, 1/4 on feature edges,
// whose point next to a curve end is the end itself) times the share of i's mass lent to
// that face or edge. Without masses S is the mask
// itself: classic Doo-Sabin (and Chaikin).
//
// Interpolating first level: each old vertex v owns a group of refined points (the corners
// of its V-face, the two points of its boundary segment, or its copy). They get the part
// of v's mass the other rows did not take, shared equally, and are translated together so
// that their centroid is v. Later levels keep such centroids (their masks' columns sum to
// 1), so the limit passes through v; and the group's momentum is exactly m_v v.

#include "zsculpt/subdivision/refinement.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "zsculpt/core/errors.h"
#include "zsculpt/mesh/mesh.h"

namespace zsculpt::subdivision_detail {

namespace {

/// Rows being filled in order: entries (column, value).
struct RowBuilder {
  std::vector<Index> outer{0};
  std::vector<Index> inner;
  std::vector<double> values;

  void reserve(size_t rows, size_t entries) {
    outer.reserve(rows + 1);
    inner.reserve(entries);
    values.reserve(entries);
  }
  void push(Index col, double value) {
    inner.push_back(col);
    values.push_back(value);
  }
  void endRow() { outer.push_back(static_cast<Index>(inner.size())); }
  [[nodiscard]] Index rows() const { return static_cast<Index>(outer.size()) - 1; }
};

/// Sorts each row's entries by column (rows are short: insertion sort).
void sortRows(RowBuilder& b) {
  for (Index r = 0; r < b.rows(); ++r) {
    for (Index p = b.outer[r] + 1; p < b.outer[r + 1]; ++p) {
      const Index col = b.inner[p];
      const double value = b.values[p];
      Index q = p;
      for (; q > b.outer[r] && b.inner[q - 1] > col; --q) {
        b.inner[q] = b.inner[q - 1];
        b.values[q] = b.values[q - 1];
      }
      b.inner[q] = col;
      b.values[q] = value;
    }
  }
}

/// Moves sorted rows into an Eigen matrix without a triplet pass.
SparseRowMatrix toSparse(Index cols, RowBuilder&& b) {
  SparseRowMatrix m(b.rows(), cols);
  m.resizeNonZeros(static_cast<Index>(b.inner.size()));
  std::copy(b.outer.begin(), b.outer.end(), m.outerIndexPtr());
  std::copy(b.inner.begin(), b.inner.end(), m.innerIndexPtr());
  std::copy(b.values.begin(), b.values.end(), m.valuePtr());
  return m;
}

/// Doo-Sabin face-point masks (CGAL DooSabin_mask_3): weight of corner j in the point of
/// corner k of an n-gon is (n+5)/(4n) for j = k and (3 + 2 cos(2 pi (k-j)/n)) / (4n)
/// otherwise. Rows and columns sum to 1. Cached per n (by offset (k - j) mod n).
class MaskCache {
 public:
  const double* mask(Index n) {
    if (static_cast<size_t>(n) >= masks_.size()) masks_.resize(static_cast<size_t>(n) + 1);
    auto& m = masks_[static_cast<size_t>(n)];
    if (m.empty()) {
      m.resize(static_cast<size_t>(n));
      const double nn = static_cast<double>(n);
      m[0] = (nn + 5.0) / (4.0 * nn);
      for (Index d = 1; d < n; ++d)
        m[static_cast<size_t>(d)] =
            (3.0 + 2.0 * std::cos(2.0 * std::numbers::pi * d / nn)) / (4.0 * nn);
    }
    return m.data();
  }

 private:
  std::vector<std::vector<double>> masks_;
};

}  // namespace

Index LevelStep::findFeatureEdge(Index a, Index b) const {
  if (a < 0 || a >= vertexFeatureEdges.rows()) return -1;
  for (Index e : vertexFeatureEdges.row(a)) {
    const auto& ends = featureEdges[static_cast<size_t>(e)];
    if ((ends[0] == a && ends[1] == b) || (ends[0] == b && ends[1] == a)) return e;
  }
  return -1;
}

// The share of an inside surface vertex's mass that the curves leaving it take.
constexpr double kCurveRootShare = 1e-3;

LevelStep refineLevel(const LevelTopology& topology, const VectorX* mass, bool interpolate) {
  const Index nV = topology.numVertices;
  const CsrIndex& faces = topology.faces;
  const Index nF = faces.rows();
  const bool surface = nF > 0;
  const Index nC = surface ? static_cast<Index>(faces.indices.size()) : 0;
  const std::vector<Index>& origin = faces.indices;
  ZSCULPT_ASSERT(mass == nullptr || mass->size() == nV, "mass size differs from vertex count");

  LevelStep step;
  step.numCorners = nC;

  // ---- corners: face, next, previous, and the corners leaving each vertex -----------------
  std::vector<Index> cornerFace(static_cast<size_t>(nC));
  for (Index f = 0; f < nF; ++f)
    for (Index c = faces.offsets[f]; c < faces.offsets[f + 1]; ++c) cornerFace[c] = f;
  auto nextCorner = [&](Index c) {
    const Index f = cornerFace[c];
    return c + 1 == faces.offsets[f + 1] ? faces.offsets[f] : c + 1;
  };
  auto prevCorner = [&](Index c) {
    const Index f = cornerFace[c];
    return c == faces.offsets[f] ? faces.offsets[f + 1] - 1 : c - 1;
  };
  CsrIndex vertexCorners;
  vertexCorners.offsets.assign(static_cast<size_t>(nV) + 1, 0);
  for (Index c = 0; c < nC; ++c) ++vertexCorners.offsets[origin[c] + 1];
  for (Index v = 0; v < nV; ++v) vertexCorners.offsets[v + 1] += vertexCorners.offsets[v];
  vertexCorners.indices.resize(static_cast<size_t>(nC));
  {
    std::vector<Index> fill(vertexCorners.offsets.begin(), vertexCorners.offsets.end() - 1);
    for (Index c = 0; c < nC; ++c) vertexCorners.indices[fill[origin[c]]++] = c;
  }

  // ---- edges: interior (two faces of opposite winding: twin corners) or feature ---------
  // The corner of an edge a->b is the one at a. Features: one face, more than two faces,
  // or two faces traversing the edge the same way (inconsistent orientation).
  std::vector<Index> twin(static_cast<size_t>(nC), -1);
  std::vector<Index> cornerFeature(static_cast<size_t>(nC), -1);
  if (surface) {
    for (Index c = 0; c < nC; ++c) {
      const Index a = origin[c];
      const Index b = origin[nextCorner(c)];
      Index same = 0, opposite = 0, oppositeCorner = -1, first = c;
      for (Index d : vertexCorners.row(a))
        if (origin[nextCorner(d)] == b) {
          ++same;
          first = std::min(first, d);
        }
      for (Index d : vertexCorners.row(b))
        if (origin[nextCorner(d)] == a) {
          ++opposite;
          oppositeCorner = d;
          first = std::min(first, d);
        }
      if (same == 1 && opposite == 1) {
        twin[c] = oppositeCorner;
      } else if (first == c) {
        cornerFeature[c] = static_cast<Index>(step.featureEdges.size());
        step.featureEdges.push_back({std::min(a, b), std::max(a, b)});
      } else {
        cornerFeature[c] = cornerFeature[first];  // `first` < c: already numbered
      }
    }
  }
  // Curve edges (a curve, or the loose edges beside a surface: a sheet with a hair) follow
  // the same curve rule, numbered after the faces' feature edges.
  const Index nSurfaceFeatures = static_cast<Index>(step.featureEdges.size());
  step.featureEdges.reserve(step.featureEdges.size() + topology.curveEdges.size());
  for (const auto& [a, b] : topology.curveEdges)
    step.featureEdges.push_back({std::min(a, b), std::max(a, b)});
  const Index nE = static_cast<Index>(step.featureEdges.size());
  {
    std::vector<std::pair<Index, Index>> pairs;
    pairs.reserve(2 * static_cast<size_t>(nE));
    for (Index e = 0; e < nE; ++e) {
      pairs.emplace_back(step.featureEdges[e][0], e);
      pairs.emplace_back(step.featureEdges[e][1], e);
    }
    step.vertexFeatureEdges = buildCsr(nV, pairs);
  }
  const CsrIndex& vertexFeatures = step.vertexFeatureEdges;

  // ---- vertices --------------------------------------------------------------------------
  // interior: no feature edge (interpolated by its V-face's centroid);
  // regular feature: two feature edges (by the midpoint of its boundary segment);
  // corner: keeps a copy of itself (rules below); curve end: its curve points stay on it;
  // pinned: interior on two faces, keeps a copy; carried: on no face nor feature edge (a
  // solid's interior, an isolated vertex), copied unchanged. A surface vertex where loose
  // edges start is a corner on a border (the curves join its copy) and a curve end inside
  // the surface (the curves start on it, its V-face interpolates it as before).
  const Index firstCopy = nC + 2 * nE;
  // Feature edges of the faces at each vertex (the curve edges are numbered after them).
  std::vector<Index> surfaceFeatures(static_cast<size_t>(nV), 0);
  for (Index e = 0; e < nSurfaceFeatures; ++e)
    for (Index v : step.featureEdges[e]) ++surfaceFeatures[v];
  std::vector<char> corner(static_cast<size_t>(nV), 0);
  std::vector<char> pinned(static_cast<size_t>(nV), 0);
  std::vector<char> curveEnd(static_cast<size_t>(nV), 0);
  step.copy.assign(static_cast<size_t>(nV), -1);
  // Shares of a vertex's mass lent to each incident face, to each feature element (feature
  // edges and the copy); half to faces and half to features when a vertex has both.
  std::vector<double> faceShare(static_cast<size_t>(nV), 0.0);
  std::vector<double> featureShare(static_cast<size_t>(nV), 0.0);
  Index nCopies = 0;
  for (Index v = 0; v < nV; ++v) {
    const Index nf = vertexCorners.rowSize(v);
    const Index nfeat = vertexFeatures.rowSize(v);
    // A fan of faces around v runs from one feature edge to the next; it is "open" when
    // they differ (one that wraps around a single non-manifold edge closes on itself). A
    // surface corner's copy goes into its open fans, so it needs one. With two feature
    // edges, `forward` and `backward` count open fans from the first to the second and
    // back: their V-faces' closing edges become the boundary segment at the next level.
    Index openFans = 0, forward = 0, backward = 0;
    if (nf > 0 && nfeat > 0) {
      for (Index c : vertexCorners.row(v)) {
        if (twin[c] >= 0) continue;
        Index x = c, end = -1;
        for (Index guard = 0; guard < nf && end < 0; ++guard) {
          const Index p = prevCorner(x);
          if (twin[p] < 0) end = cornerFeature[p];
          x = twin[p];
        }
        if (end < 0 || end == cornerFeature[c]) continue;
        ++openFans;
        if (nfeat == 2) (cornerFeature[c] == vertexFeatures.row(v)[0] ? forward : backward)++;
      }
    }
    // Corners keep a copy: curve ends and junctions, surface vertices of a single face, a
    // segment whose two fans would make it an interior edge (a sheet doubled back to back),
    // and copies of corners (`keep`), so that a corner stays one at every level.
    const bool kept = !topology.keep.empty() && topology.keep[v];
    corner[v] = nfeat > 0 && (nf == 0 || openFans > 0) &&
                (nfeat != 2 || nf == 1 || (forward == 1 && backward == 1) || kept);
    // With no open fan (a dead end of a non-manifold chain, or a sheet glued to its own
    // back), the vertex is an end of its feature curves: their points near it stay on it.
    curveEnd[v] = nf > 0 && nfeat > 0 && openFans == 0;
    const bool carried = nf == 0 && nfeat == 0;
    // An interior vertex on exactly two faces (valence 2) would have a two-sided V-face:
    // it keeps a copy instead, inserted between its two face points (see the E-faces).
    pinned[v] = surfaceFeatures[v] == 0 && nf == 2;
    if (corner[v] || carried || pinned[v]) step.copy[v] = firstCopy + nCopies++;
    const Index featureElements = nfeat + (corner[v] || pinned[v] ? 1 : 0);
    if (nf > 0) faceShare[v] = (featureElements > 0 ? 0.5 : 1.0) / nf;
    if (featureElements > 0) featureShare[v] = (nf > 0 ? 0.5 : 1.0) / featureElements;
    if (nf > 0 && surfaceFeatures[v] == 0 && nfeat > 0 && !pinned[v]) {
      // Inside the surface, where curves start: their first points (the vertex itself) take
      // a token share, so that the mass-weighted face points around it, and the surface, are
      // nearly as without the curves (half, as at a border, moved a grid's surface by a
      // tenth of its spacing: a QA pass).
      faceShare[v] = (1.0 - kCurveRootShare) / nf;
      featureShare[v] = kCurveRootShare / nfeat;
    }
    if (carried) featureShare[v] = 1.0;
  }
  const Index nNew = firstCopy + nCopies;
  step.next.keep.assign(static_cast<size_t>(nNew), 0);
  for (Index v = 0; v < nV; ++v)
    if (corner[v]) step.next.keep[step.copy[v]] = 1;
  auto curvePoint = [&](Index e, Index v) { return step.curvePoint(e, v); };

  // ---- rows before interpolation: mass transfer A and positions S -----------------------
  // Written straight into the matrices' storage: every row's length is known (n entries
  // for a corner of an n-gon, 2 for a curve point, 1 for a copy).
  SparseRowMatrix preMass(nNew, nV), prePositions(nNew, nV);
  {
    Index* outer = preMass.outerIndexPtr();
    outer[0] = 0;
    Index r = 0;
    for (Index f = 0; f < nF; ++f)
      for (Index k = 0, n = faces.rowSize(f); k < n; ++k, ++r) outer[r + 1] = outer[r] + n;
    for (Index e = 0; e < nE; ++e) {
      const auto [ea, eb] = step.featureEdges[e];
      outer[r + 1] = outer[r] + (curveEnd[ea] ? 1 : 2);
      ++r;
      outer[r + 1] = outer[r] + (curveEnd[eb] ? 1 : 2);
      ++r;
    }
    for (Index k = 0; k < nCopies; ++k, ++r) outer[r + 1] = outer[r] + 1;
    preMass.resizeNonZeros(outer[nNew]);
    prePositions.resizeNonZeros(outer[nNew]);
    std::copy(outer, outer + nNew + 1, prePositions.outerIndexPtr());
  }
  {
    const Index* outer = preMass.outerIndexPtr();
    Index* inner = preMass.innerIndexPtr();
    double* a = preMass.valuePtr();
    double* w = prePositions.valuePtr();
    Index p = 0;
    // Entry: column, mass-transfer weight (mask weight times the lent share), mask weight.
    auto put = [&](Index col, double mask, double share) {
      inner[p] = col;
      a[p] = mask * share;
      w[p] = mask;
      ++p;
    };
    MaskCache masks;
    for (Index f = 0; f < nF; ++f) {
      const Index begin = faces.offsets[f];
      const Index n = faces.rowSize(f);
      const double* mask = masks.mask(n);
      for (Index k = 0; k < n; ++k)
        for (Index j = 0; j < n; ++j) {
          const Index u = origin[begin + j];
          put(u, mask[(k - j + n) % n], faceShare[u]);
        }
    }
    for (Index e = 0; e < nE; ++e) {
      const auto [ea, eb] = step.featureEdges[e];
      // Chaikin's corner cutting: the point near the first end, then near the second. At a
      // curve end the point is the end itself; its share of the edge is split 2/3, 1/3 so
      // that every column still sums to 1 and the other point stays 1/4 a + 3/4 b once
      // its row is normalised.
      const bool endA = curveEnd[ea], endB = curveEnd[eb];
      if (endA) {
        put(ea, endB ? 1.0 : 2.0 / 3.0, featureShare[ea]);
      } else {
        put(ea, endB ? 1.0 : 0.75, featureShare[ea]);
        put(eb, endB ? 1.0 / 3.0 : 0.25, featureShare[eb]);
      }
      if (endB) {
        put(eb, endA ? 1.0 : 2.0 / 3.0, featureShare[eb]);
      } else {
        put(ea, endA ? 1.0 / 3.0 : 0.25, featureShare[ea]);
        put(eb, endA ? 1.0 : 0.75, featureShare[eb]);
      }
    }
    for (Index v = 0; v < nV; ++v)
      if (step.copy[v] >= 0) put(v, 1.0, featureShare[v]);
    // Columns in order within each row (rows are short: insertion sort), then positions:
    // the mask itself (classic, rows normalised), or mass-weighted:
    // S_ri = A_ri m_i / sum_j A_rj m_j.
    for (Index r = 0; r < nNew; ++r) {
      const Index begin = outer[r], end = outer[r + 1];
      for (Index q = begin + 1; q < end; ++q) {
        const Index col = inner[q];
        const double av = a[q], wv = w[q];
        Index t = q;
        for (; t > begin && inner[t - 1] > col; --t) {
          inner[t] = inner[t - 1];
          a[t] = a[t - 1];
          w[t] = w[t - 1];
        }
        inner[t] = col;
        a[t] = av;
        w[t] = wv;
      }
      if (mass) {
        double total = 0.0;
        for (Index q = begin; q < end; ++q) total += a[q] * (*mass)[inner[q]];
        for (Index q = begin; q < end; ++q) w[q] = a[q] * (*mass)[inner[q]] / total;
      } else if (end - begin <= 2) {
        // Curve points next to a curve end: masks whose rows do not sum to 1.
        double total = 0.0;
        for (Index q = begin; q < end; ++q) total += w[q];
        if (total != 1.0)
          for (Index q = begin; q < end; ++q) w[q] /= total;
      }
    }
    std::copy(inner, inner + outer[nNew], prePositions.innerIndexPtr());
  }

  // ---- refined faces: F-faces, E-faces, V-faces ------------------------------------------
  LevelTopology& next = step.next;
  next.numVertices = nNew;
  CsrIndex& out = next.faces;
  step.vertexFace.assign(static_cast<size_t>(nV), -1);
  // Groups owned by vertices (interpolation): members, as CSR over groups.
  std::vector<Index> groupOwner;
  CsrIndex groups;
  auto addGroup = [&](Index owner, std::span<const Index> members) {
    groupOwner.push_back(owner);
    groups.indices.insert(groups.indices.end(), members.begin(), members.end());
    groups.offsets.push_back(static_cast<Index>(groups.indices.size()));
  };
  if (surface) {
    out.offsets.reserve(static_cast<size_t>(nF) + nC + nV + 1);
    out.indices.reserve(4 * static_cast<size_t>(nC) + nE * 4);
    auto endFace = [&]() { out.offsets.push_back(static_cast<Index>(out.indices.size())); };
    // F-face: the face's own corner points, same winding (index f kept).
    for (Index f = 0; f < nF; ++f) {
      for (Index c = faces.offsets[f]; c < faces.offsets[f + 1]; ++c) out.indices.push_back(c);
      endFace();
    }
    // E-face of edge a->b (corner c in f): (f's b, f's a, g's a, g's b) reverses the edge in
    // both F-faces, so windings agree. On a feature edge each face gets its own E-face,
    // closed by the edge's two curve points.
    for (Index c = 0; c < nC; ++c) {
      const Index t = twin[c];
      if (t >= 0) {
        if (c > t) continue;
        // (f's b, f's a, [a's copy], g's a, g's b, [b's copy]): a pinned vertex's copy sits
        // on the edge joining its two face points, in both E-faces that share that edge.
        const Index a = origin[c], b = origin[nextCorner(c)];
        out.indices.insert(out.indices.end(), {nextCorner(c), c});
        if (pinned[a]) out.indices.push_back(step.copy[a]);
        out.indices.insert(out.indices.end(), {nextCorner(t), t});
        if (pinned[b]) out.indices.push_back(step.copy[b]);
      } else {
        const Index e = cornerFeature[c];
        out.indices.insert(out.indices.end(), {nextCorner(c), c, curvePoint(e, origin[c]),
                                               curvePoint(e, origin[nextCorner(c)])});
      }
      endFace();
    }
    // V-faces: around v, the next face is across the edge (previous corner, v), which
    // reverses the E-faces' edges. A fan that starts and ends on feature edges is closed by
    // their curve points (and the copy, at a corner); a full cycle is a plain V-face.
    std::vector<char> visited(static_cast<size_t>(nC), 0);
    std::vector<Index> chain;
    auto emitFace = [&](Index v, std::span<const Index> polygon) {
      if (polygon.size() < 3) return;
      if (step.vertexFace[v] < 0) step.vertexFace[v] = out.rows();
      out.indices.insert(out.indices.end(), polygon.begin(), polygon.end());
      endFace();
    };
    for (Index v = 0; v < nV; ++v) {
      for (Index c : vertexCorners.row(v)) {
        if (twin[c] >= 0 || visited[c]) continue;
        chain.clear();
        chain.push_back(curvePoint(cornerFeature[c], v));
        Index x = c, endFeature = -1;
        while (true) {
          chain.push_back(x);
          visited[x] = 1;
          const Index p = prevCorner(x);
          if (twin[p] < 0) {
            endFeature = cornerFeature[p];
            break;
          }
          x = twin[p];
          if (visited[x]) break;
        }
        // A fan closing on its own feature edge is closed by that edge's curve point alone;
        // the copy goes into open fans only (elsewhere it would open a hole).
        if (endFeature >= 0 && endFeature != cornerFeature[c]) {
          chain.push_back(curvePoint(endFeature, v));
          if (corner[v]) chain.push_back(step.copy[v]);
        }
        emitFace(v, chain);
      }
      for (Index c : vertexCorners.row(v)) {
        if (visited[c]) continue;
        chain.clear();
        Index x = c;
        while (x >= 0 && !visited[x]) {
          chain.push_back(x);
          visited[x] = 1;
          x = twin[prevCorner(x)];
        }
        emitFace(v, chain);
        if (interpolate && surfaceFeatures[v] == 0 && !pinned[v]) addGroup(v, chain);
      }
    }
  }
  // The curves' next edges (Chaikin): each curve edge's two points, the points on either
  // side of a curve vertex, a corner's copy to its curves' points. The faces' feature edges
  // are not among them: the E- and V-faces close over their curve points.
  if (nE > nSurfaceFeatures) {
    auto& edges = next.curveEdges;
    edges.reserve(2 * static_cast<size_t>(nE - nSurfaceFeatures) + nCopies);
    auto addEdge = [&](Index a, Index b) { edges.push_back({std::min(a, b), std::max(a, b)}); };
    for (Index e = nSurfaceFeatures; e < nE; ++e)
      addEdge(curvePoint(e, step.featureEdges[e][0]), curvePoint(e, step.featureEdges[e][1]));
    for (Index v = 0; v < nV; ++v) {
      const auto incident = vertexFeatures.row(v);
      if (corner[v]) {
        for (Index e : incident)
          if (e >= nSurfaceFeatures) addEdge(step.copy[v], curvePoint(e, v));
      } else if (incident.size() == 2 && vertexCorners.rowSize(v) == 0) {
        addEdge(curvePoint(incident[0], v), curvePoint(incident[1], v));
      }
    }
  }

  // Groups of the other vertices: the copy (corners, carried and valence-2 vertices), or
  // the curve points of its feature edges (a regular feature vertex's boundary segment).
  if (interpolate) {
    std::vector<Index> members;
    for (Index v = 0; v < nV; ++v) {
      members.clear();
      // Inside the surface, where curves start, the V-face is the group; the curves' first
      // points are the vertex itself already, and keep their token mass (kCurveRootShare).
      if (step.copy[v] < 0 && surfaceFeatures[v] == 0 && vertexCorners.rowSize(v) > 0) continue;
      if (step.copy[v] >= 0) {
        members.push_back(step.copy[v]);
      } else {
        for (Index e : vertexFeatures.row(v)) members.push_back(curvePoint(e, v));
      }
      if (!members.empty()) addGroup(v, members);
    }
  }

  // A refined vertex near each old one, to follow vertices down the levels.
  step.child.assign(static_cast<size_t>(nV), -1);
  for (Index v = 0; v < nV; ++v) {
    if (step.copy[v] >= 0)
      step.child[v] = step.copy[v];
    else if (curveEnd[v] && surfaceFeatures[v] > 0)
      step.child[v] = curvePoint(vertexFeatures.row(v)[0], v);
    else if (vertexCorners.rowSize(v) > 0)
      step.child[v] = vertexCorners.row(v)[0];
    else if (vertexFeatures.rowSize(v) > 0)
      step.child[v] = curvePoint(vertexFeatures.row(v)[0], v);
  }

  // Where each vertex is interpolated after this level (for a first, interpolating level):
  // its copy or curve end (exactly), its boundary segment's midpoint, its V-face's centre.
  step.anchor.resize(static_cast<size_t>(nV));
  for (Index v = 0; v < nV; ++v) {
    const auto incident = vertexFeatures.row(v);
    if (step.copy[v] < 0 && surfaceFeatures[v] == 0 && step.vertexFace[v] >= 0)
      // Inside the surface, where curves may start: its V-face, as for any interior vertex.
      step.anchor[v] = {AnchorKind::Face, step.vertexFace[v], -1};
    else if (step.copy[v] >= 0 || curveEnd[v])
      step.anchor[v] = {AnchorKind::Vertex, step.child[v], -1};
    else if (incident.size() == 2)
      step.anchor[v] = {AnchorKind::Segment, curvePoint(incident[0], v),
                        curvePoint(incident[1], v)};
    else if (step.vertexFace[v] >= 0)
      step.anchor[v] = {AnchorKind::Face, step.vertexFace[v], -1};
    else
      step.anchor[v] = {AnchorKind::Vertex, step.child[v], -1};
  }

  if (interpolate) {
    const Index nGroups = static_cast<Index>(groupOwner.size());
    std::vector<Index> groupOf(static_cast<size_t>(nNew), -1);
    for (Index g = 0; g < nGroups; ++g)
      for (Index r : groups.row(g)) groupOf[r] = g;
    // Mass lent by each old vertex to rows outside groups; the owner's groups get the rest.
    std::vector<double> lent(static_cast<size_t>(nV), 0.0);
    std::vector<Index> members(static_cast<size_t>(nV), 0);
    const Index* massOuter = preMass.outerIndexPtr();
    const Index* massInner = preMass.innerIndexPtr();
    const double* massValue = preMass.valuePtr();
    const Index* posOuter = prePositions.outerIndexPtr();
    const Index* posInner = prePositions.innerIndexPtr();
    const double* posValue = prePositions.valuePtr();
    for (Index r = 0; r < nNew; ++r)
      if (groupOf[r] < 0)
        for (Index p = massOuter[r]; p < massOuter[r + 1]; ++p) lent[massInner[p]] += massValue[p];
    for (Index g = 0; g < nGroups; ++g) members[groupOwner[g]] += groups.rowSize(g);

    // Translation: row r of group g (owner v) becomes pre_r + e_v - mean_{q in g} pre_q.
    std::vector<double> accumulator(static_cast<size_t>(nV), 0.0);
    std::vector<Index> mark(static_cast<size_t>(nV), -1);
    std::vector<Index> touched;
    RowBuilder means;
    for (Index g = 0; g < nGroups; ++g) {
      touched.clear();
      const double inv = 1.0 / groups.rowSize(g);
      for (Index r : groups.row(g))
        for (Index p = posOuter[r]; p < posOuter[r + 1]; ++p) {
          const Index col = posInner[p];
          if (mark[col] != g) {
            mark[col] = g;
            accumulator[col] = 0.0;
            touched.push_back(col);
          }
          accumulator[col] += inv * posValue[p];
        }
      for (Index col : touched) means.push(col, accumulator[col]);
      means.endRow();
    }
    std::fill(mark.begin(), mark.end(), -1);
    RowBuilder positions, transfer;
    positions.reserve(static_cast<size_t>(nNew), 3 * static_cast<size_t>(prePositions.nonZeros()));
    transfer.reserve(static_cast<size_t>(nNew), static_cast<size_t>(preMass.nonZeros()));
    for (Index r = 0; r < nNew; ++r) {
      const Index g = groupOf[r];
      if (g < 0) {
        for (Index p = posOuter[r]; p < posOuter[r + 1]; ++p)
          positions.push(posInner[p], posValue[p]);
        for (Index p = massOuter[r]; p < massOuter[r + 1]; ++p)
          transfer.push(massInner[p], massValue[p]);
      } else {
        const Index owner = groupOwner[g];
        touched.clear();
        auto add = [&](Index col, double value) {
          if (mark[col] != r) {
            mark[col] = r;
            accumulator[col] = 0.0;
            touched.push_back(col);
          }
          accumulator[col] += value;
        };
        for (Index p = posOuter[r]; p < posOuter[r + 1]; ++p) add(posInner[p], posValue[p]);
        add(owner, 1.0);
        for (Index p = means.outer[g]; p < means.outer[g + 1]; ++p)
          add(means.inner[p], -means.values[p]);
        for (Index col : touched)
          if (accumulator[col] != 0.0) positions.push(col, accumulator[col]);
        transfer.push(owner, (1.0 - lent[owner]) / members[owner]);
      }
      positions.endRow();
      transfer.endRow();
    }
    sortRows(positions);
    sortRows(transfer);
    // Eigen 3.4's SparseMatrix has no move operations: swap instead of assigning.
    SparseRowMatrix finalPositions = toSparse(nV, std::move(positions));
    SparseRowMatrix finalMass = toSparse(nV, std::move(transfer));
    step.positions.swap(finalPositions);
    step.mass.swap(finalMass);
  } else {
    step.positions.swap(prePositions);
    step.mass.swap(preMass);
  }
  return step;
}

void faceEdgesAndRings(Index numVertices, const CsrIndex& faces,
                       std::vector<std::array<Index, 2>>& edges, CsrIndex& rings) {
  // The one-ring of a through its faces: the next and the previous corner of each of its
  // corners, in order of first use. Valences are small, so a linear scan dedupes. Rows
  // are appended in vertex order, so no (vertex, neighbour) pair list is needed.
  const Index nC = static_cast<Index>(faces.indices.size());
  std::vector<Index> cornerFace(static_cast<size_t>(nC));
  for (Index f = 0; f < faces.rows(); ++f)
    for (Index c = faces.offsets[f]; c < faces.offsets[f + 1]; ++c) cornerFace[c] = f;
  std::vector<Index> start(static_cast<size_t>(numVertices) + 1, 0);
  for (Index c = 0; c < nC; ++c) ++start[faces.indices[c] + 1];
  for (Index v = 0; v < numVertices; ++v) start[v + 1] += start[v];
  std::vector<Index> corners(static_cast<size_t>(nC));
  {
    std::vector<Index> fill(start.begin(), start.end() - 1);
    for (Index c = 0; c < nC; ++c) corners[fill[faces.indices[c]]++] = c;
  }
  rings.offsets.assign(1, 0);
  rings.offsets.reserve(static_cast<size_t>(numVertices) + 1);
  rings.indices.clear();
  rings.indices.reserve(2 * static_cast<size_t>(nC));
  edges.clear();
  edges.reserve(static_cast<size_t>(nC));
  for (Index a = 0; a < numVertices; ++a) {
    const size_t first = rings.indices.size();
    for (Index k = start[a]; k < start[a + 1]; ++k) {
      const Index c = corners[k];
      const Index f = cornerFace[c];
      const Index begin = faces.offsets[f], end = faces.offsets[f + 1];
      for (Index b : {faces.indices[c + 1 == end ? begin : c + 1],
                      faces.indices[c == begin ? end - 1 : c - 1]})
        if (std::find(rings.indices.begin() + static_cast<std::ptrdiff_t>(first),
                      rings.indices.end(), b) == rings.indices.end())
          rings.indices.push_back(b);
    }
    for (size_t k = first; k < rings.indices.size(); ++k)
      if (rings.indices[k] > a) edges.push_back({a, rings.indices[k]});
    rings.offsets.push_back(static_cast<Index>(rings.indices.size()));
  }
}

SparseRowMatrix multiplyRowMajor(const SparseRowMatrix& a, const SparseRowMatrix& b) {
  ZSCULPT_ASSERT(a.cols() == b.rows(), "sparse product of mismatched sizes");
  ZSCULPT_ASSERT(a.isCompressed() && b.isCompressed(), "sparse product needs compressed input");
  const Index rows = static_cast<Index>(a.rows());
  const Index cols = static_cast<Index>(b.cols());
  const Index* aOuter = a.outerIndexPtr();
  const Index* aInner = a.innerIndexPtr();
  const double* aValue = a.valuePtr();
  const Index* bOuter = b.outerIndexPtr();
  const Index* bInner = b.innerIndexPtr();
  const double* bValue = b.valuePtr();

  // Two passes (Gustavson): count each row's distinct columns, then fill the result's
  // storage in place, so the large result is allocated once at its exact size.
  SparseRowMatrix c(rows, cols);
  Index* cOuter = c.outerIndexPtr();
  std::vector<Index> mark(static_cast<size_t>(cols), -1);
  cOuter[0] = 0;
  for (Index r = 0; r < rows; ++r) {
    Index count = 0;
    for (Index p = aOuter[r]; p < aOuter[r + 1]; ++p)
      for (Index q = bOuter[aInner[p]]; q < bOuter[aInner[p] + 1]; ++q)
        if (mark[bInner[q]] != r) {
          mark[bInner[q]] = r;
          ++count;
        }
    cOuter[r + 1] = cOuter[r] + count;
  }
  c.resizeNonZeros(cOuter[rows]);
  Index* cInner = c.innerIndexPtr();
  double* cValue = c.valuePtr();
  std::vector<double> accumulator(static_cast<size_t>(cols), 0.0);
  std::fill(mark.begin(), mark.end(), -1);
  for (Index r = 0; r < rows; ++r) {
    Index* touched = cInner + cOuter[r];
    Index count = 0;
    for (Index p = aOuter[r]; p < aOuter[r + 1]; ++p) {
      const Index k = aInner[p];
      const double value = aValue[p];
      for (Index q = bOuter[k]; q < bOuter[k + 1]; ++q) {
        const Index j = bInner[q];
        if (mark[j] != r) {
          mark[j] = r;
          accumulator[j] = 0.0;
          touched[count++] = j;
        }
        accumulator[j] += value * bValue[q];
      }
    }
    std::sort(touched, touched + count);
    for (Index k = 0; k < count; ++k) cValue[cOuter[r] + k] = accumulator[touched[k]];
  }
  return c;
}

}  // namespace zsculpt::subdivision_detail
