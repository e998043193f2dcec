// Torus-II at T / T_max under a storm of forces (no damping), stepped by velocity Verlet with
// a candidate kick filter applied through Omega^2 (docs/solver.md, "Why long storms run
// away"). The filters are those of default_filters.cpp: kick (the default), kick2,
// kick-cubic, kick-low.
//
//   experiment_soak_filters CYCLES RATIO FILTER
//
// Every 5000 cycles: total energy E, the loads' work W (sum F . dx), E - W and the largest
// speed. Stops when E exceeds 1000 (W + 1).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/forces.h"
#include "zsculpt/physics/matrices.h"

using namespace zsculpt;

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: %s CYCLES RATIO FILTER\n", argv[0]);
    return 2;
  }
  const long cycles = std::atol(argv[1]);
  const double ratio = std::atof(argv[2]);
  const std::string filter = argv[3];
  // Coefficients of phi(x) = sum c_k x^k, x = T^2 Omega^2.
  std::vector<double> c;
  if (filter == "kick")
    c = {1.0, -1.0 / 12.0};
  else if (filter == "kick2")
    c = {1.0, -1.0 / 6.0, 1.0 / 144.0};
  else if (filter == "kick-cubic")
    c = {1.0, -1.0 / 8.0, 1.0 / 192.0};
  else if (filter == "kick-low")
    c = {1.0, -0.182859, 0.0100009, -6.29554e-5};
  else {
    std::fprintf(stderr, "experiment: %s: unknown filter\n", filter.c_str());
    return 2;
  }
  UniformProperties values;
  values.mass = 0.01;
  values.stiffness = 9.5;
  const Model model = Model::fromMesh(makeBuiltin("builtin:torus:40:40"), values);
  const SystemMatrices system(model);
  const double t = ratio * criticalPeriod(system);
  const Index n = model.mesh.numVertices();
  const SparseRowMatrix& omega2 = system.omega2();
  std::mt19937_64 rng(1);
  std::uniform_int_distribution<int> nextStorm(1, 9);
  auto randomVector = [&](double scale) {
    std::normal_distribution<double> d(0, scale);
    return Vec3(d(rng), d(rng), d(rng));
  };
  struct Load {
    Index vertex;
    Vec3 force;
    long until;
  };
  std::vector<Load> loads;
  State state = State::atRest(model.mesh);
  Points external = Points::Zero(n, 3), force(n, 3), acceleration(n, 3), term(n, 3), kick(n, 3),
         before;
  auto filtered = [&]() {  // kick = phi(T^2 Omega^2) acceleration, by Horner's rule
    kick = c.back() * acceleration;
    for (size_t k = c.size() - 1; k-- > 0;) {
      term = omega2 * kick;
      kick = c[k] * acceleration + t * t * term;
    }
  };
  auto accelerate = [&]() {
    force.setZero();
    accumulateInternalForces(model, state.position, force);
    force += external;
    acceleration = system.inverseMass().asDiagonal() * force;
    filtered();
  };
  const double e0 = measure(model, state).total();
  double work = 0;
  long stormAt = nextStorm(rng);
  for (long k = 1; k <= cycles; ++k) {
    if (k == stormAt) {
      const Index v = std::uniform_int_distribution<Index>(0, n - 1)(rng);
      const long length = std::uniform_int_distribution<long>(5, 15)(rng);
      loads.push_back({v, randomVector(0.02), k + length});
      stormAt = k + nextStorm(rng);
    }
    external.setZero();
    std::erase_if(loads, [k](const Load& l) { return l.until < k; });
    for (const Load& l : loads) external.row(l.vertex) += l.force.transpose();
    accelerate();
    before = state.position;
    state.velocity += (t / 2) * kick;
    state.position += t * state.velocity;
    accelerate();
    state.velocity += (t / 2) * kick;
    work += (external.array() * (state.position - before).array()).sum();
    if (k % 5000 == 0) {
      const double e = measure(model, state).total();
      std::printf("%ld E %.4g W %.4g E-E0-W %.3g max speed %.3g\n", k, e, work, e - e0 - work,
                  state.velocity.rowwise().norm().maxCoeff());
      std::fflush(stdout);
      if (!std::isfinite(e) || e > 1e3 * (work + 1)) return 3;
    }
  }
  return 0;
}
