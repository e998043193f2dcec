#include "zsculpt/physics/thread_tuner.h"

#include <algorithm>

namespace zsculpt {

void ThreadTuner::record(double seconds) {
  if (phase_ < 2) {
    best_[phase_] = count_ == 0 ? seconds : std::min(best_[phase_], seconds);
    if (++count_ < kProbeSteps) return;
    count_ = 0;
    if (++phase_ < 2) return;
    const int winner = best_[1] < best_[0] ? 1 : 0;
    const bool clear = best_[1 - winner] >= kClearMargin * best_[winner];
    // The same clear winner as last time: probe half as often. Otherwise probe often.
    const bool again = clear && lastClear_ && candidates_[winner] == chosen_;
    hold_ = again ? std::min(2.0 * hold_, kMaxHoldSeconds) : kHoldSeconds;
    lastClear_ = clear;
    chosen_ = candidates_[winner];
    reference_ = best_[winner];
    held_ = 0.0;
    slow_ = 0;
    return;
  }
  held_ += seconds;
  slow_ = seconds > kSlowdown * reference_ ? slow_ + 1 : 0;
  if (slow_ >= kSlowSteps) {
    // The load changed: probe now, and often again.
    hold_ = kHoldSeconds;
    lastClear_ = false;
    phase_ = 0;
  } else if (held_ >= hold_) {
    phase_ = 0;
  }
}

}  // namespace zsculpt
