#pragma once
// Scripted edits: commands with a time, so headless runs can paint (scene files' "edits",
// docs/scene-format.md). The solver asks, before each cycle, which edits are due.

#include <cstddef>
#include <span>
#include <vector>

#include "zsculpt/editing/editor.h"

namespace zsculpt::editing {

struct TimedEdit {
  double time = 0.0;  // seconds of simulated time, >= 0
  EditCommand command;
  size_t source = 0;  // its position in the list it came from (scene file), for messages
};

class EditSchedule {
 public:
  EditSchedule() = default;
  /// Sorted by time, list order kept for equal times. Throws InvalidInputError
  /// "edit K: time T must be finite and >= 0".
  explicit EditSchedule(std::vector<TimedEdit> edits);

  /// The edits not returned yet whose time is <= now + slack, in order. `slack` absorbs
  /// the rounding of a time accumulated step by step (the CLI passes a millionth of the
  /// period): an edit at 0.5 s is due at the step that starts at 0.5 s, however that
  /// sum was rounded. The span is valid until the schedule is changed.
  std::span<const TimedEdit> due(double now, double slack = 0.0);

  [[nodiscard]] bool finished() const { return next_ == edits_.size(); }
  /// The edits not returned yet, in order.
  [[nodiscard]] std::span<const TimedEdit> pending() const {
    return std::span<const TimedEdit>(edits_).subspan(next_);
  }
  [[nodiscard]] size_t size() const { return edits_.size(); }
  [[nodiscard]] const std::vector<TimedEdit>& edits() const { return edits_; }
  /// Start over (every edit becomes pending again).
  void rewind() { next_ = 0; }

 private:
  std::vector<TimedEdit> edits_;
  size_t next_ = 0;
};

}  // namespace zsculpt::editing
