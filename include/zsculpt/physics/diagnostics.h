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

/// Kinetic energy, momentum, angular momentum about the centre of mass, without potential.
Diagnostics measureKinematics(const VectorX& mass, const State& state);

}  // namespace zsculpt

namespace zsculpt {

/// Random initial velocity of RMS size `amplitude` per vertex with zero net momentum
/// (the command line's --perturb AMP --seed N). Deterministic for a seed.
void randomVelocity(const VectorX& mass, double amplitude, unsigned seed, Points& velocity);

/// A rigid spin: v_i = omega x (r_i - centre of mass).
void spinVelocity(const VectorX& mass, const Points& position, const Vec3& omega,
                  Points& velocity);

}  // namespace zsculpt
