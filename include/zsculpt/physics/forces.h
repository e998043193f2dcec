#pragma once
// Forces as pure functions of positions and rest values (paper section 5), each tested on
// its own (PositionBasedDynamics style), plus the accumulation over a whole model.
//
// Every internal force here is minus the gradient of an energy, so net force and net
// torque of internal forces vanish exactly (up to rounding) and energy is well defined.

#include <span>

#include "zsculpt/core/types.h"
#include "zsculpt/physics/properties.h"

namespace zsculpt {

/// The angle at `centre` between the arms to `a` and `b`, in [0, pi], computed as
/// atan2(|u x w|, u . w): accurate near 0 and pi, unlike acos.
double angleAt(const Vec3& centre, const Vec3& a, const Vec3& b);

/// Radial spring (section 5.1), energy kappa/2 (d - lambda)^2 with d = |r_i - r_j|.
/// Writes the force on i (the force on j is its negative) and returns the energy. With
/// lambda = 0 the force is the linear -kappa (r_i - r_j) of equation 1.
double radialSpringForce(const Vec3& ri, const Vec3& rj, double kappa, double restLength,
                         Vec3& forceOnI);

/// Angle spring (section 5.2), energy kappa_theta/2 (theta - theta_0)^2 for the angle at
/// `centre` between arms to `a` and `b`. Writes the forces on centre, a and b (summing to
/// zero, with zero net torque) and returns the energy.
///
/// Differs from the paper's printed F = kappa (theta - theta_0) n x r_ij, which scales with
/// d_ij sin(theta) and is not the gradient of any energy (so it cannot conserve energy): here
/// F_a = kappa (theta - theta_0) e_a / |r_a - r_c|, e_a the unit vector in the plane of the
/// angle, perpendicular to the arm, pointing towards the other arm. Near theta = 0 or pi the
/// in-plane direction is undefined; the force stays finite (magnitude kappa |theta -
/// theta_0| / d) and takes a deterministic perpendicular direction.
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
PotentialEnergy accumulateInternalForces(const Model& model, const Points& position,
                                         Points& force);

/// Adds gravity mu_i g to `force`; returns the gravitational potential -sum mu_i g . r_i.
double accumulateGravity(const PhysicalProperties& properties, const Points& position,
                         Points& force);

/// Potential energy only (no forces).
PotentialEnergy potentialEnergy(const Model& model, const Points& position);

}  // namespace zsculpt
