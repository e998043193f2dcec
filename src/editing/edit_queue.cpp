#include "zsculpt/editing/edit_queue.h"

namespace zsculpt::editing {

void EditQueue::push(EditCommand command) {
  const std::lock_guard<std::mutex> lock(mutex_);
  pending_.push_back(std::move(command));
}

void EditQueue::drain(std::vector<EditCommand>& out) {
  out.clear();
  const std::lock_guard<std::mutex> lock(mutex_);
  pending_.swap(out);
}

size_t EditQueue::size() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  return pending_.size();
}

}  // namespace zsculpt::editing
