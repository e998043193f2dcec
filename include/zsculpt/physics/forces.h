#pragma once
// Forces as pure functions of positions and rest values (paper section 5), each tested on
// its own (PositionBasedDynamics style), plus the accumulation over a whole model.
//
// Every internal force here is minus the gradient of an energy, so net force and net
// torque of internal forces vanish exactly (up to rounding) and energy is well defined.

#include <algorithm>
#include <cstdint>
#include <span>
#include <vector>

#include "zsculpt/core/types.h"
#include "zsculpt/physics/properties.h"

namespace zsculpt {

/// The angle at `centre` between the arms to `a` and `b`, in [0, pi], computed as
/// atan2(|u x w|, u . w): accurate near 0 and pi, unlike acos. The atan2 is forces.cpp's
/// branch-free one (within about 2 ulps of libm's at any arm length; 0 for an arm of no
/// length), the one potentialEnergy takes in vectorised batches, so that rest angles made
/// with angleAt give a rest shape with no energy, to the bit.
double angleAt(const Vec3& centre, const Vec3& a, const Vec3& b);

/// Radial spring (section 5.1), energy kappa/2 (d - lambda)^2 with d = |r_i - r_j|.
/// Writes the force on i (the force on j is its negative) and returns the energy. With
/// lambda = 0 the force is the linear -kappa (r_i - r_j) of equation 1. Below d = lambda/2
/// (an edge crushed to less than half its rest length) the spring is continued by
/// kappa lambda^2/4 - kappa d^2/2, C1 at lambda/2, so that its stiffness stays within
/// kappa and the critical period of equation 5 still holds (forces.cpp says why).
double radialSpringForce(const Vec3& ri, const Vec3& rj, double kappa, double restLength,
                         Vec3& forceOnI);
/// The energy alone of a radial spring of length `length` (what radialSpringForce returns).
double radialSpringEnergy(double length, double kappa, double restLength);

/// The angle spring's profile (section 5.2): E = kappa_theta/2 (theta - theta_0)^2, except
/// near a straight (theta = pi) or folded (theta = 0) angle its rest angle is not. An angle
/// in [0, pi] is unsigned: a bend through straight is psi = pi - theta going to zero and
/// back, so (theta - theta_0)^2 has a cone tip there, and the force jumps by 2 kappa_theta
/// (pi - theta_0) whenever a vibrating sheet or curve passes through flat; explicit schemes
/// pump energy into a gently curved model at each pass (a 3-degree bend: energy x10 in
/// 60,000 steps). Within eps = min((pi - theta_0) / 2, kAngleCapWidth) of straight the
/// energy is the quadratic in psi^2 that meets it with the same value and slope, a function
/// of psi^2 and so smooth in the positions, and the same about theta = 0. slope is
/// dE/dtheta / kappa_theta and twiceEnergy 2 E / kappa_theta (theta - theta_0 and its square
/// away from the caps). docs/solver.md, "Angle springs through straight".
void angleSpringProfile(double theta, double restAngle, double& slope, double& twiceEnergy);
/// The widest cap (radians): a strongly bent rest angle (a cube's 90 degrees) keeps its
/// profile up to 0.25 rad from straight, and the cap's curvature stays within
/// (pi / 0.25) kappa_theta.
inline constexpr double kAngleCapWidth = 0.25;
/// kappa_theta times twiceEnergy / 2: the energy of an angle spring at `theta`.
double angleSpringEnergy(double theta, double restAngle, double kappa);
/// d theta / d(centre, a, b) of the angle at `centre` between the arms to `a` and `b`; false
/// (and zeros) when an arm has no length. At theta = 0 or pi (sine <= 1e-12) the in-plane
/// direction is undefined; a deterministic perpendicular one is taken.
bool angleGradient(const Vec3& centre, const Vec3& a, const Vec3& b, Vec3& gradCentre, Vec3& gradA,
                   Vec3& gradB);

/// Angle spring (section 5.2), energy angleSpringProfile's for the angle at `centre` between
/// arms to `a` and `b`. Writes the forces on centre, a and b (summing to zero, with zero net
/// torque) and returns the energy.
///
/// Differs from the paper's printed F = kappa (theta - theta_0) n x r_ij, which scales with
/// d_ij sin(theta) and is not the gradient of any energy (so it cannot conserve energy): here
/// F_a = -kappa slope(theta) d theta / d r_a = kappa slope e_a / |r_a - r_c|, e_a the unit
/// vector in the plane of the angle, perpendicular to the arm, pointing towards the other
/// arm. At theta = 0 or pi the slope is zero unless the rest angle is that angle too, so the
/// force vanishes there, continuously.
double angleSpringForce(const Vec3& centre, const Vec3& a, const Vec3& b, double kappa,
                        double restAngle, Vec3& forceOnCentre, Vec3& forceOnA, Vec3& forceOnB);

/// External torque at a vertex as virtual forces on its neighbours (section 5.3): the
/// minimum-norm forces f_k = lambda x d_k (d_k the arms) with sum_k d_k x f_k = torque, and
/// minus their sum on the centre, so the net force is zero and the net torque is `torque`.
/// When the arms cannot carry part of the torque (all collinear: a curve), that part is
/// dropped; the torque actually applied is returned.
Vec3 torqueToForces(const Vec3& centre, std::span<const Vec3> neighbours, const Vec3& torque,
                    std::span<Vec3> forceOnNeighbours, Vec3& forceOnCentre);

struct PotentialEnergy {
  double radial = 0.0;
  double angular = 0.0;
  double gravity = 0.0;
  [[nodiscard]] double total() const { return radial + angular + gravity; }
};

/// Adds the internal (radial and angle spring) forces at `position` to `force` and returns
/// their potential energy. Radial stiffness of edge (i, j) is edgeStiffness(kappa_i,
/// kappa_j); angle stiffness is the centre vertex's kappa_theta. No allocation.
PotentialEnergy accumulateInternalForces(const Model& model, const Points& position, Points& force);

/// Adds gravity mu_i g to `force`; returns the gravitational potential -sum mu_i g . r_i.
double accumulateGravity(const PhysicalProperties& properties, const Points& position,
                         Points& force);

/// The gravitational potential -sum mu_i g . r_i alone, as potentialEnergy() takes it (in
/// fixed parts on all threads: the same bits on any thread count).
double gravityEnergy(const PhysicalProperties& properties, const Points& position);

/// Potential energy only (no forces), on all threads and the same bits on any thread count
/// (every cycle's diagnostics take it).
PotentialEnergy potentialEnergy(const Model& model, const Points& position);

/// The internal forces of a whole model as the steppers evaluate them every step: the same
/// springs and formulas as accumulateInternalForces (which stays the plain serial
/// reference), organised for speed and for threads (docs/performance.md).
///
/// The vertices are cut into blocks of consecutive indices; the cut depends on the vertex
/// count only. Each block computes the radial forces on its own vertices (a gather, so
/// nothing is written outside the block: with angle springs every edge is evaluated from
/// both ends; a block without them evaluates each of its edges once, radialOnlyBlock) and every
/// angle spring centred in it once, adding the forces on its own vertices in place and
/// those on vertices of other blocks to a per-block halo buffer. A second pass adds the
/// halo buffers to their vertices in block order. Every sum therefore runs in an order
/// fixed by the model, not by the threads: the result is bit-identical whatever the
/// thread count (recorded sessions replay bit for bit). The angle springs, most of the
/// work, are evaluated in batches that the compiler vectorises (arm unit vectors shared by
/// the angles of a vertex, a branch-free atan2).
///
/// Cached from the properties: the radial stiffness kappa_ij of every edge. Call
/// propertiesChanged() (or rebuild()) after an edit; rest lengths, rest angles and angular
/// stiffness are read from the model at every evaluation and need nothing.
///
/// The two phases can run inside a caller's OpenMP parallel region (orphaned worksharing;
/// scatter() ends with a barrier), so that a stepper fuses its per-vertex work with
/// gatherBlock(); outside a parallel region they run on the calling thread.
class ForceKernel {
 public:
  ForceKernel() = default;
  /// O(edges + angles); allocates the per-thread work space for `maxThreads` threads
  /// (0: the OpenMP maximum).
  explicit ForceKernel(const Model& model, int maxThreads = 0);

  /// The properties of these vertices (or of their edges and angles) changed.
  void propertiesChanged(const Model& model, std::span<const Index> vertices);
  /// Every property may have changed.
  void rebuild(const Model& model);

  /// force = the internal forces at `position` (every row overwritten), and energy() with
  /// `withEnergy`. Uses up to `threads` threads (0: maxThreads), or the current team inside a
  /// parallel region.
  void compute(const Model& model, const Points& position, Points& force, int threads = 0,
               bool withEnergy = true);

  /// Phase 1 (worksharing over blocks, ends with a barrier): every block's own rows of
  /// `force` and its halo buffer; with `withEnergy` also the energy() at `position` (a few
  /// per cent more work).
  void scatter(const Model& model, const Points& position, Points& force, bool withEnergy = false);
  /// Phase 2 for one block: adds the halo contributions of other blocks to its rows.
  void gatherBlock(Index block, Points& force) const;

  /// The radial and angular energy at the position of the last compute() or scatter() with
  /// `withEnergy`, taken in the same pass as the forces (gravity is left at 0). Each block sums its
  /// springs' energies in eight interleaved running sums (forces.cpp, addToLanes) added in a fixed
  /// order, the blocks are added in block order: the same bits on any
  /// thread count. It agrees with potentialEnergy() to rounding (its sums run in another
  /// order, and its angles come from unit arms), so the energy of a rest shape is of the
  /// order of kappa_theta 1e-32 here where potentialEnergy() gives exactly 0.
  [[nodiscard]] PotentialEnergy energy() const;

  [[nodiscard]] Index numBlocks() const { return static_cast<Index>(blockStart_.size()) - 1; }
  /// Vertices in chunks of one degree (the fully vectorised path), for the report.
  [[nodiscard]] Index uniformVertices() const;
  [[nodiscard]] Index blockBegin(Index block) const { return blockStart_[block]; }
  [[nodiscard]] Index blockEnd(Index block) const { return blockStart_[block + 1]; }
  /// The block holding vertex v (0 <= v < the vertex count).
  [[nodiscard]] Index blockOf(Index v) const {
    return static_cast<Index>(std::upper_bound(blockStart_.begin() + 1, blockStart_.end() - 1, v) -
                              (blockStart_.begin() + 1));
  }
  [[nodiscard]] int maxThreads() const { return static_cast<int>(scratch_.size()); }
  /// Bytes held (caches, plan and work space), for the memory report.
  [[nodiscard]] size_t bytes() const;

 private:
  /// One thread's work space for one chunk of vertices (structure of arrays).
  struct Scratch {
    std::vector<double> acc;  // block accumulator, 3 per row (own rows, then halo)
    // Per half-edge (v, w) of a chunk: arm r_w - r_v (then its unit vector), length, inverse
    // length, radial force on v (then per-arm sums of angle forces); arms transposed by
    // slot for a run of equal-degree vertices.
    std::vector<double> ax, ay, az, length, invLength, gx, gy, gz, tx, ty, tz, tl;
    // Per angle of a chunk: arms (chunk half-edges), rest angle, cosine, sine, forces on
    // the two arm ends without kappa_theta (first arm's at k, second arm's at k + maxAngles).
    std::vector<Index> armP, armQ;
    std::vector<double> rest, cosine, sine, fx, fy, fz;
    // Per half-edge its radial spring's energy; per angle its squared excess theta - theta_0.
    std::vector<double> energy, excess2;
  };
  void scatterBlock(const Model& model, const Points& position, Points& force, Index block,
                    Scratch& scratch, bool withEnergy);
  /// scatterBlock for a block with no angle spring centred in it: every edge once.
  void radialOnlyBlock(const Model& model, const Points& position, Points& force, Index block,
                       Scratch& scratch, bool withEnergy);

  std::vector<Index> blockStart_{0};
  /// Chunks of at most chunkVertices_ consecutive vertices, per block (blockChunk_): their
  /// first vertex, and their vertices' common degree (0 when it varies).
  std::vector<Index> blockChunk_{0}, chunkStart_, chunkDegree_;
  /// The half-edges (rows of Mesh::vertexNeighborTable) in the kernel's order: as the mesh
  /// has them, except in a chunk of one degree d, where arm a of the chunk's vertex i is
  /// at a L + i (L vertices): the vertex across, the edge, and where a force on the vertex
  /// across goes in the block's accumulator (own rows first, then the halo).
  std::vector<Index> neighbour_, edge_, target_;
  std::vector<Index> haloStart_{0};
  /// A block without angle springs evaluates each edge once instead of from both ends (half
  /// the arms, square roots and divisions), in groups of consecutive vertices (blockGroup_
  /// per block, groupStart_ their first vertex): each group's edges touching its vertices,
  /// ascending (groupEdge_, CSR by groupEdgeStart_), with their ends as Mesh::edges() has
  /// them, and for every mesh half-edge of the vertex v the slot of its edge in v's group,
  /// or ~slot when v is the edge's second end (the force on it is then minus the edge's).
  std::vector<Index> blockGroup_{0}, groupStart_, groupEdgeStart_{0};
  std::vector<Index> groupEdge_, groupFirst_, groupSecond_, armSlot_;
  /// Per block, what other blocks left for its vertices: (local row, halo position, source
  /// block), sorted by row then source block.
  std::vector<Index> incomingStart_{0};
  std::vector<Index> incomingRow_, incomingHalo_, incomingBlock_;
  std::vector<double> halo_;
  std::vector<std::uint8_t> blockHasAngles_;
  /// Per block the radial and the angular energy of the last scatter (energy()).
  std::vector<double> blockEnergy_;
  VectorX edgeKappa_;
  /// The angle table lists every vertex's angles as the pairs (p < q) of its neighbours in
  /// neighbour order (buildAngleTable's layout): arms are found without a lookup.
  bool canonicalAngles_ = true;
  std::vector<Index> angleArm_;  // 2 per angle (half-edges), when not canonical
  /// Canonical layout, per vertex degree k: the pairs (a, b) of arms in angle order, and for
  /// every arm its terms (angle number, plus maxAngles_ for the angle's second arm) in angle
  /// order. Offsets per degree in pairStart_ / termStart_ (arm terms: CSR by degree then arm).
  std::vector<Index> pairStart_, pairA_, pairB_, termStart_, armTermStart_, armTerm_;
  Index maxAngles_ = 0;
  /// Per angle, at the angles of a by-slot run's first vertex (one per pair of arms): whether
  /// the run's angles of that pair were in a cap at the last evaluation, so that the next
  /// takes them with the cap and the others without (forces.cpp, runAngleRows). A guess that
  /// only decides speed: the forces are the same bits either way.
  std::vector<std::uint8_t> capsTaken_;
  /// Angle arms that are not edges of the centre: use the serial reference instead.
  bool reference_ = false;
  Index chunkVertices_ = 64;
  std::vector<Scratch> scratch_;
};

}  // namespace zsculpt
