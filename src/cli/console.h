#pragma once
// Standard error shared by a progress bar and the warnings a run tells as it goes: a warning
// first clears the bar's line (it was glued onto "[#####....]  42%  frame 12/30"), and the
// bar draws itself again on its next update.

#include <string>

#include "zsculpt/app/interruptions.h"
#include "zsculpt/core/errors.h"

namespace zsculpt::cli {

/// "zsculpt: warning: TEXT" on a line of its own.
void warn(const std::string& text);

/// The progress bar's side: it drew its line (true) or ended it (false); and whether a
/// warning has cleared it since, so that it must be drawn again.
void progressLineDrawn(bool drawn);
bool progressLineCleared();

/// A headless run stopped by SIGINT, SIGTERM or SIGHUP between two cycles, having removed
/// what it had written (the command line ends the process by that signal after saying so).
class InterruptedError : public Error {
 public:
  explicit InterruptedError(int signal, bool outputsWritten = false);
  [[nodiscard]] int signal() const { return signal_; }

 private:
  int signal_;
};

/// SIGINT, SIGTERM and SIGHUP noted while one lives, so that simulate and render stop between
/// cycles (throwIfInterrupted): the window's mechanism too (app/interruptions.h).
using Interruptions = app::Interruptions;

/// Throws InterruptedError if a signal came while Interruptions lived.
void throwIfInterrupted();
/// The same once the run's outputs are written (a signal during the writes let them finish),
/// so that the process still ends by the signal, saying that the outputs are whole.
void endIfInterrupted();

}  // namespace zsculpt::cli
