#pragma once
// Counts heap allocations while gCounting is set, for the tests of a path that must not
// allocate (the per-frame render path, the per-cycle solver path): operator new, and the C
// allocation functions, which the C++ counter alone does not see. libgomp makes a team for
// every parallel region that runs on one thread through posix_memalign / aligned_alloc, and
// those allocations went uncounted until the twenty-sixth session (8 a default cycle). It
// replaces the global operator new and delete and glibc's allocation entry points: include
// it in one source file of a test binary only. Sanitized builds keep their own allocator;
// there only operator new is counted, as it is where ZSCULPT_COUNT_NEW_ONLY is defined
// before the include (the renderer's tests: OSMesa's llvmpipe allocates in C on every draw,
// about 86 times a frame, which is the driver's and not the renderer's code).
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

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__) || defined(ZSCULPT_COUNT_NEW_ONLY)
#define ZSCULPT_COUNT_C_ALLOCATIONS 0
#else
#define ZSCULPT_COUNT_C_ALLOCATIONS 1
#endif

#if ZSCULPT_COUNT_C_ALLOCATIONS
extern "C" {
void* __libc_malloc(std::size_t);
void* __libc_calloc(std::size_t, std::size_t);
void* __libc_realloc(void*, std::size_t);
void* __libc_memalign(std::size_t, std::size_t);

inline void countAllocation() {
  if (gCounting.load(std::memory_order_relaxed)) gAllocations.fetch_add(1);
}
void* malloc(std::size_t size) noexcept {
  countAllocation();
  return __libc_malloc(size);
}
void* calloc(std::size_t count, std::size_t size) noexcept {
  countAllocation();
  return __libc_calloc(count, size);
}
void* realloc(void* p, std::size_t size) noexcept {
  countAllocation();
  return __libc_realloc(p, size);
}
void* memalign(std::size_t alignment, std::size_t size) noexcept {
  countAllocation();
  return __libc_memalign(alignment, size);
}
void* aligned_alloc(std::size_t alignment, std::size_t size) noexcept {
  countAllocation();
  return __libc_memalign(alignment, size);
}
int posix_memalign(void** out, std::size_t alignment, std::size_t size) noexcept {
  countAllocation();
  *out = __libc_memalign(alignment, size);
  return *out != nullptr ? 0 : 12;  // ENOMEM
}
}
#endif

void* operator new(std::size_t size) {
#if !ZSCULPT_COUNT_C_ALLOCATIONS
  if (gCounting.load(std::memory_order_relaxed)) gAllocations.fetch_add(1);
#endif
  // (Counted by malloc when the C functions are.)
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept {
  std::free(p);
}
void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}
