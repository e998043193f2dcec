// Editing module: brushes, local matrix updates against full rebuilds, the incremental
// critical period, undo and redo bit for bit, energy honesty, the edit queue, scripted
// edits, and refusal of bad input (paper sections 3 and 6).

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numbers>
#include <random>
#include <set>
#include <thread>

#include "zsculpt/core/errors.h"
#include "zsculpt/editing/editor.h"
#include "zsculpt/editing/local_update.h"
#include "zsculpt/editing/schedule.h"
#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/stepper.h"

using namespace zsculpt;
using namespace zsculpt::editing;

namespace {

bool identical(const SparseRowMatrix& a, const SparseRowMatrix& b) {
  if (a.rows() != b.rows() || a.nonZeros() != b.nonZeros()) return false;
  const size_t nnz = static_cast<size_t>(a.nonZeros());
  return std::memcmp(a.valuePtr(), b.valuePtr(), nnz * sizeof(double)) == 0 &&
         std::memcmp(a.innerIndexPtr(), b.innerIndexPtr(), nnz * sizeof(Index)) == 0 &&
         std::memcmp(a.outerIndexPtr(), b.outerIndexPtr(),
                     static_cast<size_t>(a.rows() + 1) * sizeof(Index)) == 0;
}

bool identical(const VectorX& a, const VectorX& b) {
  return a.size() == b.size() &&
         std::memcmp(a.data(), b.data(), static_cast<size_t>(a.size()) * sizeof(double)) == 0;
}

bool identical(const PhysicalProperties& a, const PhysicalProperties& b) {
  for (Property p : kAllProperties)
    if (!identical(a.values(p), b.values(p))) return false;
  return true;
}

/// Every matrix LocalMatrices keeps, copied, to compare bit for bit later.
struct MatrixSnapshot {
  SparseRowMatrix k, omega2, omega4, h, hPrime, hSecond, x, xPrime;
  VectorX inverseMass, g;
  double period = 0.0;

  explicit MatrixSnapshot(const LocalMatrices& m)
      : k(m.system().stiffness()),
        omega2(m.system().omega2()),
        omega4(m.transformation()->omega4()),
        h(m.transformation()->h()),
        hPrime(m.transformation()->hPrime()),
        hSecond(m.transformation()->hSecond()),
        x(m.transformation()->x()),
        xPrime(m.transformation()->xPrime()),
        inverseMass(m.system().inverseMass()),
        g(m.system().dampingCoefficient()),
        period(m.criticalPeriod()) {}

  [[nodiscard]] bool identicalTo(const LocalMatrices& m) const {
    const TransformationMatrices& t = *m.transformation();
    return identical(k, m.system().stiffness()) && identical(omega2, m.system().omega2()) &&
           identical(inverseMass, m.system().inverseMass()) &&
           identical(g, m.system().dampingCoefficient()) && identical(omega4, t.omega4()) &&
           identical(h, t.h()) && identical(hPrime, t.hPrime()) &&
           identical(hSecond, t.hSecond()) && identical(x, t.x()) &&
           identical(xPrime, t.xPrime()) && period == m.criticalPeriod();
  }
};

State perturbed(const Mesh& mesh, double amplitude, unsigned seed) {
  State s = State::atRest(mesh);
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, amplitude);
  for (Index i = 0; i < s.position.rows(); ++i)
    for (int c = 0; c < 3; ++c) {
      s.position(i, c) += noise(rng);
      s.velocity(i, c) = noise(rng);
    }
  return s;
}

Model makeModel(Mesh mesh, double angular = 0.3,
                double cap = std::numeric_limits<double>::infinity()) {
  UniformProperties u;
  u.mass = 0.5;
  u.stiffness = 5.0;
  u.angularStiffness = angular;
  u.damping = 0.05;
  u.stiffnessCap = cap;
  u.gravity = Vec3(0.0, 0.0, -9.81);
  return Model::fromMesh(std::move(mesh), u);
}

/// A random valid-looking command; some of them leave a property's range (add, multiply)
/// and must be refused.
class RandomEdits {
 public:
  RandomEdits(const Mesh& mesh, unsigned seed) : mesh_(mesh), rng_(seed) {
    scale_ = mesh.meanEdgeLength();
  }

  EditCommand next() {
    const double r = uniform(0.0, 1.0);
    if (r < 0.10) return Undo{};
    if (r < 0.15) return Redo{};
    if (r < 0.19) return GlobalEdit{brush()};
    if (r < 0.21) return Relax{};
    if (r < 0.24) return ScaleRest{uniform(0.8, 1.25)};
    Dab dab{brush(), BrushCentre::atVertex(vertex())};
    const double c = uniform(0.0, 1.0);
    if (c < 0.2 && mesh_.numFaces() > 0) {
      const Index f = static_cast<Index>(rng_() % static_cast<unsigned>(mesh_.numFaces()));
      Vec3 p = Vec3::Zero();
      for (Index v : mesh_.face(f)) p += mesh_.positions().row(v).transpose();
      dab.centre = BrushCentre::onFace(f, p / static_cast<double>(mesh_.face(f).size()));
    } else if (c < 0.3) {
      dab.centre = BrushCentre::atPoint(mesh_.positions().row(vertex()).transpose() +
                                        Vec3(uniform(-0.2, 0.2), 0.1, 0.0) * scale_);
    }
    return dab;
  }

 private:
  double uniform(double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng_); }
  Index vertex() { return static_cast<Index>(rng_() % static_cast<unsigned>(mesh_.numVertices())); }

  Brush brush() {
    Brush b;
    b.property = kAllProperties[rng_() % kAllProperties.size()];
    b.mode = static_cast<BrushMode>(rng_() % 4);
    b.falloff = static_cast<Falloff>(rng_() % 5);
    b.distance = rng_() % 2 ? DistanceKind::Surface : DistanceKind::Euclidean;
    b.strength = rng_() % 3 ? uniform(0.1, 1.0) : 1.0;
    b.radius = uniform(0.3, 3.5) * scale_;
    const PropertyRange range = propertyRange(b.property);
    const double top = std::isfinite(range.max) ? range.max : 10.0;
    switch (b.mode) {
      case BrushMode::Set:
        b.value = uniform(0.05 * top, top);
        break;
      case BrushMode::Add:
        b.value = uniform(-0.3, 1.0) * 0.2 * top;
        break;
      case BrushMode::Multiply:
        b.value = uniform(0.5, 1.8);
        break;
      case BrushMode::Smooth:
        break;
    }
    if (b.property == Property::RestLength && b.mode == BrushMode::Set) b.value *= 0.3 * scale_;
    return b;
  }

  const Mesh& mesh_;
  std::mt19937 rng_;
  double scale_ = 1.0;
};

struct PropertyTestStats {
  int applied = 0, refused = 0, unchanged = 0;
  double worstDifference = 0.0;
};

/// 1000 random edits (with undo and redo among them) on `model`, each followed by the local
/// update and a comparison with a full rebuild; then undo everything and redo everything.
PropertyTestStats runPropertyTest(Model model, unsigned seed) {
  PropertyTestStats stats;
  const State state = perturbed(model.mesh, 0.05 * model.mesh.meanEdgeLength(), seed);
  const double period = 0.5 * criticalPeriod(SystemMatrices(model));
  LocalMatrices matrices(model, period);
  const MatrixSnapshot initial(matrices);
  const PhysicalProperties initialProperties = model.properties;
  EditorOptions options;
  options.historyLimit = 100000;
  Editor editor(model.mesh, model.angles, options);
  RandomEdits edits(model.mesh, seed);
  for (int k = 0; k < 1000; ++k) {
    const EditCommand command = edits.next();
    const PhysicalProperties before = model.properties;
    EditResult result;
    try {
      result = editor.apply(EditTarget::of(model), state, command);
    } catch (const InvalidInputError&) {
      ++stats.refused;
      EXPECT_TRUE(identical(before, model.properties)) << "refused edit changed the model";
      continue;
    }
    if (!result.changed) {
      ++stats.unchanged;
      EXPECT_TRUE(identical(before, model.properties));
      continue;
    }
    ++stats.applied;
    matrices.update(model, result.matrixRows);
    const MatrixVerification check = verifyAgainstRebuild(
        model, matrices.system(), matrices.transformation(), &matrices.critical());
    stats.worstDifference = std::max(stats.worstDifference, check.maxAbs());
    EXPECT_LE(check.maxAbs(), 1e-12) << "after edit " << k << ": " << describe(command);
    EXPECT_EQ(matrices.criticalPeriod(), criticalPeriod(SystemMatrices(model)));
    if (check.maxAbs() > 1e-12) break;
  }
  // Undo of the whole surviving history restores properties and matrices bit for bit.
  const MatrixSnapshot final(matrices);
  const PhysicalProperties finalProperties = model.properties;
  const size_t depth = editor.undoDepth();
  for (size_t k = 0; k < depth; ++k) {
    const EditResult r = editor.undo(EditTarget::of(model), state);
    matrices.update(model, r.matrixRows);
  }
  // Edits undone earlier in the sequence were redone or replaced: what remains is the start.
  EXPECT_TRUE(identical(model.properties, initialProperties));
  EXPECT_TRUE(initial.identicalTo(matrices)) << "undo did not restore the matrices bit for bit";
  // Redo replays the undone edits (the redo history may also hold edits undone by the
  // random sequence itself, after the last new edit: those are not replayed here).
  for (size_t k = 0; k < depth; ++k) {
    const EditResult r = editor.redo(EditTarget::of(model), state);
    matrices.update(model, r.matrixRows);
  }
  EXPECT_TRUE(identical(model.properties, finalProperties));
  EXPECT_TRUE(final.identicalTo(matrices)) << "redo did not replay the matrices bit for bit";
  return stats;
}

}  // namespace

// ---- falloff and brush footprint ------------------------------------------------------------

TEST(Falloff, CurvesGoFromOneAtTheCentreToZeroAtTheRadius) {
  for (Falloff f :
       {Falloff::Smooth, Falloff::Sphere, Falloff::Linear, Falloff::Sharp, Falloff::Constant}) {
    EXPECT_EQ(falloffWeight(f, 0.0), 1.0) << falloffName(f);
    EXPECT_EQ(falloffWeight(f, 1.0), 0.0) << falloffName(f);
    EXPECT_EQ(falloffWeight(f, 2.0), 0.0) << falloffName(f);
    double previous = 1.0;
    for (double t = 0.0; t < 1.0; t += 0.01) {
      const double w = falloffWeight(f, t);
      EXPECT_GT(w, 0.0);
      EXPECT_LE(w, previous + 1e-15) << falloffName(f) << " must not increase outwards";
      previous = w;
    }
  }
  // The definitions (Blender's presets with p = 1 - d / r).
  const double t = 0.3, p = 0.7;
  EXPECT_DOUBLE_EQ(falloffWeight(Falloff::Smooth, t), 3 * p * p - 2 * p * p * p);
  EXPECT_DOUBLE_EQ(falloffWeight(Falloff::Sphere, t), std::sqrt(1 - t * t));
  EXPECT_DOUBLE_EQ(falloffWeight(Falloff::Linear, t), p);
  EXPECT_DOUBLE_EQ(falloffWeight(Falloff::Sharp, t), p * p);
  EXPECT_EQ(falloffWeight(Falloff::Constant, 0.999), 1.0);
}

TEST(BrushRegion, SurfaceDistanceIsExactOnAFlatSheetAndEuclideanIsStraight) {
  // On a flat sheet the distance along the surface is the straight one, and a dab is the
  // round footprint the brush circle shows. Along the edges alone it was |di| + |dj| (a
  // diamond of 13 vertices here, where the circle holds 21).
  const Mesh grid = makeGrid(9);
  BrushRegion region(grid);
  const Index centre = 4 + 9 * 4;
  region.compute(grid, grid.positions(), BrushCentre::atVertex(centre), 2.5, Falloff::Linear,
                 DistanceKind::Surface);
  EXPECT_EQ(region.size(), 21);  // di^2 + dj^2 <= 5
  for (Index k = 0; k < region.size(); ++k) {
    const Index v = region.vertices()[k];
    const double straight = std::hypot(v % 9 - 4, v / 9 - 4);
    EXPECT_NEAR(region.distances()[k], straight, 1e-12) << v;
    EXPECT_NEAR(region.weights()[k], 1.0 - straight / 2.5, 1e-12);
    EXPECT_EQ(region.weightOf(v), region.weights()[k]);
    if (k > 0) {
      EXPECT_GE(region.distances()[k], region.distances()[k - 1]);
    }
  }
  EXPECT_EQ(region.weightOf(0), 0.0);

  region.compute(grid, grid.positions(), BrushCentre::atVertex(centre), 2.5, Falloff::Linear,
                 DistanceKind::Euclidean);
  EXPECT_EQ(region.size(), 21);  // di^2 + dj^2 <= 5
  for (Index k = 0; k < region.size(); ++k) {
    const Index v = region.vertices()[k];
    EXPECT_DOUBLE_EQ(region.distances()[k], std::hypot(v % 9 - 4, v / 9 - 4));
  }
}

TEST(BrushRegion, EuclideanReachesAcrossTheHoleAndSurfaceDoesNot) {
  const Mesh torus = makeTorus(10, 10);
  // Vertex (0, 5) is on the inner equator; (5, 5) faces it across the hole, 2 apart.
  const Index a = 0 + 10 * 5, b = 5 + 10 * 5;
  ASSERT_NEAR((torus.positions().row(a) - torus.positions().row(b)).norm(), 2.0, 1e-12);
  BrushRegion region(torus);
  region.compute(torus, torus.positions(), BrushCentre::atVertex(a), 2.1, Falloff::Smooth,
                 DistanceKind::Euclidean);
  EXPECT_GT(region.weightOf(b), 0.0);
  region.compute(torus, torus.positions(), BrushCentre::atVertex(a), 2.1, Falloff::Smooth,
                 DistanceKind::Surface);
  EXPECT_EQ(region.weightOf(b), 0.0);
}

TEST(BrushRegion, FacePointAndFreePointCentres) {
  const Mesh grid = makeGrid(5);
  BrushRegion region(grid);
  // The centre of the face with corners 0, 1, 6, 5: each corner at sqrt(0.5).
  region.compute(grid, grid.positions(), BrushCentre::onFace(0, Vec3(0.5, 0.5, 0.0)), 1.0,
                 Falloff::Constant, DistanceKind::Surface);
  EXPECT_EQ(region.size(), 4);
  for (Index v : {0, 1, 5, 6}) EXPECT_EQ(region.weightOf(v), 1.0);
  // A free point starts at the nearest vertex.
  region.compute(grid, grid.positions(), BrushCentre::atPoint(Vec3(2.1, 2.0, 0.3)), 1.0,
                 Falloff::Linear, DistanceKind::Surface);
  EXPECT_EQ(region.vertices()[0], 2 + 5 * 2);
  EXPECT_NEAR(region.distances()[0], std::hypot(0.1, 0.3), 1e-15);
}

// ---- what a dab does --------------------------------------------------------------------------

TEST(Dab, ModesStrengthAndElementWeights) {
  Model model = makeModel(makeGrid(7));
  const State rest = State::atRest(model.mesh);
  Editor editor(model.mesh, model.angles);
  const Index centre = 3 + 7 * 3;
  Brush brush;
  brush.property = Property::Stiffness;
  brush.falloff = Falloff::Linear;
  brush.radius = 2.0;
  brush.value = 9.0;
  brush.strength = 0.5;
  const VectorX old = model.properties.stiffness;
  editor.apply(EditTarget::of(model), rest, Dab{brush, BrushCentre::atVertex(centre)});
  const BrushRegion& region = editor.lastRegion();
  for (Index v = 0; v < model.mesh.numVertices(); ++v) {
    const double f = 0.5 * region.weightOf(v);
    EXPECT_DOUBLE_EQ(model.properties.stiffness[v], old[v] + f * (9.0 - old[v]));
  }
  EXPECT_EQ(model.properties.stiffness[centre], 7.0);  // halfway at the centre

  // Full strength, constant falloff: exactly the value (lerp is exact at 1).
  brush.strength = 1.0;
  brush.falloff = Falloff::Constant;
  brush.value = 0.1;
  editor.apply(EditTarget::of(model), rest, Dab{brush, BrushCentre::atVertex(centre)});
  EXPECT_EQ(model.properties.stiffness[centre], 0.1);

  // Add and multiply.
  brush.property = Property::Mass;
  brush.mode = BrushMode::Add;
  brush.value = 0.25;
  editor.apply(EditTarget::of(model), rest, Dab{brush, BrushCentre::atVertex(centre)});
  EXPECT_DOUBLE_EQ(model.properties.mass[centre], 0.75);
  brush.mode = BrushMode::Multiply;
  brush.value = 2.0;
  editor.apply(EditTarget::of(model), rest, Dab{brush, BrushCentre::atVertex(centre)});
  EXPECT_DOUBLE_EQ(model.properties.mass[centre], 1.5);

  // Smooth: the mean of the neighbours' old values.
  Model smooth = makeModel(makeGrid(7));
  smooth.properties.damping[centre] = 4.0;
  Editor smoothEditor(smooth.mesh, smooth.angles);
  Brush s;
  s.property = Property::Damping;
  s.mode = BrushMode::Smooth;
  s.radius = 0.5;  // the centre alone
  s.falloff = Falloff::Constant;
  smoothEditor.apply(EditTarget::of(smooth), rest, Dab{s, BrushCentre::atVertex(centre)});
  EXPECT_DOUBLE_EQ(smooth.properties.damping[centre], 0.05);
  s.radius = 1.5;  // the centre and its one-ring, all from the old values
  smooth.properties.damping[centre] = 4.0;
  smoothEditor.apply(EditTarget::of(smooth), rest, Dab{s, BrushCentre::atVertex(centre)});
  EXPECT_DOUBLE_EQ(smooth.properties.damping[centre], 0.05);
  EXPECT_DOUBLE_EQ(smooth.properties.damping[centre + 1], (4.0 + 3 * 0.05) / 4.0);
}

TEST(Dab, EdgesTakeTheMeanOfTheirEndsAndAnglesTheirCentre) {
  Model model = makeModel(makeGrid(7));
  const State rest = State::atRest(model.mesh);
  Editor editor(model.mesh, model.angles);
  Brush brush;
  brush.property = Property::RestLength;
  brush.falloff = Falloff::Linear;
  brush.radius = 2.0;
  brush.value = 0.5;
  const VectorX oldLength = model.properties.restLength;
  editor.apply(EditTarget::of(model), rest, Dab{brush, BrushCentre::atVertex(24)});
  const BrushRegion& region = editor.lastRegion();
  for (Index e = 0; e < model.mesh.numEdges(); ++e) {
    const auto [i, j] = model.mesh.edge(e);
    const double w = 0.5 * (region.weightOf(i) + region.weightOf(j));
    EXPECT_DOUBLE_EQ(model.properties.restLength[e], std::lerp(oldLength[e], 0.5, w));
  }
  brush.property = Property::RestAngle;
  brush.value = 2.0;
  const VectorX oldAngle = model.properties.restAngle;
  editor.apply(EditTarget::of(model), rest, Dab{brush, BrushCentre::atVertex(24)});
  for (Index k = 0; k < model.angles.size(); ++k) {
    const double w = region.weightOf(model.angles.angles[static_cast<size_t>(k)][0]);
    EXPECT_DOUBLE_EQ(model.properties.restAngle[k], std::lerp(oldAngle[k], 2.0, w));
  }
}

// ---- locality ---------------------------------------------------------------------------------

TEST(Locality, ListedRowsAreTheRowsThatChangeAndStayNearTheDab) {
  for (Property property : kAllProperties) {
    Model model = makeModel(makeTorus(12, 12));
    const State rest = State::atRest(model.mesh);
    const SystemMatrices before(model);
    Editor editor(model.mesh, model.angles);
    Brush brush;
    brush.property = property;
    brush.mode = property == Property::Rigidity ? BrushMode::Add : BrushMode::Multiply;
    brush.value = property == Property::Rigidity ? 0.3 : 0.9;
    brush.radius = 0.8;
    const EditResult r =
        editor.apply(EditTarget::of(model), rest, Dab{brush, BrushCentre::atVertex(30)});
    ASSERT_TRUE(r.changed) << propertyName(property);
    const SystemMatrices after(model);
    const std::set<Index> listed(r.matrixRows.begin(), r.matrixRows.end());
    std::set<Index> nearby;
    for (Index v : editor.lastRegion().vertices()) {
      nearby.insert(v);
      for (Index u : model.mesh.vertexNeighbors(v)) nearby.insert(u);
    }
    for (Index i = 0; i < model.mesh.numVertices(); ++i) {
      bool rowChanged = after.inverseMass()[i] != before.inverseMass()[i] ||
                        after.dampingCoefficient()[i] != before.dampingCoefficient()[i];
      for (Index p = after.stiffness().outerIndexPtr()[i];
           p < after.stiffness().outerIndexPtr()[i + 1]; ++p)  // same pattern before and after
        rowChanged = rowChanged ||
                     after.stiffness().valuePtr()[p] != before.stiffness().valuePtr()[p] ||
                     after.omega2().valuePtr()[p] != before.omega2().valuePtr()[p];
      if (rowChanged) {
        EXPECT_TRUE(listed.count(i)) << propertyName(property) << " row " << i;
      }
    }
    for (Index i : r.matrixRows) EXPECT_TRUE(nearby.count(i)) << propertyName(property);
    if (!propertyChangesMatrices(property)) {
      EXPECT_TRUE(r.matrixRows.empty());
    }
  }
}

// ---- the property test of the issue ---------------------------------------------------------

TEST(PropertyTest, ThousandRandomEditsOnTheTorusEqualAFullRebuild) {
  const PropertyTestStats s = runPropertyTest(makeModel(makeTorus(10, 10)), 1);
  EXPECT_GT(s.applied, 600);
  EXPECT_GT(s.refused, 0);  // some adds and multiplies leave a range
  RecordProperty("worst_difference", formatNumber(s.worstDifference));
  RecordProperty("applied", s.applied);
  RecordProperty("refused", s.refused);
}

TEST(PropertyTest, ThousandRandomEditsOnTheGridWithAStiffnessCapEqualAFullRebuild) {
  const PropertyTestStats s = runPropertyTest(makeModel(makeGrid(18), 0.3, 8.0), 2);
  EXPECT_GT(s.applied, 600);
  RecordProperty("worst_difference", formatNumber(s.worstDifference));
  RecordProperty("applied", s.applied);
}

TEST(PropertyTest, ThousandRandomEditsOnNonManifoldFinsEqualAFullRebuild) {
  const PropertyTestStats s = runPropertyTest(makeModel(makeFins()), 3);
  EXPECT_GT(s.applied, 500);
  RecordProperty("worst_difference", formatNumber(s.worstDifference));
  RecordProperty("applied", s.applied);
}

TEST(CriticalPeriod, TrackerFollowsLocalEditsExactly) {
  Model model = makeModel(makeTorus(20, 20));
  LocalMatrices matrices(model, std::nullopt);
  const State rest = State::atRest(model.mesh);
  Editor editor(model.mesh, model.angles);
  Brush brush;
  brush.property = Property::Stiffness;
  brush.value = 50.0;
  brush.radius = 0.4;
  brush.falloff = Falloff::Constant;
  const double before = matrices.criticalPeriod();
  EditResult r = editor.apply(EditTarget::of(model), rest, Dab{brush, BrushCentre::atVertex(77)});
  matrices.update(model, r.matrixRows);
  EXPECT_LT(matrices.criticalPeriod(), before);  // stiffer: a shorter period
  EXPECT_EQ(matrices.criticalPeriod(), criticalPeriod(SystemMatrices(model)));
  const Index limiting = matrices.critical().limitingVertex();
  EXPECT_TRUE(std::find(r.matrixRows.begin(), r.matrixRows.end(), limiting) != r.matrixRows.end());
  // Undo: the maximum comes back down although it lived in the edited rows.
  r = editor.undo(EditTarget::of(model), rest);
  matrices.update(model, r.matrixRows);
  EXPECT_EQ(matrices.criticalPeriod(), before);
}

TEST(Undo, RestoresMatricesBitForBitAndRedoReplays) {
  Model model = makeModel(makeTorus(10, 10));
  const State state = perturbed(model.mesh, 0.02, 5);
  LocalMatrices matrices(model, 0.05);
  const MatrixSnapshot start(matrices);
  Editor editor(model.mesh, model.angles);
  Brush brush;
  brush.property = Property::Mass;
  brush.mode = BrushMode::Multiply;
  brush.value = 3.0;
  EditResult edit =
      editor.apply(EditTarget::of(model), state, Dab{brush, BrushCentre::atVertex(5)});
  matrices.update(model, edit.matrixRows);
  const MatrixSnapshot edited(matrices);
  EXPECT_FALSE(start.identicalTo(matrices));
  const EditResult undone = editor.undo(EditTarget::of(model), state);
  matrices.update(model, undone.matrixRows);
  EXPECT_TRUE(start.identicalTo(matrices));
  // Undo stores back exactly the energy the edit stored.
  EXPECT_EQ(undone.energy.potential, -edit.energy.potential);
  EXPECT_EQ(undone.energy.kinetic, -edit.energy.kinetic);
  const EditResult redone = editor.redo(EditTarget::of(model), state);
  matrices.update(model, redone.matrixRows);
  EXPECT_TRUE(edited.identicalTo(matrices));
  EXPECT_FALSE(editor.redo(EditTarget::of(model), state).changed);  // nothing left to redo
  // A new edit clears the redo history.
  editor.undo(EditTarget::of(model), state);
  editor.apply(EditTarget::of(model), state, ScaleRest{1.1});
  EXPECT_EQ(editor.redoDepth(), 0u);
}

TEST(Undo, HistoryLimitDropsTheOldest) {
  Model model = makeModel(makeGrid(5));
  const State rest = State::atRest(model.mesh);
  EditorOptions options;
  options.historyLimit = 3;
  Editor editor(model.mesh, model.angles, options);
  for (int k = 0; k < 5; ++k) editor.apply(EditTarget::of(model), rest, ScaleRest{1.1});
  EXPECT_EQ(editor.undoDepth(), 3u);
  for (int k = 0; k < 3; ++k) editor.undo(EditTarget::of(model), rest);
  EXPECT_FALSE(editor.undo(EditTarget::of(model), rest).changed);
  const double expected = makeGrid(5).meanEdgeLength() * 1.1 * 1.1;
  EXPECT_NEAR(model.properties.restLength[0], expected, 1e-15);
}

TEST(Undo, ARefusedAcceptanceLeavesTheValuesAndTheHistory) {
  // The caller's acceptance (a simulation that refuses the new values) throws: apply, undo
  // and redo each put the old values back and leave both histories as they were.
  Model model = makeModel(makeGrid(5));
  const State rest = State::atRest(model.mesh);
  Editor editor(model.mesh, model.angles);
  editor.apply(EditTarget::of(model), rest, ScaleRest{1.1});
  editor.apply(EditTarget::of(model), rest, ScaleRest{1.2});
  editor.undo(EditTarget::of(model), rest);
  const VectorX before = model.properties.restLength;
  int calls = 0;
  const Editor::Acceptance refuse = [&](const EditResult& r) {
    ++calls;
    EXPECT_TRUE(r.changed);
    EXPECT_NE(model.properties.restLength[0], before[0]);  // called with the new values
    throw InvalidInputError("refused");
  };
  EXPECT_THROW(editor.apply(EditTarget::of(model), rest, ScaleRest{2.0}, refuse),
               InvalidInputError);
  EXPECT_THROW(editor.undo(EditTarget::of(model), rest, refuse), InvalidInputError);
  EXPECT_THROW(editor.redo(EditTarget::of(model), rest, refuse), InvalidInputError);
  EXPECT_EQ(calls, 3);
  EXPECT_TRUE(model.properties.restLength == before);
  EXPECT_EQ(editor.undoDepth(), 1u);
  EXPECT_EQ(editor.redoDepth(), 1u);
  // Accepted, the same redo goes through.
  EXPECT_TRUE(editor.redo(EditTarget::of(model), rest, [](const EditResult&) {}).changed);
  EXPECT_NEAR(model.properties.restLength[0], before[0] * 1.2, 1e-14);
}

// ---- energy honesty ---------------------------------------------------------------------------

TEST(Energy, StiffnessDabAtRestStoresNothingAndLeavesEveryVertexAtRest) {
  for (Scheme scheme : {Scheme::Default, Scheme::Paper}) {
    Model model = makeModel(makeTorus(10, 10), 0.0);
    model.properties.gravity.setZero();
    State state = State::atRest(model.mesh);
    const double period = 0.5 * criticalPeriod(SystemMatrices(model));
    Stepper stepper(model, scheme, period);
    const Points external = Points::Zero(model.mesh.numVertices(), 3);
    stepper.step(state, external);
    Editor editor(model.mesh, model.angles);
    Brush brush;
    brush.property = Property::Stiffness;
    brush.value = 10.0;  // T_max shrinks by about sqrt(2): the period stays stable
    brush.radius = 1.5;
    const EditResult r =
        editor.apply(EditTarget::of(model), state, Dab{brush, BrushCentre::atVertex(42)});
    ASSERT_TRUE(r.changed);
    EXPECT_EQ(r.energy.potential, 0.0);
    EXPECT_EQ(r.energy.kinetic, 0.0);
    stepper.propertiesChanged(r.matrixRows);
    for (int k = 0; k < 200; ++k) stepper.step(state, external);
    EXPECT_TRUE(state.velocity.isZero(0.0)) << schemeName(scheme);
    EXPECT_TRUE(state.position == model.mesh.positions()) << schemeName(scheme);
  }
}

TEST(Energy, ReportedChangeEqualsTheFullEnergyDifference) {
  Model model = makeModel(makeTorus(10, 10));
  const State state = perturbed(model.mesh, 0.05, 11);
  Editor editor(model.mesh, model.angles);
  RandomEdits edits(model.mesh, 17);
  int checked = 0;
  for (int k = 0; k < 300; ++k) {
    const EditCommand command = edits.next();
    const Diagnostics before = measure(model, state);
    EditResult r;
    try {
      r = editor.apply(EditTarget::of(model), state, command);
    } catch (const InvalidInputError&) {
      continue;
    }
    const Diagnostics after = measure(model, state);
    // Rounding bound: each full sum adds a few hundred terms, each with a relative error of
    // about 1e-16, so its error is below 1e-12 of the sum of the terms' magnitudes.
    double magnitude = 0.0;
    for (const Diagnostics* d : {&before, &after})
      magnitude += d->potential.radial + d->potential.angular;
    for (Index i = 0; i < model.mesh.numVertices(); ++i)
      magnitude += 2.0 * std::abs(model.properties.mass[i] *
                                  model.properties.gravity.dot(state.position.row(i).transpose()));
    EXPECT_NEAR(r.energy.potential, after.potential.total() - before.potential.total(),
                1e-12 * magnitude)
        << describe(command);
    EXPECT_NEAR(r.energy.kinetic, after.kinetic - before.kinetic,
                1e-12 * (before.kinetic + after.kinetic))
        << describe(command);
    ++checked;
  }
  EXPECT_GT(checked, 200);
}

TEST(Energy, RelaxMakesTheCurrentShapeFreeOfStress) {
  Model model = makeModel(makeTorus(10, 10), 0.5);
  const State state = perturbed(model.mesh, 0.1, 3);
  const PotentialEnergy before = potentialEnergy(model, state.position);
  ASSERT_GT(before.radial, 0.0);
  Editor editor(model.mesh, model.angles);
  const EditResult r = editor.apply(EditTarget::of(model), state, Relax{});
  EXPECT_TRUE(r.wholeModel);
  // New rest lengths reach the matrices (the angle springs' bound: matrixEdgeStiffness).
  EXPECT_EQ(static_cast<Index>(r.matrixRows.size()), model.mesh.numVertices());
  const PotentialEnergy after = potentialEnergy(model, state.position);
  EXPECT_EQ(after.radial, 0.0);
  EXPECT_EQ(after.angular, 0.0);
  EXPECT_NEAR(r.energy.potential, -(before.radial + before.angular), 1e-12 * before.total());
}

// ---- bad input ---------------------------------------------------------------------------------

TEST(BadInput, RefusedWithAClearMessageAndTheModelUnchanged) {
  Model model = makeModel(makeTorus(10, 10));
  const State rest = State::atRest(model.mesh);
  Editor editor(model.mesh, model.angles);
  const PhysicalProperties original = model.properties;
  auto expectRefused = [&](const EditCommand& command, const std::string& fragment) {
    try {
      editor.apply(EditTarget::of(model), rest, command);
      ADD_FAILURE() << "accepted: " << describe(command);
    } catch (const InvalidInputError& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << "one line";
    }
    EXPECT_TRUE(identical(model.properties, original)) << describe(command);
    EXPECT_EQ(editor.undoDepth(), 0u);
  };
  Brush b;
  b.property = Property::Mass;
  b.value = -1.0;
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "mass -1");
  b.value = 0.0;  // mass must be > 0
  expectRefused(GlobalEdit{b}, "mass 0");
  b.property = Property::Stiffness;
  b.value = -2.0;
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "stiffness -2");
  b.property = Property::Rigidity;
  b.value = 1.5;
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "rigidity 1.5");
  b.value = 0.5;
  b.radius = 0.0;
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "radius");
  b.radius = -1.0;
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "radius");
  b.radius = std::nan("");
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "radius");
  b.radius = 1.0;
  b.strength = 1.5;
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "strength");
  b.strength = 1.0;
  expectRefused(Dab{b, BrushCentre::atVertex(100)}, "vertex 100");
  expectRefused(Dab{b, BrushCentre::onFace(-1, Vec3::Zero())}, "face -1");
  expectRefused(Dab{b, BrushCentre::atPoint(Vec3(std::nan(""), 0, 0))}, "not finite");
  // A result outside the range (add on a value near the bound) is refused as a whole,
  // naming the first element, although most of the brush's elements would be fine.
  b.property = Property::Stiffness;
  b.mode = BrushMode::Add;
  b.value = -4.9;
  b.falloff = Falloff::Constant;
  b.value = -6.0;
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "would get a value out of range");
  b.mode = BrushMode::Multiply;
  b.value = -1.0;
  expectRefused(Dab{b, BrushCentre::atVertex(0)}, "multiply");
  expectRefused(ScaleRest{0.0}, "factor");
  expectRefused(ScaleRest{-2.0}, "factor");
  // Names from scene files and the UI.
  EXPECT_THROW(propertyFromName("stifness"), InvalidInputError);
  EXPECT_THROW(brushModeFromName("paint"), InvalidInputError);
  EXPECT_THROW(falloffFromName("smoother"), InvalidInputError);
  EXPECT_THROW(distanceKindFromName("geodesic"), InvalidInputError);
  try {
    propertyFromName("stifness");
  } catch (const InvalidInputError& e) {
    EXPECT_NE(std::string(e.what()).find("stiffness"), std::string::npos) << "lists valid names";
  }
}

// ---- threading, scripted edits, the stepper ----------------------------------------------------

TEST(Schedule, DueEditsInTimeOrderWithListOrderForTies) {
  std::vector<TimedEdit> edits = {
      {1.0, ScaleRest{1.0}}, {0.2, Relax{}}, {1.0, Undo{}}, {2.0, Redo{}}};
  EditSchedule schedule(edits);
  EXPECT_TRUE(schedule.due(0.1).empty());
  auto due = schedule.due(0.3);
  ASSERT_EQ(due.size(), 1u);
  EXPECT_TRUE(std::holds_alternative<Relax>(due[0].command));
  // Ten steps of 0.1 s add up to less than 1 in floating point: the slack absorbs it.
  double t = 0.0;
  for (int k = 0; k < 10; ++k) t += 0.1;
  ASSERT_LT(t, 1.0);
  EXPECT_TRUE(schedule.due(t).empty());
  due = schedule.due(t, 1e-9);
  ASSERT_EQ(due.size(), 2u);
  EXPECT_TRUE(std::holds_alternative<ScaleRest>(due[0].command));
  EXPECT_TRUE(std::holds_alternative<Undo>(due[1].command));
  EXPECT_FALSE(schedule.finished());
  EXPECT_EQ(schedule.due(5.0).size(), 1u);
  EXPECT_TRUE(schedule.finished());
  EXPECT_THROW(EditSchedule({{-1.0, Relax{}}}), InvalidInputError);
  EXPECT_THROW(EditSchedule({{std::nan(""), Relax{}}}), InvalidInputError);
}

TEST(Stepper, PropertiesChangedWithTheListedRowsEqualsARebuild) {
  for (Scheme scheme : {Scheme::Default, Scheme::Paper}) {
    Model model = makeModel(makeGrid(12), 0.4);
    Stepper stepper(model, scheme, 0.01);
    State state = perturbed(model.mesh, 0.01, 9);
    Editor editor(model.mesh, model.angles);
    RandomEdits edits(model.mesh, 23);
    const Points external = Points::Zero(model.mesh.numVertices(), 3);
    for (int k = 0; k < 100; ++k) {
      try {
        const EditResult r = editor.apply(EditTarget::of(model), state, edits.next());
        if (r.changed) stepper.propertiesChanged(r.matrixRows);
      } catch (const InvalidInputError&) {
      }
      if (k % 10 == 0) stepper.step(state, external);
    }
    const MatrixVerification check =
        verifyAgainstRebuild(model, stepper.system(), stepper.transformation());
    EXPECT_LE(check.maxAbs(), 1e-12) << schemeName(scheme);
  }
}
