#pragma once
// Dynamic editing (paper section 3 and section 6): edit commands, their application to a
// model's physical properties, undo and redo, and the energy an edit stores.
//
// The editor changes property values only. It returns which rows of the solver's matrices
// depend on what changed (EditResult::matrixRows, see local_update.h for the locality
// rules); the caller passes them on:
//
//   Simulation:  sim.propertiesChanged(result.matrixRows)
//   Stepper:     stepper.propertiesChanged(result.matrixRows)
//   matrices:    LocalMatrices::update(model, result.matrixRows)
//
// after every edit that changed something, even when matrixRows is empty (a rest-angle
// edit changes no matrix but does change the forces a stepper may have cached).
//
// Undo and redo: each edit stores the old and new values of exactly the entries it
// changed; undo writes the old values back bit for bit, so recomputing the same rows from
// the same values gives matrices equal to those before the edit bit for bit.
//
// Energy honesty: every edit reports the energy it stored at the state it was applied to
// (potential after minus before; kinetic after minus before for a mass edit, velocities
// being kept). The sums run over the springs and vertices the edit touched only. Painting
// radial stiffness onto a model at its rest shape changes nothing but matrices: it stores
// no energy and does not move it.

#include <cstddef>
#include <deque>
#include <functional>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/editing/brush.h"
#include "zsculpt/mesh/mesh.h"
#include "zsculpt/physics/properties.h"

namespace zsculpt::editing {

/// One dab of a brush.
struct Dab {
  Brush brush;
  BrushCentre centre;
};
/// The brush applied to every element of its property at full weight (radius, falloff and
/// distance unused).
struct GlobalEdit {
  Brush brush;
};
/// The current shape becomes the rest shape: rest lengths and rest angles.
struct Relax {};
/// Rest lengths multiplied by `factor` (> 0): inflate (> 1) or shrink (< 1).
struct ScaleRest {
  double factor = 1.0;
};
struct Undo {};
struct Redo {};

using EditCommand = std::variant<Dab, GlobalEdit, Relax, ScaleRest, Undo, Redo>;

/// One line for logs: "dab stiffness set 0.5 at vertex 30, radius 1 ...".
std::string describe(const EditCommand& command);

/// What an edit works on: the model's connectivity and its (mutable) properties. For a
/// Simulation: {sim.model().mesh, sim.model().angles, sim.mutableProperties()}.
struct EditTarget {
  const Mesh& mesh;
  const AngleTable& angles;
  PhysicalProperties& properties;

  static EditTarget of(Model& model) { return {model.mesh, model.angles, model.properties}; }
};

struct EnergyChange {
  double potential = 0.0;  // radial + angular springs + gravity, after minus before
  double kinetic = 0.0;    // mass edits at non-zero velocity
  [[nodiscard]] double total() const { return potential + kinetic; }
};

/// The outcome of apply/undo/redo. Spans point into the editor's buffers: valid until its
/// next call.
struct EditResult {
  /// False when nothing changed (a dab that reached nothing or set the values already
  /// there, undo with an empty history ...): no history entry, nothing to update.
  bool changed = false;
  /// A global edit: every row is listed in matrixRows; a caller may rebuild instead.
  bool wholeModel = false;
  /// Rows of K, Omega^2, M^-1 and G whose values changed, sorted: pass to
  /// propertiesChanged / updateVertices (TransformationMatrices extends them to their
  /// one-ring itself).
  std::span<const Index> matrixRows;
  /// Vertices whose own values or whose edges' / angles' values changed, sorted (for
  /// display and for anything else that caches per-vertex data).
  std::span<const Index> vertices;
  /// Number of property entries (vertices, edges, angles) whose value changed.
  Index entriesChanged = 0;
  EnergyChange energy;
};

struct EditorOptions {
  /// Undo steps kept; the oldest are dropped beyond this (0: none kept).
  size_t historyLimit = 1000;
};

class Editor {
 public:
  /// Buffers sized for the model (O(N) once).
  Editor(const Mesh& mesh, const AngleTable& angles, const EditorOptions& options = {});

  /// Applies a command to `target` at `state` (positions: brush distances, relax and
  /// energies; velocities: kinetic energy). All or nothing: throws InvalidInputError (a
  /// value out of its range, an unknown vertex, a non-positive radius ...; also when the
  /// result would leave a property's range, naming the first element) with `target`
  /// unchanged. A command that changed something clears the redo history.
  ///
  /// `accept`, when given, is called with the result once the new values are written and
  /// before the history changes (the caller brings what depends on the values up to date
  /// there, e.g. Simulation::propertiesChanged). If it throws, the old values are written
  /// back, the history is left as it was, and the exception goes on to the caller, who then
  /// brings its dependents back to the old values.
  using Acceptance = std::function<void(const EditResult&)>;
  EditResult apply(EditTarget target, const State& state, const EditCommand& command,
                   const Acceptance& accept = nullptr);
  EditResult undo(EditTarget target, const State& state, const Acceptance& accept = nullptr);
  EditResult redo(EditTarget target, const State& state, const Acceptance& accept = nullptr);

  [[nodiscard]] size_t undoDepth() const { return undo_.size(); }
  [[nodiscard]] size_t redoDepth() const { return redo_.size(); }
  void clearHistory();

  /// The vertices and weights of the last dab (for display).
  [[nodiscard]] const BrushRegion& lastRegion() const { return region_; }

 private:
  struct Change {
    Property property = Property::Stiffness;
    std::vector<Index> indices;
    std::vector<double> before, after;
  };
  struct Record {
    std::vector<Change> changes;
    bool wholeModel = false;
  };

  void checkTarget(const EditTarget& target, const State& state) const;
  Record takeRecord();
  void recycle(Record&& record);
  // Fills change.indices/before/after for a brush over the current region (or everything).
  void brushValues(const EditTarget& target, const Brush& brush, bool global, Change& change);
  double neighbourMean(const EditTarget& target, Property property, Index element) const;
  // Writes `values` (the before or after of each change), measures the energy and
  // collects matrix rows and vertices.
  EditResult write(EditTarget target, const State& state, const Record& record, bool forward);
  EditResult commit(EditTarget target, const State& state, Record&& record,
                    const Acceptance& accept);
  // write(forward), then accept; if accept throws, write(!forward) and rethrow.
  EditResult writeAccepted(EditTarget target, const State& state, const Record& record,
                           bool forward, const Acceptance& accept);
  void collectEnergyTerms(const EditTarget& target, const Change& change);
  EnergyChange termEnergy(const EditTarget& target, const State& state, Property property) const;

  Index vertices_ = 0, edges_ = 0, angles_ = 0;
  EditorOptions options_;
  BrushRegion region_;
  std::deque<Record> undo_;
  std::vector<Record> redo_;
  std::vector<Record> spare_;  // recycled records: their vectors keep their capacity
  // Work buffers reused by every call.
  std::vector<Index> rows_, touched_, edgeTerms_, angleTerms_, vertexTerms_;
  std::vector<unsigned> edgeStamp_;
  unsigned edgeGeneration_ = 0;
};

}  // namespace zsculpt::editing
