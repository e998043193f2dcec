#include "console.h"

#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <iostream>

namespace zsculpt::cli {

namespace {
// Lock-free atomics: the handler may run on any thread (OpenMP's, the rasteriser's).
std::atomic<int> interruptingSignal{0};
std::atomic<int> interruptions{0};
static_assert(std::atomic<int>::is_always_lock_free);
// The third signal ends the process where it stands (a run stuck in a write to a pipe that
// nobody reads). Not the second: `timeout` sends its signal twice, to the process and to
// its group.
extern "C" void onInterrupt(int signal) {
  interruptingSignal.store(signal);
  if (interruptions.fetch_add(1) + 1 >= 3) {
    std::signal(signal, SIG_DFL);
    std::raise(signal);
  }
}
constexpr int kInterruptions[] = {SIGINT, SIGTERM, SIGHUP};
struct sigaction previousActions[std::size(kInterruptions)];
int interruptionsAlive = 0;
bool lineDrawn = false;  // a bar's line is on the terminal, without its line end
bool lineCleared = false;
}  // namespace

void warn(const std::string& text) {
  std::cerr.flush();
  if (lineDrawn) {
    std::fputs("\r\033[K", stderr);  // back to the line's start and clear it
    lineDrawn = false;
    lineCleared = true;
  }
  std::cerr << "zsculpt: warning: " << text << "\n";
}

void progressLineDrawn(bool drawn) {
  lineDrawn = drawn;
  lineCleared = false;
}

bool progressLineCleared() {
  return lineCleared;
}

InterruptedError::InterruptedError(int signal, bool outputsWritten)
    : Error(std::string("interrupted by ") +
            (signal == SIGINT    ? "SIGINT"
             : signal == SIGTERM ? "SIGTERM"
             : signal == SIGHUP  ? "SIGHUP"
                                 : "a signal") +
            (outputsWritten ? " as the run's outputs were written: they are whole"
                            : ": the run stopped and left no output")),
      signal_(signal) {}

Interruptions::Interruptions() {
  if (interruptionsAlive++ > 0) return;
  interruptingSignal = 0;
  interruptions = 0;
  struct sigaction action {};
  action.sa_handler = onInterrupt;
  sigemptyset(&action.sa_mask);
  // A signal ignored when the run began stays ignored (nohup's SIGHUP, an & job's SIGINT).
  for (size_t k = 0; k < std::size(kInterruptions); ++k) {
    ::sigaction(kInterruptions[k], nullptr, &previousActions[k]);
    if (previousActions[k].sa_handler != SIG_IGN) ::sigaction(kInterruptions[k], &action, nullptr);
  }
}

Interruptions::~Interruptions() {
  // After a signal the handlers stay until the command line has said so and raised it
  // (`timeout`'s second signal would otherwise end the process before the message).
  if (--interruptionsAlive > 0 || interruptingSignal.load() != 0) return;
  for (size_t k = 0; k < std::size(kInterruptions); ++k)
    ::sigaction(kInterruptions[k], &previousActions[k], nullptr);
}

void throwIfInterrupted() {
  if (const int signal = interruptingSignal.load(); signal != 0) throw InterruptedError(signal);
}

void endIfInterrupted() {
  if (const int signal = interruptingSignal.load(); signal != 0)
    throw InterruptedError(signal, true);
}

}  // namespace zsculpt::cli
