#pragma once
// The matrices of section 4.1: M and D (diagonal), the stiffness Laplacian K, the angular
// frequency matrix Omega^2 = M^-1 K, the damping coefficient G = D M^-1 / 2, and the
// transformation matrices H, H', H'' (Taylor-truncated after Omega^4) with X = H' - G H,
// X' = H'' - G H'. All sparse, CSR (Eigen row-major), on the N x N vertex graph: the same
// matrix acts on each of the three coordinate columns of the N x 3 state.
//
// K includes the angle springs through a bound: the rest Hessian of an angle spring
// kappa_theta/2 (theta - theta_0)^2 is kappa_theta grad(theta) grad(theta)^T, and by
// Cauchy-Schwarz it is at most the Laplacian of two edge springs of stiffness
// 2 kappa_theta / d^2 along its arms (d the arm's length in the mesh as loaded). Adding
// them keeps K a symmetric graph Laplacian whose largest eigenvalue bounds the true
// stiffness, so equation 5's period is honest for models with angle springs too. With no
// angle springs K is exactly the paper's.
//
// The sparsity pattern depends only on the topology, so a property edit (dynamic editing,
// section 3) recomputes values of the rows it touches in place; the full build runs the
// same row routine over every row, so a local update equals a full rebuild bit for bit.

#include <Eigen/SparseCore>
#include <span>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/physics/properties.h"

namespace zsculpt {

using SparseRowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, Index>;

/// out = A * in for an N x N CSR matrix and N x 3 points, no allocation.
void multiply(const SparseRowMatrix& a, const Points& in, Points& out);
/// out.row(i) = (A * in).row(i) for the listed rows only.
void multiplyRows(const SparseRowMatrix& a, const Points& in, Points& out,
                  std::span<const Index> rows);

/// Where entry (row, col) of a compressed row-major matrix is in its values; -1 outside its
/// pattern.
Index csrPosition(const SparseRowMatrix& m, Index row, Index col);
/// Entry (row, col) of a compressed row-major matrix, 0 outside its pattern.
double csrEntry(const SparseRowMatrix& m, Index row, Index col);

/// Section 4.1's H = Omega^-2 (1 - cos Omega T) truncated after Omega^4 (equation 3), entry
/// (j, l) from delta_jl and the entries of Omega^2 and Omega^4: the one place its
/// coefficients are written (TransformationMatrices, and the position response of the
/// paper's and the exact scheme, Stepper::positionResponse).
inline double truncatedH(double t, double delta, double omega2, double omega4) {
  const double t2 = t * t, t4 = t2 * t2, t6 = t4 * t2;
  return t2 / 2.0 * delta - t4 / 24.0 * omega2 + t6 / 720.0 * omega4;
}

/// Stiffness of edge e as the matrices see it: the radial kappa_ij of the capped vertex
/// stiffnesses plus the angle-spring bound 2 kappa_theta / l^2 of every angle that uses e as
/// an arm, l the shorter of e's loaded and rest length.
double matrixEdgeStiffness(const Model& model, Index edge);

/// M, D, K, Omega^2, G for a model.
class SystemMatrices {
 public:
  SystemMatrices() = default;
  explicit SystemMatrices(const Model& model);

  /// Recomputes the rows of K and Omega^2 for the given vertices and the G and M^-1
  /// entries (after an edit of their properties or of properties of their edges/angles).
  /// `vertices` must contain every vertex whose row changed (both ends of an edited edge).
  void updateVertices(const Model& model, std::span<const Index> vertices);

  [[nodiscard]] const SparseRowMatrix& stiffness() const { return k_; }
  [[nodiscard]] const SparseRowMatrix& omega2() const { return omega2_; }
  [[nodiscard]] const VectorX& inverseMass() const { return inverseMass_; }
  /// G = D M^-1 / 2 (diagonal), per vertex.
  [[nodiscard]] const VectorX& dampingCoefficient() const { return g_; }
  /// The paper's gamma: the smallest diagonal entry of G.
  [[nodiscard]] double gamma() const;

 private:
  void computeRow(const Model& model, Index v);

  SparseRowMatrix k_;
  SparseRowMatrix omega2_;
  VectorX inverseMass_;
  VectorX g_;
};

/// Equation 5: T_max = sqrt(12 / lambda_+), lambda_+ = 2 max_i (Omega^2)_ii (Gerschgorin),
/// i.e. sqrt(6 / max_i K_ii / mu_i). Infinite when there is no stiffness.
double criticalPeriod(const SystemMatrices& matrices);
/// The largest eigenvalue lambda_0 of Omega^2 (symmetric form M^-1/2 K M^-1/2): dense for
/// small models, a Lanczos iteration of our own otherwise (matrices.cpp).
double largestEigenvalue(const SystemMatrices& matrices);
/// sqrt(12 / lambda_0): where (omega_max T)^2 = 12, the linear stability limit of equation
/// 3's Taylor-truncated cosine and of the default scheme.
double tightCriticalPeriod(const SystemMatrices& matrices);

/// H, H', H'', X, X' of equation 3 for a period T, stored on the two-ring pattern of
/// Omega^4. Built in O(N k^2) by rows; rows can be recomputed locally after an edit.
class TransformationMatrices {
 public:
  TransformationMatrices() = default;
  TransformationMatrices(const SystemMatrices& system, double period);

  /// Recomputes the rows of Omega^4 and of H .. X' that depend on the rows of Omega^2 (or
  /// on G) at `changedVertices`: those vertices and their one-ring.
  void updateVertices(const SystemMatrices& system, std::span<const Index> changedVertices);

  [[nodiscard]] double period() const { return period_; }
  [[nodiscard]] const SparseRowMatrix& omega4() const { return omega4_; }
  [[nodiscard]] const SparseRowMatrix& h() const { return h_; }
  [[nodiscard]] const SparseRowMatrix& hPrime() const { return hPrime_; }
  [[nodiscard]] const SparseRowMatrix& hSecond() const { return hSecond_; }
  [[nodiscard]] const SparseRowMatrix& x() const { return x_; }
  [[nodiscard]] const SparseRowMatrix& xPrime() const { return xPrime_; }

 private:
  // `position` (optional, N entries): scratch for the column -> entry lookup of a full build.
  void computeRow(const SystemMatrices& system, Index row, Index* position);

  double period_ = 0.0;
  SparseRowMatrix omega4_, h_, hPrime_, hSecond_, x_, xPrime_;
};

/// Largest absolute difference between two matrices of the same size (patterns may differ).
double maxAbsDifference(const SparseRowMatrix& a, const SparseRowMatrix& b);

}  // namespace zsculpt
