// The interactive application's budgets (paper section 7, Table 1's "Disp" and "Solv"
// columns): solver time per cycle, the cost of publishing a cycle to the display, and the
// frame time of the renderer (offscreen, OSMesa/llvmpipe: a lower bound on the window's
// speed with a GPU), for Torus-II (40 x 40 quads, 1600 vertices) and a 100k-vertex torus.
//
//   build/bench/zsculpt_benchmarks --benchmark_filter=App

#include <benchmark/benchmark.h>

#include <memory>

#include "zsculpt/app/session.h"
#include "zsculpt/app/solver_thread.h"
#include "zsculpt/app/view.h"
#include "zsculpt/render/renderer.h"

namespace {

using namespace zsculpt;
using namespace zsculpt::app;

// Torus-II of Table 1 (mu = 0.01, kappa = 9.5) and a torus of 316 x 316 = 99856 vertices,
// at half of equation 5's T_max, with light angle springs.
SessionSetup torusSetup(int u) {
  io::SceneDescription scene;
  scene.mesh = "builtin:torus:" + std::to_string(u) + ":" + std::to_string(u);
  scene.properties.mass = 0.01;
  scene.properties.stiffness = 9.5;
  scene.properties.angularStiffness = 0.01;
  scene.properties.damping = 0.001;
  scene.simulation.dtRatio = 0.5;
  scene.simulation.perturb = 0.01;
  scene.forces.push_back({0, Vec3(0, 0, 0.05), 0.0, 1e9});
  return sessionSetupFromScene(scene);
}

// One solver cycle (section 6): loads, step, divergence check.
void BM_AppSolverCycle(benchmark::State& state) {
  Session session(torusSetup(static_cast<int>(state.range(0))));
  session.apply(Play{});
  for (auto _ : state) session.advance();
  state.counters["vertices"] = session.model().mesh.numVertices();
  state.counters["period_s"] = session.simulation().period();
  // Table 1's criterion: the solver keeps up while a cycle takes less than T.
}
BENCHMARK(BM_AppSolverCycle)->Arg(40)->Arg(316)->Unit(benchmark::kMillisecond)->UseRealTime();

// A cycle with a drag in progress (a moving position constraint).
void BM_AppSolverCycleDragging(benchmark::State& state) {
  Session session(torusSetup(static_cast<int>(state.range(0))));
  const Vec3 start = session.state().position.row(0).transpose();
  session.apply(DragStart{0, start});
  double z = 0.0;
  double steps = 0.0;
  for (auto _ : state) {
    z += 1e-3;
    session.apply(DragMove{start + Vec3(0, 0, z)});
    session.advance();
    steps += session.simulation().substeps();
  }
  // Steps per cycle: a fast drag splits the cycle (SimulationSettings::substepStrain).
  state.counters["steps_per_cycle"] = steps / static_cast<double>(state.iterations());
}
BENCHMARK(BM_AppSolverCycleDragging)
    ->Arg(40)
    ->Arg(316)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// Publishing: copy positions, velocities, the display scalar, measure energy and momenta,
// after a cycle as in the running application (whose diagnostics take the spring energies
// from the cycle's step: Simulation::diagnostics).
void BM_AppPublish(benchmark::State& state) {
  Session session(torusSetup(static_cast<int>(state.range(0))));
  session.apply(Play{});
  session.advance();
  Snapshot snapshot;
  session.fill(snapshot, Property::Stiffness);
  for (auto _ : state) {
    session.fill(snapshot, Property::Stiffness);
    benchmark::DoNotOptimize(snapshot.diagnostics.kinetic);
  }
}
BENCHMARK(BM_AppPublish)->Arg(40)->Arg(316)->Unit(benchmark::kMillisecond)->UseRealTime();

// The solver thread running free (no real-time pacing): cycles per second including the
// triple-buffer publish, with the benchmark thread reading snapshots like a display.
void BM_AppSolverThread(benchmark::State& state) {
  for (auto _ : state) {
    state.PauseTiming();
    auto session = std::make_unique<Session>(torusSetup(static_cast<int>(state.range(0))));
    SolverThreadOptions options;
    options.realTime = false;
    options.startRunning = true;
    options.maxCycles = static_cast<std::uint64_t>(state.range(1));
    SolverThread solver(std::move(session), options);
    state.ResumeTiming();
    solver.start();
    while (!solver.finished()) benchmark::DoNotOptimize(solver.latest().time);
    solver.stop();
  }
  state.SetItemsProcessed(state.iterations() * state.range(1));  // items = cycles
}
BENCHMARK(BM_AppSolverThread)
    ->Args({40, 200})
    ->Args({316, 10})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// One display frame: the frame from the snapshot, subdivision refresh, draw, read back
// (offscreen at 1280 x 720; the window skips the read-back).
void BM_AppFrame(benchmark::State& state) {
  std::unique_ptr<render::OffscreenRenderer> renderer;
  try {
    renderer = std::make_unique<render::OffscreenRenderer>();
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
    return;
  }
  Session session(torusSetup(static_cast<int>(state.range(0))));
  const Mesh& mesh = session.model().mesh;
  FrameBuilder builder(mesh);
  ViewSettings view;
  view.levels = affordableLevels(mesh, 2);
  view.colourByProperty = true;
  builder.setLevels(view.levels);
  Snapshot snapshot;
  session.fill(snapshot, Property::Stiffness);
  render::Frame& first = builder.build(snapshot, view, render::Camera{});
  render::frameScene(first, 1280.0 / 720.0);
  const render::Camera camera = first.camera;
  for (auto _ : state) {
    const render::Image& image = renderer->render(builder.build(snapshot, view, camera), 1280, 720);
    benchmark::DoNotOptimize(image.rgba.data());
  }
  state.counters["levels"] = view.levels;
  state.counters["drawn_vertices"] =
      builder.stencil() ? builder.stencil()->numRefinedVertices() : mesh.numVertices();
}
BENCHMARK(BM_AppFrame)->Arg(40)->Arg(316)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
