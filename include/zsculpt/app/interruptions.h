#pragma once
// SIGINT, SIGTERM and SIGHUP, noted rather than obeyed, for the one process-wide mechanism
// that the window (it closes as from its button) and the headless runs (they stop between
// cycles) both use. Until the thirty-eighth session the window had its own handlers, which
// closed a window started under nohup at the terminal's SIGHUP and never let a third signal
// end a window that did not close.

namespace zsculpt::app {

/// While one lives, SIGINT, SIGTERM and SIGHUP only note that they came (signal()), so that
/// work stops where it can rather than where it stands, which left frames of a half run, a
/// temporary file half written or a session without its recording. A third signal ends the
/// process at once by its default action (a run stuck in a write to a pipe nobody reads); not
/// the second: `timeout` sends its signal twice, to the process and to its group. A signal
/// ignored when the first one began stays ignored (nohup's SIGHUP, the SIGINT of a
/// background job). Nested ones share the handlers; the last to end puts back those there
/// before, unless a signal came: the caller then says so and ends by it, and a second signal
/// meanwhile must not end the process before the message.
class Interruptions {
 public:
  Interruptions();
  ~Interruptions();
  Interruptions(const Interruptions&) = delete;
  Interruptions& operator=(const Interruptions&) = delete;

  /// The first signal that came while one lived (since the outermost began), or 0.
  [[nodiscard]] static int signal();
};

}  // namespace zsculpt::app
