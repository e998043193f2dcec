#pragma once
// The threading contract of dynamic editing (paper section 6: the Display thread records
// user interactions "so that the Solver can incorporate them into the next time cycle").
//
// Whoever makes an edit (the display thread, a script, a test) pushes a command; the
// solver thread drains the queue between two cycles and applies the commands in order
// with its Editor, then updates its matrices. Properties and matrices are therefore only
// ever written by the solver thread, between steps: a step never sees half an edit, and
// nobody else sees a property array while it is being written. (What the display shows
// of the model is whatever the solver publishes after a cycle.)
//
// push() and drain() hold a mutex for a vector swap or an append only. drain() swaps the
// pending vector with the caller's (cleared) one, so in steady state neither side
// allocates: the two vectors trade their capacity back and forth.

#include <cstddef>
#include <mutex>
#include <vector>

#include "zsculpt/editing/editor.h"

namespace zsculpt::editing {

class EditQueue {
 public:
  /// Thread-safe.
  void push(EditCommand command);
  /// Moves every pending command, in push order, into `out` (its old content is
  /// discarded). Thread-safe; meant for the solver thread between cycles.
  void drain(std::vector<EditCommand>& out);
  /// Pending commands (a snapshot: other threads may push meanwhile).
  [[nodiscard]] size_t size() const;

 private:
  mutable std::mutex mutex_;
  std::vector<EditCommand> pending_;
};

}  // namespace zsculpt::editing
