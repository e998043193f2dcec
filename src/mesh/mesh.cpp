#include "zsculpt/mesh/mesh.h"

#include <algorithm>
#include <cstdint>
#include <string>
#include <unordered_map>

#include "zsculpt/core/errors.h"

namespace zsculpt {

CsrIndex buildCsr(Index rows, const std::vector<std::pair<Index, Index>>& pairs) {
  CsrIndex csr;
  csr.offsets.assign(static_cast<size_t>(rows) + 1, 0);
  for (const auto& [r, value] : pairs) ++csr.offsets[r + 1];
  for (Index r = 0; r < rows; ++r) csr.offsets[r + 1] += csr.offsets[r];
  csr.indices.resize(pairs.size());
  std::vector<Index> fill(csr.offsets.begin(), csr.offsets.end() - 1);
  for (const auto& [r, value] : pairs) csr.indices[fill[r]++] = value;
  return csr;
}

namespace {

std::uint64_t edgeKey(Index a, Index b) {
  if (a > b) std::swap(a, b);
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(a)) << 32) |
         static_cast<std::uint32_t>(b);
}

}  // namespace

Mesh::Mesh(Points positions, const std::vector<std::vector<Index>>& faces,
           const std::vector<std::array<Index, 2>>& explicitEdges)
    : positions_(std::move(positions)) {
  const Index n = numVertices();
  if (n == 0) throw TopologyError("the mesh has no vertices");
  for (Index v = 0; v < n; ++v) {
    if (!positions_.row(v).allFinite())
      throw InvalidInputError("vertex " + std::to_string(v) + " has a non-finite coordinate");
  }

  // Faces: validate and store as CSR.
  faces_.offsets.assign(1, 0);
  faces_.indices.clear();
  // The face that last listed each vertex: a repeat is found in one pass over the corners
  // (comparing every pair of a 200,000-corner polygon's took about 27 s).
  std::vector<std::int64_t> lastFace(faces.empty() ? 0 : static_cast<size_t>(n), -1);
  for (size_t f = 0; f < faces.size(); ++f) {
    const auto& face = faces[f];
    if (face.size() < 3)
      throw TopologyError("face " + std::to_string(f) + " has fewer than 3 corners");
    for (size_t k = 0; k < face.size(); ++k) {
      if (face[k] < 0 || face[k] >= n)
        throw TopologyError("face " + std::to_string(f) + " refers to vertex " +
                            std::to_string(face[k]) + ", out of range [0, " + std::to_string(n) +
                            ")");
      std::int64_t& seen = lastFace[static_cast<size_t>(face[k])];
      if (seen == static_cast<std::int64_t>(f))
        throw TopologyError("face " + std::to_string(f) + " repeats vertex " +
                            std::to_string(face[k]));
      seen = static_cast<std::int64_t>(f);
      faces_.indices.push_back(face[k]);
    }
    faces_.offsets.push_back(static_cast<Index>(faces_.indices.size()));
  }

  // Unique undirected edges, numbered by first occurrence.
  std::unordered_map<std::uint64_t, Index> edgeIndex;
  edgeIndex.reserve(faces_.indices.size() + explicitEdges.size());
  auto addEdge = [&](Index a, Index b) -> Index {
    auto [it, inserted] = edgeIndex.try_emplace(edgeKey(a, b), static_cast<Index>(edges_.size()));
    if (inserted) {
      if ((positions_.row(a) - positions_.row(b)).squaredNorm() == 0.0)
        throw TopologyError("vertices " + std::to_string(a) + " and " + std::to_string(b) +
                            " coincide, which would make a zero-length spring");
      edges_.push_back({std::min(a, b), std::max(a, b)});
    }
    return it->second;
  };
  std::vector<std::pair<Index, Index>> faceEdgePairs;
  std::vector<std::pair<Index, Index>> edgeFacePairs;
  faceEdgePairs.reserve(faces_.indices.size());
  edgeFacePairs.reserve(faces_.indices.size());
  for (Index f = 0; f < numFaces(); ++f) {
    const auto corners = face(f);
    const auto m = static_cast<Index>(corners.size());
    for (Index k = 0; k < m; ++k) {
      const Index e = addEdge(corners[k], corners[(k + 1) % m]);
      faceEdgePairs.emplace_back(f, e);
      edgeFacePairs.emplace_back(e, f);
    }
  }
  for (size_t k = 0; k < explicitEdges.size(); ++k) {
    const auto [a, b] = explicitEdges[k];
    if (a < 0 || a >= n || b < 0 || b >= n)
      throw TopologyError("edge " + std::to_string(k) + " refers to a vertex out of range [0, " +
                          std::to_string(n) + ")");
    if (a == b)
      throw TopologyError("edge " + std::to_string(k) + " joins vertex " + std::to_string(a) +
                          " to itself");
    addEdge(a, b);
  }
  faceEdges_ = buildCsr(numFaces(), faceEdgePairs);
  // A face listing the same edge twice (possible only with >= 4 corners revisiting a
  // pair) is kept once per incidence; edgeFaces keeps unique faces.
  std::sort(edgeFacePairs.begin(), edgeFacePairs.end());
  edgeFacePairs.erase(std::unique(edgeFacePairs.begin(), edgeFacePairs.end()), edgeFacePairs.end());
  edgeFaces_ = buildCsr(numEdges(), edgeFacePairs);

  std::vector<std::pair<Index, Index>> vertexEdgePairs;
  std::vector<std::pair<Index, Index>> vertexNeighborPairs;
  vertexEdgePairs.reserve(2 * edges_.size());
  vertexNeighborPairs.reserve(2 * edges_.size());
  for (Index e = 0; e < numEdges(); ++e) {
    const auto [a, b] = edges_[e];
    vertexEdgePairs.emplace_back(a, e);
    vertexNeighborPairs.emplace_back(a, b);
    vertexEdgePairs.emplace_back(b, e);
    vertexNeighborPairs.emplace_back(b, a);
  }
  vertexEdges_ = buildCsr(n, vertexEdgePairs);
  vertexNeighbors_ = buildCsr(n, vertexNeighborPairs);

  std::vector<std::pair<Index, Index>> vertexFacePairs;
  vertexFacePairs.reserve(faces_.indices.size());
  for (Index f = 0; f < numFaces(); ++f)
    for (Index v : face(f)) vertexFacePairs.emplace_back(v, f);
  vertexFaces_ = buildCsr(n, vertexFacePairs);
}

void Mesh::setPositions(const Points& positions) {
  if (positions.rows() != positions_.rows())
    throw InvalidInputError("positions have " + std::to_string(positions.rows()) +
                            " rows, the mesh has " + std::to_string(positions_.rows()) +
                            " vertices");
  if (!positions.allFinite()) throw InvalidInputError("positions contain a non-finite value");
  positions_ = positions;
}

Index Mesh::findEdge(Index a, Index b) const {
  if (a < 0 || b < 0 || a >= numVertices() || b >= numVertices()) return -1;
  const auto edges = vertexEdges(a);
  const auto neighbors = vertexNeighbors(a);
  for (size_t k = 0; k < edges.size(); ++k)
    if (neighbors[k] == b) return edges[k];
  return -1;
}

std::vector<Index> Mesh::boundaryEdges() const {
  std::vector<Index> out;
  for (Index e = 0; e < numEdges(); ++e)
    if (isBoundaryEdge(e)) out.push_back(e);
  return out;
}

std::vector<Index> Mesh::nonManifoldEdges() const {
  std::vector<Index> out;
  for (Index e = 0; e < numEdges(); ++e)
    if (isNonManifoldEdge(e)) out.push_back(e);
  return out;
}

std::vector<Index> Mesh::isolatedVertices() const {
  std::vector<Index> out;
  for (Index v = 0; v < numVertices(); ++v)
    if (isIsolatedVertex(v)) out.push_back(v);
  return out;
}

std::vector<Index> Mesh::componentLabels(Index* count) const {
  std::vector<Index> label(static_cast<size_t>(numVertices()), -1);
  std::vector<Index> stack;
  Index next = 0;
  for (Index seed = 0; seed < numVertices(); ++seed) {
    if (label[seed] >= 0) continue;
    label[seed] = next;
    stack.push_back(seed);
    while (!stack.empty()) {
      const Index v = stack.back();
      stack.pop_back();
      for (Index w : vertexNeighbors(v)) {
        if (label[w] < 0) {
          label[w] = next;
          stack.push_back(w);
        }
      }
    }
    ++next;
  }
  if (count) *count = next;
  return label;
}

Index Mesh::numComponents() const {
  Index count = 0;
  (void)componentLabels(&count);
  return count;
}

std::vector<Index> Mesh::twoRing(Index v) const {
  std::vector<Index> out;
  for (Index w : vertexNeighbors(v)) {
    out.push_back(w);
    for (Index x : vertexNeighbors(w))
      if (x != v) out.push_back(x);
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

BoundingBox Mesh::boundingBox() const {
  BoundingBox box;
  if (numVertices() == 0) return box;
  box.min = positions_.colwise().minCoeff().transpose();
  box.max = positions_.colwise().maxCoeff().transpose();
  return box;
}

double Mesh::meanEdgeLength() const {
  if (edges_.empty()) return 0.0;
  double sum = 0.0;
  for (const auto& [a, b] : edges_) sum += (positions_.row(a) - positions_.row(b)).norm();
  return sum / static_cast<double>(edges_.size());
}

double Mesh::meanEdgeLengthAt(Index v, const Points& positions) const {
  const auto edges = vertexEdges(v);
  if (edges.empty()) return 0.0;
  double sum = 0.0;
  for (Index e : edges) sum += (positions.row(edge(e)[0]) - positions.row(edge(e)[1])).norm();
  return sum / static_cast<double>(edges.size());
}

}  // namespace zsculpt
