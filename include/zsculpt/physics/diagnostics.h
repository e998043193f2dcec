#pragma once
// Energy and momentum of a state (paper section 7, Figures 3 and 7).

#include "zsculpt/physics/forces.h"
#include "zsculpt/physics/properties.h"

namespace zsculpt {

struct Diagnostics {
  double kinetic = 0.0;
  PotentialEnergy potential;
  [[nodiscard]] double total() const { return kinetic + potential.total(); }
  /// The paper's partial energy: total energy per vertex (Figure 3).
  double partial = 0.0;
  Vec3 momentum = Vec3::Zero();
  /// About the centre of mass.
  Vec3 angularMomentum = Vec3::Zero();
  Vec3 centreOfMass = Vec3::Zero();
  double totalMass = 0.0;
};

Diagnostics measure(const Model& model, const State& state);
/// measure() with the radial and angular energy already known at state.position (`internal`,
/// its gravity ignored), e.g. from the step's own force pass (Stepper::internalEnergy).
Diagnostics measure(const Model& model, const State& state, const PotentialEnergy& internal);

/// Kinetic energy, momentum, angular momentum about the centre of mass, without potential.
Diagnostics measureKinematics(const VectorX& mass, const State& state);

/// The mass-weighted mean sum_i m_i x_i / sum_i m_i of rows x (positions: the centre of mass;
/// velocities: its velocity), summed in 64 fixed parts added in order: the same bits on any
/// thread count.
Vec3 weightedCentre(const VectorX& mass, const Points& x, int threads = 1);

}  // namespace zsculpt

namespace zsculpt {

/// Random initial velocity of RMS size `amplitude` per vertex with zero net momentum
/// (the command line's --perturb AMP --seed N). Deterministic for a seed.
void randomVelocity(const VectorX& mass, double amplitude, unsigned seed, Points& velocity);

/// A rigid spin: v_i = omega x (r_i - centre of mass).
void spinVelocity(const VectorX& mass, const Points& position, const Vec3& omega, Points& velocity);

/// A sculptor's poke: velocity `speed` along `direction` at vertex `centre`, falling off as
/// exp(-d^2 / (2 width^2)) with the rest distance d from it, less the mean (zero net
/// momentum). Smooth on the scale of `width`, so it excites the low modes a drag excites
/// and hardly the highest ones a per-vertex random velocity fills.
void pokeVelocity(const VectorX& mass, const Points& position, Index centre, double width,
                  double speed, const Vec3& direction, Points& velocity);

}  // namespace zsculpt
