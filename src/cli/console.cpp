#include "console.h"

#include <csignal>
#include <cstdio>
#include <cstring>
#include <iostream>

namespace zsculpt::cli {

namespace {
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

void throwIfInterrupted() {
  if (const int signal = Interruptions::signal(); signal != 0) throw InterruptedError(signal);
}

void endIfInterrupted() {
  if (const int signal = Interruptions::signal(); signal != 0) throw InterruptedError(signal, true);
}

}  // namespace zsculpt::cli
