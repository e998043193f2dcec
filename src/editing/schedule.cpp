#include "zsculpt/editing/schedule.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "zsculpt/core/errors.h"

namespace zsculpt::editing {

EditSchedule::EditSchedule(std::vector<TimedEdit> edits) {
  for (size_t k = 0; k < edits.size(); ++k)
    if (!(std::isfinite(edits[k].time) && edits[k].time >= 0.0))
      throw InvalidInputError("edit " + std::to_string(k) + ": time " +
                              formatNumber(edits[k].time) + " must be finite and >= 0");
  // Sort a permutation rather than the commands themselves (cheaper moves, and GCC 12
  // reports a false maybe-uninitialized for stable_sort over std::variant).
  std::vector<size_t> order(edits.size());
  for (size_t k = 0; k < order.size(); ++k) order[k] = k;
  std::stable_sort(order.begin(), order.end(),
                   [&](size_t a, size_t b) { return edits[a].time < edits[b].time; });
  edits_.reserve(edits.size());
  for (size_t k : order) edits_.push_back(std::move(edits[k]));
}

std::span<const TimedEdit> EditSchedule::due(double now, double slack) {
  const size_t first = next_;
  while (next_ < edits_.size() && edits_[next_].time <= now + slack) ++next_;
  return {edits_.data() + first, next_ - first};
}

}  // namespace zsculpt::editing
