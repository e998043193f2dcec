#pragma once
// Passes over many rows in fixed contiguous parts, the parts on several threads (OpenMP):
// a sum taken part by part and the parts added in part order is the same bits whatever the
// thread count. For the modules built with OpenMP (physics, rigid, simulation); elsewhere the
// pragmas would be unknown.

#include <array>
#include <cstdint>

#include "zsculpt/core/types.h"

namespace zsculpt {

/// The first of `count` items in part `part` of `parts` equal contiguous parts.
inline Index partBegin(std::int64_t count, int part, int parts) {
  return static_cast<Index>(count * part / parts);
}

/// body() in one parallel region on `threads` threads, or called directly when there is one
/// (its orphaned `omp for` and `omp single` then run on the calling thread). OpenMP's `if`
/// clause is not enough: libgomp makes and frees a team for a region that runs on one
/// thread, an allocation per region, every step (8 a default cycle on one thread).
template <class Body>
void parallelRegion(int threads, Body&& body) {
  if (threads <= 1) {
    body();
    return;
  }
#pragma omp parallel num_threads(threads)
  body();
}

/// body(part, begin, end) for each of kParts fixed contiguous parts of [0, n), on `threads`
/// threads when n is above `serialUpTo` (else on the calling thread, in part order, with no
/// parallel region: parallelRegion says why).
template <int kParts, class Body>
void forEachPart(std::int64_t n, int threads, std::int64_t serialUpTo, Body&& body) {
  if (threads <= 1 || n <= serialUpTo) {
    for (int part = 0; part < kParts; ++part)
      body(part, partBegin(n, part, kParts), partBegin(n, part + 1, kParts));
    return;
  }
#pragma omp parallel for num_threads(threads)
  for (int part = 0; part < kParts; ++part)
    body(part, partBegin(n, part, kParts), partBegin(n, part + 1, kParts));
}

/// The sum over [0, n) of body(begin, end, sum), which adds the rows [begin, end) into
/// `sum` (starting from `zero`), taken in kParts fixed parts (forEachPart) added in part
/// order: the same bits on any thread count.
template <int kParts, class Sum, class Body>
Sum sumInParts(std::int64_t n, int threads, std::int64_t serialUpTo, const Sum& zero, Body&& body) {
  std::array<Sum, kParts> parts;
  forEachPart<kParts>(n, threads, serialUpTo, [&](int part, Index begin, Index end) {
    Sum& sum = parts[static_cast<size_t>(part)];
    sum = zero;
    body(begin, end, sum);
  });
  Sum total = zero;
  for (const Sum& part : parts) total += part;
  return total;
}

}  // namespace zsculpt
