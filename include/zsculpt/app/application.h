#pragma once
// The interactive window (paper section 6, Figure 2, "Display"): GLFW, Dear ImGui and the
// renderer. It draws the newest state the solver thread published, turns the mouse and the
// keyboard into commands (tools: drag, paint, pin, normal pin, force, torque), and shows
// the panels (simulation, tools and brush, display, plots, statistics, file). See
// docs/user-guide.md for the bindings.
//
// A script (--script FILE, recording.h's format plus "ui" lines) drives the same window:
// its command lines go to the solver at their cycles, its "ui" lines act as a user would
// (choose a tool, press the mouse over a vertex, move, release, take a screenshot, quit).

#include <optional>
#include <string>

#include "zsculpt/app/session.h"

namespace zsculpt::app {

struct WindowOptions {
  int width = 1280;
  int height = 800;
  /// Start with the simulation running.
  bool startRunning = true;
  /// Simulated seconds per wall second.
  double speed = 1.0;
  /// Record every applied command here (recording.h); written when the window closes or
  /// another model is opened.
  std::string recordPath;
  /// A script to run (recording.h); the window closes at its "quit" line.
  std::string scriptPath;
  /// Screenshots (F12, the File panel, scripts) go here; empty: the current folder.
  std::string screenshotDir;
  /// The final state is written here when the window closes.
  std::string stateOut;
  /// Shown in the title bar.
  std::string title = "zsculpt";
  /// What a bare mesh opened from the File panel gets (a scene brings its own): its
  /// properties and simulation settings, `open`'s flags (--mass, --stiffness, ..., --scheme,
  /// --dt-ratio) over the defaults (loadSessionSetup's meshDefaults).
  io::SceneDescription meshDefaults;
};

/// Opens the window on a session and runs until the user closes it. Returns the exit
/// status (0). Throws IOError "display: ..." when no window can be opened (no X display)
/// and InvalidInputError for a malformed script, before any window appears.
int runWindow(SessionSetup setup, const WindowOptions& options);

}  // namespace zsculpt::app
