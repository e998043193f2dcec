#pragma once
// The drift-filter row kernels as templates over a point type: PackedPoint (x and y in one
// SSE2 register, z beside it) and, where the including file is built for AVX2, QuadPoint
// (x, y, z and an unused lane in one AVX register). Element by element both do the
// operations of scalar code in its order, so the results are the same bits.
//
// Everything here has internal linkage (an unnamed namespace) and the file includes no
// library code: filter_rows_avx2.cpp is built with -mavx2, and an inline function it
// shared with other files could be the copy the linker keeps for all of them.

#include <cstddef>
#include <cstdint>

#include "filter_rows.h"

namespace zsculpt::filter_rows {
namespace {

using Pair = double __attribute__((vector_size(16)));

struct PackedPoint {
  Pair xy = {0.0, 0.0};
  double z = 0.0;
  static PackedPoint load(const double* p) { return {Pair{p[0], p[1]}, p[2]}; }
  void store(double* p) const {
    p[0] = xy[0];
    p[1] = xy[1];
    p[2] = z;
  }
};
inline PackedPoint operator+(PackedPoint a, PackedPoint b) {
  return {a.xy + b.xy, a.z + b.z};
}
inline PackedPoint operator-(PackedPoint a, PackedPoint b) {
  return {a.xy - b.xy, a.z - b.z};
}
inline PackedPoint operator*(double s, PackedPoint a) {
  return {s * a.xy, s * a.z};
}
inline PackedPoint operator*(PackedPoint a, double s) {
  return {a.xy * s, a.z * s};
}

#ifdef __AVX2__
using Quad = double __attribute__((vector_size(32)));

struct QuadPoint {
  Quad v = {0.0, 0.0, 0.0, 0.0};
  static QuadPoint load(const double* p) { return {Quad{p[0], p[1], p[2], 0.0}}; }
  void store(double* p) const {
    p[0] = v[0];
    p[1] = v[1];
    p[2] = v[2];
  }
};
inline QuadPoint operator+(QuadPoint a, QuadPoint b) {
  return {a.v + b.v};
}
inline QuadPoint operator-(QuadPoint a, QuadPoint b) {
  return {a.v - b.v};
}
inline QuadPoint operator*(double s, QuadPoint a) {
  return {s * a.v};
}
inline QuadPoint operator*(QuadPoint a, double s) {
  return {a.v * s};
}
#endif

template <class P>
inline P& operator+=(P& a, P b) {
  return a = a + b;
}
template <class P>
inline P& operator-=(P& a, P b) {
  return a = a - b;
}

// c and d as points, loaded once per pass so that they may stay in registers.
template <class P>
struct Coefficients {
  P c[4], d[4];
  explicit Coefficients(const double* k) {
    for (int q = 0; q < 4; ++q) {
      c[q] = P::load(k + 3 * q);
      d[q] = P::load(k + 12 + 3 * q);
    }
  }
};

// (A u)_i for an N x N CSR matrix A and N x 3 points u (stepper.cpp's other schemes use it
// too).
template <class P>
inline P csrRowProduct(const std::int32_t* outer, const std::int32_t* inner, const double* value,
                       const double* u, std::int32_t i) {
  P sum;
  for (std::int32_t p = outer[i]; p < outer[i + 1]; ++p)
    sum += value[p] * P::load(u + 3 * static_cast<std::size_t>(inner[p]));
  return sum;
}

// (Omega^2 u)_i.
template <class P>
inline P omegaProduct(const Inputs& in, const double* u, std::int32_t i) {
  return csrRowProduct<P>(in.outer, in.inner, in.value, u, i);
}

// (W u)_i = (Omega^2 u)_i - (Omega^2 B)_i c - B_i d.
template <class P>
inline P wProduct(const Inputs& in, const Coefficients<P>& k, const double* u, std::int32_t i) {
  P w = omegaProduct<P>(in, u, i);
  const double* ob = in.omegaBasis + 4 * static_cast<std::size_t>(i);
  const double* b = in.basis + 4 * static_cast<std::size_t>(i);
  for (int q = 0; q < 4; ++q) w -= ob[q] * k.c[q] + b[q] * k.d[q];
  return w;
}

// Adds m_i B_i x and m_i (Omega^2 B)_i x to the block sums.
template <class P>
inline void addMassBases(const Inputs& in, std::int32_t i, P x, P* basis, P* omega) {
  const double* mb = in.massBases + 8 * static_cast<std::size_t>(i);
  for (int q = 0; q < 4; ++q) {
    basis[q] += mb[q] * x;
    omega[q] += mb[4 + q] * x;
  }
}

template <class P>
inline void storeSums(const P* basis, const P* omega, double* partial) {
  for (int q = 0; q < 4; ++q) {
    basis[q].store(partial + 3 * q);
    omega[q].store(partial + 12 + 3 * q);
  }
}

template <class P>
void firstKickRows(const Inputs& in, std::int32_t begin, std::int32_t end, const double* a,
                   double* kick, const double* vIn, double* v, double half, double filter,
                   double* partial) {
  const Coefficients<P> k(in.coefficient);
  P basis[4], omega[4];
  for (std::int32_t i = begin; i < end; ++i) {
    const std::size_t o = 3 * static_cast<std::size_t>(i);
    const P kicked = half * P::load(a + o) - filter * wProduct(in, k, a, i);
    kicked.store(kick + o);
    const P vi = P::load(vIn + o) * in.dampHalf[i] + kicked;
    vi.store(v + o);
    addMassBases(in, i, vi, basis, omega);
  }
  storeSums(basis, omega, partial);
}

template <class P>
void lastKickRows(const Inputs& in, std::int32_t begin, std::int32_t end, const double* a,
                  double* kick, double* v, double half, double filter) {
  const Coefficients<P> k(in.coefficient);
  for (std::int32_t i = begin; i < end; ++i) {
    const std::size_t o = 3 * static_cast<std::size_t>(i);
    const P kicked = half * P::load(a + o) - filter * wProduct(in, k, a, i);
    kicked.store(kick + o);
    ((P::load(v + o) + kicked) * in.dampHalf[i]).store(v + o);
  }
}

template <class P>
void velocityRows(const Inputs& in, std::int32_t begin, std::int32_t end, const double* vIn,
                  double* v, const double* kick, double* partial) {
  P basis[4], omega[4];
  for (std::int32_t i = begin; i < end; ++i) {
    const std::size_t o = 3 * static_cast<std::size_t>(i);
    const P vi = P::load(vIn + o) * in.dampHalf[i] + P::load(kick + o);
    vi.store(v + o);
    addMassBases(in, i, vi, basis, omega);
  }
  storeSums(basis, omega, partial);
}

template <class P>
void hornerRows(const Inputs& in, std::int32_t begin, std::int32_t end, const double* u,
                const double* v, double* out, double a, double scale, double* partial) {
  const Coefficients<P> k(in.coefficient);
  P omega[4];
  for (std::int32_t i = begin; i < end; ++i) {
    const std::size_t o = 3 * static_cast<std::size_t>(i);
    const P x = a * P::load(v + o) + scale * wProduct(in, k, u, i);
    x.store(out + o);
    // m_i (Omega^2 B)_i made here from the row of Omega^2 B that wProduct just read: the
    // product massBases holds (the same bits), without streaming its 64-byte rows, of which
    // this pass would use half: 168 of the 1560 bytes a vertex the step moves, and at scale
    // the step waits on memory (docs/performance.md).
    const double m = in.mass[i];
    const double* ob = in.omegaBasis + 4 * static_cast<std::size_t>(i);
    for (int q = 0; q < 4; ++q) omega[q] += (m * ob[q]) * x;
  }
  for (int q = 0; q < 4; ++q) omega[q].store(partial + 12 + 3 * q);
}

template <class P>
void driftRows(const Inputs& in, std::int32_t begin, std::int32_t end, const double* w,
               const double* v, const double* rIn, double* r, double t, double t2) {
  const Coefficients<P> k(in.coefficient);
  for (std::int32_t i = begin; i < end; ++i) {
    const std::size_t o = 3 * static_cast<std::size_t>(i);
    (P::load(rIn + o) + t * (P::load(v + o) + t2 * wProduct(in, k, w, i))).store(r + o);
  }
}

template <class P>
void plainKickRows(const Inputs& in, std::int32_t begin, std::int32_t end, const double* a,
                   double* kick, double* v, double half, double filter) {
  for (std::int32_t i = begin; i < end; ++i) {
    const std::size_t o = 3 * static_cast<std::size_t>(i);
    const P kicked = half * P::load(a + o) - filter * omegaProduct<P>(in, a, i);
    kicked.store(kick + o);
    ((P::load(v + o) + kicked) * in.dampHalf[i]).store(v + o);
  }
}

template <class P>
void plainDriftRows(const Inputs& in, std::int32_t begin, std::int32_t end, const double* vIn,
                    double* v, const double* kick, const double* rIn, double* r, double t) {
  for (std::int32_t i = begin; i < end; ++i) {
    const std::size_t o = 3 * static_cast<std::size_t>(i);
    const P vi = P::load(vIn + o) * in.dampHalf[i] + P::load(kick + o);
    vi.store(v + o);
    (P::load(rIn + o) + t * vi).store(r + o);
  }
}

template <class P>
Kernels makeKernels() {
  return {&firstKickRows<P>, &lastKickRows<P>,  &velocityRows<P>,  &hornerRows<P>,
          &driftRows<P>,     &plainKickRows<P>, &plainDriftRows<P>};
}

}  // namespace
}  // namespace zsculpt::filter_rows
