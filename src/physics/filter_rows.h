#pragma once
// The default scheme's drift-filter row kernels (docs/solver.md section 6): the passes of
// stepDriftFiltered over one block's rows, built twice, for the x86-64 baseline and for
// AVX2, and chosen at run time. Both do the same IEEE operations in the same order on
// each coordinate (no FMA contraction), so they give the same bits. Private to physics:
// the AVX2 build must see no inline code that other files share (filter_rows_impl.h).

#include <cstdint>

namespace zsculpt::filter_rows {

/// What every pass reads: Omega^2 in CSR, the affine basis B, Omega^2 B, per row m_i B_i
/// then m_i (Omega^2 B)_i, the masses m_i, and the coefficients c (4 x 3) then d (4 x 3) of
/// the vector whose W product the pass takes (W u = Omega^2 u - (Omega^2 B) c - B d).
struct Inputs {
  const std::int32_t* outer = nullptr;
  const std::int32_t* inner = nullptr;
  const double* value = nullptr;
  const double* basis = nullptr;
  const double* omegaBasis = nullptr;
  const double* massBases = nullptr;
  const double* mass = nullptr;
  const double* coefficient = nullptr;
  const double* dampHalf = nullptr;
};

/// The passes, each over rows [begin, end). A pass that sums writes the block's 24 partial
/// sums (B^T M x then (Omega^2 B)^T M x, 4 x 3 each, row by row) to partial; one that sums
/// only the second leaves the first 12 alone.
struct Kernels {
  /// The first kick: kick = half a - filter (W a), then v = vIn e^{-GT/2} + kick, summed (the
  /// velocity pass fused in, where the kick was not kept from the last step). Here and below
  /// an input (vIn, rIn) may be the output itself: each row is read before it is written.
  void (*firstKick)(const Inputs&, std::int32_t begin, std::int32_t end, const double* a,
                    double* kick, const double* vIn, double* v, double half, double filter,
                    double* partial);
  /// The last kick: kick = half a - filter (W a), then v = (v + kick) e^{-GT/2}.
  void (*lastKick)(const Inputs&, std::int32_t begin, std::int32_t end, const double* a,
                   double* kick, double* v, double half, double filter);
  /// v = vIn e^{-GT/2} + kick, summed (the first kick kept from the last step).
  void (*velocity)(const Inputs&, std::int32_t begin, std::int32_t end, const double* vIn,
                   double* v, const double* kick, double* partial);
  /// out = a v + scale (W u), its (Omega^2 B)^T M sum only.
  void (*horner)(const Inputs&, std::int32_t begin, std::int32_t end, const double* u,
                 const double* v, double* out, double a, double scale, double* partial);
  /// r = rIn + t (v + t2 (W w)).
  void (*drift)(const Inputs&, std::int32_t begin, std::int32_t end, const double* w,
                const double* v, const double* rIn, double* r, double t, double t2);
  // The kick filter alone (stepDefault; only outer, inner, value and dampHalf are read):
  /// kick = half a - filter (Omega^2 a), then v = (v + kick) e^{-GT/2}.
  void (*plainKick)(const Inputs&, std::int32_t begin, std::int32_t end, const double* a,
                    double* kick, double* v, double half, double filter);
  /// v = vIn e^{-GT/2} + kick, then r = rIn + t v.
  void (*plainDrift)(const Inputs&, std::int32_t begin, std::int32_t end, const double* vIn,
                     double* v, const double* kick, const double* rIn, double* r, double t);
};

/// The AVX2 kernels where wide is set and the processor has AVX2, else the baseline.
const Kernels& kernels(bool wide);
/// Whether kernels(true) gives the AVX2 ones on this processor.
bool wideAvailable();

// Defined in filter_rows_avx2.cpp (built with -mavx2); call only where AVX2 is present.
const Kernels& avx2Kernels();

}  // namespace zsculpt::filter_rows
