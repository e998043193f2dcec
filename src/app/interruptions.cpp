#include "zsculpt/app/interruptions.h"

#include <atomic>
#include <csignal>
#include <iterator>

namespace zsculpt::app {

namespace {

// Lock-free atomics: the handler may run on any thread (OpenMP's, the rasteriser's, GLFW's).
std::atomic<int> caughtSignal{0};
std::atomic<int> signalCount{0};
static_assert(std::atomic<int>::is_always_lock_free);

extern "C" void onInterruption(int signal) {
  int none = 0;
  caughtSignal.compare_exchange_strong(none, signal);
  if (signalCount.fetch_add(1) + 1 >= 3) {
    std::signal(signal, SIG_DFL);
    std::raise(signal);
  }
}

constexpr int kSignals[] = {SIGINT, SIGTERM, SIGHUP};
struct sigaction previousActions[std::size(kSignals)];
int alive = 0;           // nesting depth; the main thread makes and ends them
bool installed = false;  // the handlers are in place (left so after a signal)

}  // namespace

Interruptions::Interruptions() {
  if (alive++ > 0) return;
  caughtSignal = 0;
  signalCount = 0;
  // Left in place after a signal (below): what was there before them is already saved.
  if (installed) return;
  installed = true;
  struct sigaction action {};
  action.sa_handler = onInterruption;
  sigemptyset(&action.sa_mask);
  for (size_t k = 0; k < std::size(kSignals); ++k) {
    ::sigaction(kSignals[k], nullptr, &previousActions[k]);
    if (previousActions[k].sa_handler != SIG_IGN) ::sigaction(kSignals[k], &action, nullptr);
  }
}

Interruptions::~Interruptions() {
  if (--alive > 0 || caughtSignal.load() != 0) return;
  for (size_t k = 0; k < std::size(kSignals); ++k)
    ::sigaction(kSignals[k], &previousActions[k], nullptr);
  installed = false;
}

int Interruptions::signal() {
  return caughtSignal.load();
}

}  // namespace zsculpt::app
