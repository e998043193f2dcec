#include "console.h"

#include <csignal>
#include <cstdio>
#include <cstring>
#include <iostream>

namespace zsculpt::cli {

namespace {
volatile std::sig_atomic_t interruptingSignal = 0;
volatile std::sig_atomic_t interruptions = 0;
// The third signal ends the process where it stands (a run stuck in a write to a pipe that
// nobody reads). Not the second: `timeout` sends its signal twice, to the process and to
// its group.
extern "C" void onInterrupt(int signal) {
  interruptingSignal = signal;
  interruptions = interruptions + 1;
  if (interruptions >= 3) {
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

InterruptedError::InterruptedError(int signal)
    : Error(std::string("interrupted by ") +
            (signal == SIGINT    ? "SIGINT"
             : signal == SIGTERM ? "SIGTERM"
             : signal == SIGHUP  ? "SIGHUP"
                                 : "a signal") +
            ": the run stopped and left no output"),
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
  if (--interruptionsAlive > 0) return;
  for (size_t k = 0; k < std::size(kInterruptions); ++k)
    ::sigaction(kInterruptions[k], &previousActions[k], nullptr);
}

void throwIfInterrupted() {
  if (interruptingSignal != 0) throw InterruptedError(interruptingSignal);
}

}  // namespace zsculpt::cli
