// The internal forces alone (sections 5.1 and 5.2: radial springs and every angle spring),
// the part of every scheme's step that no scheme avoids: symplectic Euler's step is one of
// these and an update. Tori of U x U vertices with radial and angle springs, as
// `zsculpt bench --scaling` builds them, slightly deformed so that no angle is at rest.
//
//   build/bench/zsculpt_benchmarks --benchmark_filter=InternalForces

#include <benchmark/benchmark.h>

#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/diagnostics.h"
#include "zsculpt/physics/forces.h"
#include "zsculpt/physics/properties.h"

namespace {

using namespace zsculpt;

// Arguments: U (the torus is U x U), the thread count, and 1 to sum the energy on the way
// (as the application does every cycle; the bench's stepper does not).
void BM_InternalForces(benchmark::State& state) {
  const auto u = static_cast<Index>(state.range(0));
  const int threads = static_cast<int>(state.range(1));
  const bool withEnergy = state.range(2) != 0;
  UniformProperties values;
  values.mass = 0.01;
  values.stiffness = 9.5;
  values.angularStiffness = 0.05;
  const Model model = Model::fromMesh(makeTorus(u, u), values);
  Points position = model.mesh.positions();
  Points offset = Points::Zero(position.rows(), 3);
  randomVelocity(model.properties.mass, 1e-3, 7, offset);
  position += offset;
  ForceKernel kernel(model, threads);
  Points force = Points::Zero(position.rows(), 3);
  for (auto _ : state) {
    kernel.compute(model, position, force, threads, withEnergy);
    benchmark::DoNotOptimize(force.data());
  }
  state.counters["vertices"] = static_cast<double>(position.rows());
  state.counters["angle_springs"] = static_cast<double>(model.angles.size());
}
BENCHMARK(BM_InternalForces)
    ->Args({316, 1, 0})
    ->Args({316, 1, 1})
    ->Args({316, 2, 0})
    ->Args({316, 2, 1})
    ->Args({1000, 2, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
