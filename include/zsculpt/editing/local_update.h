#pragma once
// Local update of the solver's matrices after an edit (paper section 3: "the matrices are
// updated in O(k^2) time, where k is the average valence"), the incremental critical
// period, and the check against a full rebuild.
//
// Locality: which rows of K, Omega^2 = M^-1 K, M^-1 and G = D M^-1 / 2 an edit changes.
//
//   mass mu_v          row v: M^-1_v, G_v and Omega^2's row v (K / mu_v); K unchanged
//   damping rho_v      row v: G_v only
//   stiffness kappa_v  v and its one-ring: kappa_vj (harmonic mean of the ends, capped)
//                      changes for every edge at v, i.e. K_vj, K_jv, K_vv and K_jj
//   angular kappa_th_v v and its one-ring: the angle springs centred at v add
//                      2 kappa_theta_v / d^2 to each edge at v (matrices.h)
//   rest_length l_e    rows i and j of edge e = (i, j): the angle springs' bound on e
//                      uses the shorter of the loaded and the rest length (matrices.h)
//   rigidity, rest_angle   no row: the matrices see neither (they enter the forces only)
//
// SystemMatrices::updateVertices recomputes those rows, O(k) each. Row i of Omega^4, H,
// H', H'', X, X' depends on Omega^2's rows i and j for j in the one-ring of i (Omega^4 =
// Omega^2 Omega^2) and on G_i, so TransformationMatrices::updateVertices recomputes the
// one-ring of the changed rows, O(k^2) each: in all O(k^2) per touched vertex, whatever
// the mesh size. Both recompute a row with the routine the full build uses, so the result
// equals a full rebuild bit for bit.

#include <optional>
#include <span>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/physics/properties.h"

namespace zsculpt::editing {

/// True for mass, damping, stiffness, angular stiffness and rest length.
bool propertyChangesMatrices(Property property);

/// Appends (unsorted, possibly repeated) the rows whose values depend on `property` at
/// these elements, by the table above.
void appendAffectedRows(const Mesh& mesh, Property property, std::span<const Index> elements,
                        std::vector<Index>& rows);

/// Equation 5's critical period T_max = sqrt(6 / max_i (Omega^2)_ii), kept up to date
/// under local edits: a max segment tree over the diagonal, O(log N) per changed row.
/// Equals criticalPeriod(system) exactly (a maximum has no rounding).
class CriticalPeriodTracker {
 public:
  CriticalPeriodTracker() = default;
  explicit CriticalPeriodTracker(const SystemMatrices& system);

  /// Re-reads the diagonal entries of these rows.
  void update(const SystemMatrices& system, std::span<const Index> rows);
  /// max_i (Omega^2)_ii.
  [[nodiscard]] double maxDiagonal() const { return tree_.size() > 1 ? tree_[1] : 0.0; }
  /// The vertex whose row sets T_max (the first one on ties).
  [[nodiscard]] Index limitingVertex() const;
  /// T_max of equation 5 (infinite without stiffness).
  [[nodiscard]] double period() const;

 private:
  Index leaves_ = 0;
  std::vector<double> tree_;  // tree_[leaves_ + i] = (Omega^2)_ii; tree_[k] = max of children
};

/// The matrices a solver keeps for a model (SystemMatrices, optionally the transformation
/// matrices of equation 3, the critical period), updated locally after edits.
class LocalMatrices {
 public:
  /// `transformationPeriod`: also keep H .. X' for this period (the paper scheme).
  LocalMatrices(const Model& model, std::optional<double> transformationPeriod);

  /// Recomputes the rows an edit changed (EditResult::matrixRows).
  void update(const Model& model, std::span<const Index> rows);
  /// Full rebuild.
  void rebuild(const Model& model);

  [[nodiscard]] const SystemMatrices& system() const { return system_; }
  /// Null unless a period was given.
  [[nodiscard]] const TransformationMatrices* transformation() const {
    return transformation_ ? &*transformation_ : nullptr;
  }
  [[nodiscard]] const CriticalPeriodTracker& critical() const { return critical_; }
  [[nodiscard]] double criticalPeriod() const { return critical_.period(); }

 private:
  SystemMatrices system_;
  std::optional<TransformationMatrices> transformation_;
  CriticalPeriodTracker critical_;
};

/// Largest absolute differences between locally updated matrices and a full rebuild.
struct MatrixVerification {
  double system = 0.0;          // K, Omega^2, M^-1, G
  double transformation = 0.0;  // Omega^4, H, H', H'', X, X' (0 when not kept)
  double criticalPeriod = 0.0;  // |tracked T_max - full T_max| (0 when no tracker)
  [[nodiscard]] double maxAbs() const;
};

/// Rebuilds every matrix from `model` and compares. O(N k^2): for tests and
/// --verify-matrices, not for interactive use.
MatrixVerification verifyAgainstRebuild(const Model& model, const SystemMatrices& system,
                                        const TransformationMatrices* transformation = nullptr,
                                        const CriticalPeriodTracker* critical = nullptr);

}  // namespace zsculpt::editing
