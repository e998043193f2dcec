// Semi-rigid motion (paper section 4.3): the wall time to simulate one second of a stiff
// model with and without the stiffness cap kappa_0. Without the cap the period is set by
// the stiffest spring (T_max ~ 1 / sqrt(kappa)); with it by kappa_0, and the stiff part of
// every force goes to the rigid body. Also the cost of a cycle with pinned vertices.
//
//   zsculpt_benchmarks --benchmark_filter=Rigid --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true    (one command line)
// Arguments: kappa (N/m) of every vertex, then the cap (0: none). Model: Torus-I of Table 1
// refined to 20 x 20 quads (400 vertices), mu 0.1, angle springs 0.05; period 0.5 T_max.

#include <benchmark/benchmark.h>

#include "zsculpt/mesh/builtin.h"
#include "zsculpt/physics/matrices.h"
#include "zsculpt/simulation/simulation.h"

namespace {

using namespace zsculpt;

Model stiffTorus(double kappa, double cap) {
  UniformProperties u;
  u.mass = 0.1;
  u.stiffness = kappa;
  u.angularStiffness = 0.05;
  if (cap > 0.0) u.stiffnessCap = cap;
  return Model::fromMesh(makeTorus(20, 20), u);
}

void runOneSecond(benchmark::State& state, const Model& model, bool pinned) {
  SimulationSettings settings;
  settings.period = 0.5 * criticalPeriod(SystemMatrices(model));
  const long steps = static_cast<long>(std::ceil(1.0 / settings.period));
  State start = State::atRest(model.mesh);
  randomVelocity(model.properties.mass, 0.05, 1, start.velocity);
  for (auto _ : state) {
    state.PauseTiming();
    Simulation sim(model, settings);
    sim.setState(start);
    sim.addForce(TimedLoad{7, Vec3(0.0, 0.0, 1.153)});
    if (pinned)
      for (Index v : {0, 5, 210, 215}) sim.addPositionConstraint(v);
    state.ResumeTiming();
    for (long k = 0; k < steps; ++k) sim.step();
    benchmark::DoNotOptimize(sim.state().position.data());
  }
  state.counters["dt"] = settings.period;
  state.counters["steps"] = static_cast<double>(steps);
}

void BM_RigidOneSecond(benchmark::State& state) {
  const Model model =
      stiffTorus(static_cast<double>(state.range(0)), static_cast<double>(state.range(1)));
  runOneSecond(state, model, false);
}
BENCHMARK(BM_RigidOneSecond)
    ->Args({5000, 0})
    ->Args({5000, 50})
    ->Args({5000, 5})
    ->Unit(benchmark::kMillisecond);

void BM_RigidOneSecondPinned(benchmark::State& state) {
  const Model model =
      stiffTorus(static_cast<double>(state.range(0)), static_cast<double>(state.range(1)));
  runOneSecond(state, model, true);
}
BENCHMARK(BM_RigidOneSecondPinned)->Args({5000, 0})->Args({5000, 5})->Unit(benchmark::kMillisecond);

}  // namespace
