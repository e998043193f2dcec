#include "filter_rows.h"

#include "filter_rows_impl.h"

namespace zsculpt::filter_rows {

bool wideAvailable() {
#if defined(__x86_64__) && !defined(ZSCULPT_NO_WIDE_KERNELS)
  static const bool available = __builtin_cpu_supports("avx2");
  return available;
#else
  return false;
#endif
}

const Kernels& kernels(bool wide) {
  static const Kernels baseline = makeKernels<PackedPoint>();
#if defined(__x86_64__) && !defined(ZSCULPT_NO_WIDE_KERNELS)
  if (wide && wideAvailable()) return avx2Kernels();
#else
  (void)wide;
#endif
  return baseline;
}

}  // namespace zsculpt::filter_rows
