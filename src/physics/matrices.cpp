#include "zsculpt/physics/matrices.h"

#include <Eigen/Eigenvalues>
#include <Spectra/SymEigsSolver.h>
#include <algorithm>
#include <cmath>
#include <limits>

#include "zsculpt/core/errors.h"

namespace zsculpt {

void multiply(const SparseRowMatrix& a, const Points& in, Points& out) {
  const Index* outer = a.outerIndexPtr();
  const Index* inner = a.innerIndexPtr();
  const double* value = a.valuePtr();
  const Index rows = static_cast<Index>(a.rows());
  for (Index i = 0; i < rows; ++i) {
    double x = 0.0, y = 0.0, z = 0.0;
    for (Index p = outer[i]; p < outer[i + 1]; ++p) {
      const double* r = in.data() + 3 * static_cast<Eigen::Index>(inner[p]);
      x += value[p] * r[0];
      y += value[p] * r[1];
      z += value[p] * r[2];
    }
    double* o = out.data() + 3 * static_cast<Eigen::Index>(i);
    o[0] = x;
    o[1] = y;
    o[2] = z;
  }
}

void multiplyRows(const SparseRowMatrix& a, const Points& in, Points& out,
                  std::span<const Index> rows) {
  const Index* outer = a.outerIndexPtr();
  const Index* inner = a.innerIndexPtr();
  const double* value = a.valuePtr();
  for (Index i : rows) {
    Eigen::RowVector3d sum = Eigen::RowVector3d::Zero();
    for (Index p = outer[i]; p < outer[i + 1]; ++p) sum += value[p] * in.row(inner[p]);
    out.row(i) = sum;
  }
}

namespace {

// A CSR pattern (sorted columns per row) with zero values.
SparseRowMatrix patternMatrix(Index n, const std::vector<std::vector<Index>>& columns) {
  SparseRowMatrix m(n, n);
  Eigen::VectorXi sizes(n);
  for (Index i = 0; i < n; ++i) sizes[i] = static_cast<int>(columns[i].size());
  m.reserve(sizes);
  for (Index i = 0; i < n; ++i)
    for (Index j : columns[i]) m.insert(i, j) = 0.0;
  m.makeCompressed();
  return m;
}

// Position of column `col` in row `row` of a compressed matrix, or -1.
Index findInRow(const SparseRowMatrix& m, Index row, Index col) {
  const Index* begin = m.innerIndexPtr() + m.outerIndexPtr()[row];
  const Index* end = m.innerIndexPtr() + m.outerIndexPtr()[row + 1];
  const Index* it = std::lower_bound(begin, end, col);
  return (it != end && *it == col) ? static_cast<Index>(it - m.innerIndexPtr()) : -1;
}

}  // namespace

double matrixEdgeStiffness(const Model& model, Index edge) {
  const auto [i, j] = model.mesh.edge(edge);
  const PhysicalProperties& p = model.properties;
  double kappa = edgeStiffness(cappedStiffness(p.stiffness[i], p.stiffnessCap),
                               cappedStiffness(p.stiffness[j], p.stiffnessCap));
  const auto& x = model.mesh.positions();
  const double length2 = (x.row(i) - x.row(j)).squaredNorm();
  for (Index angle : model.angles.edgeAngles.row(edge)) {
    const Index centre = model.angles.angles[angle][0];
    kappa += 2.0 * p.angularStiffness[centre] / length2;
  }
  return kappa;
}

SystemMatrices::SystemMatrices(const Model& model) {
  const Mesh& mesh = model.mesh;
  const Index n = mesh.numVertices();
  std::vector<std::vector<Index>> columns(n);
  for (Index v = 0; v < n; ++v) {
    columns[v].assign(mesh.vertexNeighbors(v).begin(), mesh.vertexNeighbors(v).end());
    columns[v].push_back(v);
    std::sort(columns[v].begin(), columns[v].end());
  }
  k_ = patternMatrix(n, columns);
  omega2_ = k_;
  inverseMass_.resize(n);
  g_.resize(n);
  for (Index v = 0; v < n; ++v) computeRow(model, v);
}

void SystemMatrices::updateVertices(const Model& model, std::span<const Index> vertices) {
  for (Index v : vertices) computeRow(model, v);
}

void SystemMatrices::computeRow(const Model& model, Index v) {
  const Mesh& mesh = model.mesh;
  const PhysicalProperties& p = model.properties;
  inverseMass_[v] = 1.0 / p.mass[v];
  g_[v] = 0.5 * p.damping[v] * inverseMass_[v];
  const auto neighbors = mesh.vertexNeighbors(v);
  const auto edges = mesh.vertexEdges(v);
  double diagonal = 0.0;
  double* kValues = k_.valuePtr();
  double* oValues = omega2_.valuePtr();
  for (size_t q = 0; q < neighbors.size(); ++q) {
    const double kappa = matrixEdgeStiffness(model, edges[q]);
    const Index pos = findInRow(k_, v, neighbors[q]);
    kValues[pos] = -kappa;
    oValues[pos] = -kappa * inverseMass_[v];
    diagonal += kappa;
  }
  const Index pos = findInRow(k_, v, v);
  kValues[pos] = diagonal;
  oValues[pos] = diagonal * inverseMass_[v];
}

double SystemMatrices::gamma() const { return g_.size() ? g_.minCoeff() : 0.0; }

double criticalPeriod(const SystemMatrices& matrices) {
  const VectorX diagonal = matrices.omega2().diagonal();
  const double largest = diagonal.size() ? diagonal.maxCoeff() : 0.0;
  if (!(largest > 0.0)) return std::numeric_limits<double>::infinity();
  return std::sqrt(6.0 / largest);
}

namespace {

// y = M^-1/2 K M^-1/2 x, the symmetric form of Omega^2, for Spectra.
class SymmetricOmega2 {
 public:
  using Scalar = double;
  explicit SymmetricOmega2(const SystemMatrices& m)
      : k_(m.stiffness()), scale_(m.inverseMass().cwiseSqrt()), tmp_(scale_.size()) {}
  [[nodiscard]] Eigen::Index rows() const { return scale_.size(); }
  [[nodiscard]] Eigen::Index cols() const { return scale_.size(); }
  void perform_op(const double* in, double* out) const {
    Eigen::Map<const VectorX> x(in, rows());
    Eigen::Map<VectorX> y(out, rows());
    tmp_ = scale_.cwiseProduct(x);
    y.noalias() = k_ * tmp_;
    y = y.cwiseProduct(scale_);
  }

 private:
  const SparseRowMatrix& k_;
  VectorX scale_;
  mutable VectorX tmp_;
};

}  // namespace

double largestEigenvalue(const SystemMatrices& matrices) {
  const Eigen::Index n = matrices.stiffness().rows();
  const VectorX scale = matrices.inverseMass().cwiseSqrt();
  if (n <= 600) {
    const Eigen::MatrixXd dense =
        scale.asDiagonal() * Eigen::MatrixXd(matrices.stiffness()) * scale.asDiagonal();
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(dense, Eigen::EigenvaluesOnly);
    return eig.eigenvalues().maxCoeff();
  }
  SymmetricOmega2 op(matrices);
  const Eigen::Index ncv = std::min<Eigen::Index>(n, 40);
  Spectra::SymEigsSolver<SymmetricOmega2> eigs(op, 1, ncv);
  eigs.init();
  eigs.compute(Spectra::SortRule::LargestAlge, 3000, 1e-9);
  if (eigs.info() != Spectra::CompInfo::Successful) {
    // Fall back to the Gerschgorin bound of equation 5 (safe: never below lambda_0).
    return 2.0 * matrices.omega2().diagonal().maxCoeff();
  }
  return eigs.eigenvalues()[0];
}

double tightCriticalPeriod(const SystemMatrices& matrices) {
  const double lambda = largestEigenvalue(matrices);
  if (!(lambda > 0.0)) return std::numeric_limits<double>::infinity();
  return std::sqrt(12.0 / lambda);
}

TransformationMatrices::TransformationMatrices(const SystemMatrices& system, double period)
    : period_(period) {
  const SparseRowMatrix& o2 = system.omega2();
  const Index n = static_cast<Index>(o2.rows());
  std::vector<std::vector<Index>> columns(n);
  for (Index i = 0; i < n; ++i) {
    auto& row = columns[i];
    for (SparseRowMatrix::InnerIterator a(o2, i); a; ++a)
      for (SparseRowMatrix::InnerIterator b(o2, a.col()); b; ++b) row.push_back(b.col());
    std::sort(row.begin(), row.end());
    row.erase(std::unique(row.begin(), row.end()), row.end());
  }
  omega4_ = patternMatrix(n, columns);
  h_ = hPrime_ = hSecond_ = x_ = xPrime_ = omega4_;
  for (Index i = 0; i < n; ++i) computeRow(system, i);
}

void TransformationMatrices::updateVertices(const SystemMatrices& system,
                                            std::span<const Index> changedVertices) {
  // Row i of Omega^4 = sum_j Omega^2_ij Omega^2_j. depends on rows i and j in its one-ring.
  const SparseRowMatrix& o2 = system.omega2();
  std::vector<Index> rows;
  for (Index v : changedVertices)
    for (SparseRowMatrix::InnerIterator it(o2, v); it; ++it) rows.push_back(it.col());
  std::sort(rows.begin(), rows.end());
  rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
  for (Index i : rows) computeRow(system, i);
}

void TransformationMatrices::computeRow(const SystemMatrices& system, Index i) {
  const SparseRowMatrix& o2 = system.omega2();
  const Index begin = omega4_.outerIndexPtr()[i];
  const Index end = omega4_.outerIndexPtr()[i + 1];
  double* o4 = omega4_.valuePtr();
  std::fill(o4 + begin, o4 + end, 0.0);
  for (SparseRowMatrix::InnerIterator a(o2, i); a; ++a)
    for (SparseRowMatrix::InnerIterator b(o2, a.col()); b; ++b)
      o4[findInRow(omega4_, i, b.col())] += a.value() * b.value();

  const double t = period_, t2 = t * t, t3 = t2 * t, t4 = t2 * t2, t5 = t4 * t, t6 = t4 * t2;
  const double g = system.dampingCoefficient()[i];
  SparseRowMatrix::InnerIterator a(o2, i);
  for (Index p = begin; p < end; ++p) {
    const Index col = omega4_.innerIndexPtr()[p];
    while (a && a.col() < col) ++a;
    const double w2 = (a && a.col() == col) ? a.value() : 0.0;
    const double w4 = o4[p];
    const double delta = (col == i) ? 1.0 : 0.0;
    // Section 4.1: H = Omega^-2 (1 - cos Omega T), H' = Omega^-1 sin Omega T,
    // H'' = cos Omega T, each truncated after Omega^4.
    const double h = t2 / 2.0 * delta - t4 / 24.0 * w2 + t6 / 720.0 * w4;
    const double hp = t * delta - t3 / 6.0 * w2 + t5 / 120.0 * w4;
    const double hpp = delta - t2 / 2.0 * w2 + t4 / 24.0 * w4;
    h_.valuePtr()[p] = h;
    hPrime_.valuePtr()[p] = hp;
    hSecond_.valuePtr()[p] = hpp;
    x_.valuePtr()[p] = hp - g * h;
    xPrime_.valuePtr()[p] = hpp - g * hp;
  }
}

double maxAbsDifference(const SparseRowMatrix& a, const SparseRowMatrix& b) {
  ZSCULPT_ASSERT(a.rows() == b.rows() && a.cols() == b.cols(), "matrix sizes differ");
  const SparseRowMatrix d = a - b;
  double largest = 0.0;
  for (Index k = 0; k < d.nonZeros(); ++k)
    largest = std::max(largest, std::abs(d.valuePtr()[k]));
  return largest;
}

}  // namespace zsculpt
