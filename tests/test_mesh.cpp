// Mesh module: connectivity for any topology, built-in models (counts of Table 1 and
// cli.md), classification queries, bad input.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include "zsculpt/core/errors.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/mesh/mesh.h"
#include "zsculpt/mesh/orientation.h"

using namespace zsculpt;

namespace {

void expectCounts(const Mesh& m, Index v, Index e, Index f) {
  EXPECT_EQ(m.numVertices(), v);
  EXPECT_EQ(m.numEdges(), e);
  EXPECT_EQ(m.numFaces(), f);
}

// Every face's Newell normal points away from the model's centroid.
void expectOutwardFaces(const Mesh& m) {
  const Vec3 centre = m.positions().colwise().mean().transpose();
  for (Index f = 0; f < m.numFaces(); ++f) {
    const auto face = m.face(f);
    Vec3 normal = Vec3::Zero(), centroid = Vec3::Zero();
    for (size_t k = 0; k < face.size(); ++k) {
      const Vec3 a = m.positions().row(face[k]).transpose();
      const Vec3 b = m.positions().row(face[(k + 1) % face.size()]).transpose();
      normal += a.cross(b);
      centroid += a;
    }
    centroid /= static_cast<double>(face.size());
    EXPECT_GT(normal.dot(centroid - centre), 0.0) << "face " << f;
  }
}

}  // namespace

TEST(Builtin, CountsMatchTable1AndTheContract) {
  expectCounts(makeBuiltin("builtin:dodecahedron"), 20, 30, 12);
  expectCounts(makeBuiltin("builtin:torus"), 100, 200, 100);
  expectCounts(makeBuiltin("builtin:torus:40:40"), 1600, 3200, 1600);
  expectCounts(makeBuiltin("builtin:grid"), 324, 612, 289);
  expectCounts(makeBuiltin("builtin:grid:5"), 25, 40, 16);
  expectCounts(makeBuiltin("builtin:helix"), 64, 63, 0);
  expectCounts(makeBuiltin("builtin:helix:10"), 10, 9, 0);
  expectCounts(makeBuiltin("builtin:lattice:3"), 27, 54, 24);
  expectCounts(makeBuiltin("builtin:lattice:4"), 64, 144, 54);
  expectCounts(makeBuiltin("builtin:fins"), 8, 10, 3);
}

TEST(Builtin, DodecahedronIsRegularWithUnitEdgesAndOutwardFaces) {
  const Mesh m = makeDodecahedron();
  for (Index e = 0; e < m.numEdges(); ++e) {
    const auto [a, b] = m.edge(e);
    EXPECT_NEAR((m.positions().row(a) - m.positions().row(b)).norm(), 1.0, 1e-12);
  }
  EXPECT_LT(m.positions().colwise().mean().norm(), 1e-12);
  for (Index v = 0; v < 20; ++v) EXPECT_EQ(m.valence(v), 3);
  expectOutwardFaces(m);
}

TEST(Builtin, DocumentedVertexOrder) {
  const Mesh torus = makeTorus(12, 8);
  // Vertex (u, v) is u + U v: u = 3, v = 0 is at angle 2 pi 3/12 = 90 degrees, outer rim.
  EXPECT_TRUE(torus.positions().row(3).isApprox(Eigen::RowVector3d(0, 3, 0), 1e-12));
  // v = 2 of 8 is a quarter turn around the tube: the top, z = 1, radius 2.
  EXPECT_TRUE(torus.positions().row(0 + 12 * 2).isApprox(Eigen::RowVector3d(2, 0, 1), 1e-12));
  expectOutwardFaces(makeLattice(3));
  const Mesh grid = makeGrid(7);
  EXPECT_TRUE(grid.positions().row(3 + 7 * 5).isApprox(Eigen::RowVector3d(3, 5, 0)));
}

TEST(Mesh, AFaceRepeatingAVertexIsRefusedWhereverTheRepeatIs) {
  // The repeat is found in one pass over the corners (comparing every pair of a 200,000-corner
  // polygon took 80 s): the first repeat in corner order is the one named, in a small face and
  // far along a large one; the same vertex in two faces is no repeat.
  constexpr Index kCorners = 5000;
  Points ring(kCorners, 3);
  for (Index k = 0; k < kCorners; ++k) {
    const double a = 2.0 * std::numbers::pi * k / kCorners;
    ring.row(k) << std::cos(a), std::sin(a), 0.0;
  }
  std::vector<Index> big(static_cast<size_t>(kCorners));
  for (Index k = 0; k < kCorners; ++k) big[static_cast<size_t>(k)] = k;
  EXPECT_EQ(Mesh(ring, {big}).numFaces(), 1);
  EXPECT_EQ(Mesh(ring, {{0, 1, 2}, {0, 2, 3}}).numFaces(), 2);
  std::vector<Index> repeating = big;
  repeating.push_back(4321);
  try {
    (void)Mesh(ring, {{0, 1, 2}, repeating});
    ADD_FAILURE() << "a repeated corner was accepted";
  } catch (const TopologyError& e) {
    EXPECT_STREQ(e.what(), "face 1 repeats vertex 4321");
  }
  try {
    (void)Mesh(ring, {{7, 8, 9, 8, 7}});
    ADD_FAILURE() << "a repeated corner was accepted";
  } catch (const TopologyError& e) {
    EXPECT_STREQ(e.what(), "face 0 repeats vertex 8");
  }
}

TEST(Mesh, GridBoundaryIsItsPerimeter) {
  const Mesh m = makeGrid(6);
  EXPECT_EQ(m.boundaryEdges().size(), 20u);
  EXPECT_TRUE(m.nonManifoldEdges().empty());
  for (Index e : m.boundaryEdges()) {
    const auto [a, b] = m.edge(e);
    for (Index v : {a, b}) {
      const double x = m.positions()(v, 0), y = m.positions()(v, 1);
      EXPECT_TRUE(x == 0 || y == 0 || x == 5 || y == 5);
    }
  }
  EXPECT_EQ(m.numComponents(), 1);
}

TEST(Mesh, FinsHaveOneNonManifoldEdgeAndSixBoundaryEdgesPerFinPair) {
  const Mesh m = makeFins();
  const auto nm = m.nonManifoldEdges();
  ASSERT_EQ(nm.size(), 1u);
  EXPECT_EQ(m.edgeFaces(nm[0]).size(), 3u);
  EXPECT_EQ(m.edge(nm[0]), (std::array<Index, 2>{0, 1}));
  EXPECT_EQ(m.boundaryEdges().size(), 9u);
}

TEST(Mesh, MeanEdgeLengthAtAVertexUsesThePositionsGiven) {
  // Grid vertex (i, j) at (i, j, 0): unit edges; the corner has two, an inner vertex four.
  const Mesh grid = makeGrid(4);
  EXPECT_DOUBLE_EQ(grid.meanEdgeLengthAt(0, grid.positions()), 1.0);
  EXPECT_DOUBLE_EQ(grid.meanEdgeLengthAt(5, grid.positions()), 1.0);
  // Stretched along x by 3: the corner's edges are 3 (to vertex 1) and 1 (to vertex 4).
  Points stretched = grid.positions();
  stretched.col(0) *= 3.0;
  EXPECT_DOUBLE_EQ(grid.meanEdgeLengthAt(0, stretched), 2.0);
  // A curve's end has one edge.
  const Mesh helix = makeHelix(8);
  EXPECT_GT(helix.meanEdgeLengthAt(0, helix.positions()), 0.0);
}

TEST(Mesh, ClosedSurfacesHaveNoBoundary) {
  EXPECT_TRUE(makeTorus().boundaryEdges().empty());
  EXPECT_TRUE(makeDodecahedron().boundaryEdges().empty());
  EXPECT_TRUE(makeLattice(3).boundaryEdges().empty());
}

TEST(Mesh, CurveHasWireEdgesAndNoFaces) {
  const Mesh m = makeHelix(10);
  for (Index e = 0; e < m.numEdges(); ++e) EXPECT_TRUE(m.isWireEdge(e));
  EXPECT_EQ(m.valence(0), 1);
  EXPECT_EQ(m.valence(5), 2);
}

TEST(Mesh, SolidCarriesItsInteriorEdges) {
  const Mesh m = makeLattice(3);
  // The centre vertex (1,1,1) = 13 has six lattice neighbours and lies on no face.
  EXPECT_EQ(m.valence(13), 6);
  EXPECT_TRUE(m.vertexFaces(13).empty());
  Index wire = 0;
  for (Index e = 0; e < m.numEdges(); ++e) wire += m.isWireEdge(e);
  // 54 edges, 48 of them on the boundary squares: the six spokes from the centre to the
  // face centres run through the inside.
  EXPECT_EQ(wire, 6);
}

TEST(Mesh, IsolatedVerticesAndComponents) {
  Points p(7, 3);
  p << 0, 0, 0, 1, 0, 0, 0, 1, 0, 5, 5, 5, 6, 5, 5, 5, 6, 5, 9, 9, 9;
  const Mesh m(p, {{0, 1, 2}, {3, 4, 5}});
  EXPECT_EQ(m.isolatedVertices(), std::vector<Index>{6});
  Index count = 0;
  const auto labels = m.componentLabels(&count);
  EXPECT_EQ(count, 3);
  EXPECT_EQ(labels[0], labels[2]);
  EXPECT_NE(labels[0], labels[3]);
}

TEST(Mesh, OneRingAndTwoRing) {
  const Mesh m = makeGrid(5);
  const Index centre = 2 + 5 * 2;
  auto ring =
      std::vector<Index>(m.vertexNeighbors(centre).begin(), m.vertexNeighbors(centre).end());
  std::sort(ring.begin(), ring.end());
  EXPECT_EQ(ring, (std::vector<Index>{7, 11, 13, 17}));
  // Two edges away on a quad grid: a diamond of 12 vertices.
  EXPECT_EQ(m.twoRing(centre).size(), 12u);
  EXPECT_EQ(m.findEdge(centre, 13) >= 0, true);
  EXPECT_EQ(m.findEdge(centre, 18), -1);
}

TEST(Mesh, EdgesAreNumberedInOrderOfFirstOccurrence) {
  Points p(4, 3);
  p << 0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0;
  const Mesh m(p, {{0, 1, 2, 3}}, {{0, 2}});
  ASSERT_EQ(m.numEdges(), 5);
  EXPECT_EQ(m.edge(0), (std::array<Index, 2>{0, 1}));
  EXPECT_EQ(m.edge(3), (std::array<Index, 2>{0, 3}));
  EXPECT_EQ(m.edge(4), (std::array<Index, 2>{0, 2}));
  EXPECT_TRUE(m.isWireEdge(4));
}

TEST(MeshErrors, BadInputIsRefusedWithAClearMessage) {
  Points p(3, 3);
  p << 0, 0, 0, 1, 0, 0, 0, 1, 0;
  EXPECT_THROW(Mesh(Points(0, 3), {}), TopologyError);
  EXPECT_THROW(Mesh(p, {{0, 1}}), TopologyError);
  EXPECT_THROW(Mesh(p, {{0, 1, 3}}), TopologyError);
  EXPECT_THROW(Mesh(p, {{0, 1, 1}}), TopologyError);
  EXPECT_THROW(Mesh(p, {}, {{0, 0}}), TopologyError);
  Points nan = p;
  nan(1, 2) = std::nan("");
  EXPECT_THROW(Mesh(nan, {{0, 1, 2}}), InvalidInputError);
  Points coincident = p;
  coincident.row(2) = coincident.row(1);
  try {
    Mesh(coincident, {{0, 1, 2}});
    FAIL() << "coincident vertices accepted";
  } catch (const TopologyError& e) {
    EXPECT_NE(std::string(e.what()).find("zero-length spring"), std::string::npos);
  }
  try {
    Mesh(p, {{0, 1, 7}});
    FAIL();
  } catch (const TopologyError& e) {
    EXPECT_EQ(std::string(e.what()), "face 0 refers to vertex 7, out of range [0, 3)");
  }
}

TEST(BuiltinErrors, UnknownOrMalformedNamesAreRefused) {
  for (const char* bad : {"builtin:cube", "builtin:torus:3", "builtin:grid:x", "builtin:grid:1",
                          "builtin:lattice", "builtin:helix:0", "builtin:torus:2:10", "torus"})
    EXPECT_THROW(makeBuiltin(bad), InvalidInputError) << bad;
}

// ---- orientation ------------------------------------------------------------------------------

namespace {

// The unit cube's six quads, wound outward.
std::vector<std::vector<Index>> cubeFaces() {
  return {{0, 3, 2, 1}, {4, 5, 6, 7}, {0, 1, 5, 4}, {2, 3, 7, 6}, {1, 2, 6, 5}, {0, 4, 7, 3}};
}

Points cubeCorners() {
  Points p(8, 3);
  p << 0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1;
  return p;
}

double signedVolume(const Points& p, const std::vector<std::vector<Index>>& faces) {
  double v = 0.0;
  for (const auto& f : faces)
    for (size_t k = 1; k + 1 < f.size(); ++k)
      v += p.row(f[0]).dot(p.row(f[k]).cross(p.row(f[k + 1]))) / 6.0;
  return v;
}

// Every edge shared by two faces is run opposite ways by them.
bool windsConsistently(const std::vector<std::vector<Index>>& faces) {
  std::vector<std::array<Index, 2>> directed;
  for (const auto& f : faces)
    for (size_t k = 0; k < f.size(); ++k) directed.push_back({f[k], f[(k + 1) % f.size()]});
  std::sort(directed.begin(), directed.end());
  return std::adjacent_find(directed.begin(), directed.end()) == directed.end();
}

}  // namespace

TEST(Orientation, AStrayFaceIsTurnedToAgreeAndAClosedSheetFacesOutward) {
  const Points p = cubeCorners();
  auto faces = cubeFaces();
  ASSERT_NEAR(signedVolume(p, faces), 1.0, 1e-15);
  EXPECT_EQ(orientFaces(p, faces).facesReversed, 0);
  EXPECT_EQ(faces, cubeFaces());
  // One face reversed: it, not its five neighbours, is turned back.
  std::reverse(faces[3].begin(), faces[3].end());
  ASSERT_FALSE(windsConsistently(faces));
  EXPECT_EQ(orientFaces(p, faces).facesReversed, 1);
  EXPECT_TRUE(windsConsistently(faces));
  EXPECT_NEAR(signedVolume(p, faces), 1.0, 1e-15);
  // Wound inward throughout: all six are turned outward.
  for (auto& f : faces) std::reverse(f.begin(), f.end());
  EXPECT_NEAR(signedVolume(p, faces), -1.0, 1e-15);
  EXPECT_EQ(orientFaces(p, faces).facesReversed, 6);
  EXPECT_NEAR(signedVolume(p, faces), 1.0, 1e-15);
  // Five of six reversed (so the propagation from face 0 would turn the five): the closed
  // sheet is still turned outward, by turning the five.
  faces = cubeFaces();
  for (size_t f = 1; f < 6; ++f) std::reverse(faces[f].begin(), faces[f].end());
  EXPECT_EQ(orientFaces(p, faces).facesReversed, 5);
  EXPECT_TRUE(windsConsistently(faces));
  EXPECT_NEAR(signedVolume(p, faces), 1.0, 1e-15);
}

TEST(Orientation, AnOpenSheetKeepsItsMajorityAndNonManifoldSheetsAreOrientedApart) {
  const Mesh grid = makeGrid(5);
  std::vector<std::vector<Index>> faces;
  for (Index f = 0; f < grid.numFaces(); ++f)
    faces.emplace_back(grid.face(f).begin(), grid.face(f).end());
  const auto original = faces;
  std::reverse(faces[0].begin(), faces[0].end());  // the first face, where a search starts
  EXPECT_EQ(orientFaces(grid.positions(), faces).facesReversed, 1);
  EXPECT_TRUE(windsConsistently(faces));
  for (size_t f = 1; f < faces.size(); ++f) EXPECT_EQ(faces[f], original[f]);
  // Fins: sheets meeting at a non-manifold spine are each consistent already; nothing turns.
  const Mesh fins = makeFins();
  std::vector<std::vector<Index>> finFaces;
  for (Index f = 0; f < fins.numFaces(); ++f)
    finFaces.emplace_back(fins.face(f).begin(), fins.face(f).end());
  const auto finsBefore = finFaces;
  const OrientationReport report = orientFaces(fins.positions(), finFaces);
  EXPECT_EQ(report.facesReversed, 0);
  EXPECT_EQ(report.nonOrientableComponents, 0);
  EXPECT_EQ(finFaces, finsBefore);
  // Three fins of three quads each on a spine: one face of one fin reversed turns back
  // alone (the spine is not crossed, so the other sheets are neither consulted nor changed).
  Points spine(2 + 3 * 6, 3);
  spine.row(0) << 0, 0, 0;
  spine.row(1) << 0, 0, 1;
  std::vector<std::vector<Index>> wings;
  for (Index k = 0; k < 3; ++k) {
    const double a = 2.0 * M_PI * static_cast<double>(k) / 3.0;
    Index previousLow = 0, previousHigh = 1;
    for (Index r = 1; r <= 3; ++r) {
      const Index low = 2 + 6 * k + 2 * (r - 1), high = low + 1;
      spine.row(low) << r * std::cos(a), r * std::sin(a), 0;
      spine.row(high) << r * std::cos(a), r * std::sin(a), 1;
      wings.push_back({previousLow, low, high, previousHigh});
      previousLow = low;
      previousHigh = high;
    }
  }
  const auto wingsBefore = wings;
  EXPECT_EQ(orientFaces(spine, wings).facesReversed, 0);
  std::reverse(wings[4].begin(), wings[4].end());  // the middle face of the second fin
  EXPECT_EQ(orientFaces(spine, wings).facesReversed, 1);
  for (size_t f = 0; f < wings.size(); ++f) {
    if (f == 4) {
      // Turned back keeping its first corner: the original cycle, rotated.
      auto rotated = wingsBefore[f];
      std::rotate(rotated.begin(), std::find(rotated.begin(), rotated.end(), wings[f][0]),
                  rotated.end());
      EXPECT_EQ(wings[f], rotated);
    } else {
      EXPECT_EQ(wings[f], wingsBefore[f]) << f;
    }
  }
}

TEST(Orientation, AMoebiusBandIsSaidToBeNonOrientable) {
  // Six quads around a half-twisted loop: no winding agrees across every edge.
  const int n = 6;
  Points p(2 * n, 3);
  for (int i = 0; i < n; ++i) {
    const double a = 2.0 * M_PI * i / n, t = 0.5 * a;
    const Vec3 centre(std::cos(a), std::sin(a), 0.0);
    const Vec3 across =
        std::cos(t) * Vec3(std::cos(a), std::sin(a), 0.0) + std::sin(t) * Vec3::UnitZ();
    p.row(2 * i) = (centre - 0.2 * across).transpose();
    p.row(2 * i + 1) = (centre + 0.2 * across).transpose();
  }
  std::vector<std::vector<Index>> faces;
  for (int i = 0; i < n; ++i) {
    const Index a = 2 * i, b = 2 * i + 1;
    // The last quad joins the first pair crossed over: the half twist.
    const Index c = i + 1 < n ? 2 * (i + 1) + 1 : 0, d = i + 1 < n ? 2 * (i + 1) : 1;
    faces.push_back({a, b, c, d});
  }
  const auto band = faces;
  const OrientationReport report = orientFaces(p, faces);
  EXPECT_EQ(report.nonOrientableComponents, 1);
  EXPECT_EQ(report.facesReversed, 0);
  EXPECT_EQ(faces, band);  // left as it is
}

TEST(Orientation, ANestedSheetKeepsItsWindingRelativeToTheSheetAroundIt) {
  // A cube of side 3 with a cube of side 1 inside. Wound into the cavity, the inner one is a
  // hollow model's inner wall (a thick-walled or 3D-printed part); wound outward, a part
  // inside another. Neither is turned; both are when the whole model is inside out.
  Points p(16, 3);
  const Points unit = cubeCorners();
  p.topRows(8) = 3.0 * unit;
  p.bottomRows(8) = (unit.array() + 1.0).matrix();
  std::vector<std::vector<Index>> outer = cubeFaces(), inner = cubeFaces();
  for (auto& f : inner) {
    for (Index& v : f) v += 8;
    std::reverse(f.begin(), f.end());  // into the cavity
  }
  auto hollow = outer;
  hollow.insert(hollow.end(), inner.begin(), inner.end());
  const auto right = hollow;
  EXPECT_EQ(orientFaces(p, hollow).facesReversed, 0);
  EXPECT_EQ(hollow, right);
  EXPECT_NEAR(signedVolume(p, hollow), 27.0 - 1.0, 1e-12);
  auto part = outer;
  for (auto f : inner) {
    std::reverse(f.begin(), f.end());
    part.push_back(f);
  }
  EXPECT_EQ(orientFaces(p, part).facesReversed, 0);
  EXPECT_NEAR(signedVolume(p, part), 28.0, 1e-12);
  auto insideOut = right;
  for (auto& f : insideOut) std::reverse(f.begin(), f.end());
  EXPECT_EQ(orientFaces(p, insideOut).facesReversed, 12);
  EXPECT_NEAR(signedVolume(p, insideOut), 26.0, 1e-12);
  // Two cubes side by side, neither inside the other: both outward.
  Points apart(16, 3);
  apart.topRows(8) = unit;
  apart.bottomRows(8) = (unit.array() + 5.0).matrix();
  auto two = outer;
  for (auto f : inner) {
    std::reverse(f.begin(), f.end());  // outward again: the second cube's own faces
    two.push_back(f);
  }
  EXPECT_EQ(orientFaces(apart, two).facesReversed, 0);
  EXPECT_NEAR(signedVolume(apart, two), 2.0, 1e-12);
  // A unit cube half sunk into the big one (an eye in a head), wound inward by mistake: it
  // is not inside, so it is turned outward, and the big one is left as it is.
  Points sunk(16, 3);
  sunk.topRows(8) = 3.0 * unit;
  sunk.bottomRows(8) = (unit.array() + 2.5).matrix();
  auto overlapping = outer;
  for (auto f : inner) overlapping.push_back(f);  // inner is wound inward
  EXPECT_EQ(orientFaces(sunk, overlapping).facesReversed, 6);
  EXPECT_NEAR(signedVolume(sunk, overlapping), 28.0, 1e-12);
  // A small part resting on the big one's top face (its bottom face's centroid on that
  // face): not inside either.
  Points resting(16, 3);
  resting.topRows(8) = 3.0 * unit;
  resting.bottomRows(8) = unit;
  resting.bottomRows(8).col(2).array() += 3.0;
  auto onTop = outer;
  for (auto f : inner) onTop.push_back(f);  // wound inward
  EXPECT_EQ(orientFaces(resting, onTop).facesReversed, 6);
  EXPECT_NEAR(signedVolume(resting, onTop), 28.0, 1e-12);
}
