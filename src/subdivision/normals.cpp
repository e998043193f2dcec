// Vertex normals by a best-plane (least-squares) fit of the one-ring (paper section 3:
// "The normal to the surface is computed through a best-plane fit of the neighboring
// vertices"): the eigenvector of the smallest eigenvalue of the points' 3x3 covariance.

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "zsculpt/core/errors.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt {

namespace {

/// Eigenvector of the smallest eigenvalue of a symmetric positive semi-definite 3x3
/// matrix, or zero when the points were (nearly) collinear and no plane is defined.
/// The smallest eigenvalue l0 is the smallest root of the characteristic cubic
/// q(l) = l^3 - T l^2 + M l - D; q is increasing and concave on [0, l0], so Newton's
/// method from 0 climbs to it monotonically (in a few steps when l0 << l1, as on any
/// smooth surface). The eigenvector is then the largest cross product of two rows of
/// C - l0 I. Several times faster than the closed-form solver (acos, cos, sin), which
/// remains the fallback for nearly equal l0, l1.
Vec3 smallestEigenvector(const Mat3& c) {
  const double a = c(0, 0), b = c(0, 1), d = c(0, 2), e = c(1, 1), f = c(1, 2), g = c(2, 2);
  const double trace = a + e + g;
  const double minors = (a * e - b * b) + (a * g - d * d) + (e * g - f * f);  // M
  if (!(minors > 1e-18 * trace * trace)) return Vec3::Zero();  // rank <= 1: collinear
  const double det = a * (e * g - f * f) - b * (b * g - f * d) + d * (b * f - e * d);
  double lambda = 0.0;
  bool converged = false;
  for (int iteration = 0; iteration < 32; ++iteration) {
    const double q = ((lambda - trace) * lambda + minors) * lambda - det;
    const double slope = (3.0 * lambda - 2.0 * trace) * lambda + minors;
    if (q >= 0.0 || !(slope > 0.0)) {
      converged = true;  // at the root (to rounding), or past the concave range
      break;
    }
    const double step = -q / slope;
    lambda += step;
    if (step <= 1e-15 * trace) {
      converged = true;
      break;
    }
  }
  if (converged) {
    const Vec3 r0(a - lambda, b, d), r1(b, e - lambda, f), r2(d, f, g - lambda);
    const Vec3 c01 = r0.cross(r1), c02 = r0.cross(r2), c12 = r1.cross(r2);
    const double n01 = c01.squaredNorm(), n02 = c02.squaredNorm(), n12 = c12.squaredNorm();
    const double best = std::max({n01, n02, n12});
    // Well separated when the cross product is not lost to rounding (|r x r| ~ l1 l2).
    if (best > 1e-16 * minors * minors) {
      const Vec3& v = best == n01 ? c01 : (best == n02 ? c02 : c12);
      return v / std::sqrt(best);
    }
  }
  Eigen::SelfAdjointEigenSolver<Mat3> solver;
  solver.computeDirect(c);
  const Vec3 values = solver.eigenvalues();  // ascending
  if (!(values[1] - values[0] > 1e-9 * std::max(values[2], 1e-300))) return Vec3::Zero();
  return solver.eigenvectors().col(0);
}

}  // namespace

void bestPlaneNormals(const CsrIndex& faces, const CsrIndex& vertexNeighbors,
                      const Points& positions, Points& normals) {
  const Index n = static_cast<Index>(positions.rows());
  ZSCULPT_ASSERT(normals.rows() == n, "bestPlaneNormals: normals must have one row per vertex");
  ZSCULPT_ASSERT(vertexNeighbors.rows() == n,
                 "bestPlaneNormals: neighbour table must have one row per vertex");

  // First pass: `normals` accumulates each vertex's area-weighted face normal (Newell's
  // vector area), which fixes the sign of the fitted plane's normal (the least-squares
  // plane has no orientation of its own).
  normals.setZero();
  for (Index f = 0; f < faces.rows(); ++f) {
    const auto corners = faces.row(f);
    Vec3 area = Vec3::Zero();
    for (size_t k = 0; k < corners.size(); ++k) {
      const Vec3 a = positions.row(corners[k]).transpose();
      const Vec3 b = positions.row(corners[(k + 1) % corners.size()]).transpose();
      area += a.cross(b);
    }
    for (Index v : corners) normals.row(v) += area.transpose();
  }

  for (Index v = 0; v < n; ++v) {
    const Vec3 reference = normals.row(v).transpose();
    const auto ring = vertexNeighbors.row(v);
    const Vec3 p = positions.row(v).transpose();
    Vec3 normal = Vec3::Zero();
    if (ring.size() >= 2) {
      // Covariance of the vertex and its neighbours about their mean, scaled to unit size.
      Vec3 mean = p;
      for (Index w : ring) mean += positions.row(w).transpose();
      mean /= static_cast<double>(ring.size() + 1);
      double scale = (p - mean).squaredNorm();
      for (Index w : ring)
        scale = std::max(scale, (positions.row(w).transpose() - mean).squaredNorm());
      if (scale > 0.0) {
        const double inv = 1.0 / std::sqrt(scale);
        Mat3 covariance = ((p - mean) * inv) * ((p - mean) * inv).transpose();
        for (Index w : ring) {
          const Vec3 d = (positions.row(w).transpose() - mean) * inv;
          covariance.noalias() += d * d.transpose();
        }
        normal = smallestEigenvector(covariance);
      }
    }
    if (normal.squaredNorm() == 0.0) normal = reference;
    if (normal.squaredNorm() == 0.0) normal = Vec3::UnitZ();  // no plane, no face
    if (reference.squaredNorm() > 0.0) {
      if (normal.dot(reference) < 0.0) normal = -normal;
    } else {
      // A curve: no winding, so a deterministic sign (largest component positive).
      Index k = 0;
      normal.cwiseAbs().maxCoeff(&k);
      if (normal[k] < 0.0) normal = -normal;
    }
    normals.row(v) = normal.normalized().transpose();
  }
}

}  // namespace zsculpt
