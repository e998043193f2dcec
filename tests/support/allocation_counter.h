#pragma once
// Counts operator new calls while gCounting is set, for the tests of a path that must not
// allocate (the per-frame render path, the per-cycle solver path). It replaces the global
// operator new and delete: include it in one source file of a test binary only.
//
// GCC 12 flags free() on memory from a replaced operator new as mismatched wherever it
// inlines the pair; the replacement pairs malloc with free, so the warning is silenced for
// the including file.

#include <atomic>
#include <cstdlib>
#include <new>

#pragma GCC diagnostic ignored "-Wmismatched-new-delete"

inline std::atomic<bool> gCounting{false};
inline std::atomic<long> gAllocations{0};

void* operator new(std::size_t size) {
  if (gCounting.load(std::memory_order_relaxed)) gAllocations.fetch_add(1);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept {
  std::free(p);
}
void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}
