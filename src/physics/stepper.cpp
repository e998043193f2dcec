#include "zsculpt/physics/stepper.h"

#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <unsupported/Eigen/MatrixFunctions>

#include "zsculpt/core/errors.h"

#ifdef _OPENMP
#include <omp.h>
#endif

namespace zsculpt {

std::string_view schemeName(Scheme scheme) {
  switch (scheme) {
    case Scheme::Default: return "default";
    case Scheme::Paper: return "paper";
    case Scheme::Exact: return "exact";
    case Scheme::SymplecticEuler: return "symplectic-euler";
    case Scheme::ImplicitEuler: return "implicit-euler";
  }
  return "?";
}

Scheme schemeFromName(std::string_view name) {
  for (Scheme s : {Scheme::Default, Scheme::Paper, Scheme::Exact, Scheme::SymplecticEuler,
                   Scheme::ImplicitEuler})
    if (schemeName(s) == name) return s;
  throw InvalidInputError("unknown scheme '" + std::string(name) +
                          "' (valid: default, paper, exact, symplectic-euler, implicit-euler)");
}

double stablePeriodLimit(Scheme scheme, double lambda0) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  if (!(lambda0 > 0.0)) return inf;
  switch (scheme) {
    case Scheme::Default:
    case Scheme::Paper: return std::sqrt(12.0 / lambda0);
    case Scheme::SymplecticEuler: return std::sqrt(4.0 / lambda0);
    case Scheme::Exact:
    case Scheme::ImplicitEuler: return inf;
  }
  return inf;
}

struct Stepper::Implicit {
  Eigen::SparseMatrix<double> a;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver;
  VectorX rhs, dv, flat;
};

namespace {

int maximumThreads() {
#ifdef _OPENMP
  return omp_get_max_threads();
#else
  return 1;
#endif
}

// (A x)_i for the N x N CSR matrix A and N x 3 points x.
inline void rowProduct(const SparseRowMatrix& a, const double* x, Index i, double out[3]) {
  const Index* outer = a.outerIndexPtr();
  const Index* inner = a.innerIndexPtr();
  const double* value = a.valuePtr();
  double sx = 0.0, sy = 0.0, sz = 0.0;
  for (Index p = outer[i]; p < outer[i + 1]; ++p) {
    const double* r = x + 3 * static_cast<size_t>(inner[p]);
    sx += value[p] * r[0];
    sy += value[p] * r[1];
    sz += value[p] * r[2];
  }
  out[0] = sx;
  out[1] = sy;
  out[2] = sz;
}

bool rowsAreZero(const Points& x, Index begin, Index end) {
  // The bits of every value but its sign, or-ed together (vectorises; NaN is not zero).
  const double* p = x.data() + 3 * static_cast<size_t>(begin);
  const size_t count = 3 * static_cast<size_t>(end - begin);
  std::uint64_t bits = 0;
  for (size_t k = 0; k < count; ++k) bits |= std::bit_cast<std::uint64_t>(p[k]) << 1;
  return bits == 0;
}

// Models up to this many vertices keep their accelerations in an array for the filter's
// product (it stays in cache); larger ones make them on the fly from the forces, saving
// the array's memory traffic. The values are the same either way.
constexpr Index kStoredAccelerationVertices = 65536;

}  // namespace

int automaticThreads(Index vertices) {
  return vertices >= kParallelMinVertices ? maximumThreads() : 1;
}

void Stepper::ThreadTuner::record(double seconds) {
  if (phase < 2) {
    best[phase] = count == 0 ? seconds : std::min(best[phase], seconds);
    if (++count < kProbeSteps) return;
    count = 0;
    if (++phase == 2) {
      chosen = best[1] < best[0] ? candidates[1] : candidates[0];
      held = 0.0;
    }
    return;
  }
  held += seconds;
  if (held >= kHoldSeconds) phase = 0;
}

Stepper::Stepper(const Model& model, Scheme scheme, double period, const StepperOptions& options)
    : model_(model), scheme_(scheme), period_(period), options_(options), system_(model) {
  if (!(period > 0.0) || !std::isfinite(period))
    throw InvalidInputError("time step " + std::to_string(period) + " must be positive");
  const Index n = model.mesh.numVertices();
  const int most = options.threads > 0 ? options.threads : automaticThreads(n);
  threads_ = most;
  tuning_ = options.threads <= 0 && most > 1;
  tuner_.candidates[0] = most;
  tuner_.candidates[1] = 1;
  forces_ = ForceKernel(model, most);
  for (Points* p : {&internal_, &previousInternal_, &acceleration_, &kick_, &totalForce_})
    p->setZero(n, 3);
  if (scheme_ == Scheme::Paper || scheme_ == Scheme::Exact)
    for (Points* p : {&work1_, &work2_, &work3_, &work4_}) p->setZero(n, 3);
  externalZero_.assign(static_cast<size_t>(forces_.numBlocks()), 1);
  dampHalf_.resize(n);
  dampFull_.resize(n);
  refreshDamping({});
  if (scheme_ == Scheme::Paper)
    transformation_ = std::make_unique<TransformationMatrices>(system_, period_);
  if (scheme_ == Scheme::Exact) setUpExact();
  if (scheme_ == Scheme::ImplicitEuler) implicit_ = std::make_unique<Implicit>();
}

Stepper::~Stepper() = default;

void Stepper::refreshDamping(std::span<const Index> vertices) {
  // mu v' = -rho v over a time tau is exactly v *= exp(-2 G tau); exp(0) = 1 exactly, so an
  // undamped vertex is left bit for bit as it is.
  const VectorX& g = system_.dampingCoefficient();
  auto refresh = [&](Index i) {
    dampHalf_[i] = std::exp(-g[i] * period_);
    dampFull_[i] = std::exp(-2.0 * g[i] * period_);
  };
  if (vertices.empty())
    for (Index i = 0; i < g.size(); ++i) refresh(i);
  else
    for (Index i : vertices) refresh(i);
}

void Stepper::propertiesChanged(std::span<const Index> vertices) {
  system_.updateVertices(model_, vertices);
  if (transformation_) transformation_->updateVertices(system_, vertices);
  if (scheme_ == Scheme::Exact) setUpExact();
  forces_.propertiesChanged(model_, vertices);
  if (!vertices.empty()) refreshDamping(vertices);
  cacheValid_ = false;
  kickValid_ = false;
}

void Stepper::rebuild() {
  system_ = SystemMatrices(model_);
  if (transformation_) *transformation_ = TransformationMatrices(system_, period_);
  if (scheme_ == Scheme::Exact) setUpExact();
  forces_.rebuild(model_);
  refreshDamping({});
  cacheValid_ = false;
  kickValid_ = false;
}

size_t Stepper::bytes() const {
  auto sparse = [](const SparseRowMatrix& m) {
    return static_cast<size_t>(m.nonZeros()) * (sizeof(double) + sizeof(Index)) +
           static_cast<size_t>(m.outerSize() + 1) * sizeof(Index);
  };
  auto dense = [](const auto& m) { return static_cast<size_t>(m.size()) * sizeof(double); };
  size_t total = sparse(system_.stiffness()) + sparse(system_.omega2()) +
                 dense(system_.inverseMass()) + dense(system_.dampingCoefficient()) +
                 forces_.bytes() + dense(dampHalf_) + dense(dampFull_) + externalZero_.size();
  for (const Points* p : std::initializer_list<const Points*>{&internal_, &previousInternal_, &acceleration_, &kick_, &totalForce_,
                          &work1_, &work2_, &work3_, &work4_})
    total += dense(*p);
  if (transformation_)
    for (const SparseRowMatrix* m :
         {&transformation_->omega4(), &transformation_->h(), &transformation_->hPrime(),
          &transformation_->hSecond(), &transformation_->x(), &transformation_->xPrime()})
      total += sparse(*m);
  total += dense(modes_) + dense(propagator_) + dense(modal1_) + dense(modal2_) + dense(modal3_);
  if (implicit_)
    total += static_cast<size_t>(implicit_->a.nonZeros()) * (sizeof(double) + sizeof(int)) +
             dense(implicit_->rhs) + dense(implicit_->dv) + dense(implicit_->flat);
  return total;
}

const Points& Stepper::lastTotalForce() const {
  if (!totalForceReady_) {
    // The last step had no external force: internal forces at its start plus gravity.
    totalForce_ = previousInternal_;
    const PhysicalProperties& p = model_.properties;
    if (!p.gravity.isZero()) {
      const Eigen::RowVector3d g = p.gravity.transpose();
      for (Index i = 0; i < totalForce_.rows(); ++i) totalForce_.row(i) += p.mass[i] * g;
    }
    totalForceReady_ = true;
  }
  return totalForce_;
}

void Stepper::step(State& state, const Points& external, std::span<const double> share) {
  ZSCULPT_ASSERT(state.position.rows() == model_.mesh.numVertices() &&
                     state.velocity.rows() == model_.mesh.numVertices() &&
                     external.rows() == model_.mesh.numVertices(),
                 "state or external forces do not match the model");
  const auto start = std::chrono::steady_clock::now();
  if (tuning_) threads_ = tuner_.next();
  switch (scheme_) {
    case Scheme::Default: stepDefault(state, external, share); break;
    case Scheme::Paper: stepPaper(state, external, share); break;
    case Scheme::Exact: stepExact(state, external, share); break;
    case Scheme::SymplecticEuler: stepSymplecticEuler(state, external, share); break;
    case Scheme::ImplicitEuler: stepImplicitEuler(state, external, share); break;
  }
  state.time += period_;
  if (tuning_)
    tuner_.record(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
}

bool Stepper::accelerationRows(Index block, const Points& internal, const Points& external,
                               std::span<const double> share, bool writeTotal) {
  // a = sigma M^-1 F_tot, F_tot = (internal + external) + mu g, in this order (section 4.3
  // for sigma).
  const Index begin = forces_.blockBegin(block), end = forces_.blockEnd(block);
  const bool zero = rowsAreZero(external, begin, end);
  const VectorX& inverseMass = system_.inverseMass();
  const PhysicalProperties& p = model_.properties;
  const bool gravity = !p.gravity.isZero();
  const double gx = p.gravity.x(), gy = p.gravity.y(), gz = p.gravity.z();
  const double* f = internal.data();
  const double* e = external.data();
  double* a = acceleration_.data();
  double* total = totalForce_.data();
  for (Index i = begin; i < end; ++i) {
    const size_t k = 3 * static_cast<size_t>(i);
    double x = f[k], y = f[k + 1], z = f[k + 2];
    if (!zero) {
      x += e[k];
      y += e[k + 1];
      z += e[k + 2];
    }
    if (gravity) {
      const double mu = p.mass[i];
      x += mu * gx;
      y += mu * gy;
      z += mu * gz;
    }
    if (writeTotal) {
      total[k] = x;
      total[k + 1] = y;
      total[k + 2] = z;
    }
    const double scale = share.empty() ? inverseMass[i] : share[static_cast<size_t>(i)] * inverseMass[i];
    a[k] = scale * x;
    a[k + 1] = scale * y;
    a[k + 2] = scale * z;
  }
  externalZero_[static_cast<size_t>(block)] = zero ? 1 : 0;
  return zero;
}

void Stepper::computeAcceleration(const Points& position, const Points& external,
                                  std::span<const double> share) {
  // Serial form for the exact and implicit schemes.
  forces_.compute(model_, position, internal_, threads_);
  for (Index b = 0; b < forces_.numBlocks(); ++b) accelerationRows(b, internal_, external, share, true);
  totalForceReady_ = true;
}

void Stepper::stepDefault(State& s, const Points& external, std::span<const double> share) {
  // Velocity Verlet with the filtered acceleration Phi a, Phi = I - T^2 Omega^2 / 12, and
  // the damping of G exactly over two half steps (stepper.h):
  //   v <- e^{-GT} v + (T/2) Phi a(r);  r <- r + T v;  v <- e^{-GT} (v + (T/2) Phi a(r)).
  // Passes over the blocks: external forces checked for zero; kick and drift; internal
  // forces (ForceKernel's two phases); kick and damping. The accelerations are made on the
  // fly inside the filter's product (a_j = sigma_j M_j^-1 ((F_j + F_ext,j) + mu_j g), the
  // same expression as accelerationRows) instead of being stored and read back. The first
  // kick equals the last step's second one while nothing but the position changed (same
  // internal forces, zero external forces, no share): it is kept in kick_.
  const double t = period_, half = 0.5 * t, filter = t * t * t / 24.0;
  const Index blocks = forces_.numBlocks();
  const bool startCached = cacheValid_;
  const bool reuseCandidate = cacheValid_ && kickValid_ && share.empty();
  const SparseRowMatrix& o2 = system_.omega2();
  const Index* outer = o2.outerIndexPtr();
  const Index* inner = o2.innerIndexPtr();
  const double* value = o2.valuePtr();
  const double* inverseMass = system_.inverseMass().data();
  const double* mass = model_.properties.mass.data();
  const Vec3 g = model_.properties.gravity;
  const bool gravity = !g.isZero();
  const double* e = external.data();
  double* r = s.position.data();
  double* v = s.velocity.data();
  double* kick = kick_.data();
  const bool stored = model_.mesh.numVertices() <= kStoredAccelerationVertices;
  bool externalZero = true;
#pragma omp parallel num_threads(threads_) if (threads_ > 1)
  {
#pragma omp for schedule(static)
    for (Index b = 0; b < blocks; ++b)
      externalZero_[static_cast<size_t>(b)] =
          rowsAreZero(external, forces_.blockBegin(b), forces_.blockEnd(b)) ? 1 : 0;
    bool zero = true;
    for (Index b = 0; b < blocks; ++b) zero = zero && externalZero_[static_cast<size_t>(b)];
    const bool reuse = reuseCandidate && zero;
    // a_j from the internal forces f, as accelerationRows makes it (and the total force),
    // and (T/2) Phi a at row i: (T/2) a_i - (T^3/24) (Omega^2 a)_i. Specialised on whether
    // there are loads, gravity and an elastic share, so that the common case is a tight loop.
    auto withCase = [&](auto&& body) {
      auto s3 = [&](auto l, auto g3) {
        share.empty() ? body(l, g3, std::false_type{}) : body(l, g3, std::true_type{});
      };
      auto s2 = [&](auto l) { gravity ? s3(l, std::true_type{}) : s3(l, std::false_type{}); };
      zero ? s2(std::false_type{}) : s2(std::true_type{});
    };
    auto acceleration = [&](auto loads, auto withGravity, auto withShare, const double* f,
                            Index j, double a[3], double* sum) {
      const size_t k = 3 * static_cast<size_t>(j);
      double x = f[k], y = f[k + 1], z = f[k + 2];
      if constexpr (decltype(loads)::value) {
        x += e[k];
        y += e[k + 1];
        z += e[k + 2];
      }
      if constexpr (decltype(withGravity)::value) {
        x += mass[j] * g.x();
        y += mass[j] * g.y();
        z += mass[j] * g.z();
      }
      if (sum) {
        sum[0] = x;
        sum[1] = y;
        sum[2] = z;
      }
      double scale = inverseMass[j];
      if constexpr (decltype(withShare)::value) scale = share[static_cast<size_t>(j)] * scale;
      a[0] = scale * x;
      a[1] = scale * y;
      a[2] = scale * z;
    };
    auto filteredKick = [&](auto loads, auto withGravity, auto withShare, const double* f,
                            Index i, double* out, double* total) {
      double wx = 0.0, wy = 0.0, wz = 0.0;
      for (Index p = outer[i]; p < outer[i + 1]; ++p) {
        double a[3];
        acceleration(loads, withGravity, withShare, f, inner[p], a, nullptr);
        wx += value[p] * a[0];
        wy += value[p] * a[1];
        wz += value[p] * a[2];
      }
      double a[3];
      acceleration(loads, withGravity, withShare, f, i, a, total);
      out[0] = half * a[0] - filter * wx;
      out[1] = half * a[1] - filter * wy;
      out[2] = half * a[2] - filter * wz;
    };
    // The same from stored accelerations.
    auto storedKick = [&](Index i, double* out) {
      const double* a = acceleration_.data();
      double wx = 0.0, wy = 0.0, wz = 0.0;
      for (Index p = outer[i]; p < outer[i + 1]; ++p) {
        const double* aj = a + 3 * static_cast<size_t>(inner[p]);
        wx += value[p] * aj[0];
        wy += value[p] * aj[1];
        wz += value[p] * aj[2];
      }
      const double* ai = a + 3 * static_cast<size_t>(i);
      out[0] = half * ai[0] - filter * wx;
      out[1] = half * ai[1] - filter * wy;
      out[2] = half * ai[2] - filter * wz;
    };
    if (!reuse && !startCached) {
      forces_.scatter(model_, s.position, internal_);
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b) forces_.gatherBlock(b, internal_);
    }
    // Kick and drift; with loads, the total force at the start on the way (lastTotalForce).
    const double* f0 = internal_.data();
    double* total = zero ? nullptr : totalForce_.data();
    withCase([&](auto loads, auto withGravity, auto withShare) {
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b)
        for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
          const size_t k = 3 * static_cast<size_t>(i);
          if (!reuse)
            filteredKick(loads, withGravity, withShare, f0, i, kick + k,
                         total ? total + k : nullptr);
          const double damp = dampHalf_[i];
          for (int d = 0; d < 3; ++d) {
            v[k + d] = v[k + d] * damp + kick[k + d];
            r[k + d] += t * v[k + d];
          }
        }
    });
    // Internal forces at the new position.
    forces_.scatter(model_, s.position, previousInternal_);
    const double* f1 = previousInternal_.data();
    if (stored) {
      withCase([&](auto loads, auto withGravity, auto withShare) {
#pragma omp for schedule(static)
        for (Index b = 0; b < blocks; ++b) {
          forces_.gatherBlock(b, previousInternal_);
          for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i)
            acceleration(loads, withGravity, withShare, f1, i,
                         acceleration_.data() + 3 * static_cast<size_t>(i), nullptr);
        }
      });
    } else {
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b) forces_.gatherBlock(b, previousInternal_);
    }
    // Second kick and damping.
    withCase([&](auto loads, auto withGravity, auto withShare) {
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b)
        for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
          const size_t k = 3 * static_cast<size_t>(i);
          if (stored)
            storedKick(i, kick + k);
          else
            filteredKick(loads, withGravity, withShare, f1, i, kick + k, nullptr);
          const double damp = dampHalf_[i];
          for (int d = 0; d < 3; ++d) v[k + d] = (v[k + d] + kick[k + d]) * damp;
        }
    });
#pragma omp single
    externalZero = zero;
  }
  // previousInternal_ now holds the forces at the new position: swap the two buffers. The
  // total force at the start was written with loads, else it is made on demand.
  internal_.swap(previousInternal_);
  totalForceReady_ = !externalZero;
  cacheValid_ = true;
  kickValid_ = share.empty() && externalZero;
}

void Stepper::stepPaper(State& s, const Points& external, std::span<const double> share) {
  const double t = period_, t2 = t * t, t3 = t2 * t, t4 = t2 * t2, t5 = t4 * t, t6 = t4 * t2;
  const Index blocks = forces_.numBlocks();
  const SparseRowMatrix& o2 = system_.omega2();
  const VectorX& g = system_.dampingCoefficient();
  const bool stored = options_.storedMatrices;
  double* r = s.position.data();
  double* v = s.velocity.data();
  const double* a = acceleration_.data();
  double* w1 = work1_.data();
  double* w3 = work3_.data();
#pragma omp parallel num_threads(threads_) if (threads_ > 1)
  {
    forces_.scatter(model_, s.position, internal_);
#pragma omp for schedule(static)
    for (Index b = 0; b < blocks; ++b) {
      forces_.gatherBlock(b, internal_);
      accelerationRows(b, internal_, external, share, true);
    }
    if (stored) {
      // Equation 3 with the stored two-ring matrices (one pattern: Omega^4's), all four
      // products of a row in one pass; the new velocity waits in work3_ (v is still read).
      const TransformationMatrices& m = *transformation_;
      const Index* outer = m.h().outerIndexPtr();
      const Index* inner = m.h().innerIndexPtr();
      const double* h = m.h().valuePtr();
      const double* hp = m.hPrime().valuePtr();
      const double* x = m.x().valuePtr();
      const double* xp = m.xPrime().valuePtr();
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b)
        for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
          double hpv[3] = {0, 0, 0}, ha[3] = {0, 0, 0}, xpv[3] = {0, 0, 0}, xa[3] = {0, 0, 0};
          for (Index p = outer[i]; p < outer[i + 1]; ++p) {
            const size_t j = 3 * static_cast<size_t>(inner[p]);
            for (int d = 0; d < 3; ++d) {
              hpv[d] += hp[p] * v[j + d];
              ha[d] += h[p] * a[j + d];
              xpv[d] += xp[p] * v[j + d];
              xa[d] += x[p] * a[j + d];
            }
          }
          const size_t k = 3 * static_cast<size_t>(i);
          for (int d = 0; d < 3; ++d) {
            r[k + d] += hpv[d] + ha[d];
            w3[k + d] = xpv[d] + xa[d];
          }
        }
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b)
        for (size_t k = 3 * static_cast<size_t>(forces_.blockBegin(b));
             k < 3 * static_cast<size_t>(forces_.blockEnd(b)); ++k)
          v[k] = w3[k];
    } else {
      // Equation 3 with the polynomials in Omega^2 applied to the state: Omega^2 v and
      // Omega^2 a in one pass, then Omega^4 v, Omega^4 a and the update in a second one (four
      // one-ring products instead of four two-ring ones; bench_physics measures both).
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b)
        for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
          rowProduct(o2, v, i, w1 + 3 * static_cast<size_t>(i));
          rowProduct(o2, a, i, w3 + 3 * static_cast<size_t>(i));
        }
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b)
        for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
          double w2[3], w4[3];
          rowProduct(o2, w1, i, w2);
          rowProduct(o2, w3, i, w4);
          const size_t k = 3 * static_cast<size_t>(i);
          for (int d = 0; d < 3; ++d) {
            const double hpv = t * v[k + d] - t3 / 6.0 * w1[k + d] + t5 / 120.0 * w2[d];
            const double hppv = v[k + d] - t2 / 2.0 * w1[k + d] + t4 / 24.0 * w2[d];
            const double ha = t2 / 2.0 * a[k + d] - t4 / 24.0 * w3[k + d] + t6 / 720.0 * w4[d];
            const double hpa = t * a[k + d] - t3 / 6.0 * w3[k + d] + t5 / 120.0 * w4[d];
            r[k + d] += hpv + ha;
            v[k + d] = (hppv - g[i] * hpv) + (hpa - g[i] * ha);
          }
        }
    }
  }
  totalForceReady_ = true;
  cacheValid_ = false;
}

void Stepper::setUpExact() {
  const Index n = model_.mesh.numVertices();
  if (n > options_.exactMaxVertices)
    throw InvalidInputError("scheme exact: the model has " + std::to_string(n) +
                            " vertices, more than the dense eigendecomposition's limit of " +
                            std::to_string(options_.exactMaxVertices));
  const VectorX& g = system_.dampingCoefficient();
  const double gamma = g.minCoeff();
  if (g.maxCoeff() - gamma > 1e-12 * std::max(1.0, std::abs(gamma)))
    throw InvalidInputError(
        "scheme exact: needs damping proportional to mass (the same rho / mu at every vertex)");
  sqrtMass_ = system_.inverseMass().cwiseInverse().cwiseSqrt();
  const VectorX scale = sqrtMass_.cwiseInverse();
  const Eigen::MatrixXd symmetric =
      scale.asDiagonal() * Eigen::MatrixXd(system_.stiffness()) * scale.asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(symmetric);
  if (eig.info() != Eigen::Success) throw SolverError("scheme exact: eigendecomposition failed");
  modes_ = eig.eigenvectors();
  propagator_.resize(n, 6);
  for (Index k = 0; k < n; ++k) {
    // x'' + 2 gamma x' + w^2 x = b (b constant over the step), as a 3 x 3 exponential.
    const double w2 = std::max(0.0, eig.eigenvalues()[k]);
    Mat3 generator;
    generator << 0, 1, 0, -w2, -2 * gamma, 1, 0, 0, 0;
    const Mat3 e = (generator * period_).exp();
    propagator_.row(k) << e(0, 0), e(0, 1), e(0, 2), e(1, 0), e(1, 1), e(1, 2);
  }
  modal1_.setZero(n, 3);
  modal2_.setZero(n, 3);
  modal3_.setZero(n, 3);
}

void Stepper::stepExact(State& s, const Points& external, std::span<const double> share) {
  computeAcceleration(s.position, external, share);
  cacheValid_ = false;
  // What the linear model -Omega^2 r does not capture, held over the step.
  multiply(system_.omega2(), s.position, work1_);
  work1_ += acceleration_;
  work2_ = sqrtMass_.asDiagonal() * s.position;
  modal1_.noalias() = modes_.transpose() * work2_;
  work2_ = sqrtMass_.asDiagonal() * s.velocity;
  modal2_.noalias() = modes_.transpose() * work2_;
  work2_ = sqrtMass_.asDiagonal() * work1_;
  modal3_.noalias() = modes_.transpose() * work2_;
  for (Index k = 0; k < modal1_.rows(); ++k) {
    const auto p = propagator_.row(k);
    const Eigen::RowVector3d r = modal1_.row(k), v = modal2_.row(k), b = modal3_.row(k);
    modal1_.row(k) = p[0] * r + p[1] * v + p[2] * b;
    modal2_.row(k) = p[3] * r + p[4] * v + p[5] * b;
  }
  const VectorX inverseSqrtMass = sqrtMass_.cwiseInverse();
  work2_.noalias() = modes_ * modal1_;
  s.position = inverseSqrtMass.asDiagonal() * work2_;
  work2_.noalias() = modes_ * modal2_;
  s.velocity = inverseSqrtMass.asDiagonal() * work2_;
}

void Stepper::stepSymplecticEuler(State& s, const Points& external, std::span<const double> share) {
  // v <- e^{-2GT} (v + T a(r)); r <- r + T v: the update fused with the acceleration.
  const double t = period_;
  const Index blocks = forces_.numBlocks();
  double* r = s.position.data();
  double* v = s.velocity.data();
  const double* a = acceleration_.data();
#pragma omp parallel num_threads(threads_) if (threads_ > 1)
  {
    forces_.scatter(model_, s.position, internal_);
#pragma omp for schedule(static)
    for (Index b = 0; b < blocks; ++b) {
      forces_.gatherBlock(b, internal_);
      accelerationRows(b, internal_, external, share, true);
      for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
        const size_t k = 3 * static_cast<size_t>(i);
        const double damp = dampFull_[i];
        for (int d = 0; d < 3; ++d) {
          v[k + d] = (v[k + d] + t * a[k + d]) * damp;
          r[k + d] += t * v[k + d];
        }
      }
    }
  }
  totalForceReady_ = true;
  cacheValid_ = false;
}

namespace {

// d theta / d(c, a, b) of the angle at c between arms to a and b (zero when degenerate).
bool angleGradient(const Vec3& c, const Vec3& a, const Vec3& b, Vec3& gc, Vec3& ga, Vec3& gb) {
  Vec3 fc, fa, fb;
  // angleSpringForce with kappa = 1 and rest angle theta - 1 returns -grad(theta).
  const Vec3 u = a - c, w = b - c;
  if (u.norm() == 0.0 || w.norm() == 0.0) return false;
  const double theta = std::atan2(u.cross(w).norm(), u.dot(w));
  angleSpringForce(c, a, b, 1.0, theta - 1.0, fc, fa, fb);
  gc = -fc;
  ga = -fa;
  gb = -fb;
  return true;
}

}  // namespace

void Stepper::stepImplicitEuler(State& s, const Points& external, std::span<const double> share) {
  // Baraff and Witkin 1998: (M + h D - h^2 J) dv = h (f0 - D v0 + h J v0), J the force
  // Jacobian: exact for radial springs with the compressive transverse term clamped at zero
  // (so the matrix stays positive definite), Gauss-Newton for angle springs.
  const double h = period_;
  const Index n = model_.mesh.numVertices();
  const Mesh& mesh = model_.mesh;
  const PhysicalProperties& p = model_.properties;
  Implicit& im = *implicit_;
  computeAcceleration(s.position, external, share);
  cacheValid_ = false;

  auto addBlock = [&](Index bi, Index bj, const Mat3& block, bool assemble) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        if (assemble)
          im.a.coeffRef(3 * bi + r, 3 * bj + c) += block(r, c);
        else
          im.a.insert(3 * bi + r, 3 * bj + c) = 0.0;  // pattern pass (first step only)
      }
  };
  auto forEachContribution = [&](bool assemble) {
    for (Index e = 0; e < mesh.numEdges(); ++e) {
      const auto [i, j] = mesh.edge(e);
      const double kappa = edgeStiffness(p.stiffness[i], p.stiffness[j]);
      Mat3 b = Mat3::Zero();
      if (assemble && kappa != 0.0) {
        const Vec3 d = s.position.row(i) - s.position.row(j);
        const double len = d.norm();
        const Vec3 u = len > 0.0 ? Vec3(d / len) : Vec3::UnitX();
        const double transverse = len > 0.0 ? std::max(0.0, 1.0 - p.restLength[e] / len) : 0.0;
        const Mat3 uu = u * u.transpose();
        b = kappa * h * h * (transverse * (Mat3::Identity() - uu) + uu);
      }
      addBlock(i, i, b, assemble);
      addBlock(j, j, b, assemble);
      addBlock(i, j, -b, assemble);
      addBlock(j, i, -b, assemble);
    }
    for (size_t k = 0; k < model_.angles.angles.size(); ++k) {
      const auto [c, a, b] = model_.angles.angles[k];
      const double kappa = p.angularStiffness[c];
      if (kappa == 0.0) continue;
      std::array<Vec3, 3> grad{Vec3::Zero(), Vec3::Zero(), Vec3::Zero()};
      if (assemble)
        angleGradient(s.position.row(c), s.position.row(a), s.position.row(b), grad[0], grad[1],
                      grad[2]);
      const std::array<Index, 3> ids{c, a, b};
      for (int q = 0; q < 3; ++q)
        for (int r = 0; r < 3; ++r)
          addBlock(ids[q], ids[r], (kappa * h * h) * grad[q] * grad[r].transpose(), assemble);
    }
    for (Index i = 0; i < n; ++i)
      addBlock(i, i, (p.mass[i] + h * p.damping[i]) * Mat3::Identity(), assemble);
  };

  if (im.a.rows() != 3 * n) {
    // Pattern: sum duplicates through triplets once, then analyse.
    std::vector<Eigen::Triplet<double>> triplets;
    im.a.resize(3 * n, 3 * n);
    Eigen::SparseMatrix<double, Eigen::RowMajor> scratch(3 * n, 3 * n);
    (void)scratch;
    auto collect = [&](Index bi, Index bj) {
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) triplets.emplace_back(3 * bi + r, 3 * bj + c, 0.0);
    };
    for (Index e = 0; e < mesh.numEdges(); ++e) {
      const auto [i, j] = mesh.edge(e);
      collect(i, j);
      collect(j, i);
    }
    for (const auto& [c, a, b] : model_.angles.angles) {
      collect(c, a), collect(a, c), collect(c, b), collect(b, c), collect(a, b), collect(b, a);
    }
    for (Index i = 0; i < n; ++i) collect(i, i);
    im.a.setFromTriplets(triplets.begin(), triplets.end());
    im.a.makeCompressed();
    im.solver.analyzePattern(im.a);
    im.rhs.resize(3 * n);
    im.dv.resize(3 * n);
    im.flat.resize(3 * n);
  }
  im.a.coeffs().setZero();
  forEachContribution(true);
  im.solver.factorize(im.a);
  if (im.solver.info() != Eigen::Success) throw DivergenceError("implicit-euler: factorisation failed");
  // -J v0 = (A - M - h D) v0 / h^2.
  for (Index i = 0; i < n; ++i) im.flat.segment<3>(3 * i) = s.velocity.row(i).transpose();
  im.rhs.noalias() = im.a * im.flat;
  for (Index i = 0; i < n; ++i) {
    const Vec3 v = s.velocity.row(i).transpose();
    const Vec3 minusJv = (im.rhs.segment<3>(3 * i) - (p.mass[i] + h * p.damping[i]) * v) / (h * h);
    const double sh = share.empty() ? 1.0 : share[i];
    im.rhs.segment<3>(3 * i) =
        h * (sh * totalForce_.row(i).transpose() - p.damping[i] * v - h * minusJv);
  }
  im.dv = im.solver.solve(im.rhs);
  for (Index i = 0; i < n; ++i) s.velocity.row(i) += im.dv.segment<3>(3 * i).transpose();
  s.position += h * s.velocity;
}

}  // namespace zsculpt
