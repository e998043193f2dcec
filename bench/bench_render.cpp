// Offscreen rendering: one 1280 x 720 frame of a ~100k-face surface (OSMesa, llvmpipe),
// the per-frame path of `zsculpt render` and the window: refresh positions (and the
// subdivision), normals, upload, draw with 4x MSAA, resolve, read back.
//
//   ./zsculpt_benchmarks --benchmark_filter=Render --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true
//
// Numbers are in docs/rendering.md.

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <ctime>

#include "zsculpt/mesh/builtin.h"
#include "zsculpt/render/plot.h"
#include "zsculpt/render/renderer.h"
#include "zsculpt/subdivision/subdivision.h"

namespace zsculpt::render {
namespace {

double processCpuMilliseconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_nsec) * 1e-6;
}

OffscreenRenderer& offscreen() {
  static OffscreenRenderer renderer;
  return renderer;
}

// Moves the control vertices a little every frame, as a simulation does.
void wobble(const Points& rest, Points& positions, int frame) {
  const double phase = 0.1 * frame;
  for (Index v = 0; v < rest.rows(); ++v) {
    positions.row(v) = rest.row(v) * (1.0 + 0.02 * std::sin(phase + 0.01 * v));
  }
}

void runFrames(benchmark::State& state, const Mesh& mesh, const SubdivisionStencil* stencil,
               bool png) {
  Points positions = mesh.positions();
  Frame frame;
  frame.mesh = &mesh;
  frame.stencil = stencil;
  frame.positions = &positions;
  frame.normals = NormalMode::BestPlane;
  frameScene(frame, 1280.0 / 720.0);
  OffscreenRenderer& renderer = offscreen();
  renderer.render(frame, 1280, 720);  // first frame: buffers and topology
  int count = 0;
  const double cpuStart = processCpuMilliseconds();
  for (auto _ : state) {
    wobble(mesh.positions(), positions, ++count);
    const Image& image = renderer.render(frame, 1280, 720);
    if (png) benchmark::DoNotOptimize(encodePng(image));
    benchmark::DoNotOptimize(image.rgba.data());
  }
  // CPU time of the whole process (llvmpipe renders on its own threads) per frame: on a
  // busy machine it varies less than the wall time.
  state.counters["process_cpu_ms"] =
      (processCpuMilliseconds() - cpuStart) / std::max<double>(1.0, static_cast<double>(count));
  const Index faces = stencil != nullptr ? stencil->refinedFaces().rows() : mesh.numFaces();
  state.counters["faces"] = static_cast<double>(faces);
}

// makeTorus(316, 316): 99,856 quads drawn as the control mesh (levels = 0).
void BM_RenderTorus100kLevel0(benchmark::State& state) {
  static const Mesh mesh = makeTorus(316, 316);
  runFrames(state, mesh, nullptr, false);
}
BENCHMARK(BM_RenderTorus100kLevel0)->Unit(benchmark::kMillisecond)->MinTime(2.0)->UseRealTime();

// makeTorus(80, 80) refined twice: 6,400 -> 102,400 faces; includes the stencil product.
void BM_RenderTorus100kLevel2(benchmark::State& state) {
  static const Mesh mesh = makeTorus(80, 80);
  SubdivisionOptions options;
  options.levels = 2;
  static const SubdivisionStencil stencil(mesh, options);
  runFrames(state, mesh, &stencil, false);
}
BENCHMARK(BM_RenderTorus100kLevel2)->Unit(benchmark::kMillisecond)->MinTime(2.0)->UseRealTime();

// The same frame encoded as PNG (what `zsculpt render` does per written frame).
void BM_RenderTorus100kLevel0Png(benchmark::State& state) {
  static const Mesh mesh = makeTorus(316, 316);
  runFrames(state, mesh, nullptr, true);
}
BENCHMARK(BM_RenderTorus100kLevel0Png)->Unit(benchmark::kMillisecond)->MinTime(2.0)->UseRealTime();

// A three-panel energy and momentum plot of 10,000 steps (CPU).
void BM_PlotEnergyMomentum10k(benchmark::State& state) {
  EnergyMomentumSeries d;
  for (int i = 0; i < 10000; ++i) {
    const double t = 1e-3 * i;
    const double k = std::exp(-0.3 * t) * std::pow(std::sin(3.0 * t), 2);
    d.time.push_back(t);
    d.kinetic.push_back(k);
    d.potential.push_back(std::exp(-0.3 * t) - k);
    d.total.push_back(std::exp(-0.3 * t));
    for (auto* c : {&d.px, &d.py, &d.pz, &d.lx, &d.ly}) c->push_back(1e-16 * std::sin(t));
    d.lz.push_back(0.5);
  }
  const auto panels = energyMomentumPanels(d);
  for (auto _ : state) benchmark::DoNotOptimize(renderPlot(panels).rgba.data());
}
BENCHMARK(BM_PlotEnergyMomentum10k)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace zsculpt::render
