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

/// body(part, begin, end) for each of kParts fixed contiguous parts of [0, n), on `threads`
/// threads when n is above `serialUpTo` (else on the calling thread, in part order).
template <int kParts, class Body>
void forEachPart(std::int64_t n, int threads, std::int64_t serialUpTo, Body&& body) {
  // clang-format off
#pragma omp parallel for num_threads(threads) if (threads > 1 && n > serialUpTo)
  // clang-format on
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
