#pragma once
// The rigid-body half of semi-rigid motion (paper section 4.3): mass properties of the
// model, Newton-Euler equations for the rigid component chi_i F_i of the forces, and the
// helpers the solver cycle uses to compose the rigid motion with the elastic deformation.
// docs/semi-rigid-and-constraints.md derives the choices and tabulates their measurements.
//
// Inertia. The paper takes the moment of inertia of "a thin shell with a vanishing
// thickness" over the current surface. The solver's mass is lumped at the vertices
// (mu_i, section 4.1), so the shell here is that lumped shell: I = sum_i mu_i (|r_i - c|^2 1
// - (r_i - c)(r_i - c)^T) about the centre of mass c, recomputed from the current positions
// every cycle. It is the only choice under which the angular momentum of the rigid motion,
// I omega, equals sum_i mu_i (r_i - c) x v_i of the very velocities the elastic solver and
// the diagnostics see, so momentum bookkeeping is exact; the same formula is a curve's
// (thin rod's) and a solid's own lumped inertia. uniformShellInertia() gives the continuous
// area-weighted shell for comparison.
//
// Integration. Kick-drift-kick (velocity Verlet) on the momenta P and L (world frame); the
// drift rotates by the exact-momentum, symplectic splitting of the free rigid body
// (McLachlan 1993; Dullweber, Leimkuhler and McLachlan 1997): in the principal frame of the
// current inertia, H = sum_k L_k^2 / (2 I_k) is split into three exactly solvable rotations
// about one principal axis each, composed symmetrically. Each sub-step is an exact rotation
// that keeps the world angular momentum, so a torque-free body conserves L to rounding and
// its energy has no drift; distances are kept exactly because only rotations are applied.

#include <span>

#include "zsculpt/core/types.h"
#include "zsculpt/mesh/mesh.h"

namespace zsculpt {

/// Total mass, centre of mass, and inertia tensor about the centre of mass (world axes).
struct MassProperties {
  double mass = 0.0;
  Vec3 centre = Vec3::Zero();
  Mat3 inertia = Mat3::Zero();
};

/// The passes over every vertex below take `threads` (the stepper's): above
/// kRigidPartRows vertices their sums run in kRigidParts fixed contiguous parts, added in
/// part order, so that the result is the same bits on any thread count; below, one loop.
inline constexpr Index kRigidPartRows = 50000;
inline constexpr int kRigidParts = 64;

/// Lumped thin-shell mass properties: vertex masses `mass` at `position` (N x 3).
MassProperties massProperties(const VectorX& mass, const Points& position, int threads = 1);

/// Inertia tensor, about its own centre (written to `centre` if given), of `totalMass`
/// spread uniformly by area over the faces (polygons fan-triangulated from their first
/// corner): the continuous thin shell of vanishing thickness. Zero for a mesh without faces.
Mat3 uniformShellInertia(const Mesh& mesh, const Points& position, double totalMass,
                         Vec3* centre = nullptr);

/// omega = I^+ L: the pseudo-inverse, so a principal axis of (near-)zero moment (the axis of
/// a straight rod, or every axis of a single vertex) carries no rotation.
Vec3 angularVelocity(const Mat3& inertia, const Vec3& angularMomentum);

/// exp([theta]_x): rotation by |theta| about theta.
Mat3 rotationFromVector(const Vec3& theta);

/// The rotation (world frame) of a free rigid body of world inertia `inertia` and world
/// angular momentum `angularMomentum` over `dt`, by the symmetric principal-axis splitting
/// described above; exact for a (nearly) isotropic body. World L is invariant under it.
Mat3 freeRotation(const Mat3& inertia, const Vec3& angularMomentum, double dt);

/// Resultant force sum_i w_i F_i and torque sum_i (r_i - centre) x w_i F_i of the weighted
/// forces. An empty `weight` means 1 everywhere.
void weightedResultant(std::span<const double> weight, const Points& position, const Points& force,
                       const Vec3& centre, Vec3& resultant, Vec3& torque, int threads = 1);

/// Momenta of the rigid component: linear P (= M V) and angular L about the centre of mass
/// (= I omega), world frame.
struct RigidMomentum {
  Vec3 linear = Vec3::Zero();
  Vec3 angular = Vec3::Zero();
};

/// P and L (about `centre`) of a velocity field.
RigidMomentum momentumOf(const VectorX& mass, const Points& position, const Points& velocity,
                         const Vec3& centre, int threads = 1);

/// The first half of a Newton-Euler kick-drift-kick step: damping over dt/2 (exponential,
/// rate `damping`), a half kick by force and torque, then the drift over dt: the centre of
/// mass moves by `translation` and the body turns by `rotation` about it.
struct RigidDrift {
  RigidMomentum half;
  Vec3 translation = Vec3::Zero();
  Mat3 rotation = Mat3::Identity();
};
RigidDrift rigidDrift(const MassProperties& start, const RigidMomentum& momentum, const Vec3& force,
                      const Vec3& torque, double dt, double damping);

/// The second half: a half kick by the forces at the end of the drift, then damping over
/// dt/2.
RigidMomentum rigidKick(const RigidMomentum& half, const Vec3& force, const Vec3& torque, double dt,
                        double damping);

/// r_i <- pivot + translation + rotation (r_i - pivot), for every row.
void applyRigidMotion(const Vec3& pivot, const Vec3& translation, const Mat3& rotation,
                      Points& position, int threads = 1);

/// v_i += scale (V + omega x (r_i - c)) with V = P / M and omega = I^+ L.
void addRigidVelocity(const MassProperties& properties, const RigidMomentum& momentum,
                      const Points& position, Points& velocity, double scale = 1.0,
                      int threads = 1);

/// Tisserand projection: removes from `velocity` the rigid motion that carries its linear
/// and angular momentum (about properties.centre), so that what is left has zero momentum
/// and zero angular momentum (when the inertia is invertible); returns the momenta removed.
/// Kinetic energy splits exactly into the removed rigid part and what is left.
RigidMomentum removeRigidMotion(const VectorX& mass, const MassProperties& properties,
                                const Points& position, Points& velocity, int threads = 1);

}  // namespace zsculpt
