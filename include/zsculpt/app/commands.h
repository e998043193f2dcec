#pragma once
// What the Display thread (or a script, or a recording) asks the Solver thread to do (paper
// section 6: "user interactions are updated into the model structures so that the Solver can
// incorporate them into the next time cycle"). Commands are plain values; the solver applies
// them between two cycles, in order, and a recording stores each with the cycle it was
// applied at, so a replay reproduces the session bit for bit (see recording.h).
//
// Every field is validated where the command is applied (Session::apply), never trusted: a
// bad command is refused with a one-line message and changes nothing.

#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <variant>

#include "zsculpt/core/types.h"
#include "zsculpt/editing/editor.h"
#include "zsculpt/physics/stepper.h"

namespace zsculpt::app {

// ---- the solver loop ----
struct Play {};
struct Pause {};
/// One cycle, also while paused.
struct StepOnce {};
/// Back to the initial state (time 0), loads and constraints as at the start; painted
/// properties are kept (undo them with Undo).
struct Reset {};

// ---- settings of the simulation panel ----
/// A new scheme and sampling period T (seconds): rebuilds the stepper, keeps the state.
struct SetTimeStep {
  Scheme scheme = Scheme::Default;
  double period = 0.0;
};
/// Gravity (m/s^2), not an undoable edit.
struct SetGravity {
  Vec3 gravity = Vec3::Zero();
};
/// kappa_0 of section 4.3 (infinity: none); rebuilds the matrices.
struct SetStiffnessCap {
  double cap = 0.0;
};

// ---- dynamic editing (section 6, "Dynamic Editing"): brush dabs, global edits (damping,
// uniform values), relax the rest shape, undo, redo ----
struct Edit {
  editing::EditCommand command;
};

// ---- loads (section 5.3) ----
enum class LoadKind { Force, Torque };
/// A force (N) or torque (N m) at a vertex from now for `duration` seconds of simulated time
/// (infinity: until cleared).
struct AddLoad {
  LoadKind kind = LoadKind::Force;
  Index vertex = 0;
  Vec3 value = Vec3::Zero();
  double duration = 0.5;
};
/// Removes the loads added by commands and by the scene.
struct ClearLoads {};

// ---- constraints (section 6, "Constraints") ----
/// Holds the vertex at `target` (absent: where it is now).
struct Pin {
  Index vertex = 0;
  std::optional<Vec3> target;
};
struct Unpin {
  Index vertex = 0;
};
/// Pins (or unpins) every vertex a brush of this radius reaches (surface distance).
struct PinBrush {
  editing::BrushCentre centre;
  double radius = 1.0;
  bool pin = true;
};
struct UnpinAll {};
/// Holds the normal at a vertex (absent: the normal it has now).
struct PinNormal {
  Index vertex = 0;
  std::optional<Vec3> normal;
};
struct UnpinNormal {
  Index vertex = 0;
};
/// The drag tool: a moving position constraint on one vertex under the cursor.
struct DragStart {
  Index vertex = 0;
  Vec3 target = Vec3::Zero();
};
struct DragMove {
  Vec3 target = Vec3::Zero();
};
struct DragEnd {};

/// Marks the session as saved (no unsaved edits) - sent after a successful save.
struct MarkSaved {};

using Command = std::variant<Play, Pause, StepOnce, Reset, SetTimeStep, SetGravity, SetStiffnessCap,
                             Edit, AddLoad, ClearLoads, Pin, Unpin, PinBrush, UnpinAll, PinNormal,
                             UnpinNormal, DragStart, DragMove, DragEnd, MarkSaved>;

/// The command's "type" in recordings: "play", "dab", "drag_move", ...
std::string_view commandName(const Command& command);
/// One line for the UI's log.
std::string describe(const Command& command);

/// {"type": "...", ...fields}: every double written so that reading it back gives the same
/// bits (nlohmann writes the shortest round-trip form).
nlohmann::json commandToJson(const Command& command);
/// Throws InvalidInputError "<where>: <reason>" for an unknown type, a missing or unknown
/// field, or a value of the wrong type.
Command commandFromJson(const nlohmann::json& json, const std::string& where);

}  // namespace zsculpt::app
