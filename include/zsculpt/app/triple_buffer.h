#pragma once
// The exchange between the Solver and the Display threads (paper section 6, Figure 2: the
// Solver "updates the display structures on completion of a cycle"; the Display "expects
// updated state vector data from the Solver").
//
// A lock-free triple buffer: three slots, one owned by the writer (back), one by the reader
// (front), one in the middle. publish() swaps back and middle in one atomic exchange and
// marks the middle fresh; update() swaps front and middle when it is fresh. So
//   - the reader always gets the newest complete value and never sees a slot being written
//     (each slot index is owned by exactly one side at any time: no tearing);
//   - neither side ever waits for the other (a slow solver never blocks the display, a slow
//     display never blocks the solver; values the reader did not pick up are overwritten).
// The exchanges are acq_rel: everything the writer stored into its slot before publish()
// happens-before the reader's reads after the update() that picked that slot up.
//
// Slots are plain values: a writer that refills its slot with assign()/resize() to the
// same sizes allocates nothing once each of the three slots has reached its size.

#include <array>
#include <atomic>
#include <cstdint>

namespace zsculpt::app {

template <class T>
class TripleBuffer {
 public:
  TripleBuffer() = default;
  TripleBuffer(const TripleBuffer&) = delete;
  TripleBuffer& operator=(const TripleBuffer&) = delete;

  // ---- writer thread only ----
  /// The slot to fill before publish(). It holds an older value (or the one before that).
  T& back() { return slots_[back_]; }
  /// Makes back() the newest value and hands the writer another slot.
  void publish() {
    const std::uint8_t previous =
        middle_.exchange(static_cast<std::uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
    back_ = previous & kIndexMask;
  }

  // ---- reader thread only ----
  /// Picks up the newest published value if there is one the reader has not seen; returns
  /// whether front() changed.
  bool update() {
    if ((middle_.load(std::memory_order_relaxed) & kFresh) == 0) return false;
    const std::uint8_t previous = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = previous & kIndexMask;
    return true;
  }
  /// The newest value picked up by update() (a default-constructed T before the first).
  [[nodiscard]] const T& front() const { return slots_[front_]; }

  // ---- before the threads start (or after they stop) ----
  /// Direct access to every slot, e.g. to preallocate them. Not thread-safe.
  T& slot(int i) { return slots_[static_cast<size_t>(i)]; }

 private:
  static constexpr std::uint8_t kIndexMask = 0x3;
  static constexpr std::uint8_t kFresh = 0x4;

  std::array<T, 3> slots_{};
  std::atomic<std::uint8_t> middle_{2};
  std::uint8_t back_ = 1;   // writer-owned
  std::uint8_t front_ = 0;  // reader-owned
};

}  // namespace zsculpt::app
