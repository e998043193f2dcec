#include "zsculpt/physics/stepper.h"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>
#include <string>
#include <type_traits>
#include <unsupported/Eigen/MatrixFunctions>

#include "filter_rows_impl.h"
#include "zsculpt/core/errors.h"
#include "zsculpt/core/parts.h"
#include "zsculpt/physics/diagnostics.h"

#ifdef _OPENMP
#include <omp.h>
#endif

namespace zsculpt {

std::string_view schemeName(Scheme scheme) {
  switch (scheme) {
    case Scheme::Default:
      return "default";
    case Scheme::Paper:
      return "paper";
    case Scheme::Exact:
      return "exact";
    case Scheme::SymplecticEuler:
      return "symplectic-euler";
    case Scheme::ImplicitEuler:
      return "implicit-euler";
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

double stablePeriodLimit(Scheme scheme, double lambda0, double largestDampingRate) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  if (scheme == Scheme::Paper) {
    const double spring = lambda0 > 0.0 ? std::sqrt(12.0 / lambda0) : inf;
    return largestDampingRate > 0.0 ? std::min(spring, 1.0 / largestDampingRate) : spring;
  }
  if (!(lambda0 > 0.0)) return inf;
  switch (scheme) {
    case Scheme::Default:
    case Scheme::Paper:
      return std::sqrt(12.0 / lambda0);
    case Scheme::SymplecticEuler:
      return std::sqrt(4.0 / lambda0);
    case Scheme::Exact:
    case Scheme::ImplicitEuler:
      return inf;
  }
  return inf;
}

double stablePeriodLimit(Scheme scheme, const SystemMatrices& system, double largestEigenvalue) {
  const VectorX& g = system.dampingCoefficient();
  return stablePeriodLimit(scheme, largestEigenvalue, g.size() > 0 ? g.maxCoeff() : 0.0);
}

double gershgorinStablePeriodLimit(Scheme scheme, const SystemMatrices& system) {
  const SparseRowMatrix& o2 = system.omega2();
  const double maxDiagonal = o2.size() > 0 ? o2.diagonal().maxCoeff() : 0.0;
  return stablePeriodLimit(scheme, system, std::max(2.0 * maxDiagonal, 0.0));
}

struct Stepper::Implicit {
  Eigen::SparseMatrix<double> a;  // symmetric, both triangles stored
  // dv is the previous step's solution until the next solve: the warm start.
  VectorX rhs, dv, flat, inverseDiagonal, residual, direction, preconditioned, product;
};

namespace {

int maximumThreads() {
#ifdef _OPENMP
  return omp_get_max_threads();
#else
  return 1;
#endif
}

// Points packed as the drift filter's row kernels pack them (filter_rows_impl.h).
using filter_rows::PackedPoint;

inline PackedPoint loadPoint(const double* p) {
  return PackedPoint::load(p);
}

inline void storePoint(double* p, PackedPoint v) {
  v.store(p);
}

// (A u)_i for the N x N CSR matrix A and N x 3 points u, written to out[0..2].
inline void rowProduct(const SparseRowMatrix& a, const double* x, Index i, double out[3]) {
  storePoint(out, filter_rows::csrRowProduct<PackedPoint>(a.outerIndexPtr(), a.innerIndexPtr(),
                                                          a.valuePtr(), x, i));
}

// The drift filter psi(x), x = T^2 lambda for each eigenvalue lambda of W: the exact
// phi / (1 + x phi^2 / 4), phi = 1 - x/12, makes every mode's mean true energy its start
// energy (docs/solver.md section 6). All those x are at most T^2 times Gershgorin's bound on
// Omega^2 (W is its M-orthogonal compression), so the fit need only hold up to that, and
// each degree fewer is one product with W fewer per step. Two forms, minimax fits of the
// relative error with psi(0) = 1: phi q, q a fit of 1 / (1 + x phi^2 / 4) (the zero at
// x = 12 built in), and psi itself, a degree lower for the same accuracy; psi itself is
// used wherever it is at least as close as the phi q it replaces on the same range.
struct DriftFit {
  double upTo;    // x range
  bool timesPhi;  // psi = phi (1 + c_1 x + ...), else psi = 1 + c_1 x + ...
  int degree;     // psi's degree
  double c[3];
};
constexpr double kBeyondAll = std::numeric_limits<double>::infinity();
constexpr DriftFit kDriftFits[] = {
    {0.88, false, 1, {-0.261967826, 0.0, 0.0}},                   // within 1.28 %
    {1.0, true, 2, {-0.184239, 0.0, 0.0}},                        // within 1.29 %
    {3.25, false, 2, {-0.269917131, 0.0374381083, 0.0}},          // within 1.77 %
    {4.0, true, 3, {-0.189984, 0.0290445, 0.0}},                  // within 1.80 %
    {7.8, false, 3, {-0.262613152, 0.04136553, -0.00251391197}},  // within 2.55 %
    {kBeyondAll, true, 4, {-0.181526, 0.0302534, -0.00126054}},   // 2.6 % on [0, 16]
};

// The bits of every value of rows [begin, end), or-ed together (vectorises): zero when all
// are +0; zero but for the sign bit when all are zeros of either sign (NaN is not zero).
std::uint64_t rowBits(const Points& x, Index begin, Index end) {
  const double* p = x.data() + 3 * static_cast<size_t>(begin);
  const size_t count = 3 * static_cast<size_t>(end - begin);
  std::uint64_t bits = 0;
  for (size_t k = 0; k < count; ++k) bits |= std::bit_cast<std::uint64_t>(p[k]);
  return bits;
}

bool rowsAreZero(const Points& x, Index begin, Index end) {
  return (rowBits(x, begin, end) << 1) == 0;
}

// The acceleration of one vertex as accelerationRows makes it, a_j = sigma_j M_j^-1
// ((F_j + F_ext,j) + mu_j g), specialised on whether there are loads, gravity and an elastic
// share (std::bool_constant flags, chosen once per pass by withLoadCase), so that the common
// case is a tight loop. `sum`, when given, receives the total force.
struct AccelerationInputs {
  const double* external;
  const double* mass;
  const double* inverseMass;
  std::span<const double> share;
  Vec3 gravity;
};

template <class Loads, class Gravity, class Share>
inline void accelerationRow(const AccelerationInputs& in, Loads, Gravity, Share, const double* f,
                            Index j, double a[3], double* sum) {
  const size_t k = 3 * static_cast<size_t>(j);
  double x = f[k], y = f[k + 1], z = f[k + 2];
  if constexpr (Loads::value) {
    x += in.external[k];
    y += in.external[k + 1];
    z += in.external[k + 2];
  }
  if constexpr (Gravity::value) {
    x += in.mass[j] * in.gravity.x();
    y += in.mass[j] * in.gravity.y();
    z += in.mass[j] * in.gravity.z();
  }
  if (sum) {
    sum[0] = x;
    sum[1] = y;
    sum[2] = z;
  }
  double scale = in.inverseMass[j];
  if constexpr (Share::value) scale = in.share[static_cast<size_t>(j)] * scale;
  a[0] = scale * x;
  a[1] = scale * y;
  a[2] = scale * z;
}

// Calls body(loads, gravity, share) with each flag as a std::bool_constant.
template <class Body>
inline void withLoadCase(bool loads, bool gravity, bool share, Body&& body) {
  auto s3 = [&](auto l, auto g3) {
    share ? body(l, g3, std::true_type{}) : body(l, g3, std::false_type{});
  };
  auto s2 = [&](auto l) { gravity ? s3(l, std::true_type{}) : s3(l, std::false_type{}); };
  loads ? s2(std::true_type{}) : s2(std::false_type{});
}

// Models up to this many vertices keep their accelerations in an array for the filter's
// product (it stays in cache); larger ones make them on the fly from the forces, saving
// the array's memory traffic. The values are the same either way.
constexpr Index kStoredAccelerationVertices = 65536;

}  // namespace

int automaticThreads(Index vertices) {
  return vertices >= kParallelMinVertices ? maximumThreads() : 1;
}

void checkPeriodRange(double period, const std::string& what) {
  if (period >= kShortestPeriod && period <= kLongestPeriod) return;
  std::ostringstream msg;
  msg.precision(6);
  msg << what << ": " << period << " s is outside [" << kShortestPeriod << ", " << kLongestPeriod
      << "] s, where the schemes' powers of the time step stay finite and nonzero (are the "
         "masses and stiffnesses in consistent units?)";
  throw InvalidInputError(msg.str());
}

Stepper::Stepper(const Model& model, Scheme scheme, double period, const StepperOptions& options)
    : model_(model), scheme_(scheme), period_(period), options_(options), system_(model) {
  if (!(period > 0.0) || !std::isfinite(period))
    throw InvalidInputError("time step " + std::to_string(period) + " must be positive");
  checkPeriodRange(period, "time step");
  if (options.threads < 0 || options.threads > kMaxThreads)
    throw InvalidInputError("threads " + std::to_string(options.threads) +
                            ": must be 0 (automatic) to " + std::to_string(kMaxThreads));
  const Index n = model.mesh.numVertices();
  const int most = options.threads > 0 ? options.threads : automaticThreads(n);
  threads_ = most;
  tuning_ = options.threads <= 0 && most > 1;
  tuner_ = ThreadTuner(most, 1);
  forces_ = ForceKernel(model, most);
  for (Points* p : {&internal_, &previousInternal_, &acceleration_, &kick_, &totalForce_})
    p->setZero(n, 3);
  if (scheme_ == Scheme::Paper || scheme_ == Scheme::Exact)
    for (Points* p : {&work1_, &work2_, &work3_, &work4_}) p->setZero(n, 3);
  if (scheme_ == Scheme::Default && options_.driftFilter) {
    for (Points* p : {&work1_, &work2_}) p->setZero(n, 3);
    affinePartial_.assign(24 * static_cast<size_t>(forces_.numBlocks()), 0.0);
    setUpAffine({});
    boundSpectrum({});
  }
  resetLoadRecord();
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
  if (scheme_ == Scheme::Default && options_.driftFilter && !vertices.empty()) {
    setUpAffine(vertices);
    boundSpectrum(vertices);
  }
  forces_.propertiesChanged(model_, vertices);
  if (!vertices.empty()) refreshDamping(vertices);
  if (begun_) dropBegunStep();
  cacheValid_ = false;
  kickValid_ = false;
}

void Stepper::setPeriod(double period) {
  if (!(period > 0.0) || !std::isfinite(period))
    throw InvalidInputError("time step " + std::to_string(period) + " must be positive");
  checkPeriodRange(period, "time step");
  if (period == period_) return;
  if (scheme_ != Scheme::Default)
    throw InvalidInputError(std::string("the ") + std::string(schemeName(scheme_)) +
                            " scheme's period is fixed when it is set up");
  period_ = period;
  refreshDamping({});
  if (options_.driftFilter) chooseDriftFit();
  kickValid_ = false;        // the cached kick is (T/2) Phi a for the old period
  if (begun_) invalidate();  // the state is at the begun step's end
}

void Stepper::rebuild() {
  // The last step's total force is made on demand from the record of its loads, which the
  // rebuild resets: make it now.
  if (!totalForceReady_) (void)lastTotalForce();
  system_ = SystemMatrices(model_);
  if (transformation_) *transformation_ = TransformationMatrices(system_, period_);
  if (scheme_ == Scheme::Exact) setUpExact();
  forces_.rebuild(model_);
  resetLoadRecord();
  if (scheme_ == Scheme::Default && options_.driftFilter) {
    affinePartial_.assign(24 * static_cast<size_t>(forces_.numBlocks()), 0.0);
    setUpAffine({});
    boundSpectrum({});
  }
  refreshDamping({});
  if (begun_) dropBegunStep();
  cacheValid_ = false;
  kickValid_ = false;
}

std::optional<PotentialEnergy> Stepper::internalEnergy() const {
  // Only the default scheme ends a step with the forces at its end position (cacheValid_);
  // the kernel's last pass is that one.
  if (scheme_ != Scheme::Default || !cacheValid_ || rewound_ || begun_ || !options_.measureEnergy)
    return std::nullopt;
  return forces_.energy();
}

void Stepper::rewind() {
  const bool begun = begun_;
  if (begun) dropBegunStep();
  // Nothing to give back: no default step since the last invalidation, rewind or startAt.
  if (scheme_ != Scheme::Default || !cacheValid_ || !rewindable_) {
    cacheValid_ = false;
    return;
  }
  rewindable_ = false;
  rewound_ = true;
  kickValid_ = false;  // the cached kick is the end's, or the begun step's
  // A begun step left its start forces in internal_ (made, or kept from the step before); a
  // finished one leaves its end forces there and its start forces in previousInternal_
  // (the swap at its end).
  if (!begun) internal_.swap(previousInternal_);
}

void Stepper::invalidate() {
  if (begun_) dropBegunStep();
  cacheValid_ = false;
}

void Stepper::dropBegunStep() {
  begun_ = false;
  if (scheme_ != Scheme::Default) return;  // the whole step was taken
  // The dropped step is the last one now, as far as lastTotalForce() and the next step's
  // comparison of loads go: its loads are the record (markZeroExternalBlocks), its total
  // force was written if it had loads and made its kick, and its start forces are in
  // internal_.
  rewound_ = true;
  kickValid_ = false;
  loadsZero_ = begunZero_;
  totalForceReady_ = !begunZero_ && !begunKeptKick_;
}

size_t Stepper::bytes() const {
  auto sparse = [](const SparseRowMatrix& m) {
    return static_cast<size_t>(m.nonZeros()) * (sizeof(double) + sizeof(Index)) +
           static_cast<size_t>(m.outerSize() + 1) * sizeof(Index);
  };
  auto dense = [](const auto& m) { return static_cast<size_t>(m.size()) * sizeof(double); };
  size_t total = sparse(system_.stiffness()) + sparse(system_.omega2()) +
                 dense(system_.inverseMass()) + dense(system_.dampingCoefficient()) +
                 forces_.bytes() + dense(dampHalf_) + dense(dampFull_) + dense(lastExternal_) +
                 externalZero_.size() + externalExactZero_.size() + externalSame_.size();
  for (const Points* p :
       std::initializer_list<const Points*>{&internal_, &previousInternal_, &acceleration_, &kick_,
                                            &totalForce_, &work1_, &work2_, &work3_, &work4_})
    total += dense(*p);
  if (transformation_)
    for (const SparseRowMatrix* m :
         {&transformation_->omega4(), &transformation_->h(), &transformation_->hPrime(),
          &transformation_->hSecond(), &transformation_->x(), &transformation_->xPrime()})
      total += sparse(*m);
  total += dense(affineBasis_) + dense(omegaBasis_) + dense(massBases_) + dense(affineMass_) +
           affinePartial_.size() * sizeof(double) + affineRows_.capacity() * sizeof(Index);
  total += dense(modes_) + dense(propagator_) + dense(modal1_) + dense(modal2_) + dense(modal3_);
  if (implicit_)
    total += static_cast<size_t>(implicit_->a.nonZeros()) * (sizeof(double) + sizeof(int)) +
             dense(implicit_->rhs) + dense(implicit_->dv) + dense(implicit_->flat);
  return total;
}

const Points& Stepper::lastTotalForce() const {
  if (!totalForceReady_) {
    // Internal forces at the last step's start, its loads and gravity, in the order of
    // accelerationRow: (F + F_ext) + mu g.
    totalForce_ = rewound_ ? internal_ : previousInternal_;
    if (!loadsZero_)
      for (Index b = 0; b < forces_.numBlocks(); ++b) {
        const Index begin = forces_.blockBegin(b), rows = forces_.blockEnd(b) - begin;
        if (externalExactZero_[static_cast<size_t>(b)])
          totalForce_.middleRows(begin, rows).array() += 0.0;
        else
          totalForce_.middleRows(begin, rows) += lastExternal_.middleRows(begin, rows);
      }
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
  checkStepInputs(state, external);
  const auto start = std::chrono::steady_clock::now();
  if (tuning_) threads_ = tuner_.next();
  takeStep(state, state, external, share, Part::Whole);  // one parallel region for both parts
  state.time += period_;
  if (tuning_)
    tuner_.record(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
}

void Stepper::beginStep(State& state, const Points& external, std::span<const double> share) {
  beginStep(state, state, external, share);
}

void Stepper::beginStep(const State& from, State& state, const Points& external,
                        std::span<const double> share) {
  checkStepInputs(from, external);
  const auto start = std::chrono::steady_clock::now();
  if (tuning_) threads_ = tuner_.next();
  if (&from != &state) {
    // Sized once (a trial state keeps its size); the time is the start's.
    state.position.resize(from.position.rows(), 3);
    state.velocity.resize(from.velocity.rows(), 3);
    state.time = from.time;
  }
  takeStep(from, state, external, share, Part::Begin);
  begun_ = true;
  rewindable_ = scheme_ == Scheme::Default;
  begunSeconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

void Stepper::finishStep(State& state, const Points& external, std::span<const double> share) {
  ZSCULPT_ASSERT(begun_, "finishStep without a begun step");
  const auto start = std::chrono::steady_clock::now();
  takeStep(state, state, external, share, Part::Finish);
  begun_ = false;
  state.time += period_;
  // The tuner times the two parts, not what the caller did between them.
  if (tuning_)
    tuner_.record(begunSeconds_ +
                  std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
}

void Stepper::checkStepInputs(const State& state, const Points& external) const {
  ZSCULPT_ASSERT(state.position.rows() == model_.mesh.numVertices() &&
                     state.velocity.rows() == model_.mesh.numVertices() &&
                     external.rows() == model_.mesh.numVertices(),
                 "state or external forces do not match the model");
  ZSCULPT_ASSERT(!begun_, "a begun step must be finished or dropped before the next");
}

void Stepper::takeStep(const State& from, State& state, const Points& external,
                       std::span<const double> share, Part part) {
  if (scheme_ == Scheme::Default) {
    if (filtersDrift())
      stepDriftFiltered(from, state, external, share, part);
    else
      stepDefault(from, state, external, share, part);
    return;
  }
  if (part == Part::Finish) return;  // the other schemes take the whole step at the begin
  if (&from != &state) {
    state.position = from.position;
    state.velocity = from.velocity;
  }
  switch (scheme_) {
    case Scheme::Default:
      break;
    case Scheme::Paper:
      stepPaper(state, external, share);
      break;
    case Scheme::Exact:
      stepExact(state, external, share);
      break;
    case Scheme::SymplecticEuler:
      stepSymplecticEuler(state, external, share);
      break;
    case Scheme::ImplicitEuler:
      stepImplicitEuler(state, external, share);
      break;
  }
  rewindable_ = false;  // they keep no forces to rewind to
}

const Points& Stepper::startAt(const Points& position) {
  ZSCULPT_ASSERT(!begun_, "startAt inside a begun step");
  // internal_ is about to change: the last step's total force, if it is to be made on demand
  // from a rewound internal_, is made now (as in rebuild()).
  if (!totalForceReady_) (void)lastTotalForce();
  const Index blocks = forces_.numBlocks();
  parallelRegion(threads_, [&] {
    forces_.scatter(model_, position, internal_, options_.measureEnergy);
#pragma omp for schedule(static)
    for (Index b = 0; b < blocks; ++b) forces_.gatherBlock(b, internal_);
  });
  cacheValid_ = true;
  rewound_ = false;
  rewindable_ = false;  // internal_ is no step's end any more
  kickValid_ = false;   // the kept kick is for the last step's end
  return internal_;
}

const Points* Stepper::turnEndForces(const Mat3& rotation) {
  // After a finished default step internal_ holds the forces at its end (endDefaultPart),
  // and the kernel their energy, which a rigid motion does not change.
  if (scheme_ != Scheme::Default || !cacheValid_ || rewound_ || begun_) return nullptr;
  const Index blocks = forces_.numBlocks();
  double* f = internal_.data();
  parallelRegion(threads_, [&] {
#pragma omp for schedule(static)
    for (Index b = 0; b < blocks; ++b)
      for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
        double* row = f + 3 * static_cast<size_t>(i);
        const Vec3 turned = rotation * Vec3(row[0], row[1], row[2]);
        row[0] = turned.x();
        row[1] = turned.y();
        row[2] = turned.z();
      }
  });
  kickValid_ = false;   // the kept kick is for the unmoved end
  rewindable_ = false;  // internal_ is no step's end any more
  return &internal_;
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
    const double scale =
        share.empty() ? inverseMass[i] : share[static_cast<size_t>(i)] * inverseMass[i];
    a[k] = scale * x;
    a[k + 1] = scale * y;
    a[k + 2] = scale * z;
  }
  externalZero_[static_cast<size_t>(block)] = zero ? 1 : 0;
  return zero;
}

void Stepper::computeAcceleration(const Points& position, const Points& external,
                                  std::span<const double> share) {
  // Serial form for the exact and implicit schemes. No energy: internalEnergy() reads the
  // kernel's only after a default step.
  forces_.compute(model_, position, internal_, threads_, false);
  for (Index b = 0; b < forces_.numBlocks(); ++b)
    accelerationRows(b, internal_, external, share, true);
  totalForceReady_ = true;
}

void Stepper::setUpAffine(std::span<const Index> vertices) {
  // The affine fields of the rest shape, span{1, X, Y, Z} (each coordinate of a velocity
  // field a member): every translation and rotation of the rest shape, and of any rigid
  // image of it, lies in it. An orthonormal basis (centred and scaled first so that the
  // rank is judged fairly: a planar grid has rank 3, a straight curve 2).
  const Index n = model_.mesh.numVertices();
  const VectorX& mass = model_.properties.mass;
  if (vertices.empty()) {
    const Points& rest = model_.mesh.positions();
    Eigen::MatrixXd affine(n, 4);
    affine.col(0).setOnes();
    const Eigen::RowVector3d centre = rest.colwise().mean();
    affine.rightCols(3) = rest.rowwise() - centre;
    const double extent = affine.rightCols(3).cwiseAbs().maxCoeff();
    if (extent > 0.0) affine.rightCols(3) /= extent;
    const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(affine);
    affineRank_ = static_cast<int>(qr.rank());
    affineBasis_.setZero(n, 4);
    // Applied to the first columns of I, never formed (it is N x N).
    affineBasis_.leftCols(affineRank_) =
        qr.householderQ() * Eigen::MatrixXd::Identity(n, affineRank_);
    omegaBasis_.setZero(n, 4);
    massBases_.setZero(n, 8);
    affineMass_ = mass;
    affineGram_.setZero();
    affineStiffness_.setZero();
    // One body: B spans the affine fields of the whole rest shape, so on a model of several
    // parts P mixes them, and W = (I - P) Omega^2 (I - P) would couple parts no spring joins
    // (a review: a cube moving past another at rest dragged it 1 m). Such models take the
    // kick filter; per-part bases (rank 4 per part) are the fuller fix.
    oneBody_ = model_.mesh.numComponents() <= 1;
  }
  // Rows whose Omega^2 B or mass changed: the edited vertices and their one-ring.
  const SparseRowMatrix& o2 = system_.omega2();
  std::vector<Index>& rows = affineRows_;
  rows.clear();
  if (vertices.empty()) {
    rows.resize(static_cast<size_t>(n));
    for (Index i = 0; i < n; ++i) rows[static_cast<size_t>(i)] = i;
  } else {
    for (Index i : vertices) {
      rows.push_back(i);
      for (SparseRowMatrix::InnerIterator it(o2, i); it; ++it) rows.push_back(it.col());
    }
    std::sort(rows.begin(), rows.end());
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
  }
  // G = B^T M B and C = B^T K B = sum_i mu_i B_i (Omega^2 B)_i^T, updated row by row: the
  // old rows' terms out, the new ones in.
  for (Index i : rows) {
    const Eigen::Vector4d b = affineBasis_.row(i).transpose();
    const Eigen::Vector4d ob = omegaBasis_.row(i).transpose();
    if (!vertices.empty()) {
      affineGram_ -= affineMass_[i] * b * b.transpose();
      affineStiffness_ -= affineMass_[i] * b * ob.transpose();
    }
    Eigen::Vector4d product = Eigen::Vector4d::Zero();
    for (SparseRowMatrix::InnerIterator it(o2, i); it; ++it)
      product += it.value() * affineBasis_.row(it.col()).transpose();
    omegaBasis_.row(i) = product.transpose();
    massBases_.row(i) << mass[i] * b.transpose(), mass[i] * product.transpose();
    affineMass_[i] = mass[i];
    affineGram_ += mass[i] * b * b.transpose();
    affineStiffness_ += mass[i] * b * product.transpose();
  }
  affineInverseGram_.setZero();
  const Eigen::MatrixXd gram = affineGram_.topLeftCorner(affineRank_, affineRank_);
  affineInverseGram_.topLeftCorner(affineRank_, affineRank_) =
      gram.llt().solve(Eigen::MatrixXd::Identity(affineRank_, affineRank_));
  // C is symmetric in exact arithmetic; keep it so, the operator's symmetry rests on it.
  affineStiffness_ = 0.5 * (affineStiffness_ + affineStiffness_.transpose()).eval();
  // Braced: angle springs at every vertex, so that Omega^2 outside the affine fields is a
  // fair picture of the stiffness. Without them the surface is a mechanism whose floppy
  // motions Omega^2 calls stiff, and a drift filter would slow them (docs/solver.md).
  const VectorX& angular = model_.properties.angularStiffness;
  const std::vector<Index>& offsets = model_.angles.vertexOffsets;
  braced_ = oneBody_ && n > 0 && angular.size() == n && static_cast<Index>(offsets.size()) == n + 1;
  for (Index i = 0; braced_ && i < n; ++i)
    braced_ =
        angular[i] > 0.0 && offsets[static_cast<size_t>(i) + 1] > offsets[static_cast<size_t>(i)];
}

void Stepper::boundSpectrum(std::span<const Index> vertices) {
  // Only the rows of edited vertices change (SystemMatrices::updateVertices): their blocks'
  // bounds are made again from all their rows, so the bound is always a fresh build's.
  const SparseRowMatrix& o2 = system_.omega2();
  const Index blocks = forces_.numBlocks();
  spectrumBound_.resize(static_cast<size_t>(blocks), 0.0);
  auto bound = [&](Index b) {
    double largest = 0.0;
    for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
      double sum = 0.0;
      for (SparseRowMatrix::InnerIterator it(o2, i); it; ++it) sum += std::abs(it.value());
      largest = std::max(largest, sum);
    }
    spectrumBound_[static_cast<size_t>(b)] = largest;
  };
  if (vertices.empty()) {
    for (Index b = 0; b < blocks; ++b) bound(b);
  } else {
    // Edits name their rows in order, so each block comes once; a repeat only remakes it.
    Index last = -1;
    for (Index v : vertices) {
      const Index b = forces_.blockOf(v);
      if (b != last) bound(b);
      last = b;
    }
  }
  chooseDriftFit();
}

void Stepper::chooseDriftFit() {
  double largest = 0.0;
  for (double b : spectrumBound_) largest = std::max(largest, b);
  const double x = period_ * period_ * largest;
  const DriftFit* fit = &kDriftFits[std::size(kDriftFits) - 1];
  for (const DriftFit& f : kDriftFits)
    if (x <= f.upTo) {
      fit = &f;
      break;
    }
  driftDegree_ = fit->degree;
  driftA_.fill(0.0);
  // Psi's coefficients a_k: c_k for psi itself; for phi q, c_k - c_{k-1} / 12 with c_0 = 1
  // and c_degree = 0.
  double previous = 1.0;
  for (int k = 1; k <= driftDegree_; ++k) {
    const double c = k <= 3 ? fit->c[k - 1] : 0.0;
    driftA_[static_cast<size_t>(k)] = fit->timesPhi ? c - previous / 12.0 : c;
    previous = c;
  }
}

VectorX Stepper::filteredPositionColumn(Index l) const {
  ZSCULPT_ASSERT(scheme_ == Scheme::Default && filtersDrift(),
                 "filteredPositionColumn is for the default scheme with its drift filter");
  const double t2 = period_ * period_;
  VectorX unit = VectorX::Zero(model_.mesh.numVertices());
  unit[l] = 1.0;
  const VectorX& mass = model_.properties.mass;
  // W u = Omega^2 u - (Omega^2 B) c - B d, as in stepDriftFiltered.
  auto apply = [&](const VectorX& u) {
    Eigen::Vector4d bu = Eigen::Vector4d::Zero(), ku = Eigen::Vector4d::Zero();
    for (Index i = 0; i < u.size(); ++i) {
      bu += mass[i] * u[i] * affineBasis_.row(i).transpose();
      ku += mass[i] * u[i] * omegaBasis_.row(i).transpose();
    }
    const Eigen::Vector4d c = affineInverseGram_ * bu;
    const Eigen::Vector4d d = affineInverseGram_ * (ku - affineStiffness_ * c);
    VectorX w = system_.omega2() * u;
    w -= omegaBasis_ * c + affineBasis_ * d;
    return w;
  };
  const VectorX phi = unit - (t2 / 12.0) * apply(unit);
  // The stepper's Horner order and roundings (stepDriftFiltered).
  const int degree = driftDegree_;
  if (degree == 1) return phi + (driftA_[1] * t2) * apply(phi);
  VectorX w = driftA_[static_cast<size_t>(degree) - 1] * phi +
              driftA_[static_cast<size_t>(degree)] * t2 * apply(phi);
  for (int k = degree - 2; k >= 1; --k) w = driftA_[static_cast<size_t>(k)] * phi + t2 * apply(w);
  return phi + t2 * apply(w);
}

void Stepper::positionResponse(Index l, std::span<const Index> rows, std::span<double> out) const {
  ZSCULPT_ASSERT(rows.size() == out.size(), "positionResponse: one output per row");
  const double t = period_, t2 = t * t;
  const SparseRowMatrix& o2 = system_.omega2();
  const bool filtered = scheme_ == Scheme::Default && filtersDrift();
  // With the drift filter the response is global (the projection sums over the model).
  const VectorX column = filtered ? filteredPositionColumn(l) : VectorX();
  // Omega^4_jl = sum_q Omega^2_jq Omega^2_ql (the paper scheme's two-ring term).
  auto omega4 = [&](Index j) {
    double sum = 0.0;
    for (Index k = o2.outerIndexPtr()[j]; k < o2.outerIndexPtr()[j + 1]; ++k)
      sum += o2.valuePtr()[k] * csrEntry(o2, o2.innerIndexPtr()[k], l);
    return sum;
  };
  for (size_t a = 0; a < rows.size(); ++a) {
    const Index j = rows[a];
    const double delta = (j == l) ? 1.0 : 0.0;
    switch (scheme_) {
      case Scheme::Default:
        // r' = r + T Psi (v + (T/2) Phi a), Psi = I without the drift filter, Phi = 1 - T^2
        // Omega^2 / 12 or its W form (the damping half step acts on v before the kick, not
        // on the kick).
        out[a] =
            filtered ? 0.5 * t2 * column[j] : 0.5 * t2 * (delta - t2 / 12.0 * csrEntry(o2, j, l));
        break;
      case Scheme::Paper:
      case Scheme::Exact:
        out[a] = truncatedH(t, delta, csrEntry(o2, j, l), omega4(j));
        break;
      case Scheme::SymplecticEuler:
      case Scheme::ImplicitEuler:
        out[a] = delta * centreResponse(l);
        break;
    }
  }
}

double Stepper::centreResponse(Index l) const {
  const double t = period_, t2 = t * t;
  switch (scheme_) {
    case Scheme::SymplecticEuler:
      return t2 * std::exp(-2.0 * system_.dampingCoefficient()[l] * t);
    case Scheme::ImplicitEuler: {
      // (M + h D + h^2 K) restricted to its diagonal.
      const double m = model_.properties.mass[l];
      return t2 * (m / (m + t * model_.properties.damping[l] +
                        t2 * csrEntry(system_.stiffness(), l, l)));
    }
    default:
      return 0.5 * t2;
  }
}

void Stepper::resetLoadRecord() {
  const size_t blocks = static_cast<size_t>(forces_.numBlocks());
  externalZero_.assign(blocks, 1);
  externalExactZero_.assign(blocks, 1);
  externalSame_.assign(blocks, 1);
  // Only the default scheme keeps its kick (markZeroExternalBlocks).
  lastExternal_.setZero(scheme_ == Scheme::Default ? model_.mesh.numVertices() : 0, 3);
  loadsZero_ = true;
}

Stepper::LoadCheck Stepper::markZeroExternalBlocks(const Points& external) {
  // Inside the step's parallel region: every thread returns the same answer. A block whose
  // loads were not all +0 keeps its rows in lastExternal_ for the next call's comparison:
  // most blocks of a loaded model have none, so this is a pass over the loaded ones only.
  const Index blocks = forces_.numBlocks();
#pragma omp for schedule(static)
  for (Index b = 0; b < blocks; ++b) {
    const size_t k = static_cast<size_t>(b);
    const Index begin = forces_.blockBegin(b), end = forces_.blockEnd(b);
    const std::uint64_t bits = rowBits(external, begin, end);
    const bool exactZero = bits == 0;
    externalZero_[k] = (bits << 1) == 0 ? 1 : 0;
    bool same = externalExactZero_[k] != 0;
    if (!exactZero) {
      const size_t first = 3 * static_cast<size_t>(begin);
      const size_t bytes = 3 * static_cast<size_t>(end - begin) * sizeof(double);
      same = !externalExactZero_[k] &&
             std::memcmp(external.data() + first, lastExternal_.data() + first, bytes) == 0;
      if (!same) std::memcpy(lastExternal_.data() + first, external.data() + first, bytes);
    }
    externalExactZero_[k] = exactZero ? 1 : 0;
    externalSame_[k] = same ? 1 : 0;
  }
  LoadCheck check;
  bool sameBits = true;
  for (Index b = 0; b < blocks; ++b) {
    check.zero = check.zero && externalZero_[static_cast<size_t>(b)];
    sameBits = sameBits && externalSame_[static_cast<size_t>(b)];
  }
  // No loads applied then and now (zeros of either sign are not applied), or loads of the
  // same bits. loadsZero_ is the last step's until the step ends.
  check.same = check.zero ? loadsZero_ : !loadsZero_ && sameBits;
  return check;
}

void Stepper::endDefaultPart(Part part, bool loadsZero, bool keptKick, bool shared) {
  if (part == Part::Begin) {
    // internal_ holds the start forces (made or kept): a dropped step's next trial takes
    // them (rewind). The finish takes the loads as this part found them.
    begunZero_ = loadsZero;
    begunKeptKick_ = keptKick;
    cacheValid_ = true;
    return;
  }
  // previousInternal_ now holds the forces at the new position: swap the two buffers. The
  // total force at the start was written with loads and a fresh first kick, else it is made
  // on demand.
  internal_.swap(previousInternal_);
  rewindable_ = true;
  totalForceReady_ = !loadsZero && !keptKick;
  keptKick_ = keptKick;
  cacheValid_ = true;
  rewound_ = false;
  kickValid_ = !shared;
  loadsZero_ = loadsZero;
}

void Stepper::stepDefault(const State& from, State& s, const Points& external,
                          std::span<const double> share, Part part) {
  // Velocity Verlet with the filtered acceleration Phi a, Phi = I - T^2 Omega^2 / 12, and
  // the damping of G exactly over two half steps (stepper.h):
  //   v <- e^{-GT} v + (T/2) Phi a(r);  r <- r + T v;  v <- e^{-GT} (v + (T/2) Phi a(r)).
  // Passes over the blocks: external forces checked for zero; kick and drift; internal
  // forces (ForceKernel's two phases); kick and damping. The accelerations are made on the
  // fly inside the filter's product (a_j = sigma_j M_j^-1 ((F_j + F_ext,j) + mu_j g), the
  // same expression as accelerationRows) instead of being stored and read back. The first
  // kick equals the last step's second one while nothing but the position changed (same
  // internal forces, the same external forces, no share): it is kept in kick_. Part::Begin
  // takes the first kick and the drift, Part::Finish the rest (beginStep, finishStep),
  // Part::Whole both (step).
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
  // The begin reads the start state from `from` (s itself, or a trial's start: beginStep).
  const double* r0 = from.position.data();
  const double* v0 = from.velocity.data();
  double* kick = kick_.data();
  const bool stored = model_.mesh.numVertices() <= kStoredAccelerationVertices;
  // The row passes that need no loads (filter_rows.h): AVX2 where the processor has it.
  const filter_rows::Kernels& rows = filter_rows::kernels(options_.wideKernels);
  filter_rows::Inputs in;
  in.outer = outer;
  in.inner = inner;
  in.value = value;
  in.dampHalf = dampHalf_.data();
  const bool begin = part != Part::Finish, finish = part != Part::Begin;
  bool externalZero = begunZero_, reused = begunKeptKick_;
  parallelRegion(threads_, [&] {
    // The finish takes the loads as the begin found them.
    const LoadCheck loads =
        begin ? markZeroExternalBlocks(external) : LoadCheck{begunZero_, begunKeptKick_};
    const bool zero = loads.zero;
    // The kept kick is the last step's second one, made with its loads.
    const bool reuse = begin ? reuseCandidate && loads.same : begunKeptKick_;
    // (T/2) Phi a at row i: (T/2) a_i - (T^3/24) (Omega^2 a)_i, with a_j from the internal
    // forces f (and the total force on the way).
    const AccelerationInputs inputs{e, mass, inverseMass, share, g};
    auto withCase = [&](auto&& body) { withLoadCase(!zero, gravity, !share.empty(), body); };
    auto acceleration = [&](auto loads, auto withGravity, auto withShare, const double* f, Index j,
                            double a[3], double* sum) {
      accelerationRow(inputs, loads, withGravity, withShare, f, j, a, sum);
    };
    auto filteredKick = [&](auto loads, auto withGravity, auto withShare, const double* f, Index i,
                            double* out, double* total) {
      PackedPoint w;
      for (Index p = outer[i]; p < outer[i + 1]; ++p) {
        double a[3];
        acceleration(loads, withGravity, withShare, f, inner[p], a, nullptr);
        w += value[p] * loadPoint(a);
      }
      double a[3];
      acceleration(loads, withGravity, withShare, f, i, a, total);
      storePoint(out, half * loadPoint(a) - filter * w);
    };
    if (begin) {
      if (!reuse && !startCached) {
        forces_.scatter(model_, from.position, internal_);
#pragma omp for schedule(static)
        for (Index b = 0; b < blocks; ++b) forces_.gatherBlock(b, internal_);
      }
      // Kick and drift; with loads, the total force at the start on the way (lastTotalForce).
      const double* f0 = internal_.data();
      double* total = zero ? nullptr : totalForce_.data();
      if (reuse) {
#pragma omp for schedule(static)
        for (Index b = 0; b < blocks; ++b)
          rows.plainDrift(in, forces_.blockBegin(b), forces_.blockEnd(b), v0, v, kick, r0, r, t);
      } else {
        withCase([&](auto loads, auto withGravity, auto withShare) {
#pragma omp for schedule(static)
          for (Index b = 0; b < blocks; ++b)
            for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
              const size_t k = 3 * static_cast<size_t>(i);
              filteredKick(loads, withGravity, withShare, f0, i, kick + k,
                           total ? total + k : nullptr);
              const PackedPoint vi = loadPoint(v0 + k) * dampHalf_[i] + loadPoint(kick + k);
              storePoint(v + k, vi);
              storePoint(r + k, loadPoint(r0 + k) + t * vi);
            }
        });
      }
    }
    if (finish) {
      // Internal forces at the new position.
      forces_.scatter(model_, s.position, previousInternal_, options_.measureEnergy);
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
      if (stored) {
#pragma omp for schedule(static)
        for (Index b = 0; b < blocks; ++b)
          rows.plainKick(in, forces_.blockBegin(b), forces_.blockEnd(b), acceleration_.data(), kick,
                         v, half, filter);
      } else {
        withCase([&](auto loads, auto withGravity, auto withShare) {
#pragma omp for schedule(static)
          for (Index b = 0; b < blocks; ++b)
            for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
              const size_t k = 3 * static_cast<size_t>(i);
              filteredKick(loads, withGravity, withShare, f1, i, kick + k, nullptr);
              storePoint(v + k, (loadPoint(v + k) + loadPoint(kick + k)) * dampHalf_[i]);
            }
        });
      }
    }
#pragma omp single
    {
      externalZero = zero;
      reused = reuse;
    }
  });
  endDefaultPart(part, externalZero, reused, !share.empty());
}

void Stepper::stepDriftFiltered(const State& from, State& s, const Points& external,
                                std::span<const double> share, Part part) {
  // Velocity Verlet with both half kicks and the drift filtered (stepper.h, docs/solver.md
  // section 6), the damping of G exact over two half steps:
  //   v <- e^{-GT} v + (T/2) Phi a(r);  r <- r + T Psi v;  v <- e^{-GT} (v + (T/2) Phi a(r)),
  //   Phi = I - T^2 W / 12,  Psi = I + a1 T^2 W + ... + aD (T^2 W)^D (kDriftFits),
  // W = (I - P) Omega^2 (I - P) the stiffness seen from outside the affine fields of the
  // rest shape (P their M-orthogonal projector), so that translations and rotations pass
  // both filters untouched. Every product with W is one pass over the blocks that also
  // sums, per block, what the next product needs of its result: B^T M u and
  // (Omega^2 B)^T M u = B^T K u, with which W u = Omega^2 u - (Omega^2 B) c - B d,
  // c = G^-1 B^T M u, d = G^-1 (B^T K u - C c). The partial sums are added in block order
  // by one thread, so the result does not depend on the thread count. The first kick
  // equals the last step's second one while nothing but the position changed (same
  // internal forces, the same external forces, no share): it is kept in kick_. Part::Begin
  // takes the first kick and the drift, Part::Finish the rest (beginStep, finishStep),
  // Part::Whole both (step).
  const int degree = driftDegree_;
  const double* psi = driftA_.data();  // Psi's coefficients a_k at psi[k]
  const double t = period_, half = 0.5 * t, t2 = t * t, filter = t * t * t / 24.0;
  const Index blocks = forces_.numBlocks();
  const bool startCached = cacheValid_;
  const bool reuseCandidate = cacheValid_ && kickValid_ && share.empty();
  const SparseRowMatrix& o2 = system_.omega2();
  const double* inverseMass = system_.inverseMass().data();
  const double* mass = model_.properties.mass.data();
  const double* massBases = massBases_.data();
  const Vec3 g = model_.properties.gravity;
  const bool gravity = !g.isZero();
  const double* e = external.data();
  double* r = s.position.data();
  double* v = s.velocity.data();
  // The begin reads the start state from `from` (s itself, or a trial's start: beginStep).
  const double* r0 = from.position.data();
  const double* v0 = from.velocity.data();
  double* kick = kick_.data();
  double* acc = acceleration_.data();
  double* w1 = work1_.data();
  double* w2 = work2_.data();
  double* partial = affinePartial_.data();
  double* coefficient = affineCoefficient_.data();  // c (4 x 3) then d (4 x 3)
  double* velocityC = velocityCoefficient_.data();
  // The row passes (filter_rows.h): AVX2 where the processor has it, the same bits.
  const filter_rows::Kernels& rows = filter_rows::kernels(options_.wideKernels);
  const filter_rows::Inputs in{
      o2.outerIndexPtr(), o2.innerIndexPtr(), o2.valuePtr(), affineBasis_.data(),
      omegaBasis_.data(), massBases,          mass,          coefficient,
      dampHalf_.data()};
  const bool begin = part != Part::Finish, finish = part != Part::Begin;
  bool externalZero = begunZero_, reused = begunKeptKick_;
  parallelRegion(threads_, [&] {
    // The finish takes the loads as the begin found them.
    const LoadCheck loads =
        begin ? markZeroExternalBlocks(external) : LoadCheck{begunZero_, begunKeptKick_};
    const bool zero = loads.zero;
    // The kept kick is the last step's second one, made with its loads.
    const bool reuse = begin ? reuseCandidate && loads.same : begunKeptKick_;
    const AccelerationInputs inputs{e, mass, inverseMass, share, g};
    auto withCase = [&](auto&& body) { withLoadCase(!zero, gravity, !share.empty(), body); };
    auto blockPartial = [&](Index b) { return partial + 24 * static_cast<size_t>(b); };
    // c and d of the vector whose block sums were just made: B^T M u (rows 0-11 of each
    // block's partial sums) and (Omega^2 B)^T M u (rows 12-23), added in block order by one
    // thread, so the result does not depend on the thread count. With knownScale, c is that
    // multiple of the velocity's c (saved when the velocity was summed) and only
    // (Omega^2 B)^T M u was summed.
    auto combine = [&](bool saveVelocity, const double* knownScale) {
#pragma omp single
      {
        Eigen::Matrix<double, 4, 3> bu = Eigen::Matrix<double, 4, 3>::Zero(), ku = bu;
        for (Index b = 0; b < blocks; ++b) {
          const double* p = blockPartial(b);
          for (int q = 0; q < 4; ++q)
            for (int d = 0; d < 3; ++d) {
              if (!knownScale) bu(q, d) += p[3 * q + d];
              ku(q, d) += p[12 + 3 * q + d];
            }
        }
        Eigen::Matrix<double, 4, 3> c;
        if (knownScale)
          c = *knownScale *
              Eigen::Map<const Eigen::Matrix<double, 4, 3, Eigen::RowMajor>>(velocityC);
        else
          c = affineInverseGram_ * bu;
        const Eigen::Matrix<double, 4, 3> d = affineInverseGram_ * (ku - affineStiffness_ * c);
        for (int q = 0; q < 4; ++q)
          for (int k = 0; k < 3; ++k) {
            coefficient[3 * q + k] = c(q, k);
            coefficient[12 + 3 * q + k] = d(q, k);
            if (saveVelocity) velocityC[3 * q + k] = c(q, k);
          }
      }
    };
    // kick_ = (T/2) Phi a = (T/2) a - (T^3/24) W a, from the internal forces f; with loads,
    // the total force on the way (lastTotalForce). The accelerations' pass sums them for W
    // (in the row, while it is in a register). The kick's pass goes on to the velocity: the
    // first kick's makes v = v e^{-GT/2} + kick and sums it for the drift (one pass fewer than
    // a velocity pass of its own), the second's finishes it, v = (v + kick) e^{-GT/2}.
    auto filteredKick = [&](const double* f, double* total, bool last) {
      withCase([&](auto loads, auto withGravity, auto withShare) {
#pragma omp for schedule(static)
        for (Index b = 0; b < blocks; ++b) {
          if (f == previousInternal_.data()) forces_.gatherBlock(b, previousInternal_);
          PackedPoint basisSum[4], omegaSum[4];
          for (Index i = forces_.blockBegin(b); i < forces_.blockEnd(b); ++i) {
            const size_t k = 3 * static_cast<size_t>(i);
            accelerationRow(inputs, loads, withGravity, withShare, f, i, acc + k,
                            total ? total + k : nullptr);
            const PackedPoint ai = loadPoint(acc + k);
            const double* mb = massBases + 8 * static_cast<size_t>(i);
            for (int q = 0; q < 4; ++q) {
              basisSum[q] += mb[q] * ai;
              omegaSum[q] += mb[4 + q] * ai;
            }
          }
          for (int q = 0; q < 4; ++q) {
            storePoint(blockPartial(b) + 3 * q, basisSum[q]);
            storePoint(blockPartial(b) + 12 + 3 * q, omegaSum[q]);
          }
        }
      });
      combine(false, nullptr);
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b) {
        if (last)
          rows.lastKick(in, forces_.blockBegin(b), forces_.blockEnd(b), acc, kick, v, half, filter);
        else
          rows.firstKick(in, forces_.blockBegin(b), forces_.blockEnd(b), acc, kick, v0, v, half,
                         filter, blockPartial(b));
      }
    };
    if (begin) {
      if (!reuse) {
        if (!startCached) {
          forces_.scatter(model_, from.position, internal_);
#pragma omp for schedule(static)
          for (Index b = 0; b < blocks; ++b) forces_.gatherBlock(b, internal_);
        }
        // First kick and damping.
        filteredKick(internal_.data(), zero ? nullptr : totalForce_.data(), false);
      } else {
        // Damping and the first kick, kept from the last step.
#pragma omp for schedule(static)
        for (Index b = 0; b < blocks; ++b)
          rows.velocity(in, forces_.blockBegin(b), forces_.blockEnd(b), v0, v, kick,
                        blockPartial(b));
      }
      combine(true, nullptr);
      // The drift, Psi v by Horner (D = degree): w = a_{D-1} v + a_D T^2 W v, then
      // w = a_k v + T^2 W w for k = D-2 .. 1, and r += T (v + T^2 W w). B^T M W = 0 (W = (I - P)
      // Omega^2 (I - P), P M-orthogonal), so B^T M (a v + T^2 W u) = a B^T M v: each term's c is a
      // times the velocity's, and only (Omega^2 B)^T M of it is summed.
      auto hornerPass = [&](const double* u, double* out, double a, double scale) {
#pragma omp for schedule(static)
        for (Index b = 0; b < blocks; ++b)
          rows.horner(in, forces_.blockBegin(b), forces_.blockEnd(b), u, v, out, a, scale,
                      blockPartial(b));
        combine(false, &a);
      };
      // Degree 1 has no Horner term: r += T (v + a_1 T^2 W v), with the velocity's c and d.
      const double* term = v;
      double driftScale = psi[1] * t2;
      if (degree > 1) {
        double* out = w1;
        double* next = w2;
        hornerPass(v, out, psi[degree - 1], psi[degree] * t2);
        for (int k = degree - 2; k >= 1; --k) {
          hornerPass(out, next, psi[k], t2);
          std::swap(out, next);
        }
        term = out;
        driftScale = t2;
      }
#pragma omp for schedule(static)
      for (Index b = 0; b < blocks; ++b)
        rows.drift(in, forces_.blockBegin(b), forces_.blockEnd(b), term, v, r0, r, t, driftScale);
    }
    if (finish) {
      // Internal forces at the new position, the second kick and damping.
      forces_.scatter(model_, s.position, previousInternal_, options_.measureEnergy);
      filteredKick(previousInternal_.data(), nullptr, true);
    }
#pragma omp single
    {
      externalZero = zero;
      reused = reuse;
    }
  });
  endDefaultPart(part, externalZero, reused, !share.empty());
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
  parallelRegion(threads_, [&] {
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
  });
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
  inverseSqrtMass_ = scale;
  // x'' + 2 gamma x' + w^2 x = b (b constant over the step), as a 3 x 3 exponential.
  auto propagatorOf = [&](double w2) {
    Mat3 generator;
    generator << 0, 1, 0, -w2, -2 * gamma, 1, 0, 0, 0;
    const Mat3 e = (generator * period_).exp();
    return std::array<double, 6>{e(0, 0), e(0, 1), e(0, 2), e(1, 0), e(1, 1), e(1, 2)};
  };
  propagator_.resize(n, 6);
  for (Index k = 0; k < n; ++k) {
    const auto e = propagatorOf(std::max(0.0, eig.eigenvalues()[k]));
    propagator_.row(k) << e[0], e[1], e[2], e[3], e[4], e[5];
  }
  // Undamped, the centre moves as x + v T + b T^2 / 2: written out, since the exponential's
  // v -> v factor is 1 only to rounding, which scaled the momentum by it every step.
  centrePropagator_ =
      gamma == 0.0 ? std::array<double, 6>{1.0, period_, 0.5 * period_ * period_, 0.0, 1.0, period_}
                   : propagatorOf(0.0);
  modal1_.setZero(n, 3);
  modal2_.setZero(n, 3);
  modal3_.setZero(n, 3);
}

void Stepper::stepExact(State& s, const Points& external, std::span<const double> share) {
  computeAcceleration(s.position, external, share);
  cacheValid_ = false;
  // The centre of mass moves by itself, a free particle under the total force over the total
  // mass (the springs' forces sum to zero), and the modes carry the motion about it. The
  // dense eigenvectors are orthogonal to the translation only to rounding: propagated through
  // them, a drifting model's growing positions leaked into the other modes and the momentum
  // drifted as t^2 (8e-9 of 3.7 kg m/s in 4000 steps of a dodecahedron).
  const VectorX& mass = model_.properties.mass;
  const Vec3 centre = weightedCentre(mass, s.position),
             centreVelocity = weightedCentre(mass, s.velocity);
  s.position.rowwise() -= centre.transpose();
  s.velocity.rowwise() -= centreVelocity.transpose();
  // What the linear model -Omega^2 r does not capture, held over the step (Omega^2 of the
  // positions about the centre: of the drifting positions, its rounding grew with them).
  // The centre's acceleration is the forces' alone: K's rows sum to zero, so Omega^2 adds
  // nothing to it but rounding (which, summed over the step, kicked the momentum).
  multiply(system_.omega2(), s.position, work1_);
  const Vec3 centreLoad = weightedCentre(mass, acceleration_);
  work1_ += acceleration_;
  work1_.rowwise() -= centreLoad.transpose();

  // To modal coordinates and back with plain loops that read the modes once each way, column
  // by column (they are column-major): Eigen's blocked products allocated packing buffers
  // every step, and its coefficient-wise ones read the modes nine and six times.
  const Index n = modes_.rows();
  const double* root = sqrtMass_.data();
  for (Index k = 0; k < modes_.cols(); ++k) {
    const double* q = modes_.col(k).data();
    double r[3] = {0, 0, 0}, v[3] = {0, 0, 0}, b[3] = {0, 0, 0};
    for (Index i = 0; i < n; ++i) {
      const double w = q[i] * root[i];
      for (int d = 0; d < 3; ++d) {
        r[d] += w * s.position(i, d);
        v[d] += w * s.velocity(i, d);
        b[d] += w * work1_(i, d);
      }
    }
    for (int d = 0; d < 3; ++d) {
      modal1_(k, d) = r[d];
      modal2_(k, d) = v[d];
      modal3_(k, d) = b[d];
    }
  }
  for (Index k = 0; k < modal1_.rows(); ++k) {
    const auto p = propagator_.row(k);
    const Eigen::RowVector3d r = modal1_.row(k), v = modal2_.row(k), b = modal3_.row(k);
    modal1_.row(k) = p[0] * r + p[1] * v + p[2] * b;
    modal2_.row(k) = p[3] * r + p[4] * v + p[5] * b;
  }
  s.position.setZero();
  s.velocity.setZero();
  for (Index k = 0; k < modes_.cols(); ++k) {
    const double* q = modes_.col(k).data();
    const Eigen::RowVector3d r = modal1_.row(k), v = modal2_.row(k);
    for (Index i = 0; i < n; ++i) {
      s.position.row(i) += q[i] * r;
      s.velocity.row(i) += q[i] * v;
    }
  }
  s.position = inverseSqrtMass_.asDiagonal() * s.position;
  s.velocity = inverseSqrtMass_.asDiagonal() * s.velocity;

  // The motion about the centre has no mean in exact arithmetic; its rounding's mean goes.
  const auto& c = centrePropagator_;
  const Vec3 centreEnd = c[0] * centre + c[1] * centreVelocity + c[2] * centreLoad;
  const Vec3 velocityEnd = c[3] * centre + c[4] * centreVelocity + c[5] * centreLoad;
  s.position.rowwise() += (centreEnd - weightedCentre(mass, s.position)).transpose();
  s.velocity.rowwise() += (velocityEnd - weightedCentre(mass, s.velocity)).transpose();
}

void Stepper::stepSymplecticEuler(State& s, const Points& external, std::span<const double> share) {
  // v <- e^{-2GT} (v + T a(r)); r <- r + T v: the update fused with the acceleration.
  const double t = period_;
  const Index blocks = forces_.numBlocks();
  double* r = s.position.data();
  double* v = s.velocity.data();
  const double* a = acceleration_.data();
  parallelRegion(threads_, [&] {
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
  });
  totalForceReady_ = true;
  cacheValid_ = false;
}

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

  // The pattern holds whole 3 x 3 blocks, so in each of block column bj's three columns
  // the block's rows are consecutive, at the same distance from the column's start: one
  // search per block finds all nine entries.
  auto addBlock = [&](Index bi, Index bj, const Mat3& block) {
    const int* outer = im.a.outerIndexPtr();
    const int* inner = im.a.innerIndexPtr();
    double* values = im.a.valuePtr();
    const int* first = std::lower_bound(inner + outer[3 * bj], inner + outer[3 * bj + 1],
                                        static_cast<int>(3 * bi));
    const Index offset = first - (inner + outer[3 * bj]);
    for (int c = 0; c < 3; ++c) {
      double* column = values + outer[3 * bj + c] + offset;
      for (int r = 0; r < 3; ++r) column[r] += block(r, c);
    }
  };
  auto assemble = [&]() {
    for (Index e = 0; e < mesh.numEdges(); ++e) {
      const auto [i, j] = mesh.edge(e);
      const double kappa = edgeStiffness(p.stiffness[i], p.stiffness[j]);
      Mat3 b = Mat3::Zero();
      if (kappa != 0.0) {
        const Vec3 d = s.position.row(i) - s.position.row(j);
        const double len = d.norm();
        const Vec3 u = len > 0.0 ? Vec3(d / len) : Vec3::UnitX();
        const double transverse = len > 0.0 ? std::max(0.0, 1.0 - p.restLength[e] / len) : 0.0;
        const Mat3 uu = u * u.transpose();
        b = kappa * h * h * (transverse * (Mat3::Identity() - uu) + uu);
      }
      addBlock(i, i, b);
      addBlock(j, j, b);
      addBlock(i, j, -b);
      addBlock(j, i, -b);
    }
    for (size_t k = 0; k < model_.angles.angles.size(); ++k) {
      const auto [c, a, b] = model_.angles.angles[k];
      const double kappa = p.angularStiffness[c];
      if (kappa == 0.0) continue;
      std::array<Vec3, 3> grad{Vec3::Zero(), Vec3::Zero(), Vec3::Zero()};
      angleGradient(s.position.row(c), s.position.row(a), s.position.row(b), grad[0], grad[1],
                    grad[2]);
      const std::array<Index, 3> ids{c, a, b};
      for (int q = 0; q < 3; ++q)
        for (int r = 0; r < 3; ++r)
          addBlock(ids[q], ids[r], (kappa * h * h) * grad[q] * grad[r].transpose());
    }
    for (Index i = 0; i < n; ++i) addBlock(i, i, (p.mass[i] + h * p.damping[i]) * Mat3::Identity());
  };

  if (im.a.rows() != 3 * n) {
    // The pattern, once: whole 3 x 3 blocks, duplicates summed through triplets.
    std::vector<Eigen::Triplet<double>> triplets;
    im.a.resize(3 * n, 3 * n);
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
    for (VectorX* v : {&im.rhs, &im.flat, &im.inverseDiagonal, &im.residual, &im.direction,
                       &im.preconditioned, &im.product})
      v->resize(3 * n);
    im.dv = VectorX::Zero(3 * n);
  }
  im.a.coeffs().setZero();
  assemble();
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
  solveImplicit(im);
  // A uniform dv is a translation, which the Jacobian does not see: the exact solution's
  // momentum change sum_i (m_i + h d_i) dv_i equals sum_i rhs_i. Restore it from the
  // iterative solution so that momentum stays exact to rounding, as with a direct solve.
  Vec3 wanted = Vec3::Zero(), got = Vec3::Zero();
  double weight = 0.0;
  for (Index i = 0; i < n; ++i) {
    const double w = p.mass[i] + h * p.damping[i];
    wanted += im.rhs.segment<3>(3 * i);
    got += w * im.dv.segment<3>(3 * i);
    weight += w;
  }
  const Vec3 shift = (wanted - got) / weight;
  for (Index i = 0; i < n; ++i) im.dv.segment<3>(3 * i) += shift;
  for (Index i = 0; i < n; ++i) s.velocity.row(i) += im.dv.segment<3>(3 * i).transpose();
  s.position += h * s.velocity;
}

void Stepper::solveImplicit(Implicit& im) const {
  // Conjugate gradients with a Jacobi preconditioner, as Baraff and Witkin solve it, warm
  // started from the previous step's dv. A = M + h D - h^2 J is symmetric positive definite
  // by construction (the clamped transverse term, Gauss-Newton angle blocks). A sparse
  // Cholesky factorisation (Eigen's simplicial LDLT) cost 0.27 s a step on Torus-II
  // (94 % of it factorising); this costs a few dozen products.
  const auto& a = im.a;
  for (Index k = 0; k < a.outerSize(); ++k) {
    double diagonal = 0.0;
    for (Eigen::SparseMatrix<double>::InnerIterator it(a, k); it; ++it)
      if (it.row() == k) diagonal = it.value();
    im.inverseDiagonal[k] = diagonal > 0.0 ? 1.0 / diagonal : 1.0;
  }
  const double bound = kImplicitTolerance * im.rhs.norm();
  im.product.noalias() = a * im.dv;
  im.residual = im.rhs - im.product;
  im.preconditioned = im.inverseDiagonal.cwiseProduct(im.residual);
  im.direction = im.preconditioned;
  double rz = im.residual.dot(im.preconditioned);
  const Index limit = 10 * a.rows() + 100;
  for (Index iteration = 0; iteration < limit && im.residual.norm() > bound; ++iteration) {
    im.product.noalias() = a * im.direction;
    const double curvature = im.direction.dot(im.product);
    if (!(curvature > 0.0) || !std::isfinite(curvature))
      throw DivergenceError("implicit-euler: the linear system is not positive definite");
    const double alpha = rz / curvature;
    im.dv += alpha * im.direction;
    im.residual -= alpha * im.product;
    im.preconditioned = im.inverseDiagonal.cwiseProduct(im.residual);
    const double next = im.residual.dot(im.preconditioned);
    im.direction = im.preconditioned + (next / rz) * im.direction;
    rz = next;
  }
}

}  // namespace zsculpt
