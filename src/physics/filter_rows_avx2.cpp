// The drift-filter row kernels for AVX2 (built with -mavx2 and no FMA: CMakeLists.txt).
// Reached only through filter_rows::kernels, after the processor was checked.
#include "filter_rows_impl.h"

namespace zsculpt::filter_rows {

#if defined(__AVX2__)
const Kernels& avx2Kernels() {
  static const Kernels wide = makeKernels<QuadPoint>();
  return wide;
}
#else
// A build without the flag (another architecture): never called, wideAvailable() is false.
const Kernels& avx2Kernels() {
  static const Kernels baseline = makeKernels<PackedPoint>();
  return baseline;
}
#endif

}  // namespace zsculpt::filter_rows
