#include "zsculpt/physics/diagnostics.h"

namespace zsculpt {

Diagnostics measureKinematics(const VectorX& mass, const State& state) {
  Diagnostics d;
  const Index n = static_cast<Index>(state.position.rows());
  Vec3 weighted = Vec3::Zero();
  for (Index i = 0; i < n; ++i) {
    const Vec3 v = state.velocity.row(i).transpose();
    d.kinetic += 0.5 * mass[i] * v.squaredNorm();
    d.momentum += mass[i] * v;
    weighted += mass[i] * state.position.row(i).transpose();
    d.totalMass += mass[i];
  }
  d.centreOfMass = weighted / d.totalMass;
  for (Index i = 0; i < n; ++i) {
    const Vec3 r = state.position.row(i).transpose() - d.centreOfMass;
    d.angularMomentum += mass[i] * r.cross(Vec3(state.velocity.row(i).transpose()));
  }
  return d;
}

namespace {

Diagnostics withPotential(const Model& model, const State& state,
                          const PotentialEnergy& potential) {
  Diagnostics d = measureKinematics(model.properties.mass, state);
  d.potential = potential;
  d.partial = d.total() / static_cast<double>(model.mesh.numVertices());
  return d;
}

}  // namespace

Diagnostics measure(const Model& model, const State& state) {
  return withPotential(model, state, potentialEnergy(model, state.position));
}

Diagnostics measure(const Model& model, const State& state, const PotentialEnergy& internal) {
  PotentialEnergy potential = internal;
  potential.gravity = gravityEnergy(model.properties, state.position);
  return withPotential(model, state, potential);
}

}  // namespace zsculpt

#include <cmath>
#include <random>

namespace zsculpt {

void randomVelocity(const VectorX& mass, double amplitude, unsigned seed, Points& velocity) {
  const Index n = static_cast<Index>(mass.size());
  velocity.resize(n, 3);
  // A fixed generator and our own Box-Muller: the same velocities on every platform.
  std::mt19937_64 rng(seed);
  auto uniform = [&]() { return (static_cast<double>(rng() >> 11) + 0.5) * 0x1.0p-53; };
  for (Index i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c)
      velocity(i, c) = std::sqrt(-2.0 * std::log(uniform())) * std::cos(6.283185307179586 * uniform());
  Eigen::RowVector3d momentum = Eigen::RowVector3d::Zero();
  for (Index i = 0; i < n; ++i) momentum += mass[i] * velocity.row(i);
  const Eigen::RowVector3d drift = momentum / mass.sum();
  for (Index i = 0; i < n; ++i) velocity.row(i) -= drift;
  const double rms = std::sqrt(velocity.squaredNorm() / std::max<Index>(n, 1));
  if (rms > 0.0) velocity *= amplitude / rms;
}

void spinVelocity(const VectorX& mass, const Points& position, const Vec3& omega,
                  Points& velocity) {
  Vec3 centre = Vec3::Zero();
  for (Index i = 0; i < position.rows(); ++i) centre += mass[i] * position.row(i).transpose();
  centre /= mass.sum();
  velocity.resize(position.rows(), 3);
  for (Index i = 0; i < position.rows(); ++i)
    velocity.row(i) = omega.cross(Vec3(position.row(i).transpose() - centre)).transpose();
}

void pokeVelocity(const VectorX& mass, const Points& position, Index centre, double width,
                  double speed, const Vec3& direction, Points& velocity) {
  const Index n = position.rows();
  velocity.resize(n, 3);
  const Eigen::RowVector3d along = speed * direction.normalized().transpose();
  const Eigen::RowVector3d origin = position.row(centre);
  Eigen::RowVector3d momentum = Eigen::RowVector3d::Zero();
  for (Index i = 0; i < n; ++i) {
    const double d2 = (position.row(i) - origin).squaredNorm();
    velocity.row(i) = std::exp(-d2 / (2.0 * width * width)) * along;
    momentum += mass[i] * velocity.row(i);
  }
  const Eigen::RowVector3d drift = momentum / mass.sum();
  for (Index i = 0; i < n; ++i) velocity.row(i) -= drift;
}

}  // namespace zsculpt
