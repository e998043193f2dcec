#include "zsculpt/physics/matrices.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "zsculpt/core/errors.h"

#ifdef _OPENMP
#include <omp.h>
#endif

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

Index csrPosition(const SparseRowMatrix& m, Index row, Index col) {
  const Index* begin = m.innerIndexPtr() + m.outerIndexPtr()[row];
  const Index* end = m.innerIndexPtr() + m.outerIndexPtr()[row + 1];
  const Index* it = std::lower_bound(begin, end, col);
  return (it != end && *it == col) ? static_cast<Index>(it - m.innerIndexPtr()) : -1;
}

double csrEntry(const SparseRowMatrix& m, Index row, Index col) {
  const Index position = csrPosition(m, row, col);
  return position >= 0 ? m.valuePtr()[position] : 0.0;
}

double matrixEdgeStiffness(const Model& model, Index edge) {
  const auto [i, j] = model.mesh.edge(edge);
  const PhysicalProperties& p = model.properties;
  double kappa = edgeStiffness(cappedStiffness(p.stiffness[i], p.stiffnessCap),
                               cappedStiffness(p.stiffness[j], p.stiffnessCap));
  // The angle springs' bound 2 kappa_theta / l^2 grows as the arm shortens. The model rests
  // at its rest lengths, not at the lengths it was loaded with: where a rest length is the
  // shorter (--rest-length-scale 0.5, a painted rest length), the loaded length understated
  // the stiffness and T_max (a grid at half its rest lengths: Hessian 1183 against 1040).
  const auto& x = model.mesh.positions();
  const double loaded2 = (x.row(i) - x.row(j)).squaredNorm();
  const double rest = model.properties.restLength[edge];
  // Lengths compared, not squares: an unscaled rest length is the loaded length's square
  // root, and its square may differ from loaded2 in the last bit.
  const double length2 = rest > 0.0 && rest < std::sqrt(loaded2) ? rest * rest : loaded2;
  // (A spring without stiffness adds nothing: skipped, as 0 / 0 where a rest length of
  // 1e-170 squares to 0 made the stiffness NaN and T_max "inf".)
  for (Index angle : model.angles.edgeAngles.row(edge)) {
    const Index centre = model.angles.angles[angle][0];
    if (p.angularStiffness[centre] != 0.0) kappa += 2.0 * p.angularStiffness[centre] / length2;
  }
  return kappa;
}

namespace {

int threadCount(Index rows) {
#ifdef _OPENMP
  return rows >= 20000 ? omp_get_max_threads() : 1;
#else
  (void)rows;
  return 1;
#endif
}

// A compressed N x N matrix with the given row sizes, pattern and values to be filled.
void allocateCsr(SparseRowMatrix& m, Index n, const std::vector<Index>& outer) {
  m.resize(n, n);
  m.resizeNonZeros(outer[static_cast<size_t>(n)]);
  std::copy(outer.begin(), outer.end(), m.outerIndexPtr());
}

}  // namespace

SystemMatrices::SystemMatrices(const Model& model) {
  // Built directly in CSR form, rows in parallel (a row depends on nothing but the model),
  // with the same arithmetic as computeRow, so a local update still equals a full rebuild
  // bit for bit.
  const Mesh& mesh = model.mesh;
  const Index n = mesh.numVertices();
  const PhysicalProperties& p = model.properties;
  const Index* off = mesh.vertexNeighborTable().offsets.data();
  const Index* nbr = mesh.vertexNeighborTable().indices.data();
  const Index* edges = mesh.vertexEdgeTable().indices.data();
  std::vector<Index> outer(static_cast<size_t>(n) + 1);
  for (Index v = 0; v <= n; ++v) outer[static_cast<size_t>(v)] = off[v] + v;
  allocateCsr(k_, n, outer);
  allocateCsr(omega2_, n, outer);
  inverseMass_.resize(n);
  g_.resize(n);
  VectorX edgeKappa(mesh.numEdges());
  const int threads = threadCount(n);
  (void)threads;
#pragma omp parallel num_threads(threads) if (threads > 1)
  {
#pragma omp for schedule(static)
    for (Index e = 0; e < mesh.numEdges(); ++e) edgeKappa[e] = matrixEdgeStiffness(model, e);
    std::vector<std::pair<Index, Index>> row;  // (column, position in the mesh's order)
#pragma omp for schedule(static)
    for (Index v = 0; v < n; ++v) {
      inverseMass_[v] = 1.0 / p.mass[v];
      g_[v] = 0.5 * p.damping[v] * inverseMass_[v];
      row.clear();
      for (Index h = off[v]; h < off[v + 1]; ++h) row.emplace_back(nbr[h], h - off[v]);
      row.emplace_back(v, -1);
      std::sort(row.begin(), row.end());
      const Index begin = outer[static_cast<size_t>(v)];
      Index* inner = k_.innerIndexPtr() + begin;
      double* kValues = k_.valuePtr() + begin;
      double* oValues = omega2_.valuePtr() + begin;
      double diagonal = 0.0;
      for (Index h = off[v]; h < off[v + 1]; ++h) diagonal += edgeKappa[edges[h]];
      for (size_t q = 0; q < row.size(); ++q) {
        inner[q] = row[q].first;
        const double value =
            row[q].second < 0 ? diagonal : -edgeKappa[edges[off[v] + row[q].second]];
        kValues[q] = value;
        oValues[q] = value * inverseMass_[v];
      }
      std::copy(inner, inner + row.size(), omega2_.innerIndexPtr() + begin);
    }
  }
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
    const Index pos = csrPosition(k_, v, neighbors[q]);
    kValues[pos] = -kappa;
    oValues[pos] = -kappa * inverseMass_[v];
    diagonal += kappa;
  }
  const Index pos = csrPosition(k_, v, v);
  kValues[pos] = diagonal;
  oValues[pos] = diagonal * inverseMass_[v];
}

double SystemMatrices::gamma() const {
  return g_.size() ? g_.minCoeff() : 0.0;
}

double criticalPeriod(const SystemMatrices& matrices) {
  const VectorX diagonal = matrices.omega2().diagonal();
  const double largest = diagonal.size() ? diagonal.maxCoeff() : 0.0;
  if (!(largest > 0.0)) return std::numeric_limits<double>::infinity();
  return std::sqrt(6.0 / largest);
}

namespace {

// The largest eigenvalue of the symmetric tridiagonal matrix with diagonal alpha and
// subdiagonal beta, by bisection on Sturm counts (Wilkinson): O(k) an evaluation, where a
// full tridiagonal eigensolve is O(k^2) and, checked every tenth of the steps, made a long
// chain's Lanczos (20,000 steps) take minutes in its checks alone. Backward stable: the
// value is within a few ulps of ||T|| of the exact one.
double largestTridiagonalEigenvalue(const std::vector<double>& alpha,
                                    const std::vector<double>& beta) {
  const size_t k = alpha.size();
  double low = std::numeric_limits<double>::infinity();
  double high = -low;
  for (size_t i = 0; i < k; ++i) {
    const double radius =
        (i > 0 ? std::abs(beta[i - 1]) : 0.0) + (i + 1 < k ? std::abs(beta[i]) : 0.0);
    low = std::min(low, alpha[i] - radius);
    high = std::max(high, alpha[i] + radius);
  }
  const double norm = std::max(std::abs(low), std::abs(high));
  const double tiny = std::numeric_limits<double>::min() / std::numeric_limits<double>::epsilon();
  // Whether T - x I has a negative pivot in every row, i.e. all k eigenvalues are below x.
  auto allBelow = [&](double x) {
    Index negative = 0;
    double pivot = 1.0;
    for (size_t i = 0; i < k; ++i) {
      pivot = (alpha[i] - x) - (i > 0 ? beta[i - 1] * beta[i - 1] / pivot : 0.0);
      if (pivot == 0.0) pivot = -tiny;  // a zero pivot counts as just below x
      negative += pivot < 0.0;
    }
    return negative == static_cast<Index>(k);
  };
  while (high - low > 4.0 * std::numeric_limits<double>::epsilon() * norm) {
    const double middle = 0.5 * (low + high);
    if (middle <= low || middle >= high) break;
    (allBelow(middle) ? high : low) = middle;
  }
  return 0.5 * (low + high);
}

}  // namespace

double largestEigenvalue(const SystemMatrices& matrices) {
  const Index n = static_cast<Index>(matrices.stiffness().rows());
  const VectorX scale = matrices.inverseMass().cwiseSqrt();
  if (n <= 600) {
    const Eigen::MatrixXd dense =
        scale.asDiagonal() * Eigen::MatrixXd(matrices.stiffness()) * scale.asDiagonal();
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(dense, Eigen::EigenvaluesOnly);
    return eig.eigenvalues().maxCoeff();
  }
  // Lanczos on the symmetric form A = S K S (S = M^-1/2), without restarts or
  // reorthogonalisation: the largest Ritz value of the tridiagonal T_k rises to lambda_0
  // from below, and loss of orthogonality only makes copies of converged values, never one
  // above it. Stiffness matrices of fine meshes crowd their top eigenvalues together;
  // a restarted solver with a small basis (Spectra's, before) spent minutes on a 1M-vertex
  // torus refining eigenvectors there, where only the value is wanted. Stop when the value
  // has settled to 1e-13 between two checks; checks come every tenth of the steps so far
  // (at least 10). A step is two passes over the rows: y = A v - beta u with y . v, then
  // w = y - alpha v with |w|^2 (its memory traffic is what a step costs at scale: A's
  // values are scaled once, and the sums are taken in fixed blocks, in block order, so the
  // value does not depend on the thread count).
  const SparseRowMatrix& k = matrices.stiffness();
  const Index* outer = k.outerIndexPtr();
  const Index* inner = k.innerIndexPtr();
  const double* kValues = k.valuePtr();
  std::vector<double> a(static_cast<size_t>(k.nonZeros()));
  std::vector<double> v(static_cast<size_t>(n)), u(static_cast<size_t>(n), 0.0),
      w(static_cast<size_t>(n));
  constexpr Index kBlock = 4096;
  const Index blocks = (n + kBlock - 1) / kBlock;
  std::vector<double> partial(static_cast<size_t>(blocks));
  auto blockSum = [&] {
    double sum = 0.0;
    for (double p : partial) sum += p;
    return sum;
  };
  const int threads = threadCount(n);
  (void)threads;
#pragma omp parallel for schedule(static) num_threads(threads) if (threads > 1)
  for (Index i = 0; i < n; ++i)
    for (Index p = outer[i]; p < outer[i + 1]; ++p)
      a[static_cast<size_t>(p)] = scale[i] * kValues[p] * scale[inner[p]];
  // A fixed pseudo-random start (reproducible), with a component on every mode.
  std::uint64_t seed = 0x9E3779B97F4A7C15ull;
  double norm2 = 0.0;
  for (double& x : v) {
    seed = seed * 6364136223846793005ull + 1442695040888963407ull;
    x = static_cast<double>(seed >> 11) * 0x1.0p-53 - 0.5;
    norm2 += x * x;
  }
  for (double& x : v) x /= std::sqrt(norm2);
  constexpr int kMaxSteps = 20000;
  int nextCheck = 10;
  std::vector<double> alpha, beta;  // T_k's diagonal and subdiagonal
  double last = 0.0;
  for (int step = 0; step < kMaxSteps; ++step) {
    const double b0 = step > 0 ? beta.back() : 0.0;
#pragma omp parallel for schedule(static) num_threads(threads) if (threads > 1)
    for (Index block = 0; block < blocks; ++block) {
      double dot = 0.0;
      for (Index i = block * kBlock; i < std::min(n, (block + 1) * kBlock); ++i) {
        double y = 0.0;
        for (Index p = outer[i]; p < outer[i + 1]; ++p)
          y += a[static_cast<size_t>(p)] * v[static_cast<size_t>(inner[p])];
        y -= b0 * u[static_cast<size_t>(i)];
        w[static_cast<size_t>(i)] = y;
        dot += y * v[static_cast<size_t>(i)];
      }
      partial[static_cast<size_t>(block)] = dot;
    }
    alpha.push_back(blockSum());
    const double a0 = alpha.back();
#pragma omp parallel for schedule(static) num_threads(threads) if (threads > 1)
    for (Index block = 0; block < blocks; ++block) {
      double sum2 = 0.0;
      for (Index i = block * kBlock; i < std::min(n, (block + 1) * kBlock); ++i) {
        const double x = w[static_cast<size_t>(i)] - a0 * v[static_cast<size_t>(i)];
        w[static_cast<size_t>(i)] = x;
        sum2 += x * x;
      }
      partial[static_cast<size_t>(block)] = sum2;
    }
    const double b = std::sqrt(blockSum());
    if (step + 1 == nextCheck || !(b > 0.0)) {
      nextCheck = step + 1 + std::max(10, (step + 1) / 10);
      const double value = largestTridiagonalEigenvalue(alpha, beta);
      // An exhausted Krylov space (b = 0) holds lambda_0 exactly.
      if (!(b > 1e-14 * std::abs(value))) return value;
      if (value - last <= 1e-13 * std::abs(value)) return value;
      last = value;
    }
    beta.push_back(b);
    // The next basis vector w / b into v, the current one into u.
    u.swap(v);
    v.swap(w);
    const double inverse = 1.0 / b;
#pragma omp parallel for schedule(static) num_threads(threads) if (threads > 1)
    for (Index i = 0; i < n; ++i) v[static_cast<size_t>(i)] *= inverse;
  }
  // Not settled: the Gerschgorin bound of equation 5, never below lambda_0.
  return 2.0 * matrices.omega2().diagonal().maxCoeff();
}

double tightCriticalPeriod(const SystemMatrices& matrices) {
  const double lambda = largestEigenvalue(matrices);
  if (!(lambda > 0.0)) return std::numeric_limits<double>::infinity();
  return std::sqrt(12.0 / lambda);
}

TransformationMatrices::TransformationMatrices(const SystemMatrices& system, double period)
    : period_(period) {
  // The two-ring pattern of Omega^4, rows in parallel: a stamp per column marks what a row
  // has already collected.
  const SparseRowMatrix& o2 = system.omega2();
  const Index n = static_cast<Index>(o2.rows());
  const Index* outer2 = o2.outerIndexPtr();
  const Index* inner2 = o2.innerIndexPtr();
  std::vector<Index> outer(static_cast<size_t>(n) + 1, 0);
  const int threads = threadCount(n);
  (void)threads;
  auto collect = [&](Index i, std::vector<Index>& stamp, std::vector<Index>& row) {
    row.clear();
    for (Index p = outer2[i]; p < outer2[i + 1]; ++p) {
      const Index a = inner2[p];
      for (Index q = outer2[a]; q < outer2[a + 1]; ++q) {
        const Index b = inner2[q];
        if (stamp[static_cast<size_t>(b)] != i) {
          stamp[static_cast<size_t>(b)] = i;
          row.push_back(b);
        }
      }
    }
    std::sort(row.begin(), row.end());
  };
#pragma omp parallel num_threads(threads) if (threads > 1)
  {
    std::vector<Index> stamp(static_cast<size_t>(n), -1), row;
#pragma omp for schedule(static)
    for (Index i = 0; i < n; ++i) {
      collect(i, stamp, row);
      outer[static_cast<size_t>(i) + 1] = static_cast<Index>(row.size());
    }
#pragma omp single
    {
      for (Index i = 0; i < n; ++i)
        outer[static_cast<size_t>(i) + 1] += outer[static_cast<size_t>(i)];
      allocateCsr(omega4_, n, outer);
    }
    std::fill(stamp.begin(), stamp.end(), -1);
#pragma omp for schedule(static)
    for (Index i = 0; i < n; ++i) {
      collect(i, stamp, row);
      std::copy(row.begin(), row.end(), omega4_.innerIndexPtr() + outer[static_cast<size_t>(i)]);
    }
  }
  h_ = hPrime_ = hSecond_ = x_ = xPrime_ = omega4_;
#pragma omp parallel num_threads(threads) if (threads > 1)
  {
    std::vector<Index> position(static_cast<size_t>(n), -1);
#pragma omp for schedule(static)
    for (Index i = 0; i < n; ++i) computeRow(system, i, position.data());
  }
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
  for (Index i : rows) computeRow(system, i, nullptr);
}

void TransformationMatrices::computeRow(const SystemMatrices& system, Index i, Index* position) {
  const SparseRowMatrix& o2 = system.omega2();
  const Index begin = omega4_.outerIndexPtr()[i];
  const Index end = omega4_.outerIndexPtr()[i + 1];
  double* o4 = omega4_.valuePtr();
  std::fill(o4 + begin, o4 + end, 0.0);
  // Omega^4_i. = sum_a Omega^2_ia Omega^2_a., summed in this loop order whether the column's
  // place is found by a lookup table (full build) or a search (local update): same bits.
  if (position)
    for (Index p = begin; p < end; ++p) position[omega4_.innerIndexPtr()[p]] = p;
  for (SparseRowMatrix::InnerIterator a(o2, i); a; ++a)
    for (SparseRowMatrix::InnerIterator b(o2, a.col()); b; ++b)
      o4[position ? position[b.col()] : csrPosition(omega4_, i, b.col())] += a.value() * b.value();

  const double t = period_, t2 = t * t, t3 = t2 * t, t4 = t2 * t2, t5 = t4 * t;
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
    const double h = truncatedH(t, delta, w2, w4);
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
  for (Index k = 0; k < d.nonZeros(); ++k) largest = std::max(largest, std::abs(d.valuePtr()[k]));
  return largest;
}

}  // namespace zsculpt
