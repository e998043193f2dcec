#include "zsculpt/app/plot_series.h"

#include <algorithm>

namespace zsculpt::app {

void PlotSeries::push(const Diagnostics& d, double t) {
  // Samples at `t` or after it go: after a Reset the old run's first sample, at t = 0 like
  // the new run's, stayed and drew a spike that never happened (a QA pass).
  while (count > 0 && time[static_cast<size_t>(at(count - 1))] >= t) {
    next = (next + kSize - 1) % kSize;
    --count;
  }
  const auto k = static_cast<size_t>(next);
  time[k] = t;
  kinetic[k] = static_cast<float>(d.kinetic);
  potential[k] = static_cast<float>(d.potential.total());
  total[k] = static_cast<float>(d.total());
  momentum[k] = static_cast<float>(d.momentum.norm());
  angular[k] = static_cast<float>(d.angularMomentum.norm());
  next = (next + 1) % kSize;
  count = std::min(count + 1, kSize);
}

}  // namespace zsculpt::app
