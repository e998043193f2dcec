#pragma once
// The window's live energy and momentum plots: a ring of the last kSize samples, one per
// state the solver publishes.

#include <array>

#include "zsculpt/physics/diagnostics.h"

namespace zsculpt::app {

struct PlotSeries {
  static constexpr int kSize = 600;
  std::array<float, kSize> kinetic{}, potential{}, total{}, momentum{}, angular{};
  std::array<double, kSize> time{};  ///< simulated time of each sample
  int count = 0;                     ///< samples held, at most kSize
  int next = 0;  ///< where the next sample goes; the samples are the count before it
  /// Adds a sample at simulated time `t`. Time going back (Reset, a rollback after a
  /// divergence) first drops the samples at and after `t`, so that no curve joins two timelines; a
  /// rollback keeps the run up to the state it went back to.
  void push(const Diagnostics& d, double t);
  void clear() { count = next = 0; }
  /// Ring index of sample i, 0 the oldest.
  [[nodiscard]] int at(int i) const { return (next - count + i + 2 * kSize) % kSize; }
};

}  // namespace zsculpt::app
