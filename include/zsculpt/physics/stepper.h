#pragma once
// The z-domain stepper (paper section 4) and the baselines it is compared with.
// docs/solver.md derives each scheme and tabulates their measured behaviour.
//
//   paper     Equation 3 as printed: R += H' V + H A, V = X' V + X A, with A = M^-1 F_tot
//             the total acceleration at the start of the step, H.. X' Taylor-truncated
//             after Omega^4. Reproduces the paper's figures; dissipates or gains energy
//             with rest-length springs and kills rotation (solver-findings.md).
//   default   What users get. Velocity Verlet whose total acceleration is filtered by
//             Phi = 2 H / T^2 truncated after Omega^2 (= I - T^2 Omega^2 / 12), with the
//             damping of G applied exactly in two half steps. Rest shape is an equilibrium,
//             linear momentum is exact, energy has no secular drift, and per mode the
//             amplification's trace is twice H'' (cos Omega T truncated after Omega^4) with
//             determinant 1, so it is stable exactly up to (omega T)^2 = 12: equation 5.
//             With StepperOptions::driftFilter (on by default), on models braced by angle
//             springs, the drift is filtered too and both filters are built on Omega^2
//             outside the affine fields of the rest shape (docs/solver.md section 6).
//   exact     The exact z-domain (modal) solution of the linear system M r'' + D r' + K r =
//             F, by a dense eigendecomposition; what K does not capture (rest lengths, angle
//             springs, loads) is held constant over the step. The tests' oracle.
//   symplectic-euler, implicit-euler (Baraff-Witkin, one linearised solve per step): the
//             baselines users would otherwise pick.
//
// External forces are held constant over a step (zero-order hold, as the z-transform of
// sampled forces assumes). No allocation per step (but for the exact scheme's dense products).
//
// Speed (docs/performance.md): the internal forces come from ForceKernel; every scheme's
// step is a few passes over blocks of vertices inside one OpenMP parallel region, each
// pass fusing what it can (the default scheme: kick and drift; forces; acceleration;
// filter product, kick and damping). Every value is computed by one thread in an order
// fixed by the model, so a state is bit-identical whatever the thread count.

#include <Eigen/Dense>
#include <Eigen/SparseCore>
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "zsculpt/physics/forces.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/physics/properties.h"
#include "zsculpt/physics/thread_tuner.h"

namespace zsculpt {

enum class Scheme { Default, Paper, Exact, SymplecticEuler, ImplicitEuler };

std::string_view schemeName(Scheme scheme);
/// Throws InvalidInputError naming the unknown scheme and listing the valid ones.
Scheme schemeFromName(std::string_view name);

/// The periods a stepper takes: the schemes' coefficients hold powers of the period up to
/// T^6 (the exact scheme's series; the default's filter T^3 / 24), which overflow or
/// underflow outside this range (a mass of 1e300 kg gave T = 2.7e149 s, T^3 = inf, and a
/// state of NaN at the first step). Every model in consistent units is far inside it.
inline constexpr double kShortestPeriod = 1e-50;
inline constexpr double kLongestPeriod = 1e50;
/// Throws InvalidInputError, "<what>: <period> s is outside ...", unless the period is in
/// [kShortestPeriod, kLongestPeriod].
void checkPeriodRange(double period, const std::string& what);

/// The largest stable period of a scheme for these matrices, from the largest eigenvalue
/// lambda_0 of Omega^2 (infinite for exact and implicit-euler): sqrt(12 / lambda_0) for
/// default and paper, sqrt(4 / lambda_0) for symplectic-euler. The paper's scheme also
/// keeps equation 4's p = 1 - gamma T > 0 at every vertex (gamma = rho / (2 mu), the
/// vertex's G_ii), so its limit is at most 1 / largestDampingRate: its truncated damping
/// runs away not far past that (a dodecahedron with 1 / gamma = 0.4 T_max decays at
/// 0.55 T_max and is gone at 0.6), however far below sqrt(12 / lambda_0) the step is.
double stablePeriodLimit(Scheme scheme, double largestEigenvalue, double largestDampingRate = 0.0);
/// The same for a model's matrices, their largest damping rate max G_ii taken from them:
/// with `largestEigenvalue` (largestEigenvalue(system)) the tight limit; the Gershgorin
/// overload takes the bound 2 max Omega^2_ii instead, never above the tight limit and cheap.
double stablePeriodLimit(Scheme scheme, const SystemMatrices& system, double largestEigenvalue);
double gershgorinStablePeriodLimit(Scheme scheme, const SystemMatrices& system);
/// Whether `period` is past a stable limit: above it, or at it to within 1e-9. At the limit
/// itself the fastest mode is marginal (its amplification a double root on the unit circle)
/// and rounding makes it grow: Torus-I, whose limit is exactly its T_max, gained 8 % of its
/// energy over 20000 steps at 1.0 T_max and 0.25 % at 0.99 T_max.
inline bool beyondStableLimit(double period, double limit) {
  return period >= limit * (1.0 - 1e-9);
}

struct StepperOptions {
  /// Paper scheme: multiply by the stored two-ring matrices H, H', X, X' instead of
  /// applying their polynomials in Omega^2 (same result; see bench for which is faster).
  bool storedMatrices = false;
  /// Default scheme: filter the drift too, r += T Psi v, with both filters built on Omega^2
  /// outside the affine fields of the rest shape (docs/solver.md section 6), on braced
  /// models (angle springs at every vertex; others keep the plain drift). Its mean energy
  /// stays within 1 % at 0.9 T_max where the kick filter alone moves by up to 2-3 %, it
  /// conserves a momentum map that equals L on rigid motions, and storms and heavy loads
  /// that make the kick filter alone run away stay bounded with it; the price is phase
  /// accuracy (the highest modes run slower) and one to four more products per step. On by
  /// default; off (`--no-drift-filter`) gives the kick filter alone.
  bool driftFilter = true;
  /// The drift filter's row passes in AVX2 where the processor has it (4 doubles a point,
  /// one instruction where the baseline takes two). The same bits either way; off only to
  /// compare the two.
  bool wideKernels = true;
  /// Default scheme: take the radial and angular energy at each step's end in the same pass
  /// as the forces there (internalEnergy()), a few per cent more work in the step, which
  /// spares a cycle's diagnostics an evaluation of every spring (about a fifth of a cycle on
  /// large models; docs/performance.md). Simulation turns it on.
  bool measureEnergy = false;
  /// Exact scheme: refuse models larger than this (dense eigendecomposition).
  Index exactMaxVertices = 4000;
  /// Threads for the step. 0 (automatic): one below kParallelMinVertices vertices; above,
  /// the stepper times a few steps with all of OpenMP's threads (OMP_NUM_THREADS) and a few
  /// with one, keeps the faster and checks again every few seconds (a second thread only
  /// helps when a core is free: on a loaded machine waiting for it costs more than it
  /// saves). The result does not depend on the thread count, so switching is invisible.
  int threads = 0;
};

/// Below this many vertices the automatic thread count is one.
inline constexpr Index kParallelMinVertices = 1024;
/// The most threads a step may be asked for (StepperOptions::threads): far beyond any
/// machine's use for it, and short of what a process can start (100000 crashed it).
inline constexpr int kMaxThreads = 256;
/// implicit-euler: conjugate gradients stop at this residual relative to the right side.
inline constexpr double kImplicitTolerance = 1e-10;
/// The most threads the automatic choice uses for a model of this many vertices.
int automaticThreads(Index vertices);

class Stepper {
 public:
  /// Builds the matrices for `model` (kept by reference: it must outlive the stepper, and
  /// property edits must be followed by propertiesChanged()).
  Stepper(const Model& model, Scheme scheme, double period, const StepperOptions& options = {});
  ~Stepper();
  Stepper(const Stepper&) = delete;
  Stepper& operator=(const Stepper&) = delete;

  /// Advances `state` by one period under `external` forces (N x 3, held over the step) and
  /// gravity. `elasticShare` (optional, N) scales each vertex's total force before it
  /// reaches the elastic stepper (section 4.3, sigma_i); empty means 1.
  void step(State& state, const Points& external, std::span<const double> elasticShare = {});

  /// step() in two parts, for a caller that may drop a step once its end positions are known
  /// (a constrained cycle's trials: Simulation). beginStep() moves the positions to the
  /// step's end (the velocity up to the second kick); finishStep() takes the rest: the
  /// default scheme's forces at the end and its second kick, and the time. Together they are
  /// step(), bit for bit, and a dropped step costs only its first part (about two fifths of
  /// a step). To drop a begun step, set the state back to its start and call rewind(): the
  /// next beginStep() starts from the start forces the dropped one made. Both parts take the
  /// same loads and share. Schemes other than default take the whole step in beginStep().
  void beginStep(State& state, const Points& external, std::span<const double> elasticShare = {});
  /// beginStep() from `from` into `state` (resized to it, its time set to from's): the same
  /// bits as copying `from` into `state` and beginning there, without the copy (the default
  /// scheme reads the start where the copy would; the others copy). A constrained cycle
  /// begins each trial from the same start this way.
  void beginStep(const State& from, State& state, const Points& external,
                 std::span<const double> elasticShare = {});
  void finishStep(State& state, const Points& external, std::span<const double> elasticShare = {});
  /// A step was begun and neither finished nor dropped (rewind(), invalidate()).
  [[nodiscard]] bool stepBegun() const { return begun_; }

  /// The internal forces at `position` (N x 3), by the step's force kernel on the step's
  /// threads, kept as the next step's start forces: for a caller that needs them itself and
  /// steps from `position` next (Simulation's rigid coupling, whose rigid motion moves the
  /// vertices after each elastic step), so that the step does not evaluate them again. The
  /// caller must invalidate() if the next step starts elsewhere. internalEnergy() is then
  /// the energy at `position`. Not between beginStep() and finishStep().
  const Points& startAt(const Points& position);
  /// The internal forces at the end of the last step turned by `rotation`, kept as the next
  /// step's start forces, as startAt() would evaluate them at the end positions moved by a
  /// rigid motion with that rotation (the springs' forces turn with the body: they depend on
  /// lengths and angles only), for a pass of 3 x 3 products instead of an evaluation. Null,
  /// changing nothing, when the end forces are not cached (a scheme other than default,
  /// invalidated, rewound or begun): then startAt().
  const Points* turnEndForces(const Mat3& rotation);

  /// Default scheme: step with period `period` from now on (Simulation splits a cycle into
  /// steps of T / n when the motion is fast: SimulationSettings::substepStrain). O(N) (the
  /// damping factors), no allocation. Throws InvalidInputError for other schemes (the paper
  /// scheme's matrices, the exact propagators and the implicit system are made for one
  /// period) and for a period that is not positive and finite.
  void setPeriod(double period);

  /// The properties of these vertices (or of their edges and angles) changed: update the
  /// matrices' rows locally and drop cached forces.
  void propertiesChanged(std::span<const Index> vertices);
  /// Rebuild everything (a global edit).
  void rebuild();
  /// Cached internal forces are stale (the state was changed from outside).
  /// Drops a begun step too.
  void invalidate();
  /// The state was set back to where the last step started, or the begun one (a constrained
  /// cycle's next trial from the same start): the internal forces there, which that step
  /// kept, serve again instead of being evaluated anew (about a fifth of a drag's cycle); the
  /// same bits either way. Otherwise like invalidate() (a scheme other than default, no step
  /// since the last invalidation, or a second rewind).
  void rewind();

  [[nodiscard]] Scheme scheme() const { return scheme_; }
  [[nodiscard]] double period() const { return period_; }
  [[nodiscard]] const SystemMatrices& system() const { return system_; }
  /// Paper scheme only (null otherwise).
  [[nodiscard]] const TransformationMatrices* transformation() const {
    return transformation_.get();
  }
  /// Total force (internal + external + gravity) at the start of the last step. Made on
  /// demand after most steps, with the masses of the time of the call: call it before the
  /// model's masses change to have the step's.
  [[nodiscard]] const Points& lastTotalForce() const;
  /// Default scheme: whether the drift is filtered (StepperOptions::driftFilter on a model
  /// braced by angle springs at every vertex, and of one connected piece).
  [[nodiscard]] bool filtersDrift() const { return braced_ && options_.driftFilter; }
  /// Default scheme with filtersDrift(): column l of the filter product Psi Phi (the end-of-step
  /// position moves by (T^2/2) sigma_l / mu_l times it per unit force held on vertex l), N long.
  /// Not for the per-step path: it allocates.
  [[nodiscard]] VectorX filteredPositionColumn(Index l) const;
  /// The step's linear response: how far the end position of each vertex in `rows` moves per
  /// unit acceleration held at vertex l over the step, into `out` (the constraint solver
  /// inverts it on its support; docs/semi-rigid-and-constraints.md). Each scheme's own: the
  /// default's (T^2/2) Phi, or Psi Phi with the drift filter; the paper's H (equation 3);
  /// symplectic Euler's damped T^2; implicit Euler's diagonal (a first-order model). The
  /// exact scheme answers with equation 3's H, which approximates its own. Not for the
  /// per-step path (the drift filter's column allocates).
  void positionResponse(Index l, std::span<const Index> rows, std::span<double> out) const;
  /// How far the centre of mass moves, times the total mass over mu_l, per unit acceleration
  /// held at l: sum_j mu_j (d r'_j / d a_l) / mu_l (the Laplacian terms cancel: K's columns
  /// sum to zero).
  [[nodiscard]] double centreResponse(Index l) const;
  /// Default scheme with filtersDrift(): the products with W the drift takes per step, the
  /// degree of Psi in T^2 W (1 to 4: the lowest whose fit holds at this period).
  [[nodiscard]] int driftProducts() const { return driftDegree_; }
  /// Default scheme with StepperOptions::measureEnergy, when the internal forces at the end
  /// of the last step, or those of startAt(), are still cached (nothing invalidated them
  /// since): their radial and angular energy, from the same pass (ForceKernel::energy).
  /// Otherwise nullopt.
  [[nodiscard]] std::optional<PotentialEnergy> internalEnergy() const;
  /// Threads the last step used.
  [[nodiscard]] int threads() const { return threads_; }
  /// Default scheme: whether the last step kept its first kick from the step before (the
  /// same position, loads of the same bits, no share) instead of making it afresh.
  [[nodiscard]] bool keptKick() const { return keptKick_; }
  /// Bytes held by the stepper (matrices, caches, work buffers), for the memory report.
  [[nodiscard]] size_t bytes() const;

 private:
  // Inside the step's parallel region: acceleration (and total force) rows of one block from
  // `internal`, the external forces, gravity and the elastic share; returns whether the
  // block's external forces are all zero.
  bool accelerationRows(Index block, const Points& internal, const Points& external,
                        std::span<const double> share, bool writeTotal);
  void computeAcceleration(const Points& position, const Points& external,
                           std::span<const double> elasticShare);
  void refreshDamping(std::span<const Index> vertices);
  // Inside the step's parallel region: marks externalZero_ per block and returns whether all
  // of the external forces are zero, and whether they are the last step's (both steps apply
  // none, or loads of the same bits).
  struct LoadCheck {
    bool zero = true;
    bool same = true;
  };
  LoadCheck markZeroExternalBlocks(const Points& external);
  // The default scheme's two parts (beginStep, finishStep), or both in one parallel region
  // (step).
  enum class Part { Begin, Finish, Whole };
  void checkStepInputs(const State& state, const Points& external) const;
  // The scheme's step, or the part of it (the schemes other than default take the whole
  // step at Part::Begin and nothing at Part::Finish).
  // `from` is the start state of the begin (state itself but for beginStep(from, state)).
  void takeStep(const State& from, State& state, const Points& external,
                std::span<const double> share, Part part);
  // A begun step is dropped (rewind, invalidate, an edit): it becomes the last step for the
  // record of loads and lastTotalForce(), with its start forces in internal_.
  void dropBegunStep();
  // Its bookkeeping after each: after the begin, what the finish needs of its loads; after
  // the finish, the swap of its force buffers and what the next step may keep.
  void endDefaultPart(Part part, bool loadsZero, bool keptKick, bool shared);
  // Forgets the last step's loads (a new block layout).
  void resetLoadRecord();
  void stepDefault(const State& from, State& s, const Points& external,
                   std::span<const double> share, Part part);
  // The default scheme with StepperOptions::driftFilter on a braced model.
  void stepDriftFiltered(const State& from, State& s, const Points& external,
                         std::span<const double> share, Part part);
  void stepPaper(State& s, const Points& external, std::span<const double> share);
  void stepExact(State& s, const Points& external, std::span<const double> share);
  void stepSymplecticEuler(State& s, const Points& external, std::span<const double> share);
  void stepImplicitEuler(State& s, const Points& external, std::span<const double> share);
  struct Implicit;
  void solveImplicit(Implicit& im) const;
  void setUpExact();
  // Default scheme: the affine fields' basis and what the filters need of it, all of it
  // (empty span) or the rows of these vertices and their one-ring.
  void setUpAffine(std::span<const Index> vertices);
  // Default scheme with the drift filter: Gershgorin's bound on Omega^2's spectrum per block
  // (all blocks, or those of these vertices), then Psi's fit for the period (driftA_).
  void boundSpectrum(std::span<const Index> vertices);
  void chooseDriftFit();

  const Model& model_;
  Scheme scheme_;
  double period_;
  StepperOptions options_;
  int threads_ = 1;
  bool tuning_ = false;  // automatic thread count (thread_tuner.h)
  ThreadTuner tuner_{1, 1};
  SystemMatrices system_;
  std::unique_ptr<TransformationMatrices> transformation_;
  ForceKernel forces_;

  // Work buffers (N x 3), allocated once. internal_ holds the internal forces at the current
  // position when cacheValid_; previousInternal_ those at the start of the last step.
  Points internal_, previousInternal_, acceleration_, kick_, work1_, work2_, work3_, work4_;
  bool cacheValid_ = false;
  // rewind() put the last step's start forces back in internal_ (previousInternal_ holds its
  // end forces, whose energy the kernel still has).
  bool rewound_ = false;
  // Default scheme: kick_ = (T/2) Phi a of the last step's end, valid for the next step's
  // start while the external forces stay the same bits (zero, or steady loads: a held force,
  // or a drag's first trial, which starts from the last trial's constraint forces) and no
  // elastic share is given.
  bool kickValid_ = false;
  bool keptKick_ = false;
  // beginStep() ran and finishStep() has not: what the begun step found of its loads, and
  // how long it took (the thread tuner times begin and finish together).
  bool begun_ = false;
  bool begunZero_ = true;
  bool begunKeptKick_ = false;
  double begunSeconds_ = 0.0;
  // rewind() has a step to give back: a default step finished or begun since the last
  // rewind, startAt or turnEndForces.
  bool rewindable_ = false;
  // Per vertex: exp(-g T) (half a step of damping, default scheme) and exp(-2 g T).
  VectorX dampHalf_, dampFull_;
  // Per block: are the external forces of its rows zero (a zero's sign aside: such loads are
  // not applied); were they all +0 at the last step (else lastExternal_ holds its rows); are
  // they the last step's, bit for bit. loadsZero_: the last step applied no loads.
  std::vector<std::uint8_t> externalZero_, externalExactZero_, externalSame_;
  Points lastExternal_;
  bool loadsZero_ = true;
  // lastTotalForce(): written by the step, or made on demand from previousInternal_, the
  // last step's loads and gravity when the step kept its first kick or had no loads.
  mutable Points totalForce_;
  mutable bool totalForceReady_ = true;

  // Default scheme: B (N x 4, orthonormal columns spanning {1, X, Y, Z} of the rest shape,
  // the first affineRank_ used), Omega^2 B, the masses G and C were made with,
  // G = B^T M B, its inverse, C = B^T K B; per block the partial sums of B^T M u and
  // (Omega^2 B)^T M u; the c and d of the last vector summed; rows to refresh.
  // Row-major: a vertex's four entries are adjacent (the step reads them row by row).
  Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor> affineBasis_, omegaBasis_;
  // Per row m_i B_i then m_i (Omega^2 B)_i, the terms of the block sums, made once.
  Eigen::Matrix<double, Eigen::Dynamic, 8, Eigen::RowMajor> massBases_;
  VectorX affineMass_;
  Eigen::Matrix4d affineGram_ = Eigen::Matrix4d::Zero(),
                  affineInverseGram_ = Eigen::Matrix4d::Zero(),
                  affineStiffness_ = Eigen::Matrix4d::Zero();
  int affineRank_ = 0;
  bool braced_ = false;
  bool oneBody_ = true;  // the mesh is one connected component (the drift filter's B is)
  std::vector<double> affinePartial_;
  std::array<double, 24> affineCoefficient_{};
  std::array<double, 12> velocityCoefficient_{};  // c of the velocity, which Psi's terms scale
  std::vector<Index> affineRows_;
  // Per block the largest sum_j |Omega^2_ij| of its rows; Psi = I + sum_{k=1..D} a_k (T^2 W)^k
  // with a_k at driftA_[k], D = driftDegree_.
  std::vector<double> spectrumBound_;
  std::array<double, 5> driftA_{};
  int driftDegree_ = 4;

  // Exact scheme: Omega^2's symmetric form = Q diag(w^2) Q^T; per-mode 2 x 3 propagators.
  Eigen::MatrixXd modes_;
  Eigen::MatrixXd propagator_;  // N x 6: phi11 phi12 gamma1 phi21 phi22 gamma2
  VectorX sqrtMass_, inverseSqrtMass_;
  Eigen::MatrixXd modal1_, modal2_, modal3_;
  // The centre of mass's propagator (the 2 x 3 of a mode with w^2 = 0): stepExact moves the
  // centre of mass on its own (stepper.cpp says why).
  std::array<double, 6> centrePropagator_{};

  // Implicit Euler: A = M + h D - h^2 J (3N x 3N).
  std::unique_ptr<Implicit> implicit_;
};

}  // namespace zsculpt
