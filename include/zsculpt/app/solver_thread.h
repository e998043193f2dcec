#pragma once
// The Solver thread of paper section 6 (Figure 2): it owns the Session, and loops
//
//   drain the command queue -> apply each command (and record it with the cycle)
//   -> if running and a step is due: one cycle -> publish the state
//
// The Display thread pushes commands (push() takes a mutex for an append) and reads the
// newest published Snapshot through a lock-free triple buffer (latest()): it is never
// blocked by a slow solver and never sees a torn state.
//
// Pacing. In real-time mode simulated time follows wall time: a cycle is due when the
// simulated time is behind the wall time elapsed while running. When the solver cannot keep
// up (a step takes longer than the period: the paper's solver fell behind beyond about 1200
// vertices), it steps back to back, simulated time runs slower than wall time, the lag is
// capped at kMaxLag (so it does not try to catch up later in a burst), and the snapshot says
// so (simOverWall < 1, fallingBehind). In free-running mode (benchmarks, tests) cycles run
// back to back.
//
// Divergence: the session rolls back (session.h); the thread pauses and reports it through
// takeMessages().

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "zsculpt/app/commands.h"
#include "zsculpt/app/session.h"
#include "zsculpt/app/triple_buffer.h"

namespace zsculpt::app {

class Recorder;

struct SolverThreadOptions {
  /// Simulated time follows wall time (true) or cycles run back to back (false).
  bool realTime = true;
  /// Simulated seconds per wall second in real-time mode.
  double speed = 1.0;
  /// Start running (Play) at once.
  bool startRunning = false;
  /// Stop after this many cycles (0: never): for benchmarks and tests.
  std::uint64_t maxCycles = 0;
};

/// A command for a given cycle, applied when the session reaches it (scripts).
struct ScheduledCommand {
  std::uint64_t cycle = 0;
  Command command;
};

class SolverThread {
 public:
  static constexpr double kMaxLag = 0.25;  ///< wall seconds the simulation may lag at most

  /// Takes the session; `recorder` (optional, may be null) receives every applied command.
  SolverThread(std::unique_ptr<Session> session, const SolverThreadOptions& options = {},
               std::shared_ptr<Recorder> recorder = nullptr);
  /// Stops and joins the thread.
  ~SolverThread();
  SolverThread(const SolverThread&) = delete;
  SolverThread& operator=(const SolverThread&) = delete;

  /// Starts the thread (publishes the initial state first).
  void start();
  /// Asks the thread to finish its cycle and joins it. Idempotent.
  void stop();
  [[nodiscard]] bool finished() const { return finished_.load(std::memory_order_acquire); }

  // ---- any thread ----
  void push(Command command);
  /// Commands applied when the session's cycle reaches their cycle (before that cycle's
  /// step), in order; merged with pushed ones. For scripts.
  void schedule(std::vector<ScheduledCommand> commands);
  /// Which property the published scalar shows.
  void setDisplayProperty(Property property);
  /// Messages for the user (refused commands, divergence, saves), oldest first.
  std::vector<std::string> takeMessages();
  /// Runs `job` on the solver thread between two cycles, with the session (for saving the
  /// scene or the mesh: the model is the solver's). The job must not throw past its own
  /// handler; its message, if non-empty, goes to takeMessages().
  void runOnSolver(std::function<std::string(Session&)> job);

  // ---- display thread only ----
  /// The newest published snapshot (picks it up if there is a newer one).
  const Snapshot& latest();
  [[nodiscard]] const Snapshot& current() const { return buffer_.front(); }

  /// The session; only while the thread is not running (before start, after stop).
  Session& sessionWhenStopped();

 private:
  void loop();
  void applyPending();
  void publish();
  void postMessage(std::string message);

  std::unique_ptr<Session> session_;
  SolverThreadOptions options_;
  std::shared_ptr<Recorder> recorder_;

  std::mutex queueMutex_;
  std::condition_variable wake_;
  std::vector<Command> pending_, draining_;
  std::vector<ScheduledCommand> scheduled_;
  std::size_t nextScheduled_ = 0;
  // Each job with the number of commands queued before it: it runs after those and before
  // the ones queued after it (a save between a paint and an undo saves the paint).
  struct Job {
    size_t after = 0;
    std::function<std::string(Session&)> run;
  };
  std::vector<Job> jobs_, runningJobs_;
  bool stopRequested_ = false;

  std::mutex messageMutex_;
  std::vector<std::string> messages_;

  std::atomic<int> displayProperty_{static_cast<int>(Property::Stiffness)};
  TripleBuffer<Snapshot> buffer_;
  std::uint64_t serial_ = 0;
  std::uint64_t applied_ = 0;

  // Timing, solver thread only.
  double stepSecondsAverage_ = 0.0;
  double simOverWall_ = 0.0;
  bool fallingBehind_ = false;

  std::thread thread_;
  std::atomic<bool> finished_{false};
  bool started_ = false;
};

}  // namespace zsculpt::app
