#pragma once
// The stepper's automatic thread count (docs/performance.md). A step's result does not
// depend on its thread count (stepper.h), so the count is only a matter of speed: on a
// shared machine a second thread can make a step slower, when the core it needs is busy and
// the first thread waits for it. ThreadTuner times steps and picks the faster of two counts.
//
// It probes: kProbeSteps steps with each candidate, the fastest step of each compared. Then
// it holds the faster for a while and probes again, as the machine's load may have changed.
// Each probe costs steps at the slower count, so the hold grows while probes keep finding a
// clear winner (twice as long each time, from kHoldSeconds up to kMaxHoldSeconds) and starts
// again from kHoldSeconds after a close call. A held step that takes kSlowdown times the
// probe's best, kSlowSteps times in a row, ends the hold at once: the load changed.

namespace zsculpt {

class ThreadTuner {
 public:
  static constexpr int kProbeSteps = 4;
  static constexpr double kHoldSeconds = 2.0;
  static constexpr double kMaxHoldSeconds = 32.0;
  /// A winner this many times faster than the other count is a clear one.
  static constexpr double kClearMargin = 1.25;
  static constexpr double kSlowdown = 2.0;
  static constexpr int kSlowSteps = 3;

  /// Tunes between `many` threads and `few` (the first probed first).
  ThreadTuner(int many, int few) : candidates_{many, few} {}

  /// The thread count for the next step.
  [[nodiscard]] int next() const { return phase_ < 2 ? candidates_[phase_] : chosen_; }
  /// Records the wall time of the step just taken with next()'s count.
  void record(double seconds);

  [[nodiscard]] bool probing() const { return phase_ < 2; }
  /// The count held since the last probe (the first candidate before any).
  [[nodiscard]] int chosen() const { return chosen_; }
  /// How long the current or next hold lasts, in seconds of stepping.
  [[nodiscard]] double holdSeconds() const { return hold_; }

 private:
  int candidates_[2];
  double best_[2] = {0.0, 0.0};
  int phase_ = 0;  // 0, 1: probing candidates_[phase_]; 2: holding chosen_
  int count_ = 0;  // steps of the current probe
  int chosen_ = candidates_[0];
  double reference_ = 0.0;  // the held count's best step in the last probe
  double held_ = 0.0;       // seconds stepped in the current hold
  double hold_ = kHoldSeconds;
  bool lastClear_ = false;  // the last probe found a clear winner
  int slow_ = 0;            // consecutive slow steps in the current hold
};

}  // namespace zsculpt
