// Position constraints (paper section 6): the cost of a cycle with many pins while one of
// them is dragged, as a sculptor does when a border is pinned and a handle is pulled.
//
//   zsculpt_benchmarks --benchmark_filter=Pins --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true    (one command line)
// Arguments: the number of pinned vertices (the first ones of the model) and the torus's U:
// a U x U torus (40: 1600 vertices; 316: 99856), mu 0.01, kappa 9.5, angle springs 0.05,
// period 0.5 T_max. The first pin's target moves 2 mm every cycle and back to the start
// every 200 cycles (a constrained cycle of trials: docs/performance.md).

#include <benchmark/benchmark.h>

#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/simulation/simulation.h"

namespace {

using namespace zsculpt;

void BM_PinsDragCycle(benchmark::State& state) {
  UniformProperties u;
  u.mass = 0.01;
  u.stiffness = 9.5;
  u.angularStiffness = 0.05;
  const Index torus = static_cast<Index>(state.range(1));
  const Model model = Model::fromMesh(makeTorus(torus, torus), u);
  SimulationSettings settings;
  settings.period = 0.5 * criticalPeriod(SystemMatrices(model));
  Simulation sim(model, settings);
  const Index pins = static_cast<Index>(state.range(0));
  Index handle = -1;
  for (Index v = 0; v < pins; ++v) {
    const Index id = sim.addPositionConstraint(v);
    if (v == 0) handle = id;
  }
  const Vec3 start = sim.state().position.row(0).transpose();
  sim.step();  // builds the response
  long cycle = 0;
  for (auto _ : state) {
    const double s = 0.002 * static_cast<double>(++cycle % 200);
    sim.setConstraintTarget(handle, start + Vec3(0.0, 0.0, s));
    sim.step();
    benchmark::DoNotOptimize(sim.state().position.data());
  }
  state.counters["steps"] = static_cast<double>(sim.constraintReport().steps);
  state.counters["error"] = sim.constraintReport().positionError;
}
BENCHMARK(BM_PinsDragCycle)
    ->Args({4, 40})
    ->Args({40, 40})
    ->Args({160, 40})
    ->Args({4, 316})
    ->Unit(benchmark::kMicrosecond);

}  // namespace
