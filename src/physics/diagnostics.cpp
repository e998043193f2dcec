#include "zsculpt/physics/diagnostics.h"

#include <array>
#include <cstdint>

#include "zsculpt/core/parts.h"

#ifdef _OPENMP
#include <omp.h>
#endif

namespace zsculpt {

Diagnostics measureKinematics(const VectorX& mass, const State& state) {
  // Every cycle's diagnostics take this; serial, on a large model, it was two passes during
  // which the step's other thread waited. So each sum is taken in kParts fixed contiguous
  // parts, the parts on all threads, then added in part order: the same bits whatever the
  // thread count.
  constexpr int kParts = 64;
  struct Part {
    double kinetic = 0.0, mass = 0.0;
    Vec3 momentum = Vec3::Zero(), weighted = Vec3::Zero(), angular = Vec3::Zero();
  };
  std::array<Part, kParts> parts;
  const std::int64_t n = state.position.rows();
#ifdef _OPENMP
  const int threads = omp_in_parallel() ? 1 : omp_get_max_threads();
#else
  const int threads = 1;
#endif
  forEachPart<kParts>(n, threads, 50000, [&](int k, Index begin, Index end) {
    Part& p = parts[static_cast<size_t>(k)];
    for (Index i = begin; i < end; ++i) {
      const Vec3 v = state.velocity.row(i).transpose();
      p.kinetic += 0.5 * mass[i] * v.squaredNorm();
      p.momentum += mass[i] * v;
      p.weighted += mass[i] * state.position.row(i).transpose();
      p.mass += mass[i];
    }
  });
  Diagnostics d;
  Vec3 weighted = Vec3::Zero();
  for (const Part& p : parts) {
    d.kinetic += p.kinetic;
    d.momentum += p.momentum;
    weighted += p.weighted;
    d.totalMass += p.mass;
  }
  d.centreOfMass = weighted / d.totalMass;
  forEachPart<kParts>(n, threads, 50000, [&](int k, Index begin, Index end) {
    Part& p = parts[static_cast<size_t>(k)];
    for (Index i = begin; i < end; ++i) {
      const Vec3 r = state.position.row(i).transpose() - d.centreOfMass;
      p.angular += mass[i] * r.cross(Vec3(state.velocity.row(i).transpose()));
    }
  });
  for (const Part& p : parts) d.angularMomentum += p.angular;
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
      velocity(i, c) =
          std::sqrt(-2.0 * std::log(uniform())) * std::cos(6.283185307179586 * uniform());
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

Vec3 weightedCentre(const VectorX& mass, const Points& x, int threads) {
  // (sum m x, sum m)
  const Eigen::Vector4d total =
      sumInParts<64>(x.rows(), threads, 50000, Eigen::Vector4d(Eigen::Vector4d::Zero()),
                     [&](Index begin, Index end, Eigen::Vector4d& sum) {
                       Vec3 weighted = sum.head<3>();
                       double m = sum[3];
                       for (Index i = begin; i < end; ++i) {
                         weighted += mass[i] * x.row(i).transpose();
                         m += mass[i];
                       }
                       sum << weighted, m;
                     });
  return total.head<3>() / total[3];
}

}  // namespace zsculpt
