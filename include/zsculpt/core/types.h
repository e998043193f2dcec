#pragma once
// Basic numeric types shared by every module.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <span>
#include <vector>

namespace zsculpt {

using Index = std::int32_t;

/// N x 3 row-major array of points or vectors: one row per vertex, x y z contiguous.
/// This is the paper's N x 3 state vector layout (section 4.1).
using Points = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using VectorX = Eigen::VectorXd;

/// Compressed rows: row i is indices[offsets[i] .. offsets[i+1]).
struct CsrIndex {
  std::vector<Index> offsets{0};
  std::vector<Index> indices;

  [[nodiscard]] Index rows() const { return static_cast<Index>(offsets.size()) - 1; }
  [[nodiscard]] std::span<const Index> row(Index i) const {
    return {indices.data() + offsets[i], static_cast<size_t>(offsets[i + 1] - offsets[i])};
  }
  [[nodiscard]] Index rowSize(Index i) const { return offsets[i + 1] - offsets[i]; }
};

}  // namespace zsculpt
